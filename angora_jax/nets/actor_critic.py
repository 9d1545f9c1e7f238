"""`ActorCritic`: a network (the trunk contract) joined with a policy head's parameter layer."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import flax.linen as nn
import jax

from angora_jax.envs.core import Sensation

if TYPE_CHECKING:  # nets must not import ppo at runtime: ppo imports nets
    from angora_jax.ppo.distributions import PolicyHead


class ActorCritic(nn.Module):
    """One step for a batch: `(carry, obs) -> (carry, distribution parameters (B, P), value (B,))`."""

    network: nn.Module
    head: PolicyHead

    def initial_carry(self, batch_size: int) -> Any:
        return self.network.initial_carry(batch_size)

    @nn.compact
    def __call__(self, carry: Any, obs: Sensation) -> tuple[Any, jax.Array, jax.Array]:
        carry, features, value = self.network(carry, obs)
        return carry, self.head.module()(features), value
