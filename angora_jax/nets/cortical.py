"""`Cortical`: a policy network whose sub-networks are named after the cortical areas of a sensorimotor hierarchy,
wired like AngoraPy's "shadow brain" (Weidler et al. 2023, `angorapy/models/shadow.py`).

    SSC_1, SSC_2  somatosensory cortex   <- proprioception, touch
    SPL           superior parietal      <- vision, SSC
    IPL           inferior parietal      <- SPL
    IPS           intraparietal sulcus   <- IPL, SSC
    MCC           midcingulate cortex    <- goal, SSC
    LPFC          lateral prefrontal     <- MCC, goal, vision (the visual "what" input)
    PMC_in, PMC   premotor cortex        <- LPFC, IPL; PMC is recurrent (rnn, lstm or gru)
    M1            primary motor cortex   <- PMC, MCC, LPFC, SSC, IPS; its output goes to the policy head

Every area but PMC is one dense layer with tanh (`Area`), so an area's recorded activity (`network.<area>`) is its
units' output and a lesion of `network.<area>` silences units exactly. AngoraPy's sizes are the defaults; a config
changes any of them with `network.areas` (e.g. `{SSC_1: 32, PMC: 64}`; PMC's is the cell's size).

Value function: with `shared_trunk` (AngoraPy's wiring) a dense net reads PMC, MCC, IPS, LPFC, SSC_2 and the
`asymmetric` inputs, so value gradients shape the areas too; otherwise (the default) a separate MLP reads all
modalities and `asymmetric`, and the areas serve the policy alone. Either way no area sees `asymmetric`.
"""

from __future__ import annotations

from collections.abc import Mapping

import flax.linen as nn
import jax
import jax.numpy as jnp

from angora_jax.envs.core import Sensation
from angora_jax.nets.models import HIDDEN_INIT, MLP, recurrent_cell, value_head, value_inputs

# AngoraPy's shadow-brain sizes (units per area; PMC's is the recurrent cell's).
AREA_SIZES = {"SSC_1": 128, "SSC_2": 64, "SPL": 256, "IPL": 256, "IPS": 128, "MCC": 64, "LPFC": 128,
              "PMC_in": 512, "PMC": 512, "M1": 256}
VALUE_SIZES = (512, 512)


class Area(nn.Module):
    """A cortical area: tanh of one dense map of its inputs (concatenated along the last axis), `(B, features)`."""

    features: int

    @nn.compact
    def __call__(self, *inputs: jax.Array) -> jax.Array:
        x = jnp.concatenate(inputs, axis=-1)
        kernel = self.param("kernel", HIDDEN_INIT, (x.shape[-1], self.features))
        bias = self.param("bias", nn.initializers.zeros, (self.features,))
        return jnp.tanh(x @ kernel + bias)


def area_sizes(overrides: Mapping[str, int] | None = None) -> dict[str, int]:
    """AngoraPy's area sizes with `overrides` applied; ValueError naming the areas when one is unknown."""
    overrides = dict(overrides or {})
    unknown = sorted(set(overrides) - set(AREA_SIZES))
    if unknown:
        raise ValueError(f"Unknown areas {unknown} in network.areas; the cortical model's areas: {list(AREA_SIZES)}.")
    bad = {name: size for name, size in overrides.items() if not isinstance(size, int) or size < 1}
    if bad:
        raise ValueError(f"Area sizes must be positive integers, got {bad}.")
    return AREA_SIZES | overrides


class Cortical(nn.Module):
    """The brain-area model (module docstring). sizes: `((area, units), ...)`, every area of `AREA_SIZES`.
    cell: "rnn", "lstm" or "gru" for PMC. shared_trunk: AngoraPy's value wiring (see the module docstring)."""

    sizes: tuple[tuple[str, int], ...] = tuple(AREA_SIZES.items())
    cell: str = "lstm"
    shared_trunk: bool = False
    value_sizes: tuple[int, ...] = VALUE_SIZES

    def initial_carry(self, batch_size: int):
        zeros = jnp.zeros((batch_size, dict(self.sizes)["PMC"]), jnp.float32)
        return (zeros, zeros) if self.cell == "lstm" else zeros

    @nn.compact
    def __call__(self, carry, obs: Sensation):
        size = dict(self.sizes)
        ssc = Area(size["SSC_2"], name="SSC_2")(Area(size["SSC_1"], name="SSC_1")(obs.proprioception, obs.touch))
        spl = Area(size["SPL"], name="SPL")(obs.vision, ssc)
        ipl = Area(size["IPL"], name="IPL")(spl)
        ips = Area(size["IPS"], name="IPS")(ipl, ssc)
        mcc = Area(size["MCC"], name="MCC")(obs.goal, ssc)
        lpfc = Area(size["LPFC"], name="LPFC")(mcc, obs.goal, obs.vision)
        pmc_in = Area(size["PMC_in"], name="PMC_in")(lpfc, ipl)
        carry, pmc = recurrent_cell(self.cell, size["PMC"], "PMC")(carry, pmc_in)
        m1 = Area(size["M1"], name="M1")(pmc, mcc, lpfc, ssc, ips)
        if self.shared_trunk:
            value_features = jnp.concatenate([pmc, mcc, ips, lpfc, ssc, obs.asymmetric], axis=-1)
        else:
            value_features = value_inputs(obs)
        return carry, m1, value_head(MLP(self.value_sizes, name="value_net")(value_features))
