"""Decoding (AngoraPy's "predictability"): how well a linear readout of a layer's activity predicts a task variable.

For each layer and variable: ridge regression (scikit-learn's `Ridge`; one fit per layer and fold serves every
variable) from the layer's units to the variable's features, scored by R^2 on held-out episodes (`GroupKFold` over
episodes, so steps of one episode never sit on both sides), only at steps where the episode is alive. Each output's
penalty is chosen by an inner `GroupKFold` over the training fold's episodes, never by leave-one-out over steps:
neighbouring steps of one episode are nearly copies, so leave-one-out rewards a readout that tells episodes apart
(a layer holding a per-episode offset) with hardly any penalty, and on new episodes that readout is worse than the
mean (held-out R^2 down to -9 on a trained agent's value pathway; -2.8 on made-up episodes whose training mean
scores -0.3, tests/test_analysis_methods.py). The baseline decodes the same variable from Gaussian noise of the
layer's shape: what a readout finds by chance. The interval is the mean over folds +- 1.96 standard errors.

A linear readout finds an input in any layer that keeps it, and random projections keep it: the same network with
random weights given the same inputs (`replay_activity(with_random_weights(agent), recording)`) decodes the inputs of
a trained reach policy about as well (R^2 0.9-1.0 in both, measured). Decodability of an input alone is no evidence
of learning; compare areas, variables that must be computed, and that control.
"""

from __future__ import annotations

import difflib
import numbers
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import xarray as xr
from sklearn.linear_model import Ridge
from sklearn.metrics import r2_score
from sklearn.model_selection import GroupKFold
from sklearn.pipeline import Pipeline, make_pipeline
from sklearn.preprocessing import StandardScaler

from angora_jax.analysis.parallel import map_in_threads
from angora_jax.experiment.config import ConfigError, check_count, check_seed
from angora_jax.experiment.run_dir import unwritable_out
from angora_jax.wording import counted

# Ridge penalties per training sample: a fit on n samples is penalised n times this, so that the penalty chosen on
# the inner folds' smaller training sets means the same on the whole training fold.
PENALTIES = np.logspace(-6, 2, 17)
MAX_SAMPLES = 20_000
# Folds over the training episodes that choose each output's penalty.
INNER_FOLDS = 5


def cross_validated_r2(features: np.ndarray, targets: np.ndarray, groups: np.ndarray, folds: int = 5,
                       spans: Sequence[slice] | None = None) -> np.ndarray:
    """Held-out R^2 of a ridge readout per fold, `(folds,)`. features `(samples, units)`, targets `(samples,
    outputs)` (R^2 weighted by each output's variance), groups `(samples,)`: samples of a group stay together.
    With `spans` (column slices of `targets`, one per variable) R^2 is per span, `(folds, len(spans))`, from one fit
    per fold for all outputs, each with its own penalty (`ridge_readout`): the fits' cost (the SVD of the units) hardly
    grows with the outputs, so decoding every variable at once costs about what one does. ValueError when a fold
    would hold out fewer than 2 samples (a recording of one step per episode and few episodes)."""
    return _cross_validated_r2s([features], targets, groups, folds, spans)[0]


