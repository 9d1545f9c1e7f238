"""Dimensionality and dynamics of recorded activity: PCA per layer (scikit-learn), and fixed and slow points of a
recurrent layer found by optimisation with JAX autodiff (Sussillo and Barak 2013).

Fixed points: for a recurrent update h' = F(h, x) under a constant input x, minimise the speed
q(h) = 0.5 |F(h, x) - h|^2 from many starting states (states the network visited) with L-BFGS (optax). Points with q
near 0 are fixed points; small but non-zero q marks slow points. The eigenvalues of the Jacobian dF/dh at a point
tell its stability (all inside the unit circle: attracting). For a recurrent area of a brain-area graph
(`network.name: areas`) x is its inputs' mean over a recording, formed as the network forms it (`area_input`), and F
uses the area's activation.
"""

from __future__ import annotations

import difflib
from collections.abc import Callable, Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import optax
import xarray as xr
from sklearn.decomposition import PCA

from angora_jax.analysis.decoding import as_names, check_recording, chosen_layers, plot_path, recorded_layers
from angora_jax.analysis.parallel import map_in_threads
from angora_jax.experiment.agent import Agent, check_agent
from angora_jax.experiment.config import ConfigError, check_count, check_seed
from angora_jax.nets.activations import ACTIVATION_RANGES, ACTIVATIONS
from angora_jax.nets.area_graph import AreaGraph, feedback_inputs
from angora_jax.nets.components import component
from angora_jax.nets.models import cell_output, recurrent_cell
from angora_jax.wording import counted


def principal_components(dataset: xr.Dataset, layers: Sequence[str] | None = None,
                         components: int = 10) -> xr.Dataset:
    """PCA of each layer's activity over the alive steps: `explained` (layer x component, the variance ratio),
    `dimensionality` (layer: components needed for 90% of the variance; the participation ratio
    (sum l)^2 / sum l^2 as `participation_ratio`) and `trajectory_<layer>` (episode x time x component: the
    activity projected on the leading components, NaN where the episode is not alive). At most as many components as
    the widest layer has units."""
    layers = chosen_layers(dataset, layers)
    components = check_count("components", components)
    # No layer has more components than units: asking for more would only pad the trajectories with NaN, at
    # episodes x steps x components floats (12 GB for 1,000 components of a 1.5M-step recording).
    components = min(components, max(dataset[f"activity_{layer}"].shape[-1] for layer in layers))
    alive = dataset["alive"].values > 0
    explained = np.full((len(layers), components), np.nan)
    data: dict[str, Any] = {}
    dims, ratios = [], []
    for i, layer in enumerate(layers):
        values = np.asarray(dataset[f"activity_{layer}"].values, np.float64)[alive]
        # One fit gives the whole spectrum and the leading components. Through the covariance (units x units), as
        # a recording has far more steps than units: an SVD of the steps x units matrix, done twice (a full fit
        # and a k-component one), took minutes on cube recordings (many thousand steps per episode).
        pca = PCA(svd_solver="covariance_eigh").fit(values)
        full = pca.explained_variance_
        k = min(components, len(full))
        explained[i, :k] = pca.explained_variance_ratio_[:k]
        dims.append(int(np.searchsorted(np.cumsum(full) / full.sum(), 0.9) + 1))
        ratios.append(float(full.sum() ** 2 / (full**2).sum()))
        projected = np.full(alive.shape + (components,), np.nan)
        projected[alive, :k] = (values - pca.mean_) @ pca.components_[:k].T
        data[f"trajectory_{layer}"] = (("episode", "time", "component"), projected)
    data["explained"] = (("layer", "component"), explained)
    data["dimensionality"] = (("layer",), np.asarray(dims))
    data["participation_ratio"] = (("layer",), np.asarray(ratios))
    return xr.Dataset(data, coords={"layer": layers, "component": np.arange(components),
                                    "time": dataset["time"]})


