"""Intrinsic timescales: the autocorrelation of each unit's activity over lags within episodes (Murray et al. 2014
measured it across cortical areas), and the lag at which it first falls below 1/e as the unit's timescale; and the
cross-correlation between areas' leading principal components over lags (which area's activity leads which).

The autocorrelation at lag k is the Pearson correlation over every pair of alive steps (t, t + k) of all episodes;
a unit constant over those pairs has none (NaN).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import xarray as xr

from angora_jax.analysis.decoding import chosen_layers, lagged_steps, plot_path
from angora_jax.analysis.parallel import map_in_threads
from angora_jax.experiment.config import check_count
from angora_jax.wording import counted


def autocorrelation(dataset: xr.Dataset, layer: str, max_lag: int = 20) -> np.ndarray:
    """`(max_lag + 1, units)`: the autocorrelation of each unit of `layer` at lags 0..max_lag (policy steps)."""
    alive = dataset["alive"].values > 0
    z = np.asarray(dataset[f"activity_{layer}"].values, np.float64)
    z = z - z[alive].mean(0)  # so that the one-pass sums below do not cancel
    return np.stack([_lagged_correlation(z, z, alive, lag) for lag in range(max_lag + 1)])


def _lagged_correlation(a: np.ndarray, b: np.ndarray, alive: np.ndarray, lag: int) -> np.ndarray:
    """Per unit, the Pearson correlation of a(t) with b(t + lag) over the pairs of alive steps of every episode
    (`lag` may be negative); NaN where no pair is alive or a side is constant over the pairs. Each side is centred
    and scaled over the pairs themselves, so |r| <= 1 at every lag and a signal correlates best with itself at lag 0
    (a mean of products, scaled once over all steps, exceeds 1 where the overlap excludes quiet steps). Inputs
    centred near 0 keep the one-pass moments exact to rounding."""
    steps = a.shape[1]
    if abs(lag) >= steps:
        return np.full(a.shape[-1], np.nan)
    now, then = lagged_steps(steps, lag)
    both = (alive[:, now] & alive[:, then]).astype(a.dtype)
    pairs = both.sum()
    if not pairs:
        return np.full(a.shape[-1], np.nan)
    x, y = a[:, now], b[:, then]

    # Moments as weighted sums over the (episode, step) grid: gathering the pairs first copied (pairs x units)
    # arrays several times per lag, 2.7x slower on a cube recording's size.
    def moment(*sides: np.ndarray) -> np.ndarray:
        return np.einsum("et" + ",etu" * len(sides) + "->u", both, *sides) / pairs

    mean_x, mean_y, square_x, square_y = moment(x), moment(y), moment(x, x), moment(y, y)
    var_x, var_y = square_x - mean_x**2, square_y - mean_y**2
    # A side constant over the pairs has a variance of rounding error: none, relative to its square's mean.
    varying = (var_x > 1e-12 * square_x) & (var_y > 1e-12 * square_y)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(varying, (moment(x, y) - mean_x * mean_y) / np.sqrt(var_x * var_y), np.nan)


def cross_correlation(dataset: xr.Dataset, layers: Sequence[str] | None = None, max_lag: int = 20) -> xr.Dataset:
    """Between every two layers, the correlation of their leading principal components (PCA over the alive steps,
    scikit-learn) at lags -max_lag..max_lag: `cross_correlation` (layer x other x lag) is corr(a(t), b(t + lag)), so
    a peak at a positive lag means `layer` leads `other`. A component's sign is arbitrary, so `peak_lag` (layer x
    other, in s) is the lag of the largest |correlation|. `max_lag` stops at the recording's steps less one."""
    from sklearn.decomposition import PCA

    layers = chosen_layers(dataset, layers)
    max_lag = _lags_within(dataset, check_count("max_lag", max_lag, least=0))  # 0: the correlation at lag 0 alone
    alive = dataset["alive"].values > 0
    leading = {}
    for layer in layers:
        values = np.asarray(dataset[f"activity_{layer}"].values, np.float64)
        component = np.zeros(values.shape[:2] + (1,))
        component[alive] = PCA(1).fit_transform(values[alive])
        leading[layer] = component
    lags = np.arange(-max_lag, max_lag + 1)
    dt = float(dataset.attrs.get("policy_step_s", 1.0))
    curves = np.array([[[_lagged_correlation(leading[a], leading[b], alive, int(k))[0] for k in lags]
                        for b in layers] for a in layers])
    peak = np.where(np.isfinite(curves).any(-1), lags[np.argmax(np.nan_to_num(np.abs(curves), nan=-1), -1)] * dt,
                    np.nan)
    return xr.Dataset({"cross_correlation": (("layer", "other", "lag"), curves),
                       "peak_lag": (("layer", "other"), peak, {"units": "s"})},
                      coords={"layer": layers, "other": layers, "lag": ("lag", lags * dt, {"units": "s"})})


