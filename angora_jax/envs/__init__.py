"""Environments: the pure `reset`/`step` contract, the task registry and the tasks."""

from angora_jax.envs import classic, locomotion, myohand, shadow_hand  # noqa: F401  (register their tasks)
from angora_jax.envs.core import ActionSpec, Env, Sensation, State
from angora_jax.envs.registry import list_tasks, make, register

__all__ = ["ActionSpec", "Env", "Sensation", "State", "list_tasks", "make", "register"]
