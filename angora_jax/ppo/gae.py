"""Generalised advantage estimation (Schulman et al. 2016) with bootstrapping on truncation."""

from __future__ import annotations

import jax
import jax.numpy as jnp


def next_values(
    values: jax.Array, last_value: jax.Array, final_values: jax.Array, dones: jax.Array, truncated: jax.Array
) -> jax.Array:
    """Value of the state after each step, `(T, N)`.

    A terminated episode is worth 0 afterwards; a truncated one is worth the value of its last observation (it would
    have gone on).

    Args:
        values: `(T, N)` values of the observations acted on.
        last_value: `(N,)` value after the rollout's last step.
        final_values: `(T, N)` values of `final_obs` (read only where truncated).
        dones: `(T, N)` 1 where an episode ended at the step.
        truncated: `(T, N)` 1 where it ended by truncation.
    """
    following = jnp.concatenate([values[1:], last_value[None]], axis=0)
    after_end = jnp.where(truncated > 0, final_values, 0.0)
    return jnp.where(dones > 0, after_end, following)


def gae(
    rewards: jax.Array, values: jax.Array, next_value: jax.Array, dones: jax.Array, gamma: float, lam: float
) -> tuple[jax.Array, jax.Array]:
    """Advantages and value targets, both `(T, N)`, from per-step arrays of shape `(T, N)`.

    The recursion A_t = delta_t + gamma * lam * A_{t+1} stops where an episode ended (`dones`); `next_value` already
    holds the bootstrap value for truncated steps (see `next_values`).
    """
    deltas = rewards + gamma * next_value - values

    def step(advantage, x):
        delta, done = x
        advantage = delta + gamma * lam * (1.0 - done) * advantage
        return advantage, advantage

    _, advantages = jax.lax.scan(step, jnp.zeros_like(deltas[0]), (deltas, dones), reverse=True)
    return advantages, advantages + values
