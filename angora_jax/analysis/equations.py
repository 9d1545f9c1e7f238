"""Equations of a layer's dynamics: sparse identification of nonlinear dynamics (SINDy, Brunton et al. 2016, through
the `pysindy` library) in the layer's leading principal components, and how well they predict held-out episodes.

The layer's activity is reduced to its top-k principal components (PCA over the alive steps of the train episodes,
scikit-learn), divided by the first component's standard deviation so that PC1 has unit variance (one common factor:
the geometry, and so the linear coefficients, stay as they are, while the sparsity threshold means the same for every
layer). SINDy then fits, by sequentially thresholded least squares over a polynomial library, either the map from a
policy step to the next, PC[k+1] = f(PC[k]) (discrete time: a network's own clock), or the vector field
dPC/dt = f(PC) (continuous time, derivatives by finite differences). Given the layer that feeds it, the leading
components of that input layer join the library as terms IN1.. (SINDy with control); without, the model is
autonomous, and what the inputs drive is what it misses.

Held-out episodes score it: the one-step R^2 of the next state, and the error of the model run from every held-out
step for `horizon` steps, each against the naive prediction that the state stays where it is (next = current).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import pysindy as ps
import xarray as xr
from sklearn.decomposition import PCA
from sklearn.metrics import r2_score

from angora_jax.analysis.decoding import plot_path, require
from angora_jax.experiment.config import ConfigError, check_count, check_number, check_seed
from angora_jax.wording import counted

# Runge-Kutta steps a policy step when a continuous-time model is run (`simulate`).
SUBSTEPS = 4
# A simulated state this large has diverged (in sindy's units, PC1's standard deviations), and its library terms
# (powers) would overflow, which pysindy refuses.
DIVERGED = 1e12


def fit_sindy(trajectories: Sequence[np.ndarray], dt: float, names: Sequence[str], discrete: bool = True,
              degree: int = 2, threshold: float = 0.05, inputs: Sequence[np.ndarray] | None = None,
              input_names: Sequence[str] = ()) -> ps.DiscreteSINDy | ps.SINDy:
    """Fit SINDy to `trajectories`, each `(steps, len(names))` sampled every `dt` s: a polynomial library up to
    `degree` (with a constant), and STLSQ dropping terms whose coefficient falls below `threshold` (in the units of
    x per step, or per s in continuous time). `discrete`: the map x[k+1] = f(x[k]); otherwise the vector field
    dx/dt = f(x) in 1/s (finite differences). With `inputs` (per trajectory `(steps, len(input_names))`), the
    library spans x and u (SINDy with control): x[k+1] = f(x[k], u[k]), or dx/dt = f(x, u). Returns the fitted
    pysindy model: its `coefficients()` are (equation x term) over the terms `get_feature_names()` ("1", "x",
    "x u", "x^2", ...)."""
    library = ps.PolynomialLibrary(degree=degree, include_bias=True)
    optimizer = ps.STLSQ(threshold=threshold)
    model = (ps.DiscreteSINDy(optimizer=optimizer, feature_library=library) if discrete else
             ps.SINDy(optimizer=optimizer, feature_library=library))
    controls = None if inputs is None else [np.asarray(u, np.float64) for u in inputs]
    return model.fit([np.asarray(x, np.float64) for x in trajectories], t=dt, u=controls,
                     feature_names=[*names, *input_names])


def simulate(model: ps.DiscreteSINDy | ps.SINDy, starts: np.ndarray, steps: int, dt: float,
             inputs: np.ndarray | None = None) -> np.ndarray:
    """`(steps + 1, n, k)`: the model run from each of the `n` rows of `starts` `(n, k)` for `steps` steps of `dt` s
    (row 0 is the start); a model with inputs takes them as `(steps, n, m)`, row h driving step h to h + 1 (held over
    the step in continuous time, integrated by `SUBSTEPS` Runge-Kutta steps). A model that diverges, or runs out
    of inputs, gives NaN from there on."""
    path = np.full((steps + 1, *starts.shape), np.nan)
    path[0] = starts
    for step in range(steps):
        controls = None if inputs is None else inputs[step]
        if isinstance(model, ps.DiscreteSINDy):
            path[step + 1] = _predict(model, path[step], controls)
        else:
            # Classical Runge-Kutta, SUBSTEPS a step, the input held: scipy's adaptive solvers shrink their steps
            # without bound on an identified field that blows up (minutes for one evaluation, measured), while
            # fixed steps cost the same whatever the model, and a blow-up shows as NaN.
            h, state = dt / SUBSTEPS, path[step]
            for _ in range(SUBSTEPS):
                k1 = _predict(model, state, controls)
                k2 = _predict(model, state + h / 2 * k1, controls)
                k3 = _predict(model, state + h / 2 * k2, controls)
                k4 = _predict(model, state + h * k3, controls)
                state = state + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
            path[step + 1] = state
    path[~np.isfinite(path).all(-1)] = np.nan
    return path


def _predict(model: ps.DiscreteSINDy | ps.SINDy, states: np.ndarray, inputs: np.ndarray | None) -> np.ndarray:
    """The model's next states (or derivatives) of `states` `(n, k)` under `inputs` `(n, m)` (None: a model without
    inputs); NaN rows where a state has diverged (NaN or beyond `DIVERGED`) or an input is NaN (past an episode's
    end), which pysindy refuses."""
    result = np.full(states.shape, np.nan)
    finite = (np.abs(states) < DIVERGED).all(-1) & (True if inputs is None else np.isfinite(inputs).all(-1))
    if finite.any():
        with np.errstate(over="ignore", invalid="ignore"):  # an unstable model overflows: NaN from then on
            result[finite] = model.predict(states[finite], u=None if inputs is None else inputs[finite])
    return result


def sindy(dataset: xr.Dataset, layer: str, components: int = 3, inputs: str | None = None, discrete: bool = True,
          degree: int = 2, threshold: float = 0.05, horizon: int = 10, held_out: float = 0.25,
          seed: int = 0) -> xr.Dataset:
    """SINDy of `layer`'s activity (`activity_<layer>`, e.g. `network.PMC.1`, a recurrent cell's output) in its
    leading `components` principal components, fitted on the train episodes and scored on the `held_out` fraction
    of the episodes (at least one; chosen at random with `seed`). `inputs`: the recorded layer that feeds it (e.g.
    `network.PMC_in`), whose leading `components` components IN1.. become terms: a cell's state at step k + 1
    follows from its state at k and its input at k + 1 (in continuous time, the input at t). Without it the model is
    autonomous, and what the inputs drive is what it misses. `discrete`, `degree`, `threshold`: as `fit_sindy`;
    `horizon`: policy steps of the multi-step prediction (which reads the recorded inputs).

    Returns a Dataset: `coefficients` (component x term, the identified equations; coordinates in units of the
    first component's standard deviation, of the layer's and of the inputs' apart, time in policy steps or s),
    `equation` (component: readable, e.g. "PC1[k+1] = 0.950 PC1[k] + ..."), `explained` (component: the layer's
    variance ratio), `r2_one_step` and `baseline_r2_one_step` (held-out R^2 of the next state, the baseline
    predicting next = current), `simulation_error` and `baseline_error` (step: root mean square error over the
    components after 0..horizon steps from every held-out step, in PC1's standard deviations) and `example_true`,
    `example_simulated` (step x component: the first held-out episode from its start). Attributes say the layer,
    inputs, time, degree, threshold, scale (PC1's standard deviation, in the layer's units) and the episodes used.
    """
    require(dataset, [layer, *([inputs] if inputs else [])])
    components, degree = check_count("components", components), check_count("degree", degree)
    horizon, threshold = check_count("horizon", horizon), check_number("threshold", threshold, 0.0)
    seed = check_seed("seed", seed)
    held_out = check_number("held_out (the fraction of the episodes held out, --held-out)", held_out, 0.0, 1.0,
                            open_low=True, open_high=True)
    values = np.asarray(dataset[f"activity_{layer}"].values, np.float64)
    episodes, steps, _ = values.shape
    if steps < 3:
        raise ValueError(f"The recording has {steps} time steps; the dynamics need at least 3 (derivatives and "
                         f"transitions within an episode): record longer episodes (angora-jax record --steps).")
    if horizon >= steps:
        raise ConfigError(f"horizon must be a whole number from 1 to {steps - 1} (--horizon; the recording has "
                          f"{counted(steps, 'time step')}), got {horizon}.")
    if episodes < 2:
        raise ValueError(f"The recording has {episodes} episode; SINDy needs one to fit and one held out: record "
                         f"more (angora-jax record --episodes).")
    # alive runs from step 0 to the episode's end; episodes with fewer than 3 alive steps give no transition or
    # derivative.
    lengths = (dataset["alive"].values > 0).sum(1)
    order = np.random.default_rng(seed).permutation(episodes)
    count = min(episodes - 1, max(1, round(held_out * episodes)))
    test = [e for e in np.sort(order[:count]) if lengths[e] >= 3]
    train = [e for e in np.sort(order[count:]) if lengths[e] >= 3]
    if not train or not test:
        raise ValueError(f"{len(train)} train and {len(test)} held-out episodes have 3 or more alive steps; SINDy "
                         f"needs at least one of each: record more episodes or steps (angora-jax record "
                         f"--episodes/--steps).")
    states, explained, scale = _components(values, lengths, train, components, layer)
    names = [f"PC{i + 1}" for i in range(components)]
    controls, input_names = None, []
    if inputs:
        driving, _, _ = _components(np.asarray(dataset[f"activity_{inputs}"].values, np.float64), lengths, train,
                                    components, inputs)
        input_names = [f"IN{i + 1}" for i in range(components)]
        # pysindy pairs u[k] with the step from x[k]: in discrete time that step's input is the one at k + 1 (the
        # last row, which no step uses, repeats).
        controls = driving if not discrete else {e: np.concatenate([u[1:], u[-1:]]) for e, u in driving.items()}
    variables = components * (2 if inputs else 1)
    terms = math.comb(variables + degree, degree)  # monomials of the variables up to `degree`, with the constant
    transitions = sum(len(states[e]) - 1 for e in train)
    if transitions < terms:
        raise ConfigError(f"The train episodes give {counted(transitions, 'transition')} for {terms} library terms: "
                          f"record more episodes or steps (angora-jax record --episodes/--steps), or use fewer "
                          f"--components or a lower --degree.")
    dt = float(dataset.attrs.get("policy_step_s", 1.0))
    model = fit_sindy([states[e] for e in train], dt, names, discrete, degree, threshold,
                      None if controls is None else [controls[e] for e in train], input_names)

    scoring = [states[e] for e in test]
    starts = np.concatenate([x[:-1] for x in scoring])
    truth = _future(scoring, horizon)
    # Row h: the input of the step from h to h + 1 after each start (NaN past the episode's end).
    future_inputs = None if controls is None else _future([controls[e] for e in test], horizon - 1)
    predicted = simulate(model, starts, horizon, dt, future_inputs)
    in_episode = np.isfinite(truth).all(-1)  # (steps + 1, starts): the step is still in the start's episode
    counts = in_episode.sum(1)

    def error(path: np.ndarray) -> np.ndarray:
        squared = ((path - truth) ** 2).mean(-1)
        squared = np.where(in_episode, np.nan_to_num(squared, nan=np.inf), 0.0)  # a diverged model: infinite error
        with np.errstate(invalid="ignore"):  # steps that no held-out episode reaches stay NaN
            return np.sqrt(np.where(counts > 0, squared.sum(1) / np.maximum(counts, 1), np.nan))

    equations = [_input_at_next_step(rhs, input_names) if discrete else rhs for rhs in model.equations()]
    one_step = np.isfinite(predicted[1]).all(-1)
    return xr.Dataset(
        {"coefficients": (("component", "term"), np.asarray(model.coefficients())),
         "equation": (("component",), [f"{name}[k+1] = {rhs}" if discrete else f"d{name}/dt = {rhs}"
                                       for name, rhs in zip(names, equations, strict=True)]),
         "explained": (("component",), explained),
         "r2_one_step": r2_score(truth[1], predicted[1], multioutput="variance_weighted") if one_step.all()
         else -np.inf,
         "baseline_r2_one_step": r2_score(truth[1], starts, multioutput="variance_weighted"),
         "simulation_error": (("step",), error(predicted)),
         "baseline_error": (("step",), error(np.broadcast_to(starts, truth.shape))),
         # The first start is the first held-out episode's first step.
         "example_true": (("step", "component"), truth[:, 0]),
         "example_simulated": (("step", "component"), np.where(in_episode[:, :1], predicted[:, 0], np.nan))},
        coords={"component": names, "term": model.get_feature_names(),
                "step_s": ("step", np.arange(horizon + 1) * dt, {"units": "s"})},
        attrs={"layer": layer, "inputs": inputs or "", "time": "discrete" if discrete else "continuous",
               "degree": degree, "threshold": threshold, "scale": scale, "train_episodes": len(train),
               "held_out_episodes": len(test), "policy_step_s": dt},
    )


def _components(values: np.ndarray, lengths: np.ndarray, train: Sequence[int], components: int,
                layer: str) -> tuple[dict[int, np.ndarray], np.ndarray, float]:
    """PCA of `values` `(episode, time, units)` over the alive steps of the `train` episodes: every episode's alive
    steps in the leading `components` components, divided by the first one's standard deviation ({episode:
    (length, components)}), the variance ratios and that standard deviation."""
    units = values.shape[-1]
    if components > units:
        raise ConfigError(f"{components} components of {layer!r}, which has {counted(units, 'unit')}: ask for at "
                          f"most {units} (--components).")
    pca = PCA(components).fit(np.concatenate([values[e, :lengths[e]] for e in train]))
    scale = float(np.sqrt(pca.explained_variance_[0]))
    if not scale > 0:
        raise ValueError(f"{layer!r} is constant over the alive steps of the train episodes: it has no dynamics to "
                         f"identify; name another layer.")
    projected = {e: pca.transform(values[e, :length]) / scale for e, length in enumerate(lengths) if length >= 3}
    return projected, pca.explained_variance_ratio_, scale


def _input_at_next_step(equation: str, input_names: Sequence[str]) -> str:
    """A discrete model's equation as pysindy writes it, every variable at [k], with the inputs at [k+1]."""
    for name in input_names:
        equation = equation.replace(f"{name}[k]", f"{name}[k+1]")
    return equation


