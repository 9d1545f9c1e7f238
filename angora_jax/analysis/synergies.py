"""Muscle synergies: how few fixed patterns of co-activation explain a muscle-driven agent's activations.

The activations `A` (samples x muscles, non-negative: every alive step of every recorded episode) are factorised by
non-negative matrix factorisation (scikit-learn's `NMF`) as `A ~ W H`, for k = 1 .. `max_synergies`: the k rows of
`H` are the synergies (each a non-negative weight per muscle, scaled to unit norm), `W` their activation over time.
Each k is scored by the variance accounted for, the synergy literature's measure (e.g. Tresch, Cheung and d'Avella
2006): VAF = 1 - ||A - W H||^2 / ||A||^2, uncentred (the squared Frobenius norms). The count is the smallest k whose
VAF reaches `threshold` (0.9 by convention).

Uncentred VAF credits a tonic co-activation to the first synergy, and a finite sample gives any factorisation some
VAF, so a count alone says little. The control, `vaf_shuffled`, factorises the same activations with each muscle's
samples permuted on their own: every muscle keeps its distribution (and so its tonic level) but loses its
co-activation with the others. Structure is where the VAF rises above that control.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import xarray as xr
from sklearn.decomposition import NMF

from angora_jax.analysis.decoding import check_recording, plot_path
from angora_jax.experiment.config import ConfigError, check_count, check_number, check_seed

ACTIVATION = "task_muscle_activation"


def synergies(data: xr.Dataset | np.ndarray, max_synergies: int | None = None, threshold: float = 0.9,
              variable: str = ACTIVATION, seed: int = 0, control: bool = True) -> xr.Dataset:
    """The VAF of 1, 2, ... synergies and the synergies of the smallest count that reaches `threshold`.

    Args:
        data: a recording (`record_activity`; its `variable` at the steps where `alive`) or an array (samples x
            muscles) of non-negative activations.
        max_synergies: fit 1 .. this many synergies, a whole number from 1 to the number of muscles; None: fit 1,
            2, ... until the VAF reaches `threshold`, at most one per muscle.
        threshold: the VAF the count must reach, a number above 0 up to 1.
        variable: the recording's variable of activations (`task_muscle_activation` of `MyoHandPose`).
        seed: NMF's initialisation seed and the control's permutations', a whole number from 0 to 2**32 - 1.
        control: also fit the shuffled control (twice the fits).

    Returns:
        A Dataset with `vaf` and `vaf_shuffled` (dim `count`: the counts fitted; the control NaN without `control`),
        `muscle_weights` (dims synergy x muscle, the muscles named where the recording names them: the chosen count's
        synergies, unit norm, ordered by their share of the activations) and `activation` (dims sample x synergy:
        each synergy's activation per sample); attributes `count` (the chosen count; the largest fitted when none
        reaches the threshold, and `reached` 0), `threshold` and `samples`.

    Raises:
        ConfigError: `max_synergies`, `threshold` or `seed` out of range (`check_count`, `check_number`,
            `check_seed`); ValueError: negative activations or a variable the recording lacks.
    """
    if max_synergies is not None:
        max_synergies = check_count("max_synergies", max_synergies)
    threshold, seed = check_number("threshold", threshold, 0.0, 1.0, open_low=True), check_seed("seed", seed)
    activations = _activations(data, variable)
    muscles = activations.shape[1]
    names = _muscle_names(data, variable, muscles)
    if max_synergies is not None and max_synergies > muscles:
        raise ConfigError(f"max_synergies must be a whole number from 1 to {muscles} (the muscles), got "
                          f"{max_synergies}.")
    fits = []
    for k in range(1, (max_synergies or muscles) + 1):
        fits.append(_factorise(activations, k, seed))
        if max_synergies is None and fits[-1][2] >= threshold:
            break
    vaf = np.array([fit[2] for fit in fits])
    fitted = len(fits)
    shuffled = np.full(fitted, np.nan)
    if control:
        rng = np.random.default_rng(seed)
        permuted = np.stack([rng.permutation(column) for column in activations.T], axis=1)
        shuffled = np.array([_factorise(permuted, k, seed)[2] for k in range(1, fitted + 1)])
    reached = bool(np.any(vaf >= threshold))
    count = int(np.argmax(vaf >= threshold)) + 1 if reached else fitted
    weights, components, _ = fits[count - 1]
    norms = np.linalg.norm(components, axis=1, keepdims=True)
    norms[norms == 0] = 1.0  # a synergy NMF left empty stays zero
    weights, components = weights * norms.T, components / norms
    order = np.argsort(-np.sum(weights, axis=0))
    return xr.Dataset(
        {"vaf": ("count", vaf, {"description": "1 - ||A - WH||^2 / ||A||^2 (uncentred)"}),
         "vaf_shuffled": ("count", shuffled, {"description": "the same with each muscle's samples permuted apart"}),
         "muscle_weights": (("synergy", "muscle"), components[order], {"description": "per synergy, unit norm"}),
         "activation": (("sample", "synergy"), weights[:, order], {"description": "each synergy's activation"})},
        coords={"count": np.arange(1, fitted + 1), "synergy": np.arange(count), "muscle": names},
        attrs={"count": count, "reached": int(reached), "threshold": threshold, "samples": len(activations)})


def _factorise(activations: np.ndarray, k: int, seed: int) -> tuple[np.ndarray, np.ndarray, float]:
    """NMF of `activations` with `k` synergies: (W, H, uncentred VAF)."""
    model = NMF(n_components=k, init="nndsvda", max_iter=1000, random_state=seed)
    weights = model.fit_transform(activations)
    residual = np.sum((activations - weights @ model.components_) ** 2)
    return weights, model.components_, 1 - residual / np.sum(activations**2)


def _muscle_names(data: xr.Dataset | np.ndarray, variable: str, muscles: int) -> np.ndarray:
    """The recording's names of the muscles (its coordinate of `variable`'s last dimension), else their indices."""
    if isinstance(data, xr.Dataset):
        dim = data[variable].dims[-1]
        if dim in data.coords and data.sizes[dim] == muscles:
            return np.asarray(data[dim].values)
    return np.arange(muscles)


def _activations(data: xr.Dataset | np.ndarray, variable: str) -> np.ndarray:
    """(samples, muscles) float64 from a recording's alive steps or an array; ValueError when negative or absent."""
    if isinstance(data, xr.Dataset):
        check_recording(data)
        if variable not in data.data_vars:
            raise ValueError(f"Not in the recording: {variable}; it has {sorted(data.data_vars)}. Record a muscle task "
                             "(MyoHandPose records task_muscle_activation).")
        values = np.asarray(data[variable].values, np.float64)[data["alive"].values > 0]
    else:
        if isinstance(data, str | Path) or not hasattr(data, "__len__"):  # a run or file name, an Agent
            check_recording(data)
        values = np.asarray(data, np.float64)
    values = values.reshape(len(values), -1)
    if values.size == 0 or np.any(values < 0) or not np.any(values > 0):
        raise ValueError("Synergies factorise non-negative activations, not all zero: give muscle activations "
                         "(e.g. task_muscle_activation), not forces or centred values.")
    return values


