"""`analyze`: analyses of a recording (`angora-jax record`) and lesions of a run, one sub-verb each."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from angora_jax.cli.arguments import (
    EXIT_OK,
    EXIT_USAGE,
    add_env_option,
    at_least_two,
    checkpoint_of,
    episode_count,
    positive_int,
    refused_existing,
)
from angora_jax.whole_files import written_whole
from angora_jax.wording import agreeing, counted

if TYPE_CHECKING:
    from angora_jax.experiment import Agent, Config

# The handlers import what they run (JAX, the analyses, runs) inside them: the parser, which every command builds, and
# `--help` need none of it.


def add_analyze(commands: argparse._SubParsersAction) -> None:
    """The `analyze` verb: its arguments and its handler."""
    analyze = commands.add_parser("analyze", help="analyses of a recording (see angora-jax record)")
    analyses = analyze.add_subparsers(dest="analysis", required=True)
    decoding = analyses.add_parser("decode", help="ridge R^2 of each variable from each layer vs a noise baseline")
    decoding.add_argument("recording", help="a NetCDF file from angora-jax record")
    decoding.add_argument("--layers", nargs="+", help="layer names (default: all)")
    decoding.add_argument("--variables", nargs="+", help="variables (default: every input_*, task_* and metric_*)")
    decoding.add_argument("--folds", type=at_least_two, default=5,
                          help="cross-validation folds, split by episode (default: 5)")
    decoding.add_argument("--lags", nargs="*", type=int, default=None,
                          help="policy steps k: decode the variable k steps after the activity (k < 0: before), "
                               "e.g. --lags -4 0 4 8 16")
    decoding.add_argument("--out", default=None,
                          help="heat map PNG, its numbers beside it as .nc; never overwritten (default: beside the "
                               "recording, *.decode.png, else the next free *.decode-N.png)")
    decoding.set_defaults(handler=command_decode)

    def analysis(name: str, help: str) -> argparse.ArgumentParser:
        parser = analyses.add_parser(name, help=help)
        parser.add_argument("recording", help="a NetCDF file from angora-jax record")
        parser.add_argument("--out", default=None,
                            help=f"PNG, its numbers beside it as .nc; never overwritten (default: beside the "
                                 f"recording, *.{name}.png, else the next free *.{name}-N.png)")
        parser.set_defaults(handler=command_analysis)
        return parser

    similar = analysis("similarity", "representational similarity (RSA): RDMs per layer over bins of a variable")
    similar.add_argument("--condition", required=True, help="variable whose quantile bins are the conditions")
    similar.add_argument("--feature", type=int, default=None, help="component of a vector condition variable")
    similar.add_argument("--bins", type=at_least_two, default=8, help="quantile bins of the condition (default: 8)")
    similar.add_argument("--layers", nargs="+", help="layer names (default: all)")
    similar.add_argument("--variables", nargs="*", default=[], help="variables to compare with as model RDMs")
    dynamics = analysis("dynamics", "PCA per layer; with --run, fixed points of a recurrent layer")
    dynamics.add_argument("--layers", nargs="+", help="layer names (default: all)")
    dynamics.add_argument("--components", type=positive_int, default=10,
                          help="principal components per layer (default: 10)")
    dynamics.add_argument("--run", default=None, help="the recorded run (for fixed points)")
    dynamics.add_argument("--checkpoint", default=None,
                               help="the recorded checkpoint (default: the cycle the recording was made from)")
    dynamics.add_argument("--recurrent", default=None, help="recurrent layer, e.g. network.PMC")
    dynamics.add_argument("--inputs", nargs="+", default=None,
                          help="the recorded layer(s) feeding it, e.g. network.PMC_in (default, for an area of a "
                               "brain-area graph: its inputs as the graph lists them)")
    scales = analysis("timescales", "activity autocorrelation and intrinsic timescale per layer")
    scales.add_argument("--layers", nargs="+", help="layer names (default: all)")
    scales.add_argument("--max-lag", type=positive_int, default=20, help="policy steps (default: 20)")
    crosscorrelation = analysis("crosscorrelation", "correlation of layers' leading components over lags")
    crosscorrelation.add_argument("--layers", nargs="+", help="layer names (default: all)")
    crosscorrelation.add_argument("--max-lag", type=positive_int, default=20, help="policy steps (default: 20)")
    seeing = analysis("visual", "inside the visual area: filters, feature maps, saliency, preferred stimuli")
    seeing.add_argument("--run", required=True, help="the recorded run (one that sees camera images)")
    seeing.add_argument("--checkpoint", default=None,
                             help="the recorded checkpoint (default: the cycle the recording was made from)")
    seeing.add_argument("--frames", type=positive_int, default=4, help="frames of the first episode (default: 4)")
    seeing.add_argument("--camera", type=int, default=0, help="which camera's frames (default: 0, the first)")
    seeing.add_argument("--units", type=positive_int, default=4, help="units per layer to show (default: 4)")
    seeing.add_argument("--steps", type=positive_int, default=256, help="steps of activation maximization")
    add_env_option(seeing)
    tuning = analysis("tuning", "unit responses as functions of a task variable")
    tuning.add_argument("--layer", required=True, help="a recorded layer, e.g. network.SSC_2")
    tuning.add_argument("--variable", required=True, help="a recorded variable, e.g. metric_goal_distance")
    tuning.add_argument("--feature", type=int, default=None, help="component of a vector variable")
    tuning.add_argument("--bins", type=at_least_two, default=10, help="quantile bins of the variable (default: 10)")
    equations = analysis("sindy", "equations of a layer's dynamics in its leading principal components (SINDy), "
                                  "scored on held-out episodes against next = current")
    equations.add_argument("--layer", required=True, help="e.g. network.PMC.1, the premotor cell's output")
    equations.add_argument("--components", type=positive_int, default=3, help="principal components (default: 3)")
    equations.add_argument("--inputs", default=None,
                           help="the layer feeding it, e.g. network.PMC_in: its leading components become terms")
    equations.add_argument("--degree", type=positive_int, default=2, help="polynomial library degree (default: 2)")
    equations.add_argument("--threshold", type=float, default=0.05,
                           help="smallest coefficient kept, in PC1 standard deviations per step (per s with "
                                "--continuous; default: 0.05)")
    equations.add_argument("--continuous", action="store_true",
                           help="fit dPC/dt (1/s) instead of the map from one policy step to the next")
    equations.add_argument("--horizon", type=positive_int, default=10,
                           help="policy steps of the held-out simulation (default: 10)")
    equations.add_argument("--held-out", type=float, default=0.25, help="fraction of episodes held out (default: 0.25)")
    synergy = analysis("synergies", "muscle synergies (NMF of the muscle activations): VAF per count, the count for "
                                    "90%% and the synergies")
    synergy.add_argument("--max-synergies", type=positive_int, default=None,
                         help="fit 1 .. this many synergies (default: until the VAF reaches the threshold)")
    synergy.add_argument("--threshold", type=float, default=0.9, help="the VAF to reach (default: 0.9)")
    synergy.add_argument("--variable", default="task_muscle_activation",
                         help="the recorded activations (default: task_muscle_activation)")
    muscles = analysis("muscles-or-movements", "ridge R^2 of muscle and of joint variables per layer; with --run, "
                                               "beside the random-weights control's")
    muscles.add_argument("--run", default=None, help="the recorded run: its network with random weights replays the "
                                                     "recording as the control")
    muscles.add_argument("--checkpoint", default=None,
                              help="the recorded checkpoint (default: the cycle the recording was made from)")
    muscles.add_argument("--layers", nargs="+", help="layer names (default: all)")
    muscles.add_argument("--muscles", nargs="+", default=["task_muscle_force", "task_muscle_activation"],
                         help="muscle variables (default: task_muscle_force task_muscle_activation)")
    muscles.add_argument("--movements", nargs="+", default=["task_joint_angles", "task_joint_velocities"],
                         help="kinematic variables (default: task_joint_angles task_joint_velocities)")
    muscles.add_argument("--folds", type=at_least_two, default=5,
                         help="cross-validation folds, split by episode (default: 5)")
    ablate = analyses.add_parser("ablate", help="task outcomes of a run with areas, modalities, units or actions "
                                                   "silenced")
    ablate.add_argument("run_dir", help="the run whose network is lesioned (its files are not changed)")
    ablate.add_argument("--lesion", nargs="*", default=[], metavar="AREA", help="dense layers or areas to silence")
    ablate.add_argument("--silence", nargs="*", default=[], metavar="MODALITY", help="input modalities to silence")
    ablate.add_argument("--fraction", nargs="*", default=[], metavar="AREA:F",
                        help="silence a random fraction F of an area's units, e.g. network.M1:0.5")
    ablate.add_argument("--action", nargs="*", default=[], metavar="I",
                        help="action components to silence, each on its own (on a muscle hand: muscle I's "
                             "excitation held at 0; a muscle's name, e.g. FPL_r, names it too)")
    ablate.add_argument("--episodes", type=episode_count, default=256,
                        help="episodes per condition, from the same starts, the intact network included (default: 256)")
    ablate.add_argument("--checkpoint", default="best", help="best, latest or a cycle number (default: best)")
    ablate.add_argument("--out", default=None,
                        help="PNG and NetCDF; never overwritten (default: RUN_DIR/ablation.png, else the next free "
                             "ablation-N.png)")
    add_env_option(ablate)
    ablate.set_defaults(handler=command_ablate)


def command_decode(args: argparse.Namespace) -> int:
    from angora_jax.analysis import decode, plot_decoding

    return _analyze(args, lambda data: decode(data, args.layers, args.variables, args.folds, lags=args.lags),
                    plot_decoding, decoding_lines, stem="decoding")


def decoding_lines(result: Any) -> Iterator[str]:
    """One line per layer (and lag) of a `decode` result: each variable's R^2 and its noise baseline; a variable that
    is constant over the steps decoded (at that lag: e.g. a success that no episode reaches 16 steps on) says so
    rather than printing "nan"."""
    for lag in (result["lag"].values if "lag" in result.dims else [None]):
        at = result if lag is None else result.sel(lag=lag)
        for layer in result["layer"].values:
            cells = []
            for v in result["variable"].values:
                r2 = at["r2"].sel(layer=layer, variable=v).item()
                cells.append(f"{v} - (constant over the steps decoded: nothing to decode)" if np.isnan(r2) else
                             f"{v} {r2:.2f} (noise {at['baseline'].sel(layer=layer, variable=v).item():.2f})")
            yield ("" if lag is None else f"lag {lag}: ") + f"{layer}: " + ", ".join(cells)


def _peaks_at_the_edge(result: Any) -> str | None:
    """A note naming the layer pairs whose peak lag is the window's last (the largest lag asked for): the largest
    |correlation| may lie beyond it, so that lag is a bound, not a peak. None when no pair's is."""
    edge = float(np.abs(result["lag"].values).max())
    peaks = result["peak_lag"]
    pairs = [f"{a} -> {b}" for a in peaks["layer"].values for b in peaks["other"].values
             if a != b and np.isfinite(lag := peaks.sel(layer=a, other=b).item()) and abs(lag) >= edge * (1 - 1e-9)]
    if not pairs:
        return None
    more = f" and {len(pairs) - 6} more" if len(pairs) > 6 else ""
    return (f"At the window's edge (+-{edge:.3g} s, --max-lag): {', '.join(pairs[:6])}{more}. Their correlation "
            "still grows there, so the peak may lie beyond it: give a larger --max-lag.")


