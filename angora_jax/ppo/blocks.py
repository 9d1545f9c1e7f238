"""Policy blocks after SAPG (Singla, Agarwal, Pathak, "SAPG: Split and Aggregate Policy Gradients", ICML 2024): which
block each environment acts in, each block's entropy weight and the leader's off-policy term. `ppo.blocks`
(`BlocksConfig`) configures them; the cycle (`angora_jax.ppo.cycle`) uses them.

Why: one PPO policy stops gaining from more environments past roughly 10-25k (SAPG, and EPO 2025), so the further
environments are spent on M policies that explore differently, while the leader (block 0), the policy evaluated and
shipped, learns from all of their data.

Advantages of the off-policy term: the followers' own GAE advantages (of the behaviour policy's value, normalised
with the minibatch's others), not advantages re-estimated with the leader's value function. They are the advantages
of the policy that acted, which is what PPO's ratio against that policy's log-probabilities weighs in its own
update; the leader's advantages differ by the blocks' difference in policy, which the clipped ratio keeps small, and
the shared network keeps the blocks' values close. They need no second value pass over the rollout. A recurrent
leader replays a follower's sequence from the carry the follower's pass stored at the chunk's start (there is no
other), so its first steps of a chunk read a follower's state.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from angora_jax.ppo.config import BlocksConfig
from angora_jax.ppo.distributions import PolicyHead
from angora_jax.ppo.losses import LossInputs
from angora_jax.ppo.parallel import local_share

LEADER = 0


def environment_blocks(num_envs: int, count: int, axis: str | None = None) -> jax.Array:
    """The block of each of this device's environments, `(N / D,)` int32: environment i of the run's `num_envs`
    is in block i // (num_envs / count), so blocks are contiguous ranges and, with D = count devices, device d holds
    block d exactly (see `angora_jax.ppo.parallel.local_share`)."""
    return local_share(jnp.arange(num_envs, dtype=jnp.int32) // (num_envs // count), axis)


def row_blocks(blocks: jax.Array, env_index: jax.Array, num_chunks: int) -> jax.Array:
    """The block of each row of a minibatch tile of `num_chunks` chunks of the trajectories `env_index` `(n,)`,
    `(num_chunks * n,)` in the order of `tbptt.gather_carries`."""
    return jnp.tile(blocks[env_index], num_chunks)


def entropy_weights(config: BlocksConfig, run_weight: jax.Array, rows: jax.Array) -> jax.Array:
    """The entropy weight of each row: its block's from `config.entropy_coefs` `(B,)`, or the run's `run_weight`
    (a scalar, so the loss is the plain PPO loss) when they are not given."""
    if not config.entropy_coefs:
        return run_weight
    return jnp.asarray(config.entropy_coefs, jnp.float32)[rows]


def leader_off_policy_loss(
    head: PolicyHead,
    leader_policy_params: jax.Array,
    batch: LossInputs,
    rows: jax.Array,
    clip_epsilon: float,
    weight: float,
    count: int,
) -> tuple[jax.Array, dict[str, jax.Array]]:
    """The leader's off-policy term on the followers' transitions of one minibatch, and its parts.

    PPO's clipped objective with the ratio pi_leader(a|s) / mu(a|s) of the leader's probability of each follower's
    action to the follower's (`batch.log_probs`, the behaviour policy's), and the follower's advantages (module
    docstring). Its mean over the follower rows is weighed by `weight` against the leader's own on-policy mean:
    the cycle's PPO loss is a mean over all rows, in which the leader's on-policy term weighs 1 / M, so this one
    weighs `weight` / M.

    Args:
        head: the policy head.
        leader_policy_params: `(s, B, P)` distribution parameters of the leader (block 0's conditioning) on the
            minibatch's observations.
        batch: the minibatch's loss inputs, leaves `(s, B)`.
        rows: `(B,)` the block of each row; rows of block 0 (the leader's own) do not count here.
        clip_epsilon: PPO's clip range.
        weight: lambda, `ppo.blocks.leader_off_policy_weight`.
        count: M, the number of blocks (> 1); each minibatch holds (M - 1) / M follower rows (as
            `BlocksConfig.count` requires), and under data parallelism a device's share of it may hold any number.

    Returns:
        The term to add to the loss (to minimise), and `leader_off_policy_loss` and `leader_clip_fraction` (the share of
        follower transitions whose ratio lies outside the clip range).
    """
    followers = jnp.broadcast_to(rows != LEADER, batch.advantages.shape).astype(jnp.float32)
    # The minibatch's follower count, (M - 1) / M of its rows, and not this share's count: a data-parallel device
    # holds whole blocks (device 0 the leader's alone), and the mean over devices of these per-device sums must be
    # the whole minibatch's mean, as each device's plain PPO loss is a mean over its equal share.
    count_followers = followers.size * (count - 1) / count
    ratio = jnp.exp(head.log_prob(leader_policy_params, batch.actions) - batch.log_probs)
    clipped = jnp.clip(ratio, 1.0 - clip_epsilon, 1.0 + clip_epsilon)
    objective = jnp.minimum(ratio * batch.advantages, clipped * batch.advantages)
    follower_mean = -(objective * followers).sum() / count_followers
    outside = jax.lax.stop_gradient(((jnp.abs(ratio - 1.0) > clip_epsilon) * followers).sum() / count_followers)
    return weight / count * follower_mean, {"leader_off_policy_loss": follower_mean, "leader_clip_fraction": outside}


def block_mask(blocks: jax.Array, block: int) -> jax.Array:
    """`(N,)` float32, 1 for the environments of `block`."""
    return (blocks == block).astype(jnp.float32)
