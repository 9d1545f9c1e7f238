"""Evaluation: run the trained policy for one episode per environment, by default acting with the mode."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp
from flax import struct

from angora_jax.envs.core import Env, Sensation
from angora_jax.nets import make_network
from angora_jax.ppo.config import PPOConfig
from angora_jax.ppo.cycle import TrainState, build_head, build_model
from angora_jax.ppo.normalization import normalize_observation


@struct.dataclass
class PolicyState:
    """What acting needs from a checkpoint: `params` (network parameters), `obs_stats` (a Sensation of
    `RunningMeanStd`, the observation normaliser) and `cycle` (int32, the training cycle it was saved at). Named as in
    `TrainState`, so it is read from a checkpoint under the same paths, and it serves where `make_evaluate` takes a
    TrainState."""

    params: Any
    obs_stats: Sensation
    cycle: jax.Array


@struct.dataclass
class SilencedPolicyState(PolicyState):
    """A `PolicyState` whose policy acts with some action components held at 0 before they reach the task (a
    denervated muscle: `analysis.silence_actions`): `silenced`, bool of the action's shape, True where the task
    receives 0 whatever the policy sends (`sent_to_task`). The mask is data of the programs that take the state, not
    a constant compiled into them, so an agent and all its variants with other masks of the same shape run the same
    programs (`Agent.acting_state`). For acting only: checkpoints and exported policies hold the plain
    `PolicyState`."""

    silenced: jax.Array


def sent_to_task(state: Any, action: jax.Array) -> jax.Array:
    """`action` (environment actions, `(..., *action_shape)`) as the task receives it from a policy acting with
    `state`: 0 in the components a `SilencedPolicyState` silences; as it is for any other state (a `PolicyState`, a
    `TrainState`)."""
    if not isinstance(state, SilencedPolicyState):
        return action
    return jnp.where(state.silenced, jnp.zeros_like(action), action)


def make_evaluate(
    env: Env, network: nn.Module | None, config: PPOConfig, num_envs: int, deterministic: bool = True,
    per_episode: bool = False, steps: int | None = None,
) -> Callable[[TrainState, jax.Array], dict[str, jax.Array]]:
    """Build the jitted `evaluate(state, key) -> metrics` for the same env, network and config as training.

    Each of `num_envs` fresh environments runs exactly one episode (up to `steps` policy steps, default
    `env.max_episode_steps`), acting with the head's mode (or sampling, when not `deterministic`; step t samples with
    `fold_in(key, t)`); observation stats are read, never updated. The loop stops as soon as every episode has ended,
    so long limits (a cube episode may last 5,000 steps) cost only the steps the longest episode takes. Metrics:
    episode_return and episode_length (means over environments), `metric/<name>` at each episode's end (or at the
    last step run, for an episode that `steps` cut short); with `per_episode`, each environment's values (arrays
    `(num_envs,)`) instead of the means. A `SilencedPolicyState` holds its silenced action components at 0 before
    they reach the task (`sent_to_task`), with the same program for any mask of that shape. The whole loop is one
    program call. A host loop over chunks of steps gives MuJoCo Warp new buffer addresses at each call, so new CUDA
    graphs; such a loop of 50 calls per lesion segfaulted on an H100
    (benchmarks/results/probing/cube_cortical_probe_h100.md), and this program did not.
    """
    env = env.sized_for(num_envs)
    limit = steps or env.max_episode_steps
    network = make_network(config.network) if network is None else network
    head = build_head(env, config)
    model = build_model(network, head, config)

    def evaluate(state: TrainState, key: jax.Array) -> dict[str, jax.Array]:
        reset_key, act_key = jax.random.split(key)
        env_state = jax.vmap(env.reset)(jax.random.split(reset_key, num_envs))

        def step(carry):
            t, env_state, net_carry, running, totals = carry
            key = jax.random.fold_in(act_key, t)
            obs = env_state.obs
            if config.normalization.observations:
                obs = normalize_observation(state.obs_stats, obs, config.normalization.clip)
            net_carry, policy_params, _ = model.apply({"params": state.params}, net_carry, obs)
            action = head.mode(policy_params) if deterministic else head.sample(policy_params, key)
            env_state = jax.vmap(env.step)(env_state, sent_to_task(state, head.env_action(action)))
            ended = running * env_state.done
            totals = {
                "episode_return": totals["episode_return"] + running * env_state.reward,
                "episode_length": totals["episode_length"] + running,
                **{f"metric/{k}": totals[f"metric/{k}"] + ended * v for k, v in env_state.metrics.items()},
            }
            return t + 1, env_state, net_carry, running * (1.0 - env_state.done), totals

        def unfinished(carry):
            t, _, _, running, _ = carry
            return jnp.logical_and(t < limit, jnp.any(running > 0))

        zeros = jnp.zeros((num_envs,), jnp.float32)
        totals = {"episode_return": zeros, "episode_length": zeros, **{f"metric/{k}": zeros for k in env.metric_names}}
        carry = (jnp.zeros((), jnp.int32), env_state, network.initial_carry(num_envs), jnp.ones_like(zeros), totals)
        _, env_state, _, running, totals = jax.lax.while_loop(unfinished, step, carry)
        totals.update({f"metric/{k}": totals[f"metric/{k}"] + running * v for k, v in env_state.metrics.items()})
        return totals if per_episode else {name: value.mean() for name, value in totals.items()}

    return jax.jit(evaluate)
