"""The brain-area model `cortical`: AngoraPy's "shadow brain" (Weidler et al. 2023, `angorapy/models/shadow.py`) as
a fixed brain-area graph (`cortical_graph`), built by `angora_jax.nets.areas.Areas` like any `areas` network. Its
areas are named after the cortical areas of a sensorimotor hierarchy:

    SSC_1, SSC_2  somatosensory cortex   <- proprioception, touch, muscle
    SPL           superior parietal      <- vision, SSC
    IPL           inferior parietal      <- SPL
    IPS           intraparietal sulcus   <- IPL, SSC
    MCC           midcingulate cortex    <- goal, SSC
    LPFC          lateral prefrontal     <- MCC, goal, vision (the visual "what" input)
    PMC_in, PMC   premotor cortex        <- LPFC, IPL; PMC is recurrent (rnn, lstm or gru)
    M1            primary motor cortex   <- PMC, MCC, LPFC, SSC, IPS; its output goes to the policy head

Every area but PMC is one dense layer with tanh, so an area's recorded activity (`network.<area>`) is its units'
output and a lesion of `network.<area>` silences units exactly. AngoraPy's sizes are the defaults; a config changes
any of them with `network.areas` (e.g. `{SSC_1: 32, PMC: 64}`; PMC's is the cell's size). The shipped config
`shadow_reach_cortical_graph` writes out the same graph in YAML.

Value function: with `shared_trunk` (AngoraPy's wiring) a dense net reads PMC, MCC, IPS, LPFC, SSC_2 and the
`asymmetric` inputs, so value gradients shape the areas too; otherwise (the default) a separate MLP reads all
modalities and `asymmetric`, and the areas serve the policy alone. Either way no area sees `asymmetric`.
"""

from __future__ import annotations

import difflib
from collections.abc import Mapping

from angora_jax.nets.area_graph import VALUE_MODALITIES, AreaGraph, AreaSpec, ValueSpec

# AngoraPy's shadow-brain sizes (units per area; PMC's is the recurrent cell's).
AREA_SIZES = {"SSC_1": 128, "SSC_2": 64, "SPL": 256, "IPL": 256, "IPS": 128, "MCC": 64, "LPFC": 128,
              "PMC_in": 512, "PMC": 512, "M1": 256}
VALUE_SIZES = (512, 512)
# Each area's inputs in the order they are concatenated (the order of its kernel's rows).
# SSC_1 reads the muscle sense as area 3a of S1 receives muscle spindle afferents.
WIRING = {"SSC_1": ("proprioception", "touch", "muscle"), "SSC_2": ("SSC_1",), "SPL": ("vision", "SSC_2"),
          "IPL": ("SPL",), "IPS": ("IPL", "SSC_2"), "MCC": ("goal", "SSC_2"), "LPFC": ("MCC", "goal", "vision"),
          "PMC_in": ("LPFC", "IPL"), "PMC": ("PMC_in",), "M1": ("PMC", "MCC", "LPFC", "SSC_2", "IPS")}
SHARED_VALUE_INPUTS = ("PMC", "MCC", "IPS", "LPFC", "SSC_2", "asymmetric")


def area_sizes(overrides: Mapping[str, int] | None = None) -> dict[str, int]:
    """AngoraPy's area sizes with `overrides` applied; ValueError naming the areas when one is unknown."""
    overrides = dict(overrides or {})
    unknown = sorted(set(overrides) - set(AREA_SIZES))
    if unknown:
        guesses = [close[0] for name in unknown if (close := difflib.get_close_matches(name, AREA_SIZES, n=1))]
        hint = f" Did you mean {' and '.join(map(repr, guesses))}?" if guesses else ""
        raise ValueError(f"Unknown areas {unknown} in network.areas.{hint} The cortical model's areas: "
                         f"{list(AREA_SIZES)}.")
    bad = {name: size for name, size in overrides.items() if not isinstance(size, int) or size < 1}
    if bad:
        raise ValueError(f"Area sizes must be positive integers, got {bad}.")
    return AREA_SIZES | overrides


def cortical_graph(sizes: Mapping[str, int] = AREA_SIZES, cell: str = "lstm", shared_trunk: bool = False,
                   value_sizes: tuple[int, ...] = VALUE_SIZES) -> AreaGraph:
    """The `cortical` model's graph.

    Args:
        sizes: units per area, every area of `AREA_SIZES` (see `area_sizes`).
        cell: "rnn", "lstm" or "gru" for PMC.
        shared_trunk: AngoraPy's value wiring (see the module docstring).
        value_sizes: the value net's layers.
    """
    areas = {name: AreaSpec(size=sizes[name], inputs=inputs, cell=cell if name == "PMC" else None)
             for name, inputs in WIRING.items()}
    value_inputs = SHARED_VALUE_INPUTS if shared_trunk else VALUE_MODALITIES
    return AreaGraph(areas=areas, policy="M1", value=ValueSpec(inputs=value_inputs, sizes=tuple(value_sizes)))