def _table(array: Any, digits: int) -> str:
    """A 2-D result as a table with every row and column (pandas' own printing hides those past the terminal's
    width behind "...")."""
    return array.to_pandas().round(digits).to_string()


def read_run_config(run_dir: str | Path) -> Config:
    """`angora_jax.experiment.run_dir.read_run_config`, imported when first called (a test hands an analysis a run
    of its own by replacing this)."""
    from angora_jax.experiment.run_dir import read_run_config

    return read_run_config(run_dir)


def load_agent(run_dir: str | Path, checkpoint: str | int, env_overrides: Sequence[str]) -> Agent:
    """`angora_jax.load_agent`, imported when first called (a test hands an analysis an agent of its own by
    replacing this)."""
    from angora_jax.experiment.agent import load_agent

    return load_agent(run_dir, checkpoint, env_overrides)


def _recorded_agent(args: argparse.Namespace, data: Any, env_options: Sequence[str] = ()) -> Agent:
    """The agent of `--run` at the checkpoint the recording `data` was made from (its `cycle`), unless --checkpoint
    names one; ValueError when that holds another cycle than the recording's: fixed points, controls and filters of
    other weights than those that made the activity would be read as if they were the same."""
    recorded = data.attrs.get("cycle")
    which = checkpoint_of(args.checkpoint) if args.checkpoint else "best" if recorded is None else int(recorded)
    task = read_run_config(args.run).env.task
    if data.attrs.get("task", task) != task:
        raise ValueError(f"The recording is of {data.attrs['task']}, and {args.run} was trained on {task}: give "
                         "--run the run it was recorded from.")
    try:
        agent = load_agent(args.run, which, env_options)
    except FileNotFoundError as error:
        if args.checkpoint or recorded is None:
            raise
        raise ValueError(f"The recording was made from the network at cycle {int(recorded)}, and {args.run} keeps no "
                         f"checkpoint of that cycle ({error}): give --run the run it was recorded from, or "
                         "--checkpoint to read another of its checkpoints on purpose.") from None
    if recorded is not None and agent.cycle != int(recorded):
        raise ValueError(f"The recording was made from cycle {int(recorded)}, and --checkpoint {which} of {args.run} "
                         f"is cycle {agent.cycle}: give --checkpoint {int(recorded)}, or leave it out.")
    return agent