def _cross_validated_r2s(feature_sets: Sequence[np.ndarray], targets: np.ndarray, groups: np.ndarray, folds: int,
                         spans: Sequence[slice] | None) -> np.ndarray:
    """`cross_validated_r2` of each of `feature_sets` on the same targets and folds, `(sets, folds[, spans])`: every
    (set, fold) fit runs in parallel (`map_in_threads`)."""
    folds = check_folds(folds)
    columns = [slice(0, targets.shape[1])] if spans is None else list(spans)
    splits = list(GroupKFold(n_splits=folds).split(targets, targets, groups))
    held_out = min(len(test) for _, test in splits)
    if held_out < 2:  # R^2 of one step is undefined: scikit-learn's is NaN, and so the mean over the folds
        raise ValueError(f"Held-out R^2 needs at least 2 steps in each fold's held-out episodes; {folds} folds over "
                         f"{counted(len(groups), 'step')} of {counted(len(np.unique(groups)), 'episode')} leave "
                         f"{counted(held_out, 'step')} in a fold: record more episodes or steps (angora-jax record "
                         "--episodes, --steps)" + (", or decode with fewer folds (--folds)." if folds > 2 else "."))

    def fold_scores(job: tuple[np.ndarray, tuple[np.ndarray, np.ndarray]]) -> list[float]:
        features, (train, test) = job
        model = ridge_readout(features[train], targets[train], groups[train])
        # A single output comes back 1-D.
        predicted = model.predict(features[test]).reshape(len(test), -1)
        return [r2_score(targets[test][:, span], predicted[:, span], multioutput="variance_weighted")
                for span in columns]

    scores = np.asarray(map_in_threads(fold_scores, [(features, split) for features in feature_sets
                                                     for split in splits]))
    scores = scores.reshape(len(feature_sets), folds, len(columns))
    return scores[..., 0] if spans is None else scores


def ridge_readout(features: np.ndarray, targets: np.ndarray, groups: np.ndarray) -> Pipeline:
    """A fitted ridge readout (standardized units, then scikit-learn's `Ridge`) from features `(samples, units)` to
    targets `(samples, outputs)`, each output with the penalty of `PENALTIES` (per sample) that predicts it best on
    held-out episodes of an inner `GroupKFold` (`INNER_FOLDS`, fewer when `groups` has fewer groups; samples of a
    group stay together). Raises ValueError when `groups` holds fewer than 2 groups."""
    episodes = len(np.unique(groups))
    if episodes < 2:
        raise ValueError("Choosing a readout's penalty on held-out episodes needs at least 2 episodes to fit it on; "
                         "record more episodes, or decode with fewer folds.")
    x = StandardScaler().fit_transform(features)
    errors = np.zeros((len(PENALTIES), targets.shape[1]))
    inner = GroupKFold(n_splits=min(INNER_FOLDS, episodes))
    for train, test in inner.split(x, targets, groups):
        errors += _penalty_path_errors(x[train], targets[train], x[test], targets[test])
    best = len(x) * PENALTIES[errors.argmin(axis=0)]
    return make_pipeline(StandardScaler(), Ridge(alpha=best, solver="svd")).fit(features, targets)


def _penalty_path_errors(x: np.ndarray, y: np.ndarray, x_test: np.ndarray, y_test: np.ndarray) -> np.ndarray:
    """Summed squared errors on `(x_test, y_test)` of the ridge fits (with intercept) on `(x, y)` at every penalty of
    `PENALTIES`, `(penalties, outputs)`. Every penalty's fit comes from one SVD of the centred units, as scikit-learn's
    `RidgeCV` computes its leave-one-out path. scikit-learn has no such path for held-out groups, and its `Ridge` fitted
    on the targets tiled once per penalty took 5x this path's time (20,000 steps of 512 units, 130 outputs)."""
    x_mean, y_mean = x.mean(axis=0), y.mean(axis=0)
    u, s, vt = np.linalg.svd(x - x_mean, full_matrices=False)
    uty = u.T @ (y - y_mean)
    projected = (x_test - x_mean) @ vt.T
    return np.stack([(((projected @ ((s / (s**2 + len(x) * penalty))[:, None] * uty)) + y_mean - y_test) ** 2)
                     .sum(axis=0) for penalty in PENALTIES])


def check_folds(folds: object) -> int:
    """`folds` as an int; ConfigError unless it is a whole number of at least 2 (`check_count`)."""
    try:
        return check_count("folds", folds, least=2)
    except ConfigError:
        raise ConfigError(f"Decoding needs a whole number of at least 2 folds (--folds), got {folds!r}: each fold's "
                          "episodes are held out while the readout is fitted on the others'.") from None


