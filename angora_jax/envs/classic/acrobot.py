"""Acrobot with gymnasium's `Acrobot-v1` dynamics (Sutton 1996; Sutton and Barto 2018, "book" equations), in JAX."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from angora_jax.envs.core import ActionSpec, Env, Sensation, episode_limit


class Acrobot(Env):
    """Swing the tip of a two-link pendulum above the bar (height 1 link length over the pivot) with a torque of
    -1, 0 or +1 N m on the middle joint (actions 0, 1, 2); reward -1 per step until then, 0 at the step that reaches it.

    Physics state is `[theta1, theta2, dtheta1, dtheta2]` (rad, rad/s; theta1 from hanging down, theta2 relative to
    the first link), integrated by one fourth-order Runge-Kutta step of 0.2 s per action; the observation
    (proprioception) is `[cos theta1, sin theta1, cos theta2, sin theta2, dtheta1, dtheta2]`. Episodes terminate when
    -cos(theta1) - cos(theta1 + theta2) > 1 and are truncated after `max_episode_steps` (500).
    """

    link_length = 1.0  # m, both links
    link_mass = 1.0  # kg, both links
    link_com = 0.5  # m, centre of mass of each link from its joint
    link_moi = 1.0  # kg m^2, both links
    gravity = 9.8
    max_vel_1 = 4 * jnp.pi
    max_vel_2 = 9 * jnp.pi
    torques = (-1.0, 0.0, 1.0)

    def __init__(self, max_episode_steps: int = 500):
        self.action_spec = ActionSpec(low=jnp.zeros((0,)), high=jnp.zeros((0,)), num_actions=3)
        self.max_episode_steps = episode_limit(max_episode_steps)
        self.dt = 0.2

    @staticmethod
    def _observe(physics: jax.Array) -> Sensation:
        theta1, theta2, dtheta1, dtheta2 = physics
        features = [jnp.cos(theta1), jnp.sin(theta1), jnp.cos(theta2), jnp.sin(theta2), dtheta1, dtheta2]
        return Sensation.make(proprioception=jnp.stack(features))

    def _reset(self, key: jax.Array):
        physics = jax.random.uniform(key, (4,), minval=-0.1, maxval=0.1)
        return physics, self._observe(physics), {}

    def _derivatives(self, s: jax.Array, torque: jax.Array) -> jax.Array:
        m, l1, lc, moi, g = self.link_mass, self.link_length, self.link_com, self.link_moi, self.gravity
        theta1, theta2, dtheta1, dtheta2 = s
        d1 = m * lc**2 + m * (l1**2 + lc**2 + 2 * l1 * lc * jnp.cos(theta2)) + 2 * moi
        d2 = m * (lc**2 + l1 * lc * jnp.cos(theta2)) + moi
        phi2 = m * lc * g * jnp.cos(theta1 + theta2 - jnp.pi / 2.0)
        phi1 = (-m * l1 * lc * dtheta2**2 * jnp.sin(theta2) - 2 * m * l1 * lc * dtheta2 * dtheta1 * jnp.sin(theta2)
                + (m * lc + m * l1) * g * jnp.cos(theta1 - jnp.pi / 2) + phi2)
        ddtheta2 = (torque + d2 / d1 * phi1 - m * l1 * lc * dtheta1**2 * jnp.sin(theta2) - phi2) / (
            m * lc**2 + moi - d2**2 / d1)
        ddtheta1 = -(d2 * ddtheta2 + phi1) / d1
        return jnp.stack([dtheta1, dtheta2, ddtheta1, ddtheta2])

    def _step(self, physics: jax.Array, info: dict, action: jax.Array, key: jax.Array):
        torque = jnp.asarray(self.torques)[action]
        half = self.dt / 2
        k1 = self._derivatives(physics, torque)
        k2 = self._derivatives(physics + half * k1, torque)
        k3 = self._derivatives(physics + half * k2, torque)
        k4 = self._derivatives(physics + self.dt * k3, torque)
        s = physics + self.dt / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
        angles = (s[:2] + jnp.pi) % (2 * jnp.pi) - jnp.pi
        velocities = jnp.clip(s[2:], -jnp.array([self.max_vel_1, self.max_vel_2]),
                              jnp.array([self.max_vel_1, self.max_vel_2]))
        physics = jnp.concatenate([angles, velocities])
        terminated = -jnp.cos(physics[0]) - jnp.cos(physics[1] + physics[0]) > 1.0
        return physics, self._observe(physics), jnp.where(terminated, 0.0, -1.0), terminated, info, {}