def command_analysis(args: argparse.Namespace) -> int:
    """similarity, dynamics, timescales, crosscorrelation, tuning, sindy, synergies and muscles-or-movements of a
    recording."""
    from angora_jax import analysis

    fixed = {}

    def compute(data):
        if args.analysis == "similarity":
            return analysis.similarity(data, args.condition, args.layers, args.variables, args.bins, args.feature)
        if args.analysis == "timescales":
            return analysis.timescales(data, args.layers, args.max_lag)
        if args.analysis == "crosscorrelation":
            return analysis.cross_correlation(data, args.layers, args.max_lag)
        if args.analysis == "tuning":
            return analysis.tuning_curves(data, args.layer, args.variable, args.bins, args.feature)
        if args.analysis == "visual":
            if "input_vision" not in data:
                if data.attrs.get("camera_images", 1) == 0:  # recordings older than the attribute say nothing
                    raise ValueError(f"The recording's task ({data.attrs.get('task', 'unknown')}) sees through no "
                                     "camera: the visual analysis is for agents that see pixels (e.g. a run of "
                                     "shadow_reach_pixels), recorded with angora-jax record RUN_DIR --images.")
                raise ValueError("The recording kept no camera images: record it with angora-jax record RUN_DIR "
                                 "--images.")
            cameras = data["input_vision"].sizes["camera"]
            if not 0 <= args.camera < cameras:
                raise ValueError(f"--camera must be in [0, {cameras}): the recording has {counted(cameras, 'camera')}.")
            images = data["input_vision"].values[0, : args.frames, args.camera]
            agent = _recorded_agent(args, data, args.env_option)
            return analysis.visual_analysis(agent, images, args.units, args.steps)
        if args.analysis == "synergies":
            return analysis.synergies(data, args.max_synergies, args.threshold, args.variable)
        if args.analysis == "muscles-or-movements":
            control = None
            if args.run:
                control = analysis.replay_activity(analysis.with_random_weights(_recorded_agent(args, data)), data)
            return analysis.muscles_or_movements(data, control, args.layers, args.muscles, args.movements,
                                                 args.folds)
        if args.analysis == "sindy":
            return analysis.sindy(data, args.layer, args.components, args.inputs, not args.continuous, args.degree,
                                  args.threshold, args.horizon, args.held_out)
        if (args.run is None) != (args.recurrent is None) or (args.inputs is not None and args.run is None):
            raise ValueError("Fixed points need --run and --recurrent together, and --inputs only with them (not "
                             "needed for a recurrent area of a brain-area graph: its inputs come from the recording).")
        if args.run:
            fixed.update(analysis.agent_fixed_points(_recorded_agent(args, data), data, args.recurrent, args.inputs))
        return analysis.principal_components(data, args.layers, args.components)

    def plot(result, path):
        if args.analysis == "dynamics":
            analysis.plot_dynamics(result, path, fixed or None)
        else:
            {"similarity": analysis.plot_similarity, "timescales": analysis.plot_timescales,
             "crosscorrelation": analysis.plot_cross_correlation, "visual": analysis.plot_visual,
             "tuning": analysis.plot_tuning, "sindy": analysis.plot_sindy, "synergies": analysis.plot_synergies,
             "muscles-or-movements": analysis.plot_muscles_or_movements}[args.analysis](result, path)

    def summary(result):
        if args.analysis == "similarity":
            yield f"Layer x layer RDM similarity (Spearman):\n{_table(result['layer_similarity'], 2)}"
            if "model_similarity" in result:
                yield f"Layer x variable (Spearman):\n{_table(result['model_similarity'], 2)}"
        elif args.analysis == "crosscorrelation":
            yield f"Lag of the peak |correlation| (s; > 0: the row leads):\n{_table(result['peak_lag'], 3)}"
            if edge := _peaks_at_the_edge(result):
                yield edge
        elif args.analysis == "timescales":
            yield from (f"{layer}: {_timescale_said(result, layer)}" for layer in result["layer"].values)
        elif args.analysis == "visual":
            units = len(result["unit"])
            driven = agreeing(units, "unit 0", f"units 0-{units - 1}")
            yield from (f"{layer}: preferred stimuli drive {driven} to " + ", ".join(
                f"{a:.3g}" for a in result["preferred_activation"].sel(layer=layer).values)
                for layer in result["layer"].values)
        elif args.analysis == "tuning":
            strength = result["strength"].values
            yield f"eta^2 of {args.variable} per unit: median {np.median(strength):.2f}, max {strength.max():.2f}"
        elif args.analysis == "synergies":
            yield "VAF by count (shuffled control): " + ", ".join(
                f"{k} {v:.3f} ({c:.3f})" for k, v, c in zip(result["count"].values, result["vaf"].values,
                                                         result["vaf_shuffled"].values, strict=True))
            count = result.attrs["count"]
            yield (f"{counted(count, 'synergy', 'synergies')} {agreeing(count, 'reaches', 'reach')} VAF "
                   f"{args.threshold}" if result.attrs["reached"] else
                   f"No count up to {result.sizes['count']} reaches VAF {args.threshold}")
        elif args.analysis == "muscles-or-movements":
            control = "" if args.run else " (no control: give --run)"
            yield from (f"{layer}: muscles R^2 {result['kind_r2'].sel(layer=layer, kind_name='muscle').item():.2f}, "
                        f"movements {result['kind_r2'].sel(layer=layer, kind_name='movement').item():.2f}; random "
                        f"weights {result['control_kind_r2'].sel(layer=layer, kind_name='muscle').item():.2f}, "
                        f"{result['control_kind_r2'].sel(layer=layer, kind_name='movement').item():.2f}{control}"
                        for layer in result["layer"].values)
        elif args.analysis == "sindy":
            yield from result["equation"].values
            error, baseline = result["simulation_error"].values[-1], result["baseline_error"].values[-1]
            yield (f"Held out ({counted(result.attrs['held_out_episodes'], 'episode')}): one-step R^2 "
                   f"{float(result['r2_one_step']):.3f} (next = current {float(result['baseline_r2_one_step']):.3f}); "
                   f"RMSE after {counted(args.horizon, 'step')} {error:.3g} (next = current {baseline:.3g}) PC1 std")
        else:
            for layer in result["layer"].values:
                count = result["dimensionality"].sel(layer=layer).item()
                yield (f"{layer}: {counted(count, 'component')} for 90% of the variance, "
                       f"participation ratio {result['participation_ratio'].sel(layer=layer).item():.1f}")
            if fixed:
                largest = np.median(np.abs(fixed["eigenvalues"][:, 0]))
                yield (f"{args.recurrent}: {int(fixed['fixed'].sum())} of {counted(len(fixed['fixed']), 'start')} "
                       f"reached a fixed point; largest |eigenvalue| median {largest:.3f}")

    return _analyze(args, compute, plot, summary)


