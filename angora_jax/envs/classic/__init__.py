"""Classic control tasks in pure JAX (gymnasium's dynamics), for fast tests and examples of the Env contract."""

import functools

from angora_jax.envs.classic.acrobot import Acrobot
from angora_jax.envs.classic.cartpole import CartPole
from angora_jax.envs.classic.mountain_car import MountainCar
from angora_jax.envs.classic.pendulum import Pendulum
from angora_jax.envs.registry import register

register("CartPole", CartPole)
register("Pendulum", Pendulum)
register("Acrobot", Acrobot)
register("MountainCar", MountainCar)
register("MountainCarContinuous", functools.partial(MountainCar, continuous=True))

__all__ = ["Acrobot", "CartPole", "MountainCar", "Pendulum"]
