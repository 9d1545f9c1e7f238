"""Batched rollouts of a uniformly random policy: the smoke test of a task and the baseline of benchmarks."""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp

from angora_jax.envs.core import Env, State


def random_action(env: Env, key: jax.Array, num_envs: int) -> jax.Array:
    """Uniform random actions for `num_envs` environments, shape `(num_envs, *action_spec.shape)`."""
    spec = env.action_spec
    if spec.discrete:
        return jax.random.randint(key, (num_envs,), 0, spec.num_actions)
    return jax.random.uniform(key, (num_envs, spec.size), minval=spec.low, maxval=spec.high)


def make_random_rollout(env: Env, num_envs: int, num_steps: int) -> Callable[[State, jax.Array], tuple]:
    """Compile-ready `rollout(state, key) -> (state, rewards, dones, metrics)` over `num_steps` policy steps of
    `num_envs` environments (`state` from `jax.vmap(env.reset)`); outputs have shape `(num_steps, num_envs)`."""
    step = jax.vmap(env.step)

    def one_step(state: State, key: jax.Array):
        state = step(state, random_action(env, key, num_envs))
        return state, (state.reward, state.done, state.metrics)

    def rollout(state: State, key: jax.Array):
        state, (rewards, dones, metrics) = jax.lax.scan(one_step, state, jax.random.split(key, num_steps))
        return state, rewards, dones, metrics

    return rollout


def batched_reset(env: Env, key: jax.Array, num_envs: int) -> State:
    """`num_envs` fresh environments from one key."""
    return jax.vmap(env.reset)(jax.random.split(key, num_envs))


def episode_mean(values: jax.Array, dones: jax.Array) -> jax.Array:
    """Mean of `values` at episode ends (`dones` == 1); NaN when no episode ended."""
    count = jnp.sum(dones)
    return jnp.where(count > 0, jnp.sum(values * dones) / jnp.maximum(count, 1), jnp.nan)