def _analyze(args: argparse.Namespace, compute, plot, summary, stem: str | None = None) -> int:
    """Read the recording, compute, write `<out>.png` and `<out>.nc` (default: `<recording>.<stem or the
    analysis>.png`, or the next free `-2`, `-3` ... name), print the summary; usage errors exit 2."""
    import xarray as xr

    from angora_jax.analysis.decoding import nothing_ran
    from angora_jax.experiment.run_dir import CONFIG_FILE

    recording = Path(args.recording)
    if (recording / CONFIG_FILE).is_file():
        raise FileNotFoundError(f"{recording} is a run directory, not a recording: record its activity first, "
                                f"angora-jax record {recording} --out {recording.name}.nc, then analyze that file.")
    if recording.is_dir():
        raise FileNotFoundError(f"{recording} is a folder, not a recording: give the file that angora-jax record "
                                "wrote (its --out, FILE.nc).")
    if not recording.is_file():
        raise FileNotFoundError(f"No recording {recording}; make one with angora-jax record RUN_DIR --out FILE.")
    out = output_path(args.analysis, args.out, recording.parent, f"{recording.stem}.{stem or args.analysis}")
    if out is None:
        return EXIT_USAGE
    try:
        data = xr.load_dataset(recording)
    except Exception as error:  # a file that is not NetCDF, or cut short or damaged: xarray's readers raise
        # ValueError, OSError or TypeError, and scipy's reader IndexError or KeyError for a header cut short
        cause = (str(error).splitlines() or [""])[0].rstrip(".: ")
        with recording.open("rb") as file:
            netcdf = file.read(4)[:3] in (b"CDF", b"\x89HD")  # classic NetCDF's or HDF5's (NetCDF-4's) first bytes
        fix = ("It starts as NetCDF does, so it is likely cut short or damaged (a copy that stopped, a disk that "
               "filled while it was written): copy it again, or record again with" if netcdf else "Make one with")
        print(f"angora-jax analyze {args.analysis}: {recording} is not a recording that this machine can read (a "
              f"NetCDF file from angora-jax record): {type(error).__name__}: {cause}. {fix} angora-jax record "
              "RUN_DIR --out FILE.nc.", file=sys.stderr)
        return EXIT_USAGE
    if not {"episode", "time"} <= set(data.dims) or "alive" not in data:
        print(f"angora-jax analyze {args.analysis}: {recording} is NetCDF but not a recording (it lacks the episode "
              "and time dimensions or the alive mask of angora-jax record; an analysis's numbers, perhaps). Make "
              "one with angora-jax record RUN_DIR --out FILE.nc.", file=sys.stderr)
        return EXIT_USAGE
    if (why := nothing_ran(data)) is not None:  # named by its file here, not as "This recording"
        print(f"angora-jax analyze {args.analysis}: {recording} {why}", file=sys.stderr)
        return EXIT_USAGE
    try:
        result = compute(data)
    except ValueError as error:
        print(f"angora-jax analyze {args.analysis}: {error}", file=sys.stderr)
        return EXIT_USAGE
    write_plot_and_numbers(result, out, plot)
    for line in summary(result):
        print(line)
    print(f"Plot: {out}; numbers: {out.with_suffix('.nc')}")
    return EXIT_OK


