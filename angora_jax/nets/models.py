"""Built-in networks. Each follows the network contract (see `angora_jax.nets`): one time step for a batch,
`__call__(carry, obs) -> (carry, policy_features, value)`, plus `initial_carry(batch_size)`.

Policy inputs are the modalities proprioception, touch, muscle, vision and goal; `asymmetric` reaches only the value
function. Empty modalities (size 0) are skipped, so no model assumes any particular one is present.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np

from angora_jax.envs.core import Sensation
from angora_jax.envs.mjx_env import on_gpu

POLICY_MODALITIES = ("proprioception", "touch", "muscle", "vision", "goal")

HIDDEN_INIT = nn.initializers.orthogonal(np.sqrt(2.0))
_VALUE_INIT = nn.initializers.orthogonal(1.0)


def policy_inputs(obs: Sensation) -> jax.Array:
    """The modalities the policy may read, concatenated: `(B, sum of sizes)`."""
    return jnp.concatenate([getattr(obs, name) for name in POLICY_MODALITIES], axis=-1)


def value_inputs(obs: Sensation) -> jax.Array:
    """Policy modalities plus `asymmetric`, concatenated: `(B, sum of sizes)`."""
    return jnp.concatenate([policy_inputs(obs), obs.asymmetric], axis=-1)


class MLP(nn.Module):
    """Dense layers with tanh, orthogonal init (gain sqrt 2)."""

    sizes: tuple[int, ...]

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        for size in self.sizes:
            x = jnp.tanh(nn.Dense(size, kernel_init=HIDDEN_INIT)(x))
        return x


def value_head(features: jax.Array, name: str = "value") -> jax.Array:
    """The value estimate `(B,)` from features `(B, F)`: one dense unit, orthogonal init with gain 1."""
    return nn.Dense(1, kernel_init=_VALUE_INIT, name=name)(features)[..., 0]


class FeedForward(nn.Module):
    """MLP policy and value, the policy with an optional memory; without one the carry is an empty `(B, 0)` array, so
    it shares the recurrent training path.

    Attributes:
        sizes: units of each dense layer of a trunk.
        shared: one trunk over the policy modalities; the value head reads its features and `asymmetric`. Otherwise a
            separate value trunk reads all modalities including `asymmetric`.
        memory: units of a GRU beside the policy trunk (0: none). It reads the policy's inputs, and its output is
            added to the trunk's features through a layer that starts at zero (`memory_out`), so the network starts
            as the MLP alone: `ppo.init_from` a run of the same MLP without memory gives its policy unchanged, and
            training then lets it use what it remembers (a policy that infers the physics drawn by domain
            randomization from what its actions did). The carry is the GRU's `(B, memory)` state.
    """

    sizes: tuple[int, ...] = (64, 64)
    shared: bool = False
    memory: int = 0
    runs_sequences = True

    # The modules that memory adds to the MLP: `ppo.init_from` a run without them keeps them as initialized.
    MEMORY_MODULES = ("policy_memory", "memory_out")

    def initial_carry(self, batch_size: int) -> jax.Array:
        return initial_cell_carry("gru", self.memory, batch_size)

    @nn.compact
    def __call__(self, carry: jax.Array, obs: Sensation, resets: jax.Array | None = None,
                 initial: jax.Array | None = None) -> tuple[jax.Array, jax.Array, jax.Array]:
        inputs = policy_inputs(obs)
        features = MLP(self.sizes, name="policy_trunk")(inputs)
        if self.memory:
            carry, remembered = run_cell(recurrent_cell("gru", self.memory, "policy_memory"), carry, inputs, resets,
                                         initial)
            features = features + nn.Dense(features.shape[-1], kernel_init=nn.initializers.zeros,
                                           name="memory_out")(remembered)
        if self.shared:
            value = value_head(jnp.concatenate([features, obs.asymmetric], axis=-1))
        else:
            value = value_head(MLP(self.sizes, name="value_trunk")(value_inputs(obs)))
        return carry, features, value


class ModalityEncoder(nn.Module):
    """Embeds each non-empty modality with its own dense layer and concatenates the embeddings, so modalities
    enter separately (a subclass can route them to different sub-networks)."""

    width: int
    modalities: tuple[str, ...] = POLICY_MODALITIES

    @nn.compact
    def __call__(self, obs: Sensation) -> jax.Array:
        parts = [
            jnp.tanh(nn.Dense(self.width, kernel_init=HIDDEN_INIT, name=f"embed_{name}")(getattr(obs, name)))
            for name in self.modalities
            if getattr(obs, name).shape[-1] > 0
        ]
        return jnp.concatenate(parts, axis=-1)


class ConcatEncoder(nn.Module):
    """Concatenates the modalities, then one dense embedding (OpenAI-style)."""

    width: int
    modalities: tuple[str, ...] = POLICY_MODALITIES

    @nn.compact
    def __call__(self, obs: Sensation) -> jax.Array:
        x = jnp.concatenate([getattr(obs, name) for name in self.modalities], axis=-1)
        return jnp.tanh(nn.Dense(self.width, kernel_init=HIDDEN_INIT)(x))


RECURRENT_CELLS = ("rnn", "lstm", "gru")


def recurrent_cell(kind: str, size: int, name: str, activation: Callable[[jax.Array], jax.Array] = jnp.tanh
                   ) -> nn.RNNCellBase:
    """A flax cell of `size` units: "rnn" (Elman), "lstm" or "gru", with `activation` in its update (the Elman
    update's, the LSTM's and GRU's candidate); its carry is `(c, h)` for an LSTM and `h` otherwise, each `(B, size)`
    (see `initial_cell_carry`), and its output `h`."""
    if kind == "rnn":
        return nn.SimpleCell(size, activation_fn=activation, name=name)
    if kind == "lstm":
        return nn.OptimizedLSTMCell(size, activation_fn=activation, name=name)
    if kind == "gru":
        return nn.GRUCell(size, activation_fn=activation, name=name)
    raise ValueError(f"Unknown recurrent cell {kind!r}; use one of {RECURRENT_CELLS}.")


def initial_cell_carry(kind: str, size: int, batch_size: int) -> jax.Array | tuple[jax.Array, jax.Array]:
    """The zero carry of a `recurrent_cell` of `kind` and `size` for `batch_size` environments."""
    zeros = jnp.zeros((batch_size, size), jnp.float32)
    return (zeros, zeros) if kind == "lstm" else zeros


# Longest sequence that `run_cell` unrolls on a GPU instead of looping over.
MAX_UNROLLED_STEPS = 32


def unrolled_steps(length: int) -> int:
    """How many steps of a training sequence of `length` steps `run_cell` unrolls per loop iteration: the whole
    sequence (a TBPTT chunk, 16 steps by default; up to MAX_UNROLLED_STEPS) on a GPU, where a loop pays bookkeeping
    per step and blocks fusion across steps; 1 (a plain loop) on a CPU, where the loop runs faster. Either way the
    same steps are computed. Measured by benchmarks/cell_unroll.py: on one H100 at 8,192 envs, unrolled cycles of
    the cube's brain-area config take 0.93 of the loop's time and the paper's 1024-unit LSTM's 0.80; on 2 CPU cores
    the test suite's brain-area reach cycle takes 0.63 s looped against 0.70 s unrolled."""
    return length if on_gpu() and length <= MAX_UNROLLED_STEPS else 1


def reset_carry(carry: Any, initial: Any, reset: jax.Array) -> Any:
    """Replace the carry by `initial` in the rows where `reset` `(B,)` is nonzero (an episode starts there)."""

    def pick(init, current):
        mask = reset.reshape(reset.shape + (1,) * (current.ndim - 1)) > 0
        return jnp.where(mask, init, current)

    return jax.tree.map(pick, initial, carry)


def run_cell(cell: nn.RNNCellBase, carry: Any, inputs: jax.Array, resets: jax.Array | None = None,
             initial: Any = None) -> tuple[Any, jax.Array]:
    """`cell` for one step, `(carry, inputs (B, F)) -> (carry, output (B, size))`; or, given `resets` `(s, B)`, over
    a sequence `inputs (s, B, F)` -> (final carry, outputs (s, B, size)), the carry replaced by `initial` before
    each step where `resets` is set. Only the cell is scanned: what feeds it ran before as one batch of s x B rows."""
    if resets is None:
        return cell(carry, inputs)

    def step(cell, carry, x):
        inputs_t, reset_t = x
        return cell(reset_carry(carry, initial, reset_t), inputs_t)

    return nn.scan(step, variable_broadcast="params", split_rngs={"params": False},
                   unroll=unrolled_steps(inputs.shape[0]))(
        cell, carry, (inputs, resets))


def cell_output(kind: str, carry: jax.Array | tuple[jax.Array, jax.Array]) -> jax.Array:
    """The output `h` that a `recurrent_cell` of `kind` gave with `carry`: the LSTM's second entry, else the carry."""
    return carry[1] if kind == "lstm" else carry


class Recurrent(nn.Module):
    """Encoder, then a recurrent cell (Elman RNN, LSTM or GRU), then the heads.

    Attributes:
        width: units of the encoder's embeddings.
        cell_size: units of the recurrent cell.
        cell: "rnn", "lstm" or "gru".
        encoder: "modality" (one embedding per modality) or "concat" (one embedding of all).
        shared: the value head reads the policy's recurrent features and `asymmetric`; otherwise a second encoder +
            cell reads all modalities including `asymmetric` and the carry holds both cells' states.
    """

    width: int = 64
    cell_size: int = 64
    cell: str = "lstm"
    encoder: str = "modality"
    shared: bool = False
    runs_sequences = True

    def initial_carry(self, batch_size: int):
        pathways = ("policy",) if self.shared else ("policy", "value")
        return {pathway: initial_cell_carry(self.cell, self.cell_size, batch_size) for pathway in pathways}

    def _encode(self, obs: Sensation, modalities: tuple[str, ...], name: str) -> jax.Array:
        encoder = ModalityEncoder if self.encoder == "modality" else ConcatEncoder
        return encoder(self.width, modalities, name=name)(obs)

    @nn.compact
    def __call__(self, carry, obs: Sensation, resets: jax.Array | None = None, initial=None):
        def cell(pathway: str, inputs: jax.Array):
            start = None if initial is None else initial[pathway]
            module = recurrent_cell(self.cell, self.cell_size, f"{pathway}_cell")
            return run_cell(module, carry[pathway], inputs, resets, start)

        policy_carry, features = cell("policy", self._encode(obs, POLICY_MODALITIES, "policy_encoder"))
        new_carry = {"policy": policy_carry}
        if self.shared:
            value = value_head(jnp.concatenate([features, obs.asymmetric], axis=-1))
        else:
            all_modalities = POLICY_MODALITIES + ("asymmetric",)
            new_carry["value"], value_features = cell("value", self._encode(obs, all_modalities, "value_encoder"))
            value = value_head(value_features)
        return new_carry, features, value
