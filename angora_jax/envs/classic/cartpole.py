"""CartPole with gymnasium's `CartPole-v1` dynamics (Barto et al. 1983), in pure JAX."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from angora_jax.envs.core import ActionSpec, Env, Sensation, episode_limit


class CartPole(Env):
    """Push a cart left (action 0) or right (1) to keep a pole upright; reward 1 per step.

    Physics state is `[x, x_dot, theta, theta_dot]` (m, m/s, rad, rad/s), observed as proprioception. The episode
    terminates when |x| > 2.4 m or |theta| > 12 degrees and is truncated after `max_episode_steps` (500).
    """

    gravity = 9.8
    mass_cart = 1.0
    mass_pole = 0.1
    half_length = 0.5
    force_mag = 10.0
    x_limit = 2.4
    theta_limit = 12 * 2 * jnp.pi / 360

    def __init__(self, max_episode_steps: int = 500):
        self.action_spec = ActionSpec(low=jnp.zeros((0,)), high=jnp.zeros((0,)), num_actions=2)
        self.max_episode_steps = episode_limit(max_episode_steps)
        self.dt = 0.02

    def _reset(self, key: jax.Array):
        physics = jax.random.uniform(key, (4,), minval=-0.05, maxval=0.05)
        return physics, Sensation.make(proprioception=physics), {}

    def _step(self, physics: jax.Array, info: dict, action: jax.Array, key: jax.Array):
        x, x_dot, theta, theta_dot = physics
        force = jnp.where(action == 1, self.force_mag, -self.force_mag)
        total_mass = self.mass_cart + self.mass_pole
        pole_moment = self.mass_pole * self.half_length
        cos, sin = jnp.cos(theta), jnp.sin(theta)
        temp = (force + pole_moment * theta_dot**2 * sin) / total_mass
        theta_acc = (self.gravity * sin - cos * temp) / (
            self.half_length * (4.0 / 3.0 - self.mass_pole * cos**2 / total_mass)
        )
        x_acc = temp - pole_moment * theta_acc * cos / total_mass
        # Explicit Euler, in gymnasium's order, so trajectories match CartPole-v1.
        physics = jnp.stack(
            [x + self.dt * x_dot, x_dot + self.dt * x_acc, theta + self.dt * theta_dot, theta_dot + self.dt * theta_acc]
        )
        terminated = (jnp.abs(physics[0]) > self.x_limit) | (jnp.abs(physics[2]) > self.theta_limit)
        return physics, Sensation.make(proprioception=physics), jnp.float32(1.0), terminated, info, {}
