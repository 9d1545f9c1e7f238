"""In-silico lesions: silence units of a dense layer and see what the task metric loses.

A unit of a dense layer is silenced by zeroing its kernel column and bias entry: its pre-activation is then 0, and
so is its output after the networks' tanh (or relu). The rest of the network is untouched, and an empty unit set
leaves the parameters bit for bit as they were.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import jax
import numpy as np

from angora_jax.experiment.agent import Agent


def dense_layers(agent: Agent) -> dict[str, int]:
    """The lesionable layers of `agent`: dense layer name (module path, as in recordings) -> its number of units."""
    found = {}
    for path, leaf in jax.tree_util.tree_flatten_with_path(agent.params)[0]:
        names = [str(getattr(p, "key", p)) for p in path]
        if names[-1] == "kernel" and leaf.ndim == 2:
            found[".".join(names[:-1])] = int(leaf.shape[-1])
    return found


def lesion(agent: Agent, layer: str, units: Sequence[int] | np.ndarray) -> Agent:
    """`agent` with `units` (indices) of dense layer `layer` silenced; ValueError naming the layers when unknown."""
    layers = dense_layers(agent)
    if layer not in layers:
        raise ValueError(f"No dense layer {layer!r} to lesion; the agent's dense layers: {sorted(layers)}.")
    units = np.asarray(units, int)
    if units.size and (units.min() < 0 or units.max() >= layers[layer]):
        raise ValueError(f"Units {units.tolist()} out of range for {layer!r}, which has {layers[layer]} units.")
    if not units.size:
        return agent

    def silence(path, leaf):
        names = [str(getattr(p, "key", p)) for p in path]
        if ".".join(names[:-1]) != layer:
            return leaf
        return leaf.at[..., units].set(0.0)

    params = jax.tree_util.tree_map_with_path(silence, agent.params)
    return replace(agent, state=agent.state.replace(params=params))


def lesion_fraction(agent: Agent, layer: str, fraction: float, seed: int = 0) -> Agent:
    """`lesion` of a random `fraction` (0 to 1) of the layer's units, drawn with `seed`."""
    if not 0.0 <= fraction <= 1.0:
        raise ValueError(f"fraction must lie in [0, 1], got {fraction}.")
    size = dense_layers(agent).get(layer, 0)
    units = np.random.default_rng(seed).permutation(size)[: round(fraction * size)]
    return lesion(agent, layer, units)
