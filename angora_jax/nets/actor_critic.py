"""`ActorCritic`: a network (the trunk contract) joined with a policy head's parameter layer."""

from __future__ import annotations

from typing import Any, Protocol

import flax.linen as nn
import jax
import jax.numpy as jnp

from angora_jax.envs.core import Sensation, is_image


class HeadLayer(Protocol):
    """What the network needs of a policy head (`angora_jax.ppo.PolicyHead` is one): the layer that maps its
    features to the distribution's parameters. Declared here since ppo, which holds the heads, builds on nets."""

    def module(self) -> nn.Module:
        """Flax layer from trunk features `(..., F)` to distribution parameters `(..., P)`."""
        ...


class ActorCritic(nn.Module):
    """One step for a batch: `(carry, obs) -> (carry, distribution parameters (B, P), value (B,))`.

    Attributes:
        visual: the visual area (`nets.visual`), for tasks whose `vision` holds camera images: it encodes each camera's
            image (one encoder for all cameras) and the network reads the features, `(B, cameras * features)`, as
            `vision`.
        blocks: M policies in one network (SAPG's policy blocks): with M > 1 a learned embedding of the block
            (`block_embedding` units, parameters `block_embedding`) joins the `goal` modality, so that every network
            reads it without a change of its own; M = 1 adds no parameters.
        block_embedding: units of the block embedding.
    """

    network: nn.Module
    head: HeadLayer
    visual: nn.Module | None = None
    blocks: int = 1
    block_embedding: int = 32

    def initial_carry(self, batch_size: int) -> Any:
        return self.network.initial_carry(batch_size)

    def perceive(self, obs: Sensation) -> Sensation:
        """`obs` (leaves with any leading axes) with camera images replaced by the visual area's features; as it is
        without images. Training encodes a whole sequence at once with it, as one batch, before the recurrent scan."""
        images = obs.vision
        if not is_image(images):
            return obs
        if self.visual is None:
            raise ValueError(f"The observation holds camera images (vision {images.shape} uint8) but the network "
                             "has no visual area: set ppo.network.visual (e.g. {encoder: cornet_z}).")
        lead, cameras = images.shape[:-4], images.shape[-4]
        features = self.visual(images.reshape((-1, *images.shape[-3:])))
        return obs.replace(vision=features.reshape((*lead, cameras * features.shape[-1])))

    @property
    def runs_sequences(self) -> bool:
        """Whether `__call__` also runs whole sequences (the network's `runs_sequences`, see `angora_jax.nets`)."""
        return bool(getattr(self.network, "runs_sequences", False))

    @nn.compact
    def __call__(self, carry: Any, obs: Sensation, resets: jax.Array | None = None,
                 initial: Any = None, block: jax.Array | None = None) -> tuple[Any, jax.Array, jax.Array]:
        """One step; or, given `resets` `(s, B)` and `initial` (a network that `runs_sequences`), a sequence with obs
        leaves `(s, B, ...)`: (final carry, distribution parameters (s, B, P), values (s, B)).

        With `blocks` > 1, `block` `(B,)` int32 says which block's policy acts in each row (constant along a
        sequence); None acts with the leader, block 0, as evaluation and loaded agents do.
        """
        sequence = () if resets is None else (resets, initial)
        obs = self.perceive(obs)
        if self.blocks > 1:
            obs = self.conditioned(obs, block)
        carry, features, value = self.network(carry, obs, *sequence)
        return carry, self.head.module()(features), value

    def conditioned(self, obs: Sensation, block: jax.Array | None) -> Sensation:
        """`obs` with the embedding of each row's block appended to `goal`; rows are the last batch axis."""
        rows = obs.goal.shape[-2]
        block = jnp.zeros((rows,), jnp.int32) if block is None else block
        embedding = nn.Embed(self.blocks, self.block_embedding, name="block_embedding")(block)
        embedding = jnp.broadcast_to(embedding, (*obs.goal.shape[:-1], self.block_embedding))
        return obs.replace(goal=jnp.concatenate([obs.goal, embedding.astype(obs.goal.dtype)], axis=-1))
