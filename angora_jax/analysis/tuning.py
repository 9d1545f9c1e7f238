"""Tuning: each unit's mean response as a function of a task variable (quantile bins over the alive steps), with
standard errors, and how strongly the variable drives the unit (eta squared: the share of the unit's variance that
the bin means explain)."""

from __future__ import annotations

import numpy as np
import xarray as xr

from angora_jax.analysis.decoding import plot_path, require
from angora_jax.analysis.similarity import condition_labels
from angora_jax.analysis.units import as_scalar


def tuning_curves(dataset: xr.Dataset, layer: str, variable: str, bins: int = 10,
                  feature: int | None = None) -> xr.Dataset:
    """`response` and `sem` (bin x unit): the mean activity of every unit of `layer` per quantile bin of `variable`
    (its `feature`-th component for a vector variable); `center` (bin): the variable's mean in the bin;
    `strength` (unit): eta squared, 0 (untuned) to 1 (the bin explains all of the unit's variance)."""
    require(dataset, [layer])
    labels = condition_labels(dataset, variable, bins, feature)
    feature = None if feature is None else int(as_scalar(feature))  # checked: a NumPy or JAX integer as an int
    alive = labels >= 0
    activity = np.asarray(dataset[f"activity_{layer}"].values, np.float64)[alive]
    values = np.asarray(dataset[variable].values, np.float64)
    values = (values[..., feature] if values.ndim == 3 else values)[alive]
    label = labels[alive]
    count = label.max() + 1
    response = np.stack([activity[label == b].mean(0) for b in range(count)])
    sem = np.stack([activity[label == b].std(0, ddof=1) / np.sqrt(max((label == b).sum(), 1)) for b in range(count)])
    between = sum((label == b).sum() * (response[b] - activity.mean(0)) ** 2 for b in range(count))
    total = ((activity - activity.mean(0)) ** 2).sum(0)
    strength = np.divide(between, total, out=np.zeros_like(total), where=total > 0)
    return xr.Dataset(
        {"response": (("bin", "unit"), response), "sem": (("bin", "unit"), sem),
         "center": (("bin",), np.array([values[label == b].mean() for b in range(count)])),
         "strength": (("unit",), strength)},
        coords={"bin": np.arange(count), "unit": np.arange(activity.shape[-1])},
        attrs={"layer": layer, "variable": variable, "feature": -1 if feature is None else feature},
    )


def plot_tuning(result: xr.Dataset, path: str, units: int = 6) -> None:
    """The tuning curves of the `units` most strongly tuned units, with +-1 s.e.m."""
    plot_path("plot_tuning", result, "response", "tuning_curves", path)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    best = np.argsort(-result["strength"].values)[:units]
    fig, ax = plt.subplots(figsize=(5, 3.4))
    for unit in best:
        ax.errorbar(result["center"].values, result["response"].values[:, unit], yerr=result["sem"].values[:, unit],
                    capsize=2, label=f"unit {unit} (eta2 {result['strength'].values[unit]:.2f})")
    ax.set(xlabel=result.attrs["variable"], ylabel=f"{result.attrs['layer']} activity")
    ax.legend(fontsize=6)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
