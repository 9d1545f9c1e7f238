"""Activation functions of brain-area graphs (`network.graph.areas.<name>.activation`), by name.

`lif` is AngoraPy's LiF (`angorapy/common/activations.py`): the soft leaky integrate-and-fire rate of Hunsberger &
Eliasmith (2015), the steady firing rate of a LIF neuron under a constant input current, smoothed at the threshold so
that it has a gradient everywhere. It is a rate function, not a spiking neuron: it keeps no state between steps.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp

# Below this input (in units of gamma) softplus underflows in float32, and the rate's log takes its asymptote instead.
_LIF_ASYMPTOTE = -20.0
LIF_TAU_REF = 0.004  # s: AngoraPy's refractory period, so its rates stay below 1 / 0.004 s = 250 Hz


def lif(x: jax.Array, tau_rc: float = 0.02, tau_ref: float = LIF_TAU_REF, v_th: float = 1.0,
        gamma: float = 0.01) -> jax.Array:
    """AngoraPy's LiF rate (Hz) for input current `x` (any shape): `v_th / (tau_ref + tau_rc * log(1 + 1 / z))`
    with `z = gamma * softplus(x / gamma)`, a smooth `max(x, 0)`. Near 0 for very negative `x`, about `9.6 Hz` at 0
    (the smoothing), rising towards `v_th / tau_ref` for large `x`.

    Args:
        x: the input current.
        tau_rc: membrane time constant (s).
        tau_ref: refractory period (s), so the rate stays below `1 / tau_ref`.
        v_th: the firing threshold.
        gamma: smoothing of the threshold.
    """
    scaled = x / gamma
    valid = scaled > _LIF_ASYMPTOTE
    z = gamma * jax.nn.softplus(scaled)
    # Two `where`s: the unused branch of one still gets a gradient, which must not be NaN (1 / 0 where z underflows).
    q = jnp.where(valid, jnp.log1p(1.0 / jnp.where(valid, z, 1.0)), -scaled - jnp.log(gamma))
    return v_th / (tau_ref + tau_rc * q)


def lif_fraction(x: jax.Array) -> jax.Array:
    """`lif(x)` with AngoraPy's constants as a fraction of its maximum rate `1 / tau_ref` (250 Hz), so in [0, 1):
    the rates themselves (up to 250) would saturate the tanh of the areas they feed. 0.039 at `x = 0`."""
    return lif(x) * LIF_TAU_REF


ACTIVATIONS: dict[str, Callable[[jax.Array], jax.Array]] = {
    "tanh": jnp.tanh,
    "relu": jax.nn.relu,
    "lif": lif_fraction,
}

# The interval (low, high) holding every output of each activation and 0: where the state of a recurrent cell with
# that activation stays when it starts at 0 (an Elman update, a GRU's mixture of candidate and state, an LSTM's h).
ACTIVATION_RANGES: dict[str, tuple[float, float]] = {
    "tanh": (-1.0, 1.0),
    "relu": (0.0, float("inf")),
    "lif": (0.0, 1.0),
}
