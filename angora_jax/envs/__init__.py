"""Environments: the pure `reset`/`step` contract, the task registry and the tasks (each task's module is imported
when the task is first made or asked about: `registry.SHIPPED_TASKS`)."""

from typing import TYPE_CHECKING

from angora_jax.lazy_names import lazy_names

if TYPE_CHECKING:  # the names this package gives, each imported when first used (angora_jax.lazy_names)
    from angora_jax.envs.core import ActionSpec, Env, Sensation, State
    from angora_jax.envs.registry import list_tasks, make, register

__all__ = ["ActionSpec", "Env", "Sensation", "State", "list_tasks", "make", "register"]

lazy_names(__name__)