def find_fixed_points(step: Callable[[jax.Array], jax.Array], starts: jax.Array, iterations: int = 500,
                      tolerance: float = 1e-6, bounds: tuple[np.ndarray, np.ndarray] | None = None
                      ) -> dict[str, np.ndarray]:
    """Minimise q(h) = 0.5 |step(h) - h|^2 from each row of `starts` `(K, n)` with L-BFGS for `iterations` steps.
    In float32 q bottoms out near 1e-7 for a 256-unit GRU (1e-13 for 64 units; measured), hence the tolerance.

    Args:
        step: the recurrent update, a map of a state `(n,)` to the next one.
        starts: the states the searches start from, `(K, n)`.
        iterations: L-BFGS steps of each search.
        tolerance: a point with q at most this is fixed.
        bounds: `(low, high)`, each `(n,)` or scalar (infinite where open), the states the network can reach. The
            search stays among them: each step's result is clipped to them (projected L-BFGS), so a coordinate pushed
            past its bound stops there and may move back inside at a later step. Without them the search leaves the
            state space wherever the update saturates: a GRU whose update gate is shut keeps any state, so it finds
            "slow points" at |h| >> 1 that the network never visits.

    Returns:
        Host arrays: `points` (K, n), `speed` (K,) the final q, `fixed` (K,) whether q <= tolerance, and
        `eigenvalues` (K, n) of the Jacobian of `step` at each point (complex; points equal to 1e-4 share those of
        the first of them), sorted by decreasing modulus.
    """
    low, high = (-np.inf, np.inf) if bounds is None else (np.asarray(b, np.float32) for b in bounds)

    def speed(h):
        return 0.5 * jnp.sum((step(h) - h) ** 2)

    optimizer = optax.lbfgs()
    value_and_grad = optax.value_and_grad_from_state(speed)

    def minimise(h):
        def body(_, carry):
            h, state = carry
            value, grad = value_and_grad(h, state=state)
            updates, state = optimizer.update(grad, state, h, value=value, grad=grad, value_fn=speed)
            return jnp.clip(optax.apply_updates(h, updates), low, high), state

        h, _ = jax.lax.fori_loop(0, iterations, body, (h, optimizer.init(h)))
        return h, speed(h)

    points, speeds = jax.jit(jax.vmap(minimise))(jnp.clip(jnp.asarray(starts, jnp.float32), low, high))
    points = np.asarray(points)
    # The eigendecomposition is O(n^3) per point: decompose each distinct point (equal to 1e-4) once.
    _, first, inverse = np.unique(np.round(points, 4), axis=0, return_index=True, return_inverse=True)
    jacobians = np.asarray(jax.vmap(jax.jacobian(step))(jnp.asarray(points[first])), np.float64)
    distinct = np.stack(map_in_threads(np.linalg.eigvals, jacobians))
    eigenvalues = distinct[inverse.reshape(-1)]
    order = np.argsort(-np.abs(eigenvalues), axis=-1)
    return {"points": points, "speed": np.asarray(speeds), "fixed": np.asarray(speeds) <= tolerance,
            "eigenvalues": np.take_along_axis(eigenvalues, order, axis=-1)}


def recurrent_step(agent: Agent, layer: str, inputs: jax.Array | Sequence[jax.Array | None]
                   ) -> tuple[Callable[[jax.Array], jax.Array], int]:
    """The update of the recurrent layer `layer` of `agent` (e.g. `network.PMC`, `network.policy_cell`) under a
    constant input, as a map of its flattened carry (`(c, h)` for an LSTM) to the next one, and the carry's length.

    Args:
        inputs: the constant input `(features,)`; or its parts in the order the layer reads them, concatenated, each
            `(features_i,)` or None for the layer's own output (an area of a graph that reads itself: its previous
            output, which the carry holds, so it is part of the state rather than held constant). The cell's activation
            is the area's (`network.graph.areas.<name>.activation`) for an area of a brain-area graph, tanh otherwise
            (the cells of the built-in `Recurrent` networks).
    """
    params, kind, size = _cell(agent, layer)
    cell = recurrent_cell(kind, size, "cell", ACTIVATIONS[_activation(agent, layer)])
    parts = 2 if kind == "lstm" else 1
    pieces = [inputs] if isinstance(inputs, jax.Array | np.ndarray) else list(inputs)
    width = sum(size if piece is None else len(piece) for piece in pieces)
    expected = int(params[{"lstm": "ii", "gru": "ir", "rnn": "i"}[kind]]["kernel"].shape[0])
    if width != expected:
        raise ConfigError(f"inputs of {layer!r} must give the {expected} input features it reads; those given have "
                          f"{width}: name the layers that feed it, in the order it reads them.")

    def step(flat: jax.Array) -> jax.Array:
        carry = tuple(jnp.split(flat[None], parts, axis=-1)) if parts == 2 else flat[None]
        own = cell_output(kind, carry)
        x = jnp.concatenate([own if piece is None else jnp.asarray(piece, jnp.float32)[None] for piece in pieces],
                            axis=-1)
        carry, _ = cell.apply({"params": params}, carry, x)
        return jnp.concatenate(jax.tree.leaves(carry), axis=-1)[0]

    return step, parts * size


