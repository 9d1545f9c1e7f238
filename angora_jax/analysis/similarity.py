"""Representational similarity analysis (RSA) of recorded activity, with rsatoolbox.

Conditions are bins of a task variable (quantile bins of a scalar such as `metric_goal_distance` or `time_in_episode`
for phases of the episode, or of one feature of a vector variable such as `input_goal`), over the steps where the
episode is alive. For every layer, rsatoolbox averages the activity per condition and computes the representational
dissimilarity matrix (RDM, correlation distance by default). Layers are then compared with each other, and with
model RDMs: for each task variable, the Euclidean distances between its condition means (what an area that encodes
exactly that variable would show). Comparisons are Spearman correlations of the RDMs' upper triangles.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import xarray as xr
from rsatoolbox.data import Dataset
from rsatoolbox.rdm import RDMs, calc_rdm, compare

from angora_jax.analysis.decoding import as_names, chosen_layers, plot_path, recorded_layers, require
from angora_jax.analysis.units import as_scalar, is_unit
from angora_jax.experiment.config import ConfigError, check_count
from angora_jax.wording import counted, did_you_mean


def condition_labels(dataset: xr.Dataset, variable: str, bins: int = 8, feature: int | None = None) -> np.ndarray:
    """Condition of every step `(episode, time)`: the quantile bin of `variable` (its `feature`-th component for a
    vector variable: a whole number from 0 to its features - 1, ConfigError otherwise), numbered 0..k-1 with k <= bins
    (ties in the quantiles merge bins), -1 where the episode is not alive. `bins` is a whole number of at least 2
    (ConfigError otherwise: 1.5 failed in np.linspace, and 1 or 0 gave one condition without a word)."""
    bins = check_count("bins", bins, least=2)
    if variable not in dataset.data_vars:
        raise ValueError(f"No variable {variable!r} in the recording; it has {sorted(dataset.data_vars)}.")
    values = np.asarray(dataset[variable].values, np.float64)
    if values.ndim == 3:
        count = values.shape[-1]
        if feature is None:
            raise ConfigError(f"{variable} has {counted(count, 'feature')}; choose one with feature=<index> "
                              "(--feature).")
        if not is_unit(as_scalar(feature), count):
            raise ConfigError(f"feature={feature!r} (--feature) is not a feature of {variable}: give a whole number "
                              f"from 0 to {count - 1} ({variable} has {counted(count, 'feature')}).")
        values = values[..., as_scalar(feature)]
    elif feature is not None:
        raise ConfigError(f"{variable} is one number per step, with no features: drop feature={feature!r} "
                          "(--feature).")
    alive = dataset["alive"].values > 0
    labels = np.digitize(values, np.quantile(values[alive], np.linspace(0, 1, bins + 1)[1:-1]))
    compact = np.full(labels.shape, -1)
    compact[alive] = np.unique(labels[alive], return_inverse=True)[1]
    return compact


# rsatoolbox's `calc_rdm` methods that an RDM of each condition's mean pattern can use: its cross-validated ones need
# repeats of each condition.
RDM_METHODS = ("correlation", "euclidean", "mahalanobis", "poisson")
_CROSS_VALIDATED = ("crossnobis", "poisson_cv")


def check_rdm_method(method: object) -> None:
    """ConfigError naming the methods for a `method` not in `RDM_METHODS`: rsatoolbox raised a NotImplementedError
    without a message for an unknown one, and an AssertionError for a cross-validated one."""
    if isinstance(method, str) and method in RDM_METHODS:
        return
    why = (f" ({method} is cross-validated: it needs repeats of each condition, and similarity compares their mean "
           "patterns)" if method in _CROSS_VALIDATED else did_you_mean(method, RDM_METHODS))
    raise ConfigError(f"method must be one of {', '.join(map(repr, RDM_METHODS))} (rsatoolbox's RDM methods), got "
                      f"{method!r}.{why}")


def layer_rdms(dataset: xr.Dataset, labels: np.ndarray, layers: Sequence[str] | None = None,
               method: str = "correlation") -> RDMs:
    """One RDM per layer over the conditions in `labels` (from `condition_labels`), as rsatoolbox RDMs with the
    descriptor `layer`.

    Args:
        method: one of `RDM_METHODS`, rsatoolbox's `calc_rdm` methods that need no repeats of a condition.
    """
    check_rdm_method(method)
    def units(layer: str) -> int:
        return int(np.prod(dataset[f"activity_{layer}"].shape[2:]))

    # The correlation between two conditions' mean patterns needs at least two units: a one-unit layer (the value
    # output) has none, so it is left out unless named.
    layers = chosen_layers(dataset, layers) if layers is not None else [
        layer for layer in recorded_layers(dataset) if method != "correlation" or units(layer) > 1]
    alive = labels.reshape(-1) >= 0
    patterns = [_patterns(dataset[f"activity_{layer}"], labels, alive) for layer in layers]
    if method == "poisson":  # rsatoolbox takes logs of the rates: NaN below -0.1 (its prior), meaningless below 0
        negative = {layer: float(p.measurements.min()) for layer, p in zip(layers, patterns, strict=True)
                    if p.measurements.size and p.measurements.min() < 0}
        if negative:
            which = ", ".join(f"{layer} (down to {low:.3g})" for layer, low in negative.items())
            raise ValueError(f"The poisson RDM treats activity as firing rates, which are not negative, but {which} "
                             f"{'hold' if len(negative) > 1 else 'holds'} negative values (tanh or linear units): use "
                             "correlation or euclidean, or leave the layer out (--layers).")
    rdms = [calc_rdm(pattern, method=method, descriptor="condition") for pattern in patterns]
    undefined = [layer for layer, rdm in zip(layers, rdms, strict=True) if np.isnan(rdm.dissimilarities).any()]
    if undefined:
        why = ", ".join(f"{layer} ({units(layer)} unit{'s' * (units(layer) > 1)})" for layer in undefined)
        raise ValueError(f"The {method} RDM of {why} is undefined: some condition's mean pattern has one unit or is "
                         "constant across its units. Leave the layer out (--layers), or use another method.")
    result = RDMs(np.concatenate([r.dissimilarities for r in rdms]), dissimilarity_measure=method,
                  rdm_descriptors={"layer": layers}, pattern_descriptors=rdms[0].pattern_descriptors)
    return result


def variable_rdms(dataset: xr.Dataset, labels: np.ndarray, variables: Sequence[str]) -> RDMs:
    """Model RDMs: for each task variable, Euclidean distances between its means per condition."""
    alive = labels.reshape(-1) >= 0
    rdms = [calc_rdm(_patterns(dataset[v], labels, alive), method="euclidean", descriptor="condition")
            for v in variables]
    return RDMs(np.concatenate([r.dissimilarities for r in rdms]), dissimilarity_measure="euclidean",
                rdm_descriptors={"variable": list(variables)}, pattern_descriptors=rdms[0].pattern_descriptors)


def similarity(dataset: xr.Dataset, condition: str, layers: Sequence[str] | None = None,
               variables: Sequence[str] = (), bins: int = 8, feature: int | None = None,
               method: str = "correlation") -> xr.Dataset:
    """RSA of `layers` (default all) over bins of `condition` (see `condition_labels`), as a Dataset with `rdm`
    (layer x condition x condition_), `layer_similarity` (layer x layer_: Spearman correlation of their RDMs) and,
    for `variables`, `model_similarity` (layer x variable: each layer's RDM against the variable's model RDM).
    `method`: the layers' dissimilarity, one of `RDM_METHODS`."""
    variables = as_names(variables)
    require(dataset, (), variables)
    labels = condition_labels(dataset, condition, bins, feature)
    rdms = layer_rdms(dataset, labels, layers, method)
    layers = rdms.rdm_descriptors["layer"]
    data = {"rdm": (("layer", "condition", "condition_"), rdms.get_matrices()),
            "layer_similarity": (("layer", "layer_"), compare(rdms, rdms, method="spearman"))}
    coords = {"layer": layers, "layer_": layers, "condition": np.arange(rdms.n_cond),
              "condition_": np.arange(rdms.n_cond)}
    if variables:
        models = variable_rdms(dataset, labels, variables)
        data["model_similarity"] = (("layer", "variable"), compare(rdms, models, method="spearman"))
        coords["variable"] = list(variables)
    return xr.Dataset(data, coords=coords, attrs={"condition": condition, "bins": bins, "method": method,
                                                  "feature": -1 if feature is None else feature})


