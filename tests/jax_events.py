"""Listening to JAX's compile events in a test."""

import contextlib
from collections.abc import Iterator

import jax


@contextlib.contextmanager
def jax_events(event: str) -> Iterator[list[str]]:
    """Within: the names of the functions for which JAX reports `/jax/core/compile/<event>` (for instance
    `backend_compile_duration`, a compile or a read from the persistent cache, or `jaxpr_trace_duration`), in a
    list."""
    names = []

    def listen(name, _, fun_name="", **__):
        if name == f"/jax/core/compile/{event}":
            names.append(fun_name)

    jax.monitoring.register_event_duration_secs_listener(listen)
    try:
        yield names
    finally:
        jax.monitoring.unregister_event_duration_listener(listen)
