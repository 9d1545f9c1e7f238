"""angora_jax: goal-driven sensorimotor modeling in JAX (MJX Shadow-hand tasks, recurrent PPO)."""

from angora_jax.envs import list_tasks, make

make_env = make

__all__ = ["list_tasks", "make", "make_env"]
