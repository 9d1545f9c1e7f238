"""Policy/value networks.

Network contract (what `make_cycle` accepts; every built-in model follows it). A network is a Flax module with

- `initial_carry(self, batch_size: int) -> carry`: the recurrent state at an episode's start, a pytree of float
  arrays with leading axis `batch_size`. It must work on the unbound module (no params). Feed-forward models return
  `jnp.zeros((batch_size, 0))`.
- `__call__(self, carry, obs: Sensation) -> (carry, policy_features, value)`: one time step for a batch of B
  environments. `obs` leaves are `(B, size)` (normalised; empty modalities are `(B, 0)`). `policy_features` is
  `(B, F)` and goes to the policy head; `value` is `(B,)`. The policy features must not depend on
  `obs.asymmetric`, which only the value function may read.

The trainer resets the carry to `initial_carry` where an episode starts and scans the module over time, so a
network never sees episode boundaries itself. A network may instead run whole training sequences itself: it sets
`runs_sequences = True` and also accepts `__call__(carry, obs, resets, initial)` with obs leaves `(s, B, size)` and
`resets` `(s, B)`, returning (final carry, `(s, B, F)`, `(s, B)`). Every built-in model does, through
`nets.models.run_cell`: its dense layers take all s x B rows at once and only its cells scan, which on a GPU is far
fewer kernel launches than a scan over every layer. Register a builder with `register_network(name, builder)` to select
it from `NetworkConfig.name`, or pass the module to `make_cycle` directly. A network of brain areas needs no Python:
`network.name: areas` builds `Areas` from the graph in `network.graph` (`AreaGraph`, see `nets.area_graph`).
"""

from angora_jax.nets.actor_critic import ActorCritic
from angora_jax.nets.area_graph import AreaGraph, AreaSpec, ValueSpec, check_graph
from angora_jax.nets.areas import Areas
from angora_jax.nets.models import FeedForward, ModalityEncoder, Recurrent, policy_inputs, value_inputs
from angora_jax.nets.registry import list_networks, make_network, register_network

__all__ = [
    "ActorCritic",
    "AreaGraph",
    "AreaSpec",
    "Areas",
    "FeedForward",
    "ModalityEncoder",
    "Recurrent",
    "ValueSpec",
    "check_graph",
    "list_networks",
    "make_network",
    "policy_inputs",
    "register_network",
    "value_inputs",
]
