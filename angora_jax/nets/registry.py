"""Network registry: `make_network(ppo.NetworkConfig)` builds a registered model; `register_network` adds one."""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol

import flax.linen as nn

from angora_jax.nets.area_graph import AreaGraph, check_graph
from angora_jax.nets.areas import Areas
from angora_jax.nets.cortical import area_sizes, cortical_graph
from angora_jax.nets.models import FeedForward, Recurrent
from angora_jax.registry import Registry


class NetworkSettings(Protocol):
    """What the shipped builders read of a run's `ppo.network` section (`angora_jax.ppo.NetworkConfig`, whose
    docstring says what each means, is one); a builder of one's own gets the whole section. Declared here since ppo,
    which holds the config, builds on nets."""

    name: str
    width: int | None
    cell_size: int | None
    shared_trunk: bool
    memory: int
    cell: str | None
    areas: dict[str, int]
    graph: AreaGraph | None


NETWORKS: Registry[Callable[[NetworkSettings], nn.Module]] = Registry("network", "networks")


def register_network(name: str, builder: Callable[[NetworkSettings], nn.Module]) -> None:
    """Make `builder(network_config) -> module` (a module following the network contract) available by name."""
    NETWORKS.register(name, builder)


def list_networks() -> list[str]:
    """Names of all registered networks, sorted."""
    return NETWORKS.names()


def make_network(config: NetworkSettings) -> nn.Module:
    """Build the network `config.name` with the sizes in `config`."""
    return NETWORKS.get(config.name)(config)


def _recurrent(cell: str, encoder: str, width: int, cell_size: int) -> Callable[[NetworkSettings], nn.Module]:
    def build(config: NetworkSettings) -> nn.Module:
        return Recurrent(
            width=config.width or width,
            cell_size=config.cell_size or cell_size,
            cell=config.cell or cell,
            encoder=encoder,
            shared=config.shared_trunk,
        )

    return build


register_network("simple", lambda c: FeedForward(sizes=(c.width or 64,) * 2, shared=c.shared_trunk, memory=c.memory))
register_network("deeper", lambda c: FeedForward(sizes=(c.width or 64,) * 4, shared=c.shared_trunk, memory=c.memory))
register_network("rnn", _recurrent("rnn", "modality", width=64, cell_size=64))
register_network("lstm", _recurrent("lstm", "modality", width=64, cell_size=64))
register_network("gru", _recurrent("gru", "modality", width=64, cell_size=64))
# OpenAI's in-hand manipulation policy: modalities concatenated, a dense embedding, then a wide LSTM (network.cell
# may make it an rnn or gru).
register_network("wide", _recurrent("lstm", "concat", width=512, cell_size=1024))


def _cortical(config: NetworkSettings) -> nn.Module:
    """AngoraPy's shadow brain (`angora_jax.nets.cortical`): cell_size sizes the premotor cell (PMC) unless
    network.areas does; width sets the value net's two layers."""
    sizes = area_sizes(({"PMC": config.cell_size} if config.cell_size else {}) | config.areas)
    return Areas(cortical_graph(sizes, cell=config.cell or "lstm", shared_trunk=config.shared_trunk,
                                value_sizes=(config.width or 512,) * 2))


def _areas(config: NetworkSettings) -> nn.Module:
    """The brain-area graph of the config (`angora_jax.nets.area_graph`)."""
    return Areas(check_graph(config.graph))


register_network("cortical", _cortical)
register_network("areas", _areas)