def _patterns(array: xr.DataArray, labels: np.ndarray, alive: np.ndarray) -> Dataset:
    values = np.asarray(array.values, np.float64)
    samples = values.reshape(values.shape[0] * values.shape[1], -1)[alive]
    return Dataset(samples, obs_descriptors={"condition": labels.reshape(-1)[alive]})


def plot_similarity(result: xr.Dataset, path: str) -> None:
    """One panel per layer's RDM, up to six a row, then the layer x layer similarity (and layer x variable, when
    computed) below them, larger: the brain-area model's 15 layers in one row made a figure 44 inches wide."""
    plot_path("plot_similarity", result, "rdm", "similarity", path)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    layers = list(result["layer"].values)
    extra = ["layer_similarity"] + (["model_similarity"] if "model_similarity" in result else [])
    columns = max(min(6, len(layers)), len(extra))
    rows = -(-len(layers) // columns)
    fig = plt.figure(figsize=(2.6 * columns, 2.6 * rows + 5.0))
    grid = fig.add_gridspec(rows + 1, columns, height_ratios=[1.0] * rows + [2.0])
    for i, layer in enumerate(layers):
        ax = fig.add_subplot(grid[i // columns, i % columns])
        ax.imshow(result["rdm"].sel(layer=layer).values, cmap="viridis")
        ax.set_title(layer.removeprefix("network."), fontsize=8)
        ax.set_xlabel(f"{result.attrs['condition']} bin", fontsize=7)
    span = columns // len(extra)
    for i, name in enumerate(extra):
        ax = fig.add_subplot(grid[rows, i * span:(i + 1) * span])
        values = result[name].values
        ax.imshow(values, vmin=-1, vmax=1, cmap="RdBu_r")
        ticks = [str(t).removeprefix("network.") for t in result[name][result[name].dims[1]].values]
        ax.set_xticks(range(values.shape[1]), ticks, rotation=90, fontsize=6)
        ax.set_yticks(range(values.shape[0]), [t.removeprefix("network.") for t in layers], fontsize=6)
        ax.set_title(f"{name.replace('_', ' ')} (Spearman)", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
