"""Pendulum swing-up with gymnasium's `Pendulum-v1` dynamics, in pure JAX."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from angora_jax.envs.core import ActionSpec, Env, Sensation, episode_limit


class Pendulum(Env):
    """Swing a pendulum up and hold it with a torque in [-2, 2] N m.

    Physics state is `[theta, theta_dot]` (rad from upright, rad/s); the observation (proprioception) is
    `[cos theta, sin theta, theta_dot]`. Reward is -(theta^2 + 0.1 theta_dot^2 + 0.001 torque^2) with theta
    wrapped to [-pi, pi); episodes never terminate and are truncated after `max_episode_steps` (200).
    """

    gravity = 10.0
    mass = 1.0
    length = 1.0
    max_speed = 8.0
    max_torque = 2.0

    def __init__(self, max_episode_steps: int = 200):
        self.action_spec = ActionSpec(low=jnp.full((1,), -self.max_torque), high=jnp.full((1,), self.max_torque))
        self.max_episode_steps = episode_limit(max_episode_steps)
        self.dt = 0.05

    @staticmethod
    def _observe(physics: jax.Array) -> Sensation:
        theta, theta_dot = physics
        return Sensation.make(proprioception=jnp.stack([jnp.cos(theta), jnp.sin(theta), theta_dot]))

    def _reset(self, key: jax.Array):
        physics = jax.random.uniform(key, (2,), minval=jnp.array([-jnp.pi, -1.0]), maxval=jnp.array([jnp.pi, 1.0]))
        return physics, self._observe(physics), {}

    def _step(self, physics: jax.Array, info: dict, action: jax.Array, key: jax.Array):
        theta, theta_dot = physics
        torque = jnp.clip(action[0], -self.max_torque, self.max_torque)
        wrapped = (theta + jnp.pi) % (2 * jnp.pi) - jnp.pi
        cost = wrapped**2 + 0.1 * theta_dot**2 + 0.001 * torque**2
        theta_dot = (
            theta_dot
            + (3 * self.gravity / (2 * self.length) * jnp.sin(theta) + 3.0 / (self.mass * self.length**2) * torque)
            * self.dt
        )
        theta_dot = jnp.clip(theta_dot, -self.max_speed, self.max_speed)
        physics = jnp.stack([theta + theta_dot * self.dt, theta_dot])
        return physics, self._observe(physics), -cost, jnp.bool_(False), info, {}
