"""Brain-area graphs: the wiring of the `areas` network (`angora_jax.nets.areas`) as data, given in a config's
`ppo.network.graph`, and `check_graph`, which refuses a graph that cannot run before anything compiles, naming the
area and the fix.

    ppo:
      network:
        name: areas
        graph:
          areas:                   # each area reads its inputs concatenated, in the order listed
            S1:  {size: 64, inputs: [proprioception, touch, PMC]}
            PMC: {size: 64, inputs: [S1, goal], cell: gru}
            M1:  {size: 32, inputs: [PMC, S1], activation: lif}
          policy: M1               # the area the policy head reads
          value: {inputs: [proprioception, touch, vision, goal, asymmetric], sizes: [512, 512]}

An area's inputs are other areas and the policy's input modalities (proprioception, touch, muscle, vision, goal);
only the value function may read `asymmetric` (privileged information such as the object's true pose). A dense area
is one dense layer and its activation; a recurrent area (`cell`) is an rnn, lstm or gru cell over its inputs.

Recurrence closes loops. An area that reads a recurrent area which itself depends on it (a feedback input: above,
S1 reads PMC and PMC reads S1) reads that area's output of the previous step, from the carry; every other input is
the same step's (above, S1 then PMC then M1). So a loop must pass through a recurrent area: a loop of dense areas
alone could not be computed and is refused.
"""

from __future__ import annotations

import difflib
from dataclasses import field

from angora_jax.frozen_settings import settings
from angora_jax.nets.activations import ACTIVATIONS
from angora_jax.nets.models import POLICY_MODALITIES, RECURRENT_CELLS

VALUE_ONLY = "asymmetric"
VALUE_MODALITIES = (*POLICY_MODALITIES, VALUE_ONLY)
# The network's own submodules beside the areas: no area may take their names.
RESERVED = ("value_net", "value")


@settings
class AreaSpec:
    """One area of a graph.

    Attributes:
        size: its units (a recurrent area's: its cell's).
        inputs: what it reads, concatenated in this order: other areas and the modalities proprioception, touch, muscle,
            vision and goal.
        activation: "tanh", "relu" or "lif" (AngoraPy's leaky integrate-and-fire rate, as a fraction of its maximum:
            `angora_jax.nets.activations`); a recurrent area's cell uses it for its update.
        cell: null for a dense area (one dense layer, then the activation), or "rnn" (Elman), "lstm" or "gru" for a
            recurrent one.
    """

    size: int
    inputs: tuple[str, ...]
    activation: str = "tanh"
    cell: str | None = None


@settings
class ValueSpec:
    """The value function of a graph.

    Attributes:
        inputs: what the value net reads, concatenated in this order: modalities, `asymmetric` and areas.
        sizes: the value net's dense tanh layers (`network.value_net`) before the value head (`network.value`); empty,
            the head reads the inputs directly.
    """

    inputs: tuple[str, ...] = VALUE_MODALITIES
    sizes: tuple[int, ...] = (512, 512)


@settings
class AreaGraph:
    """The wiring of an `areas` network (see the module docstring for an example).

    Attributes:
        areas: area name -> `AreaSpec` (its size, inputs, activation and cell); names are letters, digits and
            underscores, and become module paths (`network.<name>`) in parameters, recordings and lesions.
        policy: the area whose output the policy head reads.
        value: the value function (`ValueSpec`); by default, as for the `cortical` model, a separate two-layer net over
            every modality and `asymmetric`, so that the areas serve the policy alone.
    """

    areas: dict[str, AreaSpec]
    policy: str
    value: ValueSpec = field(default_factory=ValueSpec)

    def __hash__(self) -> int:
        # Flax modules hash their fields; a dict cannot be hashed, its items can.
        return hash((tuple(self.areas.items()), self.policy, self.value))


def area_inputs(graph: AreaGraph) -> dict[str, tuple[str, ...]]:
    """Area -> the areas among its inputs (its modalities left out)."""
    return {name: tuple(source for source in spec.inputs if source in graph.areas)
            for name, spec in graph.areas.items()}


