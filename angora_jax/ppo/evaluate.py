"""Evaluation: run the trained policy for one episode per environment, by default acting with the mode."""

from __future__ import annotations

from collections.abc import Callable

import flax.linen as nn
import jax
import jax.numpy as jnp

from angora_jax.envs.core import Env
from angora_jax.nets import ActorCritic, make_network
from angora_jax.ppo.config import PPOConfig
from angora_jax.ppo.cycle import TrainState, build_head
from angora_jax.ppo.normalization import normalize_observation


def make_evaluate(
    env: Env, network: nn.Module | None, config: PPOConfig, num_envs: int, deterministic: bool = True,
    per_episode: bool = False,
) -> Callable[[TrainState, jax.Array], dict[str, jax.Array]]:
    """Build the jitted `evaluate(state, key) -> metrics` for the same env, network and config as training.

    Each of `num_envs` fresh environments runs exactly one episode (up to `env.max_episode_steps` steps), acting with
    the head's mode (or sampling, when not `deterministic`); observation stats are read, never updated. Metrics:
    episode_return and episode_length (means over environments), `metric/<name>` at each episode's end; with
    `per_episode`, each environment's values (arrays `(num_envs,)`) instead of the means.
    """
    network = make_network(config.network) if network is None else network
    head = build_head(env, config)
    model = ActorCritic(network, head)

    def evaluate(state: TrainState, key: jax.Array) -> dict[str, jax.Array]:
        reset_key, act_key = jax.random.split(key)
        env_state = jax.vmap(env.reset)(jax.random.split(reset_key, num_envs))

        def step(carry, key):
            env_state, net_carry, running, totals = carry
            obs = env_state.obs
            if config.normalization.observations:
                obs = normalize_observation(state.obs_stats, obs, config.normalization.clip)
            net_carry, policy_params, _ = model.apply({"params": state.params}, net_carry, obs)
            action = head.mode(policy_params) if deterministic else head.sample(policy_params, key)
            env_state = jax.vmap(env.step)(env_state, head.env_action(action))
            ended = running * env_state.done
            totals = {
                "episode_return": totals["episode_return"] + running * env_state.reward,
                "episode_length": totals["episode_length"] + running,
                **{f"metric/{k}": totals[f"metric/{k}"] + ended * v for k, v in env_state.metrics.items()},
            }
            return (env_state, net_carry, running * (1.0 - env_state.done), totals), None

        zeros = jnp.zeros((num_envs,), jnp.float32)
        totals = {"episode_return": zeros, "episode_length": zeros, **{f"metric/{k}": zeros for k in env.metric_names}}
        carry = (env_state, network.initial_carry(num_envs), jnp.ones_like(zeros), totals)
        (_, _, _, totals), _ = jax.lax.scan(step, carry, jax.random.split(act_key, env.max_episode_steps))
        return totals if per_episode else {name: value.mean() for name, value in totals.items()}

    return jax.jit(evaluate)
