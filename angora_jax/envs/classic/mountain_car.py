"""Mountain car with gymnasium's dynamics (Moore 1990): `MountainCar-v0` (3 discrete pushes) and
`MountainCarContinuous-v0` (a force in [-1, 1]), in pure JAX."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from angora_jax.envs.core import ActionSpec, Env, Sensation, episode_limit


class MountainCar(Env):
    """Drive an underpowered car up the right hill of the valley y = sin(3x): it must swing back and forth first.

    Physics state and observation (proprioception) are `[position, velocity]` (position in [-1.2, 0.6], velocity in
    [-0.07, 0.07] per step). continuous=False (`MountainCar-v0`): actions 0, 1, 2 push left, not at all, right
    (0.001 each); reward -1 per step; the goal is position >= 0.5; truncated after 200 steps. continuous=True
    (`MountainCarContinuous-v0`): a force in [-1, 1] times 0.0015; reward -0.1 x force^2 per step and +100 at the
    goal, position >= 0.45; truncated after 999 steps. Episodes start at rest at a position drawn from
    [-0.6, -0.4].
    """

    min_position, max_position, max_speed, gravity = -1.2, 0.6, 0.07, 0.0025

    def __init__(self, continuous: bool = False, max_episode_steps: int | None = None):
        self.continuous = continuous
        if continuous:
            self.action_spec = ActionSpec(low=-jnp.ones((1,)), high=jnp.ones((1,)))
        else:
            self.action_spec = ActionSpec(low=jnp.zeros((0,)), high=jnp.zeros((0,)), num_actions=3)
        self.goal_position = 0.45 if continuous else 0.5
        self.max_episode_steps = episode_limit((999 if continuous else 200) if max_episode_steps is None
                                               else max_episode_steps)
        self.dt = 1.0  # the dynamics are per step; gymnasium gives no time unit

    def _reset(self, key: jax.Array):
        physics = jnp.stack([jax.random.uniform(key, (), minval=-0.6, maxval=-0.4), jnp.float32(0.0)])
        return physics, Sensation.make(proprioception=physics), {}

    def _step(self, physics: jax.Array, info: dict, action: jax.Array, key: jax.Array):
        position, velocity = physics
        if self.continuous:
            push = jnp.clip(action[0], -1.0, 1.0) * 0.0015
        else:
            push = (action - 1) * 0.001
        velocity = jnp.clip(velocity + push - self.gravity * jnp.cos(3 * position), -self.max_speed, self.max_speed)
        position = jnp.clip(position + velocity, self.min_position, self.max_position)
        velocity = jnp.where((position == self.min_position) & (velocity < 0), 0.0, velocity)
        terminated = (position >= self.goal_position) & (velocity >= 0)
        if self.continuous:
            reward = jnp.where(terminated, 100.0, 0.0) - 0.1 * action[0] ** 2
        else:
            reward = jnp.float32(-1.0)
        physics = jnp.stack([position, velocity])
        return physics, Sensation.make(proprioception=physics), reward, terminated, info, {}
