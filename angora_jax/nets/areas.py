"""`Areas`: the network of a brain-area graph (`angora_jax.nets.area_graph`), the `areas` network of a config
(`network.name: areas` with `network.graph`). The built-in `cortical` model is one such graph
(`angora_jax.nets.cortical.cortical_graph`).

Each area is a submodule named as the area, so its parameters are `network.<area>`; a dense area's recorded activity
is `network.<area>` (its units' output) and a recurrent area's `network.<area>.0` and `.1` (its carry and output, as
any cell's); `analysis.lesion_area(agent, "network.<area>")` silences a dense area's units. The carry holds each
recurrent area's cell state by name (`{"PMC": ...}`), or is empty `(B, 0)` when no area is recurrent.
"""

from __future__ import annotations

from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp

from angora_jax.envs.core import Sensation
from angora_jax.nets.activations import ACTIVATIONS
from angora_jax.nets.area_graph import VALUE_MODALITIES, AreaGraph, evaluation_order, feedback_inputs
from angora_jax.nets.models import (
    HIDDEN_INIT,
    MLP,
    cell_output,
    initial_cell_carry,
    recurrent_cell,
    run_cell,
    value_head,
)


class Area(nn.Module):
    """A dense area: the activation of one dense map of its inputs (concatenated along the last axis),
    `(B, features)`; orthogonal kernel (gain sqrt 2), zero bias.

    Attributes:
        activation: a name of `nets.activations.ACTIVATIONS`.
    """

    features: int
    activation: str = "tanh"

    @nn.compact
    def __call__(self, *inputs: jax.Array) -> jax.Array:
        x = jnp.concatenate(inputs, axis=-1)
        kernel = self.param("kernel", HIDDEN_INIT, (x.shape[-1], self.features))
        bias = self.param("bias", nn.initializers.zeros, (self.features,))
        return ACTIVATIONS[self.activation](x @ kernel + bias)


class Areas(nn.Module):
    """The network of `graph` (checked with `area_graph.check_graph`), following the network contract: one step
    `(carry, obs) -> (carry, policy features (B, policy area's size), value (B,))`. Areas are computed in
    `evaluation_order`; a feedback input reads its recurrent source's output of the previous step from the carry.

    A graph without feedback inputs also runs whole sequences (`runs_sequences`, see `angora_jax.nets`): every dense
    area and the value net take all s x B rows at once and only the recurrent areas scan, each over its inputs'
    sequence. With feedback, an area's input at t needs a cell's output at t - 1, so training scans the whole step.
    """

    graph: AreaGraph

    @property
    def runs_sequences(self) -> bool:
        return not feedback_inputs(self.graph)

    def initial_carry(self, batch_size: int) -> Any:
        recurrent = {name: spec for name, spec in self.graph.areas.items() if spec.cell is not None}
        if not recurrent:
            return jnp.zeros((batch_size, 0), jnp.float32)
        return {name: initial_cell_carry(spec.cell, spec.size, batch_size) for name, spec in recurrent.items()}

    @nn.compact
    def __call__(self, carry: Any, obs: Sensation, resets: jax.Array | None = None,
                 initial: Any = None) -> tuple[Any, jax.Array, jax.Array]:
        areas, feedback = self.graph.areas, feedback_inputs(self.graph)
        if resets is not None and feedback:
            raise ValueError(f"A graph with feedback inputs {sorted(feedback)} runs one step at a time: call it "
                             "without resets (the trainer scans it; see runs_sequences).")
        outputs = {modality: getattr(obs, modality) for modality in VALUE_MODALITIES}
        new_carry = {}
        for name in evaluation_order(self.graph):
            spec = areas[name]
            inputs = [cell_output(areas[source].cell, carry[source]) if (name, source) in feedback else outputs[source]
                      for source in spec.inputs]
            if spec.cell is None:
                outputs[name] = Area(spec.size, spec.activation, name=name)(*inputs)
            else:
                cell = recurrent_cell(spec.cell, spec.size, name, ACTIVATIONS[spec.activation])
                start = None if initial is None else initial[name]
                new_carry[name], outputs[name] = run_cell(cell, carry[name], jnp.concatenate(inputs, axis=-1),
                                                          resets, start)
        value_features = jnp.concatenate([outputs[source] for source in self.graph.value.inputs], axis=-1)
        value = value_head(MLP(self.graph.value.sizes, name="value_net")(value_features))
        return new_carry or carry, outputs[self.graph.policy], value