def _cell(agent: Agent, layer: str) -> tuple[Any, str, int]:
    """The parameters of the recurrent `layer` of `agent`, its kind ("lstm", "gru" or "rnn") and its units."""
    params = component(agent.params, layer)
    kind = _cell_kind(params, layer)
    return params, kind, _cell_size(params, kind)


def _cell_kind(params: Any, layer: str) -> str:
    names = set(params)
    for kind, keys in (("lstm", {"hi", "hf", "hg", "ho"}), ("gru", {"hr", "hz", "hn"}), ("rnn", {"h", "i"})):
        if keys <= names:
            return kind
    raise ValueError(f"{layer!r} is not a recurrent cell of angora_jax's (its parameters: {sorted(names)}): fixed "
                     "points are searched in an LSTM, GRU or Elman (rnn) cell's update, as the built-in networks and "
                     "brain-area graphs use them. Without --run and --recurrent, analyze dynamics gives the PCA of "
                     "every layer, a network of one's own included.")


def _cell_size(params: Any, kind: str) -> int:
    return int(params[{"lstm": "hi", "gru": "hr", "rnn": "h"}[kind]]["kernel"].shape[-1])


def _graph_area(agent: Agent, layer: str) -> tuple[AreaGraph, str] | None:
    """The brain-area graph of `agent` and the area's name when `layer` is `network.<area>` of one, else None."""
    graph = getattr(agent.network, "graph", None)
    name = layer.removeprefix("network.")
    return (graph, name) if isinstance(graph, AreaGraph) and name in graph.areas else None


def _activation(agent: Agent, layer: str) -> str:
    area = _graph_area(agent, layer)
    return "tanh" if area is None else area[0].areas[area[1]].activation


def _state_bounds(agent: Agent, layer: str) -> tuple[np.ndarray, np.ndarray]:
    """`(low, high)` of the states that `layer`'s carry, flattened as `recurrent_step` flattens it, reaches from the
    zero carry: its output within its activation's range (and 0); an LSTM's cell state c is unbounded."""
    _, kind, size = _cell(agent, layer)
    low, high = (np.full(size, bound) for bound in ACTIVATION_RANGES[_activation(agent, layer)])
    if kind == "lstm":
        return np.concatenate([np.full(size, -np.inf), low]), np.concatenate([np.full(size, np.inf), high])
    return low, high


