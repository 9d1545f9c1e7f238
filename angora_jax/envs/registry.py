"""Task registry: `make(name, **options)` builds an environment by name; `list_tasks()` lists the names."""

from __future__ import annotations

from collections.abc import Callable

from angora_jax.envs.core import Env
from angora_jax.envs.host import PREFIX, make_gymnasium
from angora_jax.registry import Registry

TASKS: Registry[Callable[..., Env]] = Registry("task", "tasks")


def register(name: str, factory: Callable[..., Env]) -> None:
    """Make `factory(**options) -> Env` available as `make(name, **options)`."""
    TASKS.register(name, factory)


def list_tasks() -> list[str]:
    """Names of all registered tasks, sorted."""
    return TASKS.names()


def make(name: str, **options) -> Env:
    """Build the task `name`; `options` go to its constructor (e.g. reward coefficients, episode length).
    `gym:<id>` is any Gymnasium environment, simulated on the host (`angora_jax.envs.host`)."""
    if is_gymnasium(name):
        return make_gymnasium(name, **options)
    return TASKS.get(name)(**options)


def is_gymnasium(name: str) -> bool:
    """Whether task `name` is a Gymnasium id run on the host (`gym:<id>`) rather than a registered task."""
    return name.startswith(PREFIX)