def decode(dataset: xr.Dataset, layers: Sequence[str] | None = None, variables: Sequence[str] | None = None,
           folds: int = 5, seed: int = 0, lags: Sequence[int] | None = None,
           max_samples: int = MAX_SAMPLES, baseline: bool = True) -> xr.Dataset:
    """R^2 of every layer x variable, with the noise baseline and 95% intervals, as a Dataset with variables `r2`,
    `r2_low`, `r2_high`, `baseline` (dims layer x variable). A variable constant over the steps used (a metric that
    never changes in the recording, or an input held fixed) has nothing to decode: its cells are NaN.

    Args:
        layers: names as in `activity_<name>` (default: all).
        variables: dataset variables to decode, e.g. `input_goal`, `task_cube_angular_velocity`, `metric_goal_distance`
            (default: every `input_*`, `task_*` and `metric_*`).
        folds: cross-validation folds over the episodes, at least 2.
        seed: draws the noise baseline, a whole number from 0 to 2**32 - 1.
        lags: policy steps k; with them, the variable at step t + k is decoded from the activity at step t (k > 0: which
            areas predict the future; k < 0: which keep the past), and every result gets a leading `lag` dim (coordinate
            in steps, `lag_s` in s). Every lag reads the same steps t: those alive with the variable alive at every t +
            k, so the lags compare one set of activity, and one readout per layer and fold fits every lag and variable
            at once (a lag costs hardly more than none). One or more whole numbers, each shorter than the recording.
        max_samples: at most this many of those steps, evenly spaced over them (consecutive steps are strongly
            correlated, so a stride loses little, and a readout's cost grows with the steps: 64 trained cube episodes
            hold about 75,000); the attribute `samples` says how many were used, one number per lag.
        baseline: False leaves `baseline` NaN and skips its fits (e.g. for a control network's decoding, whose layers
            have the same widths as the network it controls for, so the same baseline). The noise baseline is one draw
            per layer width, shared by layers of that width.
    """
    folds, seed, max_samples = check_folds(folds), check_seed("seed", seed), check_count("max_samples", max_samples)
    lags = None if lags is None else _checked_lags(lags)
    layers = chosen_layers(dataset, layers)
    variables = as_names(variables) if variables else [
        n for n in dataset.data_vars if n.startswith(("input_", "task_", "metric_"))]
    require(dataset, layers, variables)
    steps = dataset.sizes["time"]
    if lags is not None and any(abs(k) >= steps for k in lags):
        raise ConfigError(f"lags must be shorter than the recording's {counted(steps, 'step')}, got {lags}.")
    result = _decode_lags(dataset, layers, variables, folds, np.random.default_rng(seed),
                          lags if lags is not None else [0], max_samples, baseline)
    names = ("r2", "r2_low", "r2_high", "baseline")
    coords = {"layer": layers, "variable": variables}
    # The steps each readout was fitted and scored on, at each lag: NetCDF keeps lists of numbers as attributes.
    attrs = {"folds": folds, "description": "held-out ridge R^2 (GroupKFold over episodes)",
             "samples": [int(result["samples"])] * (len(lags) if lags is not None else 1)}
    if lags is None:
        return xr.Dataset({name: (("layer", "variable"), result[name][0]) for name in names}, coords=coords,
                          attrs=attrs)
    dt = float(dataset.attrs.get("policy_step_s", 1.0))
    return xr.Dataset({name: (("lag", "layer", "variable"), result[name]) for name in names},
                      coords={"lag": list(lags), "lag_s": ("lag", np.asarray(lags) * dt, {"units": "s"}), **coords},
                      attrs=attrs)


def _checked_lags(lags: object) -> list[int]:
    """`decode`'s `lags` as a list of ints; ConfigError unless they are one or more whole numbers: a single number or
    text failed with a TypeError, 1.5 inside NumPy, and none at all (`--lags` alone) with "min() arg is an empty
    sequence"."""
    try:
        given = [] if isinstance(lags, str | numbers.Number) else list(lags)
    except TypeError:
        given = []
    if not given or not all(isinstance(k, numbers.Integral) and not isinstance(k, bool) for k in given):
        raise ConfigError(f"lags must be one or more whole numbers of policy steps (--lags), e.g. [-4, 0, 4], got "
                          f"{lags!r}.")
    return [int(k) for k in given]