def area_input(agent: Agent, dataset: xr.Dataset, layer: str) -> dict[str, np.ndarray | None]:
    """The mean input of the recurrent area `layer` (`network.<area>`) of `agent`'s brain-area graph over the alive
    steps of `dataset`, per source in the order the area reads them (`network.graph.areas.<area>.inputs`; the
    area's cell reads them concatenated): source -> mean `(features_i,)`, or None for the area itself.

    As `Areas.__call__` forms it: an area's recorded output (`network.<source>`; a recurrent area's
    `network.<source>.1`), a modality's observation (`input_<modality>`, normalised as the agent normalises it; an
    empty modality, which the recording leaves out, adds nothing). A feedback input (a recurrent source that depends
    on this area, `area_graph.feedback_inputs`) is its source's output of the previous step: the recorded output
    shifted by one step, 0 (the initial carry's) at each episode's first step. Every input is held at its mean, so
    the fixed points are those of the area with the loop through other areas opened (they follow the area's mean
    input, not its own state); an area that reads itself reads its own state (None: see `recurrent_step`)."""
    check_agent(agent)
    area = _graph_area(agent, layer)
    graph = getattr(agent.network, "graph", None)
    if area is None and isinstance(graph, AreaGraph):
        recurrent = [f"network.{n}" for n, spec in graph.areas.items() if spec.cell is not None]
        close = difflib.get_close_matches(layer, [f"network.{n}" for n in graph.areas], n=1)
        raise ValueError(f"This agent's brain-area graph has no area {layer!r}"
                         + (f" (did you mean {close[0]!r}?)" if close else "")
                         + f"; its recurrent areas: {', '.join(recurrent) or 'none'}.")
    if area is None:
        raise ValueError(f"{layer!r} is not an area of a brain-area graph (network.name: areas), so its inputs are not "
                         "known: give the recorded layer(s) that feed it (inputs=..., angora-jax analyze dynamics "
                         "--inputs), e.g. network.PMC_in.")
    graph, name = area
    if graph.areas[name].cell is None:
        recurrent = [f"network.{n}" for n, spec in graph.areas.items() if spec.cell is not None]
        raise ValueError(f"{layer!r} is a dense area, without a cell to have fixed points; the graph's recurrent "
                         f"areas: {', '.join(recurrent) or 'none'}.")
    alive = dataset["alive"].values > 0
    feedback = feedback_inputs(graph)
    means: dict[str, np.ndarray | None] = {}
    for source in graph.areas[name].inputs:
        if source == name:
            means[source] = None
        elif source in graph.areas:
            recurrent = graph.areas[source].cell is not None
            values = _recorded(dataset, f"network.{source}" + (".1" if recurrent else ""), layer)
            if (name, source) in feedback:
                values = np.concatenate([np.zeros_like(values[:, :1]), values[:, :-1]], axis=1)
            means[source] = values[alive].mean(0)
        elif f"input_{source}" in dataset and dataset[f"input_{source}"].ndim == 3:
            means[source] = _normalised(agent, source, dataset[f"input_{source}"].values)[alive].mean(0)
        elif dataset.attrs.get("camera_images") and source == "vision":
            raise ValueError(f"{layer!r} reads vision, which this agent sees as camera images encoded by its visual "
                             "area: give its inputs explicitly (inputs=...).")
        else:
            means[source] = np.zeros(0, np.float32)
    return means


def _recorded(dataset: xr.Dataset, name: str, layer: str) -> np.ndarray:
    if f"activity_{name}" not in dataset:
        raise ValueError(f"The recording has no activity_{name}, an input of {layer!r}.")
    return np.asarray(dataset[f"activity_{name}"].values)


def _normalised(agent: Agent, modality: str, raw: np.ndarray) -> np.ndarray:
    """Raw observations of `modality` `(..., features)` as the network read them (`Agent.apply`)."""
    norm = agent.config.ppo.normalization
    if not norm.observations:
        return np.asarray(raw)
    stats = getattr(agent.state.obs_stats, modality)
    return np.asarray(stats.normalize(jnp.asarray(raw, jnp.float32), norm.clip))