def output_path(analysis: str, given: str | None, directory: Path, stem: str) -> Path | None:
    """Where an analysis writes its plot, with its numbers beside it (the suffix .nc). `given` (--out) unless it or
    its numbers exist: then None, after saying so on stderr. Without --out, the first of `directory/<stem>.png`,
    `<stem>-2.png`, ... that neither file takes: a second analysis of the same recording with other options keeps
    the first's results."""
    from angora_jax.experiment.run_dir import numbered_paths, unwritable_out

    if given:
        out = Path(given)
        from matplotlib.backend_bases import FigureCanvasBase

        # The plot's format comes from the suffix, and the numbers take the suffix .nc: a name ending in .nc, or in
        # no image format, failed in matplotlib after the analysis had been computed.
        if out.suffix[1:].lower() not in set(FigureCanvasBase.get_supported_filetypes()) - {"nc"}:
            print(f"angora-jax analyze {analysis}: --out names the plot, an image (.png, .pdf, .svg ...), and its "
                  f"numbers are written beside it as .nc: give e.g. {out.with_suffix('.png')}, not {out.name}.",
                  file=sys.stderr)
            return None
        if any(refused_existing(f"analyze {analysis}", path, "analyses") for path in (out, out.with_suffix(".nc"))):
            return None
        # Asked before the analysis, which may take minutes: a mistyped folder otherwise failed only after it.
        if (why := unwritable_out(out)) is not None:
            print(f"angora-jax analyze {analysis}: --out {out}: {why}; give a path in a folder you can write to.",
                  file=sys.stderr)
            return None
        return out
    return next(path for path in numbered_paths(directory, stem, ".png")
                if not path.exists() and not path.with_suffix(".nc").exists())