def _decode_lags(dataset: xr.Dataset, layers: list[str], variables: list[str], folds: int, rng: np.random.Generator,
                 lags: list[int], max_samples: int, baseline: bool) -> dict[str, np.ndarray]:
    """`decode`'s arrays (lag x layer x variable) and the number of steps used (`samples`)."""
    steps = dataset.sizes["time"]
    alive = dataset["alive"].values > 0
    now = np.arange(max(0, -min(lags)), steps - max(0, max(lags)))
    keep = alive[:, now]
    for k in lags:
        keep = keep & alive[:, now + k]
    episode, step = np.nonzero(keep)
    chosen = np.linspace(0, len(episode) - 1, min(len(episode), max_samples)).round().astype(int)
    episode, step = episode[chosen], now[step[chosen]]
    if len(np.unique(episode)) < folds:
        raise ValueError(f"Decoding with {folds} folds needs at least {folds} episodes alive at the lags {lags}; the "
                         f"recording has {len(np.unique(episode))}: decode with fewer folds (--folds), or record more "
                         "episodes (angora-jax record --episodes).")
    shape = (len(lags), len(layers), len(variables))
    result = {name: np.full(shape, np.nan) for name in ("r2", "r2_low", "r2_high", "baseline")}
    result["samples"] = len(episode)
    cells, targets = [], []
    for i, k in enumerate(lags):
        for j, variable in enumerate(variables):
            values = _samples(dataset[variable].values[episode, step + k])
            if not np.all(values.std(axis=0) == 0):  # a constant has nothing to decode: its cells stay NaN
                cells.append((i, j))
                targets.append(values)
    if not cells:
        return result
    widths = np.cumsum([0] + [t.shape[1] for t in targets])
    spans = [slice(a, b) for a, b in zip(widths[:-1], widths[1:], strict=True)]
    stacked = np.concatenate(targets, axis=1)
    where = tuple(np.transpose(cells))
    features = [_samples(dataset[f"activity_{layer}"].values[episode, step]) for layer in layers]
    # One noise draw per layer width, in the order the layers first have it.
    widths = list(dict.fromkeys(f.shape[1] for f in features)) if baseline else []
    noise = [rng.standard_normal((len(episode), width)) for width in widths]
    scores = _cross_validated_r2s(features + noise, stacked, episode, folds, spans)
    chance = dict(zip(widths, scores[len(features):].mean(axis=1), strict=True))
    for i, layer_scores in enumerate(scores[: len(features)]):
        half = 1.96 * layer_scores.std(axis=0, ddof=1) / np.sqrt(folds)
        mean = layer_scores.mean(axis=0)
        for name, value in (("r2", mean), ("r2_low", mean - half), ("r2_high", mean + half)):
            result[name][where[0], i, where[1]] = value
        if baseline:
            result["baseline"][where[0], i, where[1]] = chance[features[i].shape[1]]
    return result


def as_names(names: str | Sequence[str]) -> list[str]:
    """A name or names as a list: one name given as a string is one name, not its letters."""
    return [names] if isinstance(names, str) else list(names)


def chosen_layers(dataset: xr.Dataset, layers: str | Sequence[str] | None) -> list[str]:
    """The layers an analysis of `dataset` takes: every recorded one for None, one name given as a string, else
    `layers`; a ValueError (`require`) for one the recording lacks."""
    chosen = recorded_layers(dataset) if layers is None else as_names(layers)
    if not chosen and layers is not None:  # a filter that kept nothing: analyses of no layer, or a failure in NumPy
        raise ValueError(f"layers={layers!r} chooses no layer: name one or more of the recording's "
                         f"({', '.join(recorded_layers(dataset))}), or leave layers out for all of them.")
    require(dataset, chosen)
    return chosen