def timescales(dataset: xr.Dataset, layers: Sequence[str] | None = None, max_lag: int = 20) -> xr.Dataset:
    """Per layer: `autocorrelation` (layer x lag, the mean over its units), and per unit the timescale in s (the
    first lag, linearly interpolated, where its autocorrelation drops below 1/e; NaN when it stays above within
    `max_lag` or the unit is constant) summarised as `timescale_median` and `timescale_iqr_low/high` (layer).
    `max_lag` stops at the recording's steps less one. ValueError when no episode is alive for 2 consecutive steps
    (a recording of one step)."""
    layers = chosen_layers(dataset, layers)
    max_lag = _lags_within(dataset, check_count("max_lag", max_lag))  # a timescale needs a lag past 0
    alive = dataset["alive"].values > 0
    if not (alive[:, :-1] & alive[:, 1:]).any():  # else every timescale is NaN, as if longer than the lags
        raise ValueError(f"Timescales need episodes alive for at least 2 consecutive steps (an autocorrelation at a "
                         f"lag of 1 step); the recording has {counted(dataset.sizes['time'], 'step')} per episode "
                         "and none such: record more steps (angora-jax record --steps).")
    dt = float(dataset.attrs.get("policy_step_s", 1.0))
    curves, medians, low, high = [], [], [], []
    for acf in map_in_threads(lambda layer: autocorrelation(dataset, layer, max_lag), layers):
        curves.append(np.nanmean(acf, axis=1) if np.isfinite(acf).any() else np.full(max_lag + 1, np.nan))
        tau = np.array([_crossing(acf[:, unit]) for unit in range(acf.shape[1])]) * dt
        finite = tau[np.isfinite(tau)]
        quartiles = np.percentile(finite, [25, 50, 75]) if finite.size else np.full(3, np.nan)
        low.append(quartiles[0])
        medians.append(quartiles[1])
        high.append(quartiles[2])
    return xr.Dataset(
        {"autocorrelation": (("layer", "lag"), np.asarray(curves)),
         "timescale_median": (("layer",), np.asarray(medians), {"units": "s"}),
         "timescale_iqr_low": (("layer",), np.asarray(low), {"units": "s"}),
         "timescale_iqr_high": (("layer",), np.asarray(high), {"units": "s"})},
        coords={"layer": layers, "lag": ("lag", np.arange(max_lag + 1) * dt, {"units": "s"})},
    )


def _lags_within(dataset: xr.Dataset, max_lag: int) -> int:
    """`max_lag`, but at most the recording's steps less one: no two of its steps lie further apart, and each lag
    past them would cost a pass over the recording for a NaN."""
    return min(max_lag, dataset.sizes["time"] - 1)


def _crossing(acf: np.ndarray, level: float = 1.0 / np.e) -> float:
    """First lag (in steps, interpolated) where `acf` falls below `level`; NaN if it never does."""
    below = np.flatnonzero(acf < level)
    if not below.size or not np.isfinite(acf[0]):
        return np.nan
    k = below[0]
    return float(k - 1 + (acf[k - 1] - level) / (acf[k - 1] - acf[k])) if k > 0 else 0.0


def plot_timescales(result: xr.Dataset, path: str) -> None:
    """Mean autocorrelation per layer over lags (s), with the 1/e level."""
    plot_path("plot_timescales", result, "autocorrelation", "timescales", path)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5, 3.4))
    for layer in result["layer"].values:
        tau = float(result["timescale_median"].sel(layer=layer))
        ax.plot(result["lag"].values, result["autocorrelation"].sel(layer=layer).values,
                label=f"{str(layer).removeprefix('network.')} (tau {tau:.3g} s)")
    ax.axhline(1 / np.e, color="k", lw=0.6, ls="--")
    ax.set(xlabel="lag (s)", ylabel="autocorrelation (mean over units)")
    ax.legend(fontsize=6)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def plot_cross_correlation(result: xr.Dataset, path: str) -> None:
    """The cross-correlation curves of every pair of different layers over lags (s)."""
    plot_path("plot_cross_correlation", result, "cross_correlation", "cross_correlation", path)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    layers = list(result["layer"].values)
    pairs = len(layers) * (len(layers) - 1) // 2
    # A model of many areas has many pairs (17 layers: 136): the legend goes beside the axes, in columns of at most
    # 25 entries, and the saved image grows to hold it (bbox_inches), rather than the legend covering the curves or
    # squeezing the axes away.
    columns = max(1, -(-pairs // 25))
    fig, ax = plt.subplots(figsize=(5.5, max(3.4, 0.16 * min(pairs, 25))))
    # Matplotlib's 10 colours repeated from the 11th pair on, so two curves read alike: 20 colours times 7 line
    # styles tell 140 pairs apart (17 layers, the reach model's); past that the printed lag table and the .nc are the
    # readable output.
    dashes = ("-", "--", ":", "-.", (0, (3, 1, 1, 1, 1, 1)), (0, (5, 2, 1, 2)), (0, (1, 3)))
    styles = [(plt.cm.tab20(k % 20), dashes[k // 20 % len(dashes)]) for k in range(pairs)]
    pair_names = [(layer, other) for i, layer in enumerate(layers) for other in layers[i + 1:]]
    for (layer, other), (colour, style) in zip(pair_names, styles, strict=True):
        name = f"{str(layer).removeprefix('network.')} -> {str(other).removeprefix('network.')}"
        ax.plot(result["lag"].values, result["cross_correlation"].sel(layer=layer, other=other).values, color=colour,
                linestyle=style, label=name)
    ax.axvline(0, color="k", lw=0.5)
    ax.set(xlabel="lag (s; > 0: the first leads)", ylabel="correlation of leading components")
    ax.legend(fontsize="x-small", loc="upper left", bbox_to_anchor=(1.01, 1), ncols=columns, borderaxespad=0)
    fig.savefig(path, dpi=100, bbox_inches="tight")
    plt.close(fig)
