"""Muscles or movements: does a cortical area's activity read out more like the muscles' forces and activations or
like the joints' kinematics (the classic question about motor cortex, e.g. Kakei, Hoffman and Strick 1999)?

For each layer, `decode`'s cross-validated ridge R^2 of the muscle variables and of the movement variables, side by
side, and the same decoding of the untrained control: the network with random weights given the same inputs
(`replay_activity(with_random_weights(agent), recording)`, as `decode`'s docstring says why). A layer's `preference`
is its mean muscle R^2 minus its mean movement R^2; what the control's layers prefer is what the structure and the
inputs give without learning. Muscles and joints are coupled by the body (forces move the joints), so both are
decodable from most layers; compare layers, and each with its control, not the two R^2 with zero.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import xarray as xr

from angora_jax.analysis.decoding import MAX_SAMPLES, chosen_layers, decode, plot_path

MUSCLE_VARIABLES = ("task_muscle_force", "task_muscle_activation")
MOVEMENT_VARIABLES = ("task_joint_angles", "task_joint_velocities")


def muscles_or_movements(recording: xr.Dataset, control: xr.Dataset | None = None,
                         layers: Sequence[str] | None = None, muscles: Sequence[str] = MUSCLE_VARIABLES,
                         movements: Sequence[str] = MOVEMENT_VARIABLES, folds: int = 5, seed: int = 0,
                         max_samples: int = MAX_SAMPLES) -> xr.Dataset:
    """Held-out R^2 of muscle and movement variables from each layer, with the random-weights control.

    Args:
        recording: a recording of a muscle-driven agent (`record_activity`; MyoHandPose records the default
            variables).
        control: the same recording replayed through the untrained network
            (`replay_activity(with_random_weights(agent), recording)`); None: no control (its results stay NaN).
        layers: names as in `activity_<name>` (default: all).
        muscles: the recording's muscle variables.
        movements: the recording's kinematic variables.
        folds: `decode`'s folds (GroupKFold over episodes).
        seed: the noise baseline's seed.
        max_samples: `decode`'s limit of steps.

    Returns:
        `decode`'s Dataset (dims layer x variable: `r2`, `r2_low`, `r2_high`, `baseline`) with `control_r2`,
        `control_r2_low`, `control_r2_high`, the coordinate `kind` of each variable ("muscle" or "movement"),
        `kind_r2` and `control_kind_r2` (layer x kind: the mean R^2 over the kind's variables), and `preference`
        and `control_preference` (layer: the muscles' mean R^2 minus the movements').

    Raises:
        ValueError: a variable or layer the recording lacks, or a control of other episodes or layers.
    """
    layers = chosen_layers(recording, layers)
    variables = [*muscles, *movements]
    if not muscles or not movements:
        raise ValueError("Give at least one muscle variable and one movement variable to compare.")
    if control is not None and (control.sizes["episode"], control.sizes["time"]) != (recording.sizes["episode"],
                                                                                     recording.sizes["time"]):
        raise ValueError("The control must replay this recording's episodes: make it with "
                         "replay_activity(with_random_weights(agent), recording).")
    options = {"layers": layers, "variables": variables, "folds": folds, "seed": seed, "max_samples": max_samples}
    result = decode(recording, **options)
    if control is not None:
        replayed = decode(control, **options, baseline=False)
        result = result.assign({f"control_{name}": replayed[name] for name in ("r2", "r2_low", "r2_high")})
    else:
        result = result.assign({f"control_{name}": xr.full_like(result["r2"], np.nan)
                                for name in ("r2", "r2_low", "r2_high")})
    result = result.assign_coords(kind=("variable", ["muscle"] * len(muscles) + ["movement"] * len(movements)))
    for prefix in ("", "control_"):
        by_kind = result[f"{prefix}r2"].groupby("kind").mean().rename(kind="kind_name")
        result[f"{prefix}kind_r2"] = by_kind
        result[f"{prefix}preference"] = by_kind.sel(kind_name="muscle") - by_kind.sel(kind_name="movement")
    return result.assign_attrs(description="held-out ridge R^2 of muscle and movement variables (decode), trained "
                                           "and random-weights control")


def plot_muscles_or_movements(result: xr.Dataset, path: str) -> None:
    """Per layer, bars of the mean muscle R^2 and the mean movement R^2, the random-weights control's hatched."""
    plot_path("plot_muscles_or_movements", result, "kind_r2", "muscles_or_movements", path)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    layers = [str(layer).removeprefix("network.") for layer in result["layer"].values]
    x = np.arange(len(layers))
    fig, ax = plt.subplots(figsize=(4.5 + 1.0 * len(layers), 3.4))  # the legend beside the bars
    for i, (kind, color) in enumerate((("muscle", "tab:red"), ("movement", "tab:blue"))):
        ax.bar(x + (2 * i - 1.5) * 0.2, result["kind_r2"].sel(kind_name=kind).values, 0.2, color=color,
               label=f"{kind}s")
        ax.bar(x + (2 * i - 0.5) * 0.2, result["control_kind_r2"].sel(kind_name=kind).values, 0.2, color=color,
               alpha=0.4, hatch="//", label=f"{kind}s, random weights")
    ax.set_xticks(x, layers, rotation=30, ha="right")
    ax.set_ylabel("held-out R^2 (mean over variables)")
    ax.axhline(0, color="k", lw=0.5)
    ax.legend(fontsize="small", loc="upper left", bbox_to_anchor=(1, 1))
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