def agent_fixed_points(agent: Agent, dataset: xr.Dataset, layer: str, inputs: str | Sequence[str] | None = None,
                       starts: int = 64, iterations: int = 500, seed: int = 0) -> dict[str, np.ndarray]:
    """Fixed and slow points of `agent`'s recurrent `layer` under its mean input over the recording's alive steps.

    The cell's activation is the area's (tanh for the built-in `Recurrent` networks). The search stays among the
    states the cell can reach (its activation's range, `find_fixed_points`' bounds).

    Args:
        agent: the trained agent.
        dataset: its recording (`analysis.recording`).
        layer: the recurrent layer, e.g. `network.PMC`.
        inputs: the recorded layer(s) that feed it (e.g. `network.PMC_in`), concatenated in the order given; or None
            for a recurrent area of a brain-area graph (`network.<area>`), whose inputs the graph names (`area_input`:
            the sources in the order of the area's `inputs`, feedback inputs at their previous step).
        starts: the number of carries the network visited (recorded as `<layer>.0...`) that the searches start from
            (at least 1).
        iterations: L-BFGS steps of each search (at least 1).
        seed: picks the starting carries (a whole number from 0 to 2**32 - 1).

    Returns:
        `find_fixed_points`'s arrays plus `input` (the constant input, the parts held constant concatenated: an area
        that reads itself reads its state instead).
    """
    check_agent(agent)
    check_recording(dataset)
    starts, iterations = check_count("starts", starts), check_count("iterations", iterations)
    seed = check_seed("seed", seed)
    alive = dataset["alive"].values > 0
    if inputs is None:
        pieces = list(area_input(agent, dataset, layer).values())
    else:
        names = as_names(inputs)
        pieces = [_recorded(dataset, name, layer)[alive].mean(0) for name in names]
    carry_names = sorted(n for n in recorded_layers(dataset) if n.startswith(f"{layer}.0"))
    if not carry_names:
        modules = sorted({n.rsplit(".", 1)[0] for n in recorded_layers(dataset) if n.endswith(".0")})
        near = [m for m in modules if m.endswith(f".{layer}")] or difflib.get_close_matches(layer, modules, n=1)
        raise ValueError(f"The recording has no carry of {layer!r} (looked for activity_{layer}.0...)"
                         + (f"; did you mean {near[0]!r}?" if near else ".")
                         + f" Recurrent modules recorded: {', '.join(modules) or 'none'}.")
    visited = np.concatenate([np.asarray(dataset[f"activity_{n}"].values)[alive] for n in carry_names], axis=-1)
    rows = np.random.default_rng(seed).choice(len(visited), size=min(starts, len(visited)), replace=False)
    step, size = recurrent_step(agent, layer, pieces)
    if visited.shape[-1] != size:
        raise ConfigError(f"The recording's carry of {layer!r} has {counted(visited.shape[-1], 'value')}; this "
                          f"agent's cell holds {size}: the recording is of another agent. Record this one (angora-jax "
                          f"record RUN_DIR, or record_activity(agent)).")
    drive = np.concatenate([np.zeros(0, np.float32), *(piece for piece in pieces if piece is not None)])
    return find_fixed_points(step, visited[rows], iterations, bounds=_state_bounds(agent, layer)) | {"input": drive}


def plot_dynamics(pcs: xr.Dataset, path: str, fixed_points: dict[str, np.ndarray] | None = None) -> None:
    """Variance explained per layer, and each layer's first two components over time for a few episodes (with the
    fixed points' eigenvalue moduli when given)."""
    plot_path("plot_dynamics", pcs, "explained", "principal_components", path)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    layers = list(pcs["layer"].values)
    panels = 1 + len(layers) + (fixed_points is not None)
    fig, axes = plt.subplots(1, panels, figsize=(3.0 * panels, 3.0), squeeze=False)
    for layer in layers:
        axes[0][0].plot(np.nancumsum(pcs["explained"].sel(layer=layer).values), marker=".",
                        label=layer.removeprefix("network."))
    axes[0][0].set(xlabel="components", ylabel="cumulative variance explained", ylim=(0, 1.02))
    axes[0][0].legend(fontsize=6)
    for ax, layer in zip(axes[0][1:], layers, strict=False):
        trajectory = pcs[f"trajectory_{layer}"].values
        for episode in range(min(5, trajectory.shape[0])):
            ax.plot(trajectory[episode, :, 0], trajectory[episode, :, 1], lw=0.8)
        ax.set(title=layer.removeprefix("network."), xlabel="PC 1", ylabel="PC 2")
    if fixed_points is not None:
        ax = axes[0][-1]
        moduli = np.abs(fixed_points["eigenvalues"])
        ax.hist(moduli[:, 0], bins=20)
        ax.axvline(1.0, color="k", lw=0.8)
        ax.set(xlabel="largest |eigenvalue| at the point", ylabel="points",
               title=f"{int(fixed_points['fixed'].sum())} fixed of {len(moduli)}")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)