def write_plot_and_numbers(result, out: Path, plot) -> None:
    """`plot(result, path)` to `out` (PNG) and `result` to `out` with the suffix .nc (NetCDF), each written whole
    (`written_whole`): an interrupted analysis leaves no half file. The folders missing on the way are made, as
    record makes its --out's."""
    out.parent.mkdir(parents=True, exist_ok=True)
    with written_whole(out) as draft:
        plot(result, str(draft))
    with written_whole(out.with_suffix(".nc")) as draft:
        result.to_netcdf(draft, engine="scipy")


def action_components(agent: Agent, given: list[str]) -> list[tuple[int, str]]:
    """`--action`'s values as (index, lesion name): action indices, or on a muscle hand muscles' names too."""
    task = getattr(agent.env, "task", None)
    muscles = list(task.task_variable_labels().get("muscle_excitation", ())) if task is not None else []
    components = []
    for value in given:
        if value.isdigit():
            index = int(value)
        elif value in muscles:
            index = muscles.index(value)
        else:
            names = f" or muscle names ({', '.join(muscles)})" if muscles else ""
            raise ValueError(f"--action takes action indices{names}, got {value!r}.")
        components.append((index, f"-action {index}" + (f" ({muscles[index]})" if index < len(muscles) else "")))
    return components