def policy_modalities(graph: AreaGraph) -> set[str]:
    """The modalities that reach the policy: those read by its area or any area on the way to it."""
    reads = area_inputs(graph)
    side = {graph.policy, *upstream(reads, graph.policy)}
    return {source for area in side for source in graph.areas[area].inputs if source in POLICY_MODALITIES}


def upstream(reads: dict[str, tuple[str, ...]], area: str) -> set[str]:
    """Every area that `area` depends on through `reads` (area -> areas it reads), at any depth; `area` itself only
    when it lies on a cycle."""
    found: set[str] = set()
    stack = list(reads[area])
    while stack:
        source = stack.pop()
        if source not in found:
            found.add(source)
            stack.extend(reads[source])
    return found


def feedback_inputs(graph: AreaGraph) -> frozenset[tuple[str, str]]:
    """`(area, source)` pairs where `area` reads the recurrent area `source` from the previous step: `source` depends
    on `area`, so the input closes a loop through `source`'s recurrence."""
    reads = area_inputs(graph)
    return frozenset((area, source) for area, sources in reads.items() for source in sources
                     if graph.areas[source].cell is not None and area in upstream(reads, source))


def evaluation_order(graph: AreaGraph) -> tuple[str, ...]:
    """The areas in an order that computes each after every area it reads at the same step (those it reads as
    feedback come later), keeping the listed order where the wiring allows; ValueError for a cycle of dense areas."""
    feedback = feedback_inputs(graph)
    waiting = {area: {s for s in sources if (area, s) not in feedback} for area, sources in area_inputs(graph).items()}
    order: list[str] = []
    while waiting:
        ready = next((area for area, sources in waiting.items() if not sources - set(order)), None)
        if ready is None:
            cycle = " -> ".join(_cycle({area: tuple(sources) for area, sources in waiting.items()}))
            raise ValueError(
                f"network.graph.areas: {cycle} form a loop of dense areas, which no step can compute (each needs the "
                "other's output of the same step): make one of them recurrent (cell: rnn, lstm or gru), so that the "
                "loop passes its previous step's output, or remove one of these inputs.")
        order.append(ready)
        del waiting[ready]
    return tuple(order)


def _cycle(reads: dict[str, tuple[str, ...]]) -> list[str]:
    """One cycle of `reads` (area -> areas it reads, with at least one cycle), in the direction of the signal."""
    area = next(iter(reads))
    path: list[str] = []
    while area not in path:  # every area left waits on one: following the first wait from anywhere loops
        path.append(area)
        area = next(source for source in reads[area] if source in reads)
    loop = path[path.index(area):] + [area]
    return loop[::-1]


def check_graph(graph: AreaGraph | None) -> AreaGraph:
    """Return `graph` when an `areas` network can be built from it; otherwise raise a ValueError naming the area
    (`network.graph.areas.<name>`) or key and the fix: no graph, an input that is neither an area nor a modality, an
    area that reads `asymmetric`, a loop of dense areas, an area (and so its inputs) that reaches neither head, a
    policy that no input reaches, an unknown activation or cell, a size that is not positive."""
    if graph is None:
        raise ValueError("network.name=areas needs network.graph: the areas, the area the policy reads and the value "
                         "net (see the shipped config shadow_reach_cortical_graph).")
    if not graph.areas:
        raise ValueError("network.graph.areas is empty: give the areas, e.g. {M1: {size: 64, inputs: [proprioception, "
                         "goal]}}, and name the one the policy reads in network.graph.policy.")
    for name, spec in graph.areas.items():
        _check_area(graph, name, spec)
    if graph.policy not in graph.areas:
        raise ValueError(f"network.graph.policy={graph.policy!r} is not an area{_close(graph.policy, graph.areas)}: "
                         f"name the area whose output the policy head reads, one of {', '.join(graph.areas)}.")
    value = graph.value
    if not value.inputs:
        raise ValueError(f"network.graph.value.inputs is empty: list what the value net reads, e.g. "
                         f"[{', '.join(VALUE_MODALITIES)}].")
    _check_sources("network.graph.value.inputs", value.inputs, graph, (*graph.areas, *VALUE_MODALITIES))
    if any(not isinstance(size, int) or size < 1 for size in value.sizes):
        raise ValueError(f"network.graph.value.sizes are the value net's layer sizes, positive integers; got "
                         f"{list(value.sizes)}.")
    evaluation_order(graph)
    reads = area_inputs(graph)
    heads = {graph.policy, *(source for source in value.inputs if source in graph.areas)}
    used = heads.union(*(upstream(reads, area) for area in heads))
    for name, spec in graph.areas.items():
        if name not in used:
            # Most often a misspelt override (`areas.PMC_In=...` for PMC_in) that made a new area: say so first.
            others = [other for other in graph.areas if other != name]
            misspelt = difflib.get_close_matches(name, others, n=1)
            hint = (f" If you meant the area {misspelt[0]!r}, an override of a name that is not an area's makes a new "
                    f"area: the areas are {', '.join(others)}.") if misspelt else ""
            raise ValueError(
                f"network.graph.areas.{name} reaches neither head: no area on the way to the policy "
                f"({graph.policy}) or the value net reads it, so its inputs ({', '.join(spec.inputs)}) reach nothing. "
                f"List {name} in the inputs of such an area or in network.graph.value.inputs, or remove it.{hint}")
    policy_side = sorted({graph.policy, *upstream(reads, graph.policy)})
    if not any(source in POLICY_MODALITIES for area in policy_side for source in graph.areas[area].inputs):
        raise ValueError(
            f"network.graph.policy={graph.policy!r}: no input modality reaches it, its areas "
            f"({', '.join(policy_side)}) read only each other. List one of {', '.join(POLICY_MODALITIES)} in the "
            "inputs of one of them.")
    return graph


