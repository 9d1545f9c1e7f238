"""The PPO objective (Schulman et al. 2017) with an optionally clipped value loss. The other "Implementation matters"
detail, per-minibatch advantage normalisation, happens before the loss (`normalized_advantages`), where a data-parallel
cycle can pool the statistics of all its minibatches at once."""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

from angora_jax.ppo.distributions import PolicyHead
from angora_jax.ppo.normalization import pooled_moments


@struct.dataclass
class LossInputs:
    """What the loss needs from the rollout, for one minibatch; all leaves share a batch shape, e.g. `(s, B)`."""

    actions: jax.Array
    log_probs: jax.Array
    values: jax.Array
    advantages: jax.Array
    targets: jax.Array


def ppo_loss(
    head: PolicyHead,
    policy_params: jax.Array,
    values: jax.Array,
    batch: LossInputs,
    clip_epsilon: float,
    value_coef: float,
    entropy_coef: float | jax.Array,
    value_clip: bool,
) -> tuple[jax.Array, dict[str, jax.Array]]:
    """Total loss (to minimise) and its parts.

    policy_params `(..., P)` and values `(...)` come from the current network on the minibatch's observations.
    Returns `loss = policy_loss + value_coef * value_loss - entropy_coef * entropy` and a dict with the parts,
    `entropy_coef` a scalar or one weight per row `(B,)` (the mean of the weighted entropies then),
    the approximate KL divergence to the rollout policy and the fraction of clipped ratios. `batch.advantages` are
    used as given (normalised or not).
    """
    advantages = batch.advantages
    log_ratio = head.log_prob(policy_params, batch.actions) - batch.log_probs
    ratio = jnp.exp(log_ratio)
    clipped_ratio = jnp.clip(ratio, 1.0 - clip_epsilon, 1.0 + clip_epsilon)
    policy_loss = -jnp.minimum(ratio * advantages, clipped_ratio * advantages).mean()

    value_error = (values - batch.targets) ** 2
    if value_clip:
        clipped_values = batch.values + jnp.clip(values - batch.values, -clip_epsilon, clip_epsilon)
        value_error = jnp.maximum(value_error, (clipped_values - batch.targets) ** 2)
    value_loss = 0.5 * value_error.mean()

    entropies = head.entropy(policy_params)
    entropy = entropies.mean()
    # A weight per row (policy blocks, `angora_jax.ppo.blocks`) weighs each row's entropy; a scalar the mean's.
    bonus = entropy_coef * entropy if jnp.ndim(entropy_coef) == 0 else (entropy_coef * entropies).mean()
    loss = policy_loss + value_coef * value_loss - bonus
    parts = {
        "loss": loss,
        "policy_loss": policy_loss,
        "value_loss": value_loss,
        "entropy": entropy,
        # The low-variance k3 estimator of KL(old || new) (Schulman 2020).
        "approx_kl": jax.lax.stop_gradient(((ratio - 1.0) - log_ratio).mean()),
        "clip_fraction": jax.lax.stop_gradient((jnp.abs(ratio - 1.0) > clip_epsilon).mean()),
    }
    return loss, parts


def advantage_moments(advantages: jax.Array, axis_name: str | None = None) -> tuple[jax.Array, jax.Array]:
    """Mean and std of each minibatch's advantages, leaves `(K, ...)` for K minibatches; `(K,)` each.

    With `axis_name`, each device holds an equal share of every minibatch and the statistics are those of the whole
    minibatches, pooled for all K in one all-reduce (a collective per minibatch would cost its latency K times).
    """
    axes = tuple(range(1, advantages.ndim))
    mean, var = advantages.mean(axes), advantages.var(axes)
    if axis_name is not None:
        mean, var = pooled_moments(mean, var, axis_name)
    return mean, jnp.sqrt(var)


def normalized_advantages(advantages: jax.Array, mean: jax.Array, std: jax.Array) -> jax.Array:
    """`(advantages - mean) / std` of one minibatch, guarded against a zero std."""
    return (advantages - mean) / (std + 1e-8)
