"""Acting: roll the current policy out in a batch of environments with `lax.scan`, chunk by chunk.

The rollout is a scan over C chunks of a scan over s steps, so its outputs come chunked `(C, s, N, ...)` and the
recurrent carry is stored once per chunk start `(C, N, ...)`, which is what truncated BPTT replays from.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
from flax import struct

from angora_jax.envs.core import Env, Sensation, State
from angora_jax.nets.models import reset_carry
from angora_jax.ppo.distributions import PolicyHead
from angora_jax.ppo.normalization import normalize_observation, update_observation_stats

# (params, carry, obs) -> (carry, policy parameters (B, P), value (B,))
ApplyFn = Callable[[Any, Any, Sensation], tuple[Any, jax.Array, jax.Array]]


@struct.dataclass
class ActorState:
    """What acting carries from one step (and cycle) to the next, for N environments.

    Attributes:
        reset: `(N,)` float32, 1 where an episode starts at the next step, so the carry is reset before acting.
        episode_return: `(N,)` undiscounted raw return of the running episodes.
    """

    env_state: State
    carry: Any
    reset: jax.Array
    episode_return: jax.Array


@struct.dataclass
class Trajectory:
    """Per-step rollout data; every leaf is `(C, s, N, ...)`.

    Attributes:
        obs: the (normalised) observations the policy acted on.
        resets: 1 where the carry was reset before the step.
        actions: the actions taken, in the head's stored space.
        log_probs: their log-probabilities under the policy that acted.
        values: value estimates of `obs`.
        rewards: raw rewards.
        final_values: value of `final_obs` where the step was truncated, else 0.
        episode_return: of the episode that ended at this step, else 0.
        episode_length: of the episode that ended at this step, else 0.
        metrics: the task metrics at this step.
    """

    obs: Sensation
    resets: jax.Array
    actions: jax.Array
    log_probs: jax.Array
    values: jax.Array
    rewards: jax.Array
    dones: jax.Array
    truncated: jax.Array
    final_values: jax.Array
    episode_return: jax.Array
    episode_length: jax.Array
    metrics: dict[str, jax.Array]


def make_rollout(
    env: Env,
    apply_fn: ApplyFn,
    head: PolicyHead,
    initial_carry: Any,
    num_chunks: int,
    chunk_length: int,
    normalize_obs: bool,
    clip: float,
    axis_name: str | None = None,
) -> Callable[..., tuple[ActorState, Sensation, Trajectory, Any, jax.Array]]:
    """Build `rollout(params, obs_stats, actor, keys) -> (actor, obs_stats, trajectory, start_carries, last_value)`.

    `initial_carry` is the network's carry for N environments; `keys` `(N,)` holds one PRNG key per environment,
    from which that environment's actions are drawn (so they do not depend on how environments are batched).
    Observation stats are updated after every step (when `normalize_obs`), and each observation is normalised with
    the stats from before its own update.
    `start_carries` has leaves `(C, N, ...)`, `last_value` `(N,)` is the value after the last step. Under data
    parallelism N is this device's share and `axis_name` pools the observation stats over the devices.
    """
    step_env = jax.vmap(env.step)

    def observe(obs_stats: Sensation, obs: Sensation) -> Sensation:
        return normalize_observation(obs_stats, obs, clip) if normalize_obs else obs

    def step(params, carry):
        obs_stats, actor, keys = carry
        keys, action_keys = jnp.moveaxis(jax.vmap(jax.random.split)(keys), 1, 0)
        state = actor.env_state
        obs = observe(obs_stats, state.obs)
        if normalize_obs:
            obs_stats = update_observation_stats(obs_stats, state.obs, axis_name)
        net_carry = reset_carry(actor.carry, initial_carry, actor.reset)
        net_carry, policy_params, value = apply_fn(params, net_carry, obs)
        action = jax.vmap(head.sample)(policy_params, action_keys)
        log_prob = head.log_prob(policy_params, action)
        with jax.named_scope("env_step"):
            next_state = step_env(state, head.env_action(action))

        # Truncations are rare, so the extra forward pass for their bootstrap value runs only when one happens.
        def final_value():
            return apply_fn(params, net_carry, observe(obs_stats, next_state.final_obs))[2]

        final_values = (
            jax.lax.cond(jnp.any(next_state.truncated > 0), final_value, lambda: jnp.zeros_like(value))
            * next_state.truncated
        )
        episode_return = actor.episode_return + next_state.reward
        done = next_state.done
        out = Trajectory(
            obs=obs,
            resets=actor.reset,
            actions=action,
            log_probs=log_prob,
            values=value,
            rewards=next_state.reward,
            dones=done,
            truncated=next_state.truncated,
            final_values=final_values,
            episode_return=episode_return * done,
            episode_length=(state.steps + 1).astype(jnp.float32) * done,
            metrics=next_state.metrics,
        )
        actor = ActorState(next_state, net_carry, done, episode_return * (1.0 - done))
        return (obs_stats, actor, keys), out

    def rollout(params, obs_stats: Sensation, actor: ActorState, keys: jax.Array):
        def chunk(carry, _):
            start_carry = carry[1].carry
            carry, out = jax.lax.scan(lambda c, _: step(params, c), carry, length=chunk_length)
            return carry, (out, start_carry)

        (obs_stats, actor, _), (trajectory, start_carries) = jax.lax.scan(
            chunk, (obs_stats, actor, keys), length=num_chunks
        )
        obs = observe(obs_stats, actor.env_state.obs)
        _, _, last_value = apply_fn(params, reset_carry(actor.carry, initial_carry, actor.reset), obs)
        return actor, obs_stats, trajectory, start_carries, last_value

    return rollout