def _check_area(graph: AreaGraph, name: str, spec: AreaSpec) -> None:
    where = f"network.graph.areas.{name}"
    if not name.isidentifier():
        raise ValueError(f"network.graph.areas: {name!r} cannot name an area; use letters, digits and underscores "
                         "(module paths join names with dots, e.g. network.PMC).")
    if name in (*VALUE_MODALITIES, *RESERVED):
        kind = "an input modality" if name in VALUE_MODALITIES else "the network's value net or head"
        raise ValueError(f"network.graph.areas: {name!r} names {kind}; give the area another name.")
    if not isinstance(spec.size, int) or spec.size < 1:
        raise ValueError(f"{where}.size must be a positive integer (the area's units), got {spec.size!r}.")
    if not spec.inputs:
        raise ValueError(f"{where}.inputs is empty: list what {name} reads, areas or modalities "
                         f"({', '.join(POLICY_MODALITIES)}).")
    if VALUE_ONLY in spec.inputs:
        raise ValueError(f"{where} reads {VALUE_ONLY!r}, which only the value function may read (the policy must act "
                         f"on what the agent senses): list it in network.graph.value.inputs instead.")
    _check_sources(f"{where}.inputs", spec.inputs, graph, (*graph.areas, *POLICY_MODALITIES))
    if spec.activation not in ACTIVATIONS:
        raise ValueError(f"{where}.activation={spec.activation!r} is unknown{_close(spec.activation, ACTIVATIONS)}; "
                         f"use one of {', '.join(ACTIVATIONS)}.")
    if spec.cell is not None and spec.cell not in RECURRENT_CELLS:
        raise ValueError(f"{where}.cell={spec.cell!r} is unknown{_close(spec.cell, RECURRENT_CELLS)}; use one of "
                         f"{', '.join(RECURRENT_CELLS)} for a recurrent area, or null for a dense one.")


def _check_sources(where: str, sources: tuple[str, ...], graph: AreaGraph, allowed: tuple[str, ...]) -> None:
    """Each of `sources` is `allowed` (areas and modalities) and listed once; ValueError naming `where` otherwise."""
    inputs = [name for name in allowed if name not in graph.areas]
    for source in sources:
        if source not in allowed:
            raise ValueError(
                f"{where} names {source!r}, which is neither an area nor an input{_close(source, allowed)}: the "
                f"areas are {', '.join(graph.areas)}; the inputs {', '.join(inputs)}.")
    repeated = sorted({source for source in sources if sources.count(source) > 1})
    if repeated:
        raise ValueError(f"{where} lists {', '.join(repeated)} more than once; list each input once.")


def _close(name: str, names) -> str:
    close = difflib.get_close_matches(str(name), list(names), n=1)
    return f" (did you mean {close[0]!r}?)" if close else ""