def _future(trajectories: list[np.ndarray], horizon: int) -> np.ndarray:
    """`(horizon + 1, starts, k)`: for every step but the last of each trajectory, the states 0..horizon steps
    later, NaN past the trajectory's end."""
    rows = []
    for x in trajectories:
        padded = np.concatenate([x, np.full((horizon, x.shape[1]), np.nan)])
        rows.extend(padded[t:t + horizon + 1] for t in range(len(x) - 1))
    return np.stack(rows, axis=1)


def plot_sindy(result: xr.Dataset, path: str) -> None:
    """The identified coefficients (component x term), the held-out error over the horizon against next = current,
    and the first held-out episode's leading components with the model's simulation from its start."""
    plot_path("plot_sindy", result, "coefficients", "sindy", path)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    coefficients = result["coefficients"].values
    # The coefficients above, as wide as their terms need; the two curves below.
    fig = plt.figure(figsize=(max(8.0, 2.5 + 0.3 * coefficients.shape[1]), 6.4))
    grid = fig.add_gridspec(2, 2, height_ratios=[1.0, 1.3])
    axes = [fig.add_subplot(grid[0, :]), fig.add_subplot(grid[1, 0]), fig.add_subplot(grid[1, 1])]
    bound = max(float(np.abs(coefficients).max()), 1e-12)
    image = axes[0].imshow(coefficients, cmap="RdBu_r", vmin=-bound, vmax=bound, aspect="auto")
    axes[0].set_xticks(range(coefficients.shape[1]), result["term"].values, rotation=60, ha="right", fontsize=7)
    discrete = result.attrs["time"] == "discrete"
    axes[0].set_yticks(range(coefficients.shape[0]),
                       [f"{c}[k+1]" if discrete else f"d{c}/dt" for c in result["component"].values])
    axes[0].set_title(f"{str(result.attrs['layer']).removeprefix('network.')}: identified terms")
    fig.colorbar(image, ax=axes[0])
    seconds = result["step_s"].values
    axes[1].plot(seconds, result["simulation_error"].values, marker=".",
                 label=f"SINDy (one-step R^2 {float(result['r2_one_step']):.2f})")
    axes[1].plot(seconds, result["baseline_error"].values, marker=".", ls="--",
                 label=f"next = current ({float(result['baseline_r2_one_step']):.2f})")
    axes[1].set(xlabel="prediction horizon (s)", ylabel="held-out RMSE (PC1 std)")
    axes[1].legend(fontsize=7)
    for i, component in enumerate(result["component"].values[:2]):
        line, = axes[2].plot(seconds, result["example_true"].values[:, i], label=f"{component}")
        axes[2].plot(seconds, result["example_simulated"].values[:, i], ls="--", color=line.get_color(),
                     label=f"{component} simulated")
    axes[2].set(xlabel="time in episode (s)", ylabel="PC (PC1 std)", title="a held-out episode")
    axes[2].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