def command_ablate(args: argparse.Namespace) -> int:
    from angora_jax.analysis import (
        ablation,
        lesion_area,
        lesion_fraction,
        plot_ablation,
        silence_actions,
        silence_modality,
    )

    # In the run directory an earlier ablation is kept: the next free name (ablation-2.png, ...), as evaluations do.
    out = output_path("ablate", args.out, Path(args.run_dir), "ablation")
    if out is None:
        return EXIT_USAGE
    agent = load_agent(args.run_dir, checkpoint_of(args.checkpoint), args.env_option)
    try:
        lesions = {f"-{area}": lesion_area(agent, area) for area in args.lesion}
        lesions |= {f"-{modality} input": silence_modality(agent, modality) for modality in args.silence}
        lesions |= {name: silence_actions(agent, [index]) for index, name in action_components(agent, args.action)}
        for spec in args.fraction:
            area, _, text = spec.rpartition(":")
            fraction = float(text) if text.replace(".", "", 1).isdigit() else -1.0
            if not area or not 0.0 <= fraction <= 1.0:
                raise ValueError(f"--fraction takes AREA:F with F in [0, 1], e.g. network.M1:0.5, got {spec!r}.")
            lesions[f"-{fraction:.0%} {area}"] = lesion_fraction(agent, area, fraction)
    except ValueError as error:
        print(f"angora-jax analyze ablate: {error}", file=sys.stderr)
        return EXIT_USAGE
    result = ablation(agent, lesions, args.episodes)
    best = (agent.config.checkpoint.best_metric or "").removeprefix("metric/")
    outcome = best if best in result["outcome"] else "episode_return"  # the run's own measure of success
    write_plot_and_numbers(result, out, lambda result, path: plot_ablation(result, outcome, path))
    for name in result["lesion"].values:
        print(f"{name:>24}: " + ", ".join(f"{o} {result['mean'].sel(lesion=name, outcome=o).item():.3g} +- "
                                          f"{result['sem'].sel(lesion=name, outcome=o).item():.2g}"
                                          for o in result["outcome"].values))
    print(f"Plot ({outcome}): {out}; numbers: {out.with_suffix('.nc')}")
    return EXIT_OK


def _timescale_said(result, layer: str) -> str:
    """A layer's median timescale, or why it has none (a NaN alone would leave the user guessing)."""
    median = result["timescale_median"].sel(layer=layer).item()
    if np.isfinite(median):
        return f"timescale median {median:.3g} s"
    if not np.isfinite(result["autocorrelation"].sel(layer=layer).values).any():
        return "no timescale: its units are constant over the recording"
    lags = result["lag"].values
    return (f"timescale longer than {lags[-1]:.3g} s: no unit's autocorrelation falls below 1/e within "
            f"{counted(len(lags) - 1, 'step')} (give a larger --max-lag)")

