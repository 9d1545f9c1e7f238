"""The PPO objective (Schulman et al. 2017) with the "Implementation matters" details: per-minibatch advantage
normalisation and an optionally clipped value loss."""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

from angora_jax.ppo.distributions import PolicyHead


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
    entropy_coef: float,
    value_clip: bool,
    normalize_advantages: bool,
    axis_name: str | None = None,
) -> tuple[jax.Array, dict[str, jax.Array]]:
    """Total loss (to minimise) and its parts.

    policy_params `(..., P)` and values `(...)` come from the current network on the minibatch's observations.
    Returns `loss = policy_loss + value_coef * value_loss - entropy_coef * entropy` and a dict with the parts,
    the approximate KL divergence to the rollout policy and the fraction of clipped ratios. With `axis_name`, this
    device holds an equal share of a minibatch split over devices, and advantages are normalised by the whole
    minibatch's mean and std.
    """
    advantages = batch.advantages
    if normalize_advantages:
        advantages = (advantages - _mean(advantages, axis_name)) / (_std(advantages, axis_name) + 1e-8)
    log_ratio = head.log_prob(policy_params, batch.actions) - batch.log_probs
    ratio = jnp.exp(log_ratio)
    clipped_ratio = jnp.clip(ratio, 1.0 - clip_epsilon, 1.0 + clip_epsilon)
    policy_loss = -jnp.minimum(ratio * advantages, clipped_ratio * advantages).mean()

    value_error = (values - batch.targets) ** 2
    if value_clip:
        clipped_values = batch.values + jnp.clip(values - batch.values, -clip_epsilon, clip_epsilon)
        value_error = jnp.maximum(value_error, (clipped_values - batch.targets) ** 2)
    value_loss = 0.5 * value_error.mean()

    entropy = head.entropy(policy_params).mean()
    loss = policy_loss + value_coef * value_loss - entropy_coef * entropy
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


def _mean(x: jax.Array, axis_name: str | None) -> jax.Array:
    return x.mean() if axis_name is None else jax.lax.pmean(x.mean(), axis_name)


def _std(x: jax.Array, axis_name: str | None) -> jax.Array:
    if axis_name is None:
        return x.std()
    return jnp.sqrt(jax.lax.pmean(((x - _mean(x, axis_name)) ** 2).mean(), axis_name))
