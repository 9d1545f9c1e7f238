"""Equations of a layer's dynamics: sparse identification of nonlinear dynamics (SINDy, Brunton et al. 2016, through
the `pysindy` library) in the layer's leading principal components, and how well they predict held-out episodes.

The layer's activity is reduced to its top-k principal components (PCA over the alive steps of the train episodes,
scikit-learn), divided by the first component's standard deviation so that PC1 has unit variance (one common factor:
the geometry, and so the linear coefficients, stay as they are, while the sparsity threshold means the same for every
layer). SINDy then fits, by sequentially thresholded least squares over a polynomial library, either the map from a
policy step to the next, PC[k+1] = f(PC[k]) (discrete time: a network's own clock), or the vector field
dPC/dt = f(PC) (continuous time, derivatives by finite differences). The model is autonomous: the layer's inputs
are not terms, so what it cannot predict is what the inputs drive.

Held-out episodes score it: the one-step R^2 of the next state, and the error of the model run from every held-out
step for `horizon` steps, each against the naive prediction that the state stays where it is (next = current).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import pysindy as ps
import xarray as xr
from scipy.integrate import solve_ivp
from sklearn.decomposition import PCA
from sklearn.metrics import r2_score

from angora_jax.analysis.decoding import require


def fit_sindy(trajectories: Sequence[np.ndarray], dt: float, names: Sequence[str], discrete: bool = True,
              degree: int = 2, threshold: float = 0.05) -> ps.DiscreteSINDy | ps.SINDy:
    """Fit SINDy to `trajectories`, each `(steps, len(names))` sampled every `dt` s: a polynomial library up to
    `degree` (with a constant), and STLSQ dropping terms whose coefficient falls below `threshold` (in the units of
    x per step, or per s in continuous time). `discrete`: the map x[k+1] = f(x[k]); otherwise the vector field
    dx/dt = f(x) in 1/s (finite differences). Returns the fitted pysindy model: its `coefficients()` are
    (equation x term) over the terms `get_feature_names()` ("1", "x", "x y", "x^2", ...)."""
    library = ps.PolynomialLibrary(degree=degree, include_bias=True)
    optimizer = ps.STLSQ(threshold=threshold)
    model = (ps.DiscreteSINDy(optimizer=optimizer, feature_library=library) if discrete else
             ps.SINDy(optimizer=optimizer, feature_library=library))
    return model.fit([np.asarray(x, np.float64) for x in trajectories], t=dt, feature_names=list(names))


def simulate(model: ps.DiscreteSINDy | ps.SINDy, starts: np.ndarray, steps: int, dt: float) -> np.ndarray:
    """`(steps + 1, n, k)`: the model run from each of the `n` rows of `starts` `(n, k)` for `steps` steps of `dt` s
    (row 0 is the start). A model that diverges gives NaN from where its values stop being finite."""
    path = np.full((steps + 1, *starts.shape), np.nan)
    path[0] = starts
    if isinstance(model, ps.DiscreteSINDy):
        for step in range(steps):
            path[step + 1] = _predict(model, path[step])
    else:
        # All starts as one system, so one integration serves them.
        def field(_, flat):
            return _predict(model, flat.reshape(starts.shape)).ravel()

        solution = solve_ivp(field, (0.0, steps * dt), starts.ravel(), t_eval=np.arange(steps + 1) * dt)
        path[:solution.y.shape[1]] = solution.y.T.reshape(-1, *starts.shape)
    path[~np.isfinite(path).all(-1)] = np.nan
    return path


def _predict(model: ps.DiscreteSINDy | ps.SINDy, states: np.ndarray) -> np.ndarray:
    """The model's next states (or derivatives) of `states` `(n, k)`; NaN rows for states that are not finite (a
    diverged simulation), which pysindy refuses."""
    result = np.full(states.shape, np.nan)
    finite = np.isfinite(states).all(-1)
    if finite.any():
        with np.errstate(over="ignore", invalid="ignore"):  # an unstable model overflows: NaN from then on
            result[finite] = model.predict(states[finite])
    return result


def sindy(dataset: xr.Dataset, layer: str, components: int = 3, discrete: bool = True, degree: int = 2,
          threshold: float = 0.05, horizon: int = 10, held_out: float = 0.25, seed: int = 0) -> xr.Dataset:
    """SINDy of `layer`'s activity (`activity_<layer>`, e.g. `network.PMC.1`, a recurrent cell's output) in its
    leading `components` principal components, fitted on the train episodes and scored on the `held_out` fraction
    of the episodes (at least one; chosen at random with `seed`). `discrete`, `degree`, `threshold`: as
    `fit_sindy`; `horizon`: policy steps of the multi-step prediction.

    Returns a Dataset: `coefficients` (component x term, the identified equations; PC coordinates in units of PC1's
    standard deviation, time in policy steps or s), `equation` (component: readable, e.g. "PC1[k+1] = 0.950
    PC1[k] + ..."), `explained` (component: variance ratio), `r2_one_step` and `baseline_r2_one_step` (held-out R^2
    of the next state, the baseline predicting next = current), `simulation_error` and `baseline_error` (step:
    root mean square error over the components after 0..horizon steps from every held-out step, in PC1's standard
    deviations) and `example_true`, `example_simulated` (step x component: the first held-out episode from its
    start). Attributes say the layer, time, degree, threshold, scale (PC1's standard deviation, in the layer's units)
    and the episodes used.
    """
    require(dataset, [layer])
    values = np.asarray(dataset[f"activity_{layer}"].values, np.float64)
    episodes, steps, units = values.shape
    if components > units:
        raise ValueError(f"{components} components of {layer!r}, which has {units} units: ask for at most {units} "
                         f"(--components).")
    if steps < 3:
        raise ValueError(f"The recording has {steps} time steps; the dynamics need at least 3 (derivatives and "
                         f"transitions within an episode): record longer episodes (angora-jax record --steps).")
    if not 0 < horizon < steps:
        raise ValueError(f"A horizon of {horizon} steps in a recording of {steps}: give --horizon from 1 to "
                         f"{steps - 1}.")
    if not 0 < held_out < 1:
        raise ValueError(f"held_out is the fraction of the episodes held out, between 0 and 1 (--held-out), got "
                         f"{held_out}.")
    if episodes < 2:
        raise ValueError(f"The recording has {episodes} episode; SINDy needs one to fit and one held out: record "
                         f"more (angora-jax record --episodes).")
    lengths = (dataset["alive"].values > 0).sum(1)  # alive runs from step 0 to the episode's end
    order = np.random.default_rng(seed).permutation(episodes)
    count = min(episodes - 1, max(1, round(held_out * episodes)))
    test, train = np.sort(order[:count]), np.sort(order[count:])
    pca = PCA(components).fit(np.concatenate([values[e, :lengths[e]] for e in train]))
    scale = float(np.sqrt(pca.explained_variance_[0]))
    if not scale > 0:
        raise ValueError(f"{layer!r} is constant over the alive steps of the train episodes: it has no dynamics to "
                         f"identify; name another layer.")
    names = [f"PC{i + 1}" for i in range(components)]

    def trajectories(chosen: np.ndarray) -> list[np.ndarray]:
        # Episodes with fewer than 3 alive steps give no transition or derivative.
        return [pca.transform(values[e, :lengths[e]]) / scale for e in chosen if lengths[e] >= 3]

    fitting, scoring = trajectories(train), trajectories(test)
    terms = math.comb(components + degree, degree)  # monomials of the components up to `degree`, with the constant
    transitions = sum(len(x) - 1 for x in fitting)
    if transitions < terms or not scoring:
        raise ValueError(f"The train episodes give {transitions} transitions for {terms} library terms, and "
                         f"{len(scoring)} held-out episodes have 3 or more alive steps: record more episodes or "
                         f"steps (angora-jax record --episodes/--steps), or use fewer --components or a lower "
                         f"--degree.")
    dt = float(dataset.attrs.get("policy_step_s", 1.0))
    model = fit_sindy(fitting, dt, names, discrete, degree, threshold)

    starts = np.concatenate([x[:-1] for x in scoring])
    truth = _future(scoring, horizon)
    predicted = simulate(model, starts, horizon, dt)
    in_episode = np.isfinite(truth).all(-1)  # (steps + 1, starts): the step is still in the start's episode
    counts = in_episode.sum(1)

    def error(path: np.ndarray) -> np.ndarray:
        squared = ((path - truth) ** 2).mean(-1)
        squared = np.where(in_episode, np.nan_to_num(squared, nan=np.inf), 0.0)  # a diverged model: infinite error
        with np.errstate(invalid="ignore"):  # steps that no held-out episode reaches stay NaN
            return np.sqrt(np.where(counts > 0, squared.sum(1) / np.maximum(counts, 1), np.nan))

    persistence = np.broadcast_to(starts, truth.shape)
    one_step = np.isfinite(predicted[1]).all(-1)
    step_s = np.arange(horizon + 1) * dt
    return xr.Dataset(
        {"coefficients": (("component", "term"), np.asarray(model.coefficients())),
         "equation": (("component",), [f"{name}[k+1] = {rhs}" if discrete else f"d{name}/dt = {rhs}"
                                       for name, rhs in zip(names, model.equations(), strict=True)]),
         "explained": (("component",), pca.explained_variance_ratio_),
         "r2_one_step": r2_score(truth[1], predicted[1], multioutput="variance_weighted") if one_step.all()
         else -np.inf,
         "baseline_r2_one_step": r2_score(truth[1], starts, multioutput="variance_weighted"),
         "simulation_error": (("step",), error(predicted)),
         "baseline_error": (("step",), error(persistence)),
         # The first start is the first held-out episode's first step.
         "example_true": (("step", "component"), truth[:, 0]),
         "example_simulated": (("step", "component"), np.where(in_episode[:, :1], predicted[:, 0], np.nan))},
        coords={"component": names, "term": model.get_feature_names(),
                "step_s": ("step", step_s, {"units": "s"})},
        attrs={"layer": layer, "time": "discrete" if discrete else "continuous", "degree": degree,
               "threshold": threshold, "scale": scale, "train_episodes": len(fitting),
               "held_out_episodes": len(scoring), "policy_step_s": dt},
    )


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
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    coefficients = result["coefficients"].values
    fig, axes = plt.subplots(1, 3, figsize=(4.0 + 0.45 * coefficients.shape[1] + 7.0, 3.4),
                             gridspec_kw={"width_ratios": [1.0 + 0.12 * coefficients.shape[1], 1, 1]})
    bound = max(float(np.abs(coefficients).max()), 1e-12)
    image = axes[0].imshow(coefficients, cmap="RdBu_r", vmin=-bound, vmax=bound, aspect="auto")
    axes[0].set_xticks(range(coefficients.shape[1]), result["term"].values, rotation=60, ha="right", fontsize=7)
    discrete = result.attrs["time"] == "discrete"
    axes[0].set_yticks(range(coefficients.shape[0]),
                       [f"{c}[k+1]" if discrete else f"d{c}/dt" for c in result["component"].values])
    axes[0].set_title(f"{str(result.attrs['layer']).removeprefix('network.')}: identified terms", fontsize=9)
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
