"""Task registry: `make(name, **options)` builds an environment by name; `list_tasks()` lists the names."""

from __future__ import annotations

from collections.abc import Callable

from angora_jax.envs.core import Env

_FACTORIES: dict[str, Callable[..., Env]] = {}


def register(name: str, factory: Callable[..., Env]) -> None:
    """Make `factory(**options) -> Env` available as `make(name, **options)`."""
    if name in _FACTORIES:
        raise ValueError(f"Task {name!r} is already registered.")
    _FACTORIES[name] = factory


def list_tasks() -> list[str]:
    """Names of all registered tasks, sorted."""
    return sorted(_FACTORIES)


def make(name: str, **options) -> Env:
    """Build the task `name`; `options` go to its constructor (e.g. reward coefficients, episode length)."""
    try:
        factory = _FACTORIES[name]
    except KeyError:
        raise ValueError(f"Unknown task {name!r}. Known tasks: {', '.join(list_tasks())}.") from None
    return factory(**options)