def plot_synergies(result: xr.Dataset, path: str) -> None:
    """The VAF against the number of synergies (the threshold dashed) and the chosen synergies' muscle weights."""
    plot_path("plot_synergies", result, "count", "synergies", path)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    count = result.sizes["synergy"]
    # Tall enough for one readable label per muscle.
    height = max(3.2, 0.11 * result.sizes["muscle"] + 1.0)
    fig, axes = plt.subplots(1, 1 + count, figsize=(3.6 + 2.4 * count, height), squeeze=False)
    ax = axes[0][0]
    ax.plot(result["count"].values, result["vaf"].values, marker="o", label="activations")
    if "vaf_shuffled" in result and not np.all(np.isnan(result["vaf_shuffled"].values)):
        ax.plot(result["count"].values, result["vaf_shuffled"].values, marker="o", color="0.6",
                label="muscles shuffled apart")
        ax.legend(fontsize="small", loc="lower right")
    ax.axhline(result.attrs["threshold"], ls="--", color="k", lw=0.8)
    ax.set(xlabel="synergies", ylabel="VAF", ylim=(0, 1.02), title=f"{result.attrs['count']} reach the threshold"
           if result.attrs["reached"] else "none reach the threshold")
    muscles = result["muscle"].values
    for i, ax in enumerate(axes[0][1:]):
        ax.barh(np.arange(len(muscles)), result["muscle_weights"].values[i], color="tab:blue")
        ax.set(title=f"synergy {i + 1}", xlabel="weight", ylabel="muscle" if i == 0 else None)
        ax.set_yticks(np.arange(len(muscles)), [str(m) for m in muscles], fontsize=6)
        ax.invert_yaxis()
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