def require(dataset: xr.Dataset, layers: str | Sequence[str], variables: str | Sequence[str] = ()) -> None:
    """Raise a ValueError naming what of `layers` (names as `record` gives them, e.g. network.PMC.1: the recording
    keeps each as `activity_<name>`) and `variables` the recording lacks, with the nearest name and what it has."""
    layers, variables = as_names(layers), as_names(variables)
    recorded = recorded_layers(dataset)
    problems = []
    for name in layers:
        if f"activity_{name}" in dataset.data_vars:
            continue
        # A recurrent module records its outputs by index (e.g. network.PMC.1, the cell's output).
        outputs = [layer for layer in recorded if layer.startswith(f"{name}.")]
        close = difflib.get_close_matches(name.removeprefix("activity_"), recorded, n=1)
        problems.append(f"no layer {name!r}" + (
            f" (module {name} records {', '.join(outputs)}: name one of those)" if outputs else
            f" (layers are named without the activity_ prefix: {name.removeprefix('activity_')!r})"
            if name.startswith("activity_") and name.removeprefix("activity_") in recorded else
            f" (did you mean {close[0]!r}?)" if close else ""))
    names = sorted(v for v in dataset.data_vars if not str(v).startswith("activity_"))
    for name in variables:
        if name not in dataset.data_vars:
            close = difflib.get_close_matches(name, names, n=1)
            problems.append(f"no variable {name!r}" + (f" (did you mean {close[0]!r}?)" if close else ""))
    if problems:
        raise ValueError(f"Not in the recording: {'; '.join(problems)}. Its layers: {', '.join(recorded)}. Its "
                         f"variables: {', '.join(names)}.")


def lagged_steps(steps: int, lag: int) -> tuple[slice, slice]:
    """`(now, then)`: the time slices of a recording of `steps` steps whose pairs (t, t + lag) are in the recording
    (`lag` may be negative)."""
    return slice(max(0, -lag), steps - max(0, lag)), slice(max(0, lag), steps + min(0, lag))


def check_recording(dataset: object) -> None:
    """TypeError naming what to do when `dataset` is not a recording (an xarray Dataset): a run directory, a saved
    recording's file name or an Agent given in its place, as a notebook easily does."""
    if isinstance(dataset, xr.Dataset):
        if "alive" not in dataset.data_vars:  # read by every analysis: xarray's KeyError would name no fix
            raise ValueError("This recording has no alive (which steps of each episode ran), which every analysis "
                             "reads: give the recording as record_activity returns it, or keep alive when selecting "
                             "its variables.")
        if (why := nothing_ran(dataset)) is not None:
            raise ValueError(f"This recording {why}")
        return
    if isinstance(dataset, str | Path):
        fix = (f"record one first: record_activity({str(dataset)!r})" if Path(dataset).is_dir() else
               f"read it first: xarray.load_dataset({str(dataset)!r})")
        given = f"the {'folder' if Path(dataset).is_dir() else 'name'} {str(dataset)!r}"
    else:
        kind = type(dataset).__name__
        given = f"{'an' if kind[0] in 'AEIOU' else 'a'} {kind}"
        fix = "record one first: record_activity(agent)" if hasattr(dataset, "initial_carry") else "give one"
    raise TypeError(f"Analyses read a recording (the xarray Dataset that record_activity returns, or a file of "
                    f"save_activity read with xarray.load_dataset), not {given}: {fix}.")


def nothing_ran(dataset: xr.Dataset) -> str | None:
    """Why the recording `dataset` has no step that ran (the end of a sentence about it, with the fix), or None:
    no episode or step (a selection of episodes that kept none), or `alive` 0 everywhere. Replaying one failed with
    "batch_size must be a whole number of at least 1", or returned activity that every analysis leaves out; PCA,
    tuning and similarity failed in scikit-learn or NumPy ("Found array with 0 sample(s)", IndexError)."""
    if np.asarray(dataset["alive"].values).any():
        return None
    episodes, steps = dataset.sizes.get("episode", 0), dataset.sizes.get("time", 0)
    held = (f"holds {counted(episodes, 'episode')} of {counted(steps, 'step')}, with alive 0 at every step"
            if episodes and steps else f"holds no {'episode' if not episodes else 'step'}")
    return (f"{held}: analyses and replays read only the steps that ran (alive 1). Record one with episodes "
            "(angora-jax record RUN_DIR --episodes N; in Python record_activity(run_dir, episodes=N)), or select "
            "episodes of one that keep some of their steps.")


