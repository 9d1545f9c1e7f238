"""Truncated BPTT: unrolling a network over a chunk from a stored carry, and tiling chunks into minibatches.

The rollout is kept as chunks: arrays of shape `(C, s, N, ...)` (C chunks of s steps for N environments) and the
carry at each chunk's start `(C, N, ...)`. A minibatch is a tile of n trajectories x m chunks, flattened to a
batch of B = m * n sequences of s steps.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp

from angora_jax.nets.models import reset_carry
from angora_jax.ppo.parallel import local_share


def unroll(
    step: Callable[[Any, Any], tuple[Any, jax.Array, jax.Array]],
    carry: Any,
    initial: Any,
    obs: Any,
    resets: jax.Array,
    runs_sequences: bool = False,
) -> tuple[Any, jax.Array, jax.Array]:
    """Run `step(carry, obs_t) -> (carry, policy_params, value)` over a sequence, resetting the carry first
    wherever `resets[t]` is set.

    Args:
        step: the network's step.
        carry: pytree with leading axis B, the carry at the sequence's start.
        initial: pytree with leading axis B, the carry a reset restores.
        obs: pytree with leaves `(s, B, ...)`.
        resets: `(s, B)`.
        runs_sequences: `step(carry, obs, resets, initial)` runs the whole sequence itself (a network that
            `runs_sequences`, see `angora_jax.nets`): its feed-forward layers take all s x B rows at once and only its
            recurrent cells scan, instead of a scan over every layer of every step.

    Returns:
        The final carry, policy parameters `(s, B, P)` and values `(s, B)`.
    """
    if runs_sequences:
        return step(carry, obs, resets, initial)

    if all(leaf.size == 0 for leaf in jax.tree.leaves(carry)):
        # No recurrent state (feed-forward networks): the steps are independent, so they run as one batch of s x B
        # rows (one large matrix product per layer) instead of a scan of s small sequential ones, which on a GPU
        # costs a kernel launch per step and layer.
        params, values = jax.vmap(lambda obs_t: step(carry, obs_t)[1:])(obs)
        return carry, params, values

    def body(carry, x):
        obs_t, reset_t = x
        carry, params, value = step(reset_carry(carry, initial, reset_t), obs_t)
        return carry, (params, value)

    carry, (params, values) = jax.lax.scan(body, carry, (obs, resets))
    return carry, params, values


def minibatch_indices(
    key: jax.Array, num_envs: int, num_chunks: int, tile: tuple[int, int], axis: str | None = None
) -> tuple[jax.Array, ...]:
    """A random partition of the (trajectory, chunk) grid into tiles of n trajectories x m chunks for one epoch.

    Stratified over trajectories: the N trajectories form n contiguous blocks of N / n, each block is shuffled on
    its own, and tile row k takes the k-th trajectory of every block, so every tile holds one trajectory of each
    block (trajectories are exchangeable, so this is as good a partition as an unstratified one). Chunk positions
    are shuffled and cut into groups of m. Returns `env_index (K, n)` and `chunk_index (K, m)` int32 arrays, one
    row per minibatch, K = (N / n) * (C / m).

    With `axis` (data parallelism over D devices holding N / D trajectories each, see `angora_jax.ppo.parallel`),
    `num_envs` and `tile` are still the run's totals and the partition is the same as on one device; each device
    gets `env_index (K, n / D)`: its share of every tile, as indices into its own N / D trajectories.
    """
    n, m = tile
    block = num_envs // n
    env_key, chunk_key = jax.random.split(key)
    block_keys = local_share(jax.random.split(env_key, n), axis)
    shuffled = jax.vmap(lambda k: jax.random.permutation(k, block))(block_keys)  # (blocks here, N / n)
    envs = (jnp.arange(shuffled.shape[0])[:, None] * block + shuffled).T
    chunks = jax.random.permutation(chunk_key, num_chunks).reshape(-1, m)
    env_rows, chunk_rows = jnp.meshgrid(jnp.arange(envs.shape[0]), jnp.arange(chunks.shape[0]), indexing="ij")
    return envs[env_rows.ravel()], chunks[chunk_rows.ravel()]


def gather_sequences(data: Any, chunk_index: jax.Array, env_index: jax.Array) -> Any:
    """Select a tile from chunked data with leaves `(C, s, N, ...)`; returns leaves `(s, m * n, ...)`."""

    def take(x):
        tile = x[chunk_index][:, :, env_index]
        tile = jnp.swapaxes(tile, 0, 1)
        return tile.reshape((tile.shape[0], tile.shape[1] * tile.shape[2]) + tile.shape[3:])

    return jax.tree.map(take, data)


def gather_carries(carries: Any, chunk_index: jax.Array, env_index: jax.Array) -> Any:
    """Select the start carries of a tile from leaves `(C, N, ...)`; returns leaves `(m * n, ...)`, ordered like
    `gather_sequences`."""

    def take(x):
        tile = x[chunk_index][:, env_index]
        return tile.reshape((tile.shape[0] * tile.shape[1],) + tile.shape[2:])

    return jax.tree.map(take, carries)
