"""Classic control tasks in pure JAX (gymnasium's dynamics), for fast tests and examples of the Env contract."""

from angora_jax.envs.classic.cartpole import CartPole
from angora_jax.envs.classic.pendulum import Pendulum
from angora_jax.envs.registry import register

register("CartPole", CartPole)
register("Pendulum", Pendulum)

__all__ = ["CartPole", "Pendulum"]