def plot_path(plot: str, result: object, needs: str, analysis: str, path: str | Path) -> None:
    """Before `plot` draws: TypeError naming `analysis` when `result` is not what it returns (a Dataset holding
    `needs`: the recording or a DataArray given in its place failed deep in xarray); the folders on the way to `path`
    made, as save_activity and export_policy make theirs (ValueError when a file is on the way)."""
    if not isinstance(result, xr.Dataset) or needs not in result.variables:
        given = (f"a recording: give it {analysis}(recording, ...)" if isinstance(result, xr.Dataset) and any(
                 str(name).startswith("activity_") for name in result.data_vars) else
                 f"a Dataset without {needs}" if isinstance(result, xr.Dataset) else
                 f"{'an' if type(result).__name__[0] in 'AEIOU' else 'a'} {type(result).__name__}")
        raise TypeError(f"{plot} draws what {analysis} returns (a Dataset with {needs}), not {given}.")
    if (why := unwritable_out(path)) is not None:
        raise ValueError(f"{why}; give {plot} a path in a folder you can write to.")
    Path(path).absolute().parent.mkdir(parents=True, exist_ok=True)


def recorded_layers(dataset: xr.Dataset) -> list[str]:
    """The layer names of a recording (its `activity_<name>` variables); TypeError for what is none
    (`check_recording`)."""
    check_recording(dataset)
    return [name.removeprefix("activity_") for name in dataset.data_vars if name.startswith("activity_")]


def _samples(values: np.ndarray) -> np.ndarray:
    """(samples[, features]) -> (samples, features) float64."""
    return np.asarray(values, np.float64).reshape(len(values), -1)


def plot_decoding(result: xr.Dataset, path: str) -> None:
    """A heat map layer x variable of R^2 (the baseline in each cell's label); for a lagged decoding, R^2 against
    the lag per variable, one line per layer, the noise baseline dashed."""
    plot_path("plot_decoding", result, "r2", "decode", path)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if "lag" in result.dims:
        variables = result["variable"].values
        fig, axes = plt.subplots(1, len(variables), figsize=(4.2 * len(variables), 3.4), squeeze=False)
        for ax, variable in zip(axes[0], variables, strict=True):
            for layer in result["layer"].values:
                cell = result.sel(layer=layer, variable=variable)
                line, = ax.plot(result["lag_s"].values, cell["r2"].values, marker=".",
                                label=str(layer).removeprefix("network."))
                ax.fill_between(result["lag_s"].values, cell["r2_low"].values, cell["r2_high"].values,
                                color=line.get_color(), alpha=0.2, linewidth=0)
                ax.plot(result["lag_s"].values, cell["baseline"].values, ls="--", color=line.get_color(), lw=0.8)
            ax.set(title=str(variable), xlabel="lag of the variable after the activity (s)", ylabel="held-out R^2")
            ax.axvline(0, color="k", lw=0.5)
        axes[0][0].legend(fontsize="small")
        fig.tight_layout()
        fig.savefig(path, dpi=100)
        plt.close(fig)
        return
    r2 = result["r2"].values
    fig, ax = plt.subplots(figsize=(1.2 + 1.1 * r2.shape[1], 1.0 + 0.45 * r2.shape[0]))
    image = ax.imshow(r2, vmin=0, vmax=1, cmap="viridis", aspect="auto")
    ax.set_xticks(range(r2.shape[1]), result["variable"].values, rotation=45, ha="right")
    ax.set_yticks(range(r2.shape[0]), result["layer"].values)
    for (i, j), value in np.ndenumerate(r2):
        chance = result["baseline"].values[i, j]
        ax.text(j, i, f"{value:.2f}" + (f"\n({chance:.2f})" if np.isfinite(chance) else ""), ha="center",
                va="center", fontsize=7, color="white" if value < 0.5 else "black")
    fig.colorbar(image, ax=ax, label="held-out R^2 (noise baseline)")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
