"""Verbs that act with a trained policy: `evaluate` it, `render` a video, `export` it to one file, `record` its
layers' activity."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from angora_jax.cli.arguments import (
    EXIT_OK,
    EXIT_USAGE,
    add_env_option,
    checkpoint_of,
    episode_count,
    frame_side,
    positive_int,
    refused_existing,
    seed,
)
from angora_jax.envs.rendering import CAMERAS, RenderError
from angora_jax.experiment.evaluation_settings import DEFAULT_BATCH, PATHS
from angora_jax.wording import counted

# The handlers import what they run (JAX, the agent, runs) inside them: the parser, which every command builds, and
# `--help` need none of it.


def add_evaluate(commands: argparse._SubParsersAction) -> None:
    """The `evaluate` verb: its arguments and its handler."""
    evaluate = commands.add_parser(
        "evaluate", help="episode statistics of a trained policy (eager CPU path or batched); JSON + box plot"
    )
    evaluate.add_argument("run_dir", help="the run whose policy is evaluated")
    evaluate.add_argument("--checkpoint", default="best",
                          help="best, latest, a cycle number, or snapshots: each snapshot the run keeps in turn, "
                               "to follow its policy over training (default: best)")
    evaluate.add_argument("--episodes", "--num-envs", type=episode_count, default=480,
                          help="episodes to run, at most 1,000,000 (default: 480)")
    evaluate.add_argument("--seed", type=seed, default=0,
                          help="seed of the episodes' starts and goals (default: 0); the same seed gives the same "
                               "episodes to every checkpoint")
    evaluate.add_argument(
        "--stochastic", "--sample", action="store_true", help="sample actions instead of taking the mode"
    )
    evaluate.add_argument("--batch", type=positive_int, default=DEFAULT_BATCH,
                          help="episodes run at once (default: %(default)s); results do not depend on it")
    evaluate.add_argument("--path", choices=PATHS, default="cpu",
                          help="cpu: the eager path on the host (default): C MuJoCo for MuJoCo tasks, a task's "
                               "own JAX steps for others; batched: all episodes at once on the training path (MJX, "
                               "the GPU when there is one)")
    evaluate.add_argument("--out", default=None, metavar="FOLDER",
                          help="the folder for the evaluation's JSON and box plot (default: RUN_DIR/evaluation), "
                          "e.g. for a run on a share you may not write to; nothing in it is overwritten")
    evaluate.add_argument("--workers", type=positive_int, default=1,
                          help="threads stepping C MuJoCo physics (default: 1); results do not depend on it")
    add_env_option(evaluate)
    evaluate.set_defaults(handler=command_evaluate)


def add_render(commands: argparse._SubParsersAction) -> None:
    """The `render` verb: its arguments and its handler."""
    render = commands.add_parser("render", help="a video of a trained policy (or random actions) on a MuJoCo task")
    render.add_argument("run_dir", nargs="?", help="the run whose policy acts; leave out with --task")
    render.add_argument("--out", required=True, help="video path: .mp4 (imageio-ffmpeg) or .gif; never overwritten")
    render.add_argument("--task", help="render this task with random actions instead of a run's policy")
    render.add_argument("--checkpoint", default="best", help="best, latest or a cycle number (default: best)")
    render.add_argument("--episodes", type=episode_count, default=1,
                        help="episodes, one after another (default: 1; their frames must fit in memory)")
    render.add_argument("--camera", default="front", choices=sorted(CAMERAS), help="view of the hand (default: front)")
    render.add_argument("--width", type=frame_side, default=320,
                        help="frame width in pixels, 16 to 4,096 (default: 320)")
    render.add_argument("--height", type=frame_side, default=240,
                        help="frame height in pixels, 16 to 4,096 (default: 240)")
    render.add_argument("--seed", type=seed, default=0, help="seed of the episodes' starts and goals (default: 0)")
    render.add_argument("--stochastic", action="store_true", help="sample actions instead of taking the mode")
    render.set_defaults(handler=command_render)


def add_export(commands: argparse._SubParsersAction) -> None:
    """The `export` verb: its arguments and its handler."""
    export = commands.add_parser("export", help="a trained policy in one file (aj.load_policy reads it)")
    export.add_argument("run_dir", help="the run whose policy is exported")
    export.add_argument("--out", required=True, help="the file to write, ending in .msgpack, or a folder to write "
                                                     "RUN_NAME.msgpack in (an existing one, or a name ending in /); "
                                                     "never overwritten")
    export.add_argument("--checkpoint", default="best", help="best, latest or a cycle number (default: best)")
    export.set_defaults(handler=command_export)


def add_record(commands: argparse._SubParsersAction) -> None:
    """The `record` verb: its arguments and its handler."""
    record = commands.add_parser("record", help="every layer's activity with inputs, actions and task variables, "
                                                "as NetCDF (angora_jax.analysis)")
    record.add_argument("run_dir", help="the run whose network is recorded")
    record.add_argument("--out", required=True, help="NetCDF file to write (never overwritten)")
    record.add_argument("--episodes", type=episode_count, default=64,
                        help="episodes recorded (default: 64; the recording must fit in memory)")
    record.add_argument("--steps", type=positive_int, default=None,
                        help="policy steps (default: until every episode has ended, at most the episode length)")
    record.add_argument("--checkpoint", default="best", help="best, latest or a cycle number (default: best)")
    record.add_argument("--seed", type=seed, default=0, help="seed of the episodes' starts and goals (default: 0)")
    add_env_option(record)
    record.add_argument("--images", action="store_true", help="keep the camera images of a task that sees through "
                        "cameras (large; needed to replay the recording through another network)")
    record.set_defaults(handler=command_record)


def command_evaluate(args: argparse.Namespace) -> int:
    from angora_jax.experiment import evaluation
    from angora_jax.experiment.agent import snapshot_cycles

    if args.checkpoint == "snapshots":
        checkpoints = snapshot_cycles(args.run_dir)
        if not checkpoints:
            print(f"angora-jax evaluate: {args.run_dir} keeps no snapshots; train with checkpoint.snapshot_every=N "
                  "to keep one every N cycles.", file=sys.stderr)
            return EXIT_USAGE
    else:
        checkpoints = [checkpoint_of(args.checkpoint)]
    rows = []
    for checkpoint in checkpoints:
        result = evaluation.evaluate(args.run_dir, checkpoint, args.episodes, args.stochastic, args.seed,
                                     batch=args.batch, workers=args.workers, path=args.path,
                                     env_overrides=args.env_option, save=args.out or True)
        meta = result.meta
        if checkpoint == "best" and meta["checkpoint"] == "latest":
            print(f"{args.run_dir} keeps no best checkpoint (no best metric, or fewer than checkpoint.best_episodes "
                  "episodes ended while it trained): its latest is evaluated.", file=sys.stderr)
        actions = "sampled" if args.stochastic else "deterministic (mode)"
        threads = f", {meta['workers']} threads stepping physics" if meta["workers"] > 1 else ""
        print(f"{args.run_dir}, checkpoint of cycle {meta['cycle']}, {counted(args.episodes, 'episode')} on "
              f"{meta['physics']} ({meta['batch']} at a time{threads}), {actions} actions, "
              f"{meta['wall_seconds']:.1f} s:")
        print(f"  {'':>22} {'mean':>9} {'median':>9} {'mode':>9} {'stderr':>9}")
        for name, stats in result.summary.items():
            print(f"  {name:>22} " + " ".join(f"{stats[k]:9.4g}" for k in ("mean", "median", "mode", "stderr")))
        print(f"Written: {result.json_path} and {result.plot_path}")
        rows.append((meta["cycle"], result.summary["episode_return"], result.summary["episode_length"]))
    if len(rows) > 1:
        print(f"Over the snapshots:\n  {'cycle':>7} {'return':>11} {'stderr':>9} {'length':>9}")
        for cycle, returns, lengths in rows:
            print(f"  {cycle:7d} {returns['mean']:11.4g} {returns['stderr']:9.3g} {lengths['mean']:9.4g}")
    return EXIT_OK


def command_render(args: argparse.Namespace) -> int:
    from angora_jax.experiment.video import render_video

    checkpoint = checkpoint_of(args.checkpoint)
    options = dict(checkpoint=checkpoint, episodes=args.episodes, camera=args.camera, width=args.width,
                   height=args.height, seed=args.seed, stochastic=args.stochastic)
    try:
        out = render_video(args.out, args.run_dir, task=args.task, **options)
    except (RenderError, FileExistsError, ValueError) as error:
        print(f"angora-jax render: {error}", file=sys.stderr)
        return EXIT_USAGE
    print(f"Video: {out}")
    return EXIT_OK


def command_export(args: argparse.Namespace) -> int:
    from angora_jax.experiment.agent import read_checkpoint
    from angora_jax.experiment.export import export_policy, policy_path

    asked = checkpoint_of(args.checkpoint)
    try:  # before the run is read: a name that is no .msgpack file, refused with the name to give
        out = policy_path(args.out, args.run_dir)
    except ValueError as error:
        print(f"angora-jax export: {error}", file=sys.stderr)
        return EXIT_USAGE
    try:
        out = export_policy(args.run_dir, out, asked)
    except FileExistsError as error:
        print(f"angora-jax export: {error}", file=sys.stderr)
        return EXIT_USAGE
    used = read_checkpoint(args.run_dir, asked)
    instead = (" (the run keeps no best checkpoint: its checkpoint.best_metric is null, or too few episodes had ended "
               "when it saved)") if used != asked else ""
    print(f"Policy of the {used} checkpoint{instead}: {out} (load it with angora_jax.load_policy)")
    return EXIT_OK



def command_record(args: argparse.Namespace) -> int:
    from angora_jax.analysis import record_activity, save_activity
    from angora_jax.experiment import ConfigError, RunDirError
    from angora_jax.experiment.run_dir import unwritable_out

    out = Path(args.out)
    if out.suffix.lower() != ".nc":
        print(f"angora-jax record: a recording is a NetCDF file: give --out a name ending in .nc (e.g. "
              f"{out.with_suffix('.nc')}), not {out.name}.", file=sys.stderr)
        return EXIT_USAGE
    if refused_existing("record", out, "recordings"):
        return EXIT_USAGE
    if (why := unwritable_out(out)) is not None:  # before the episodes, which may take minutes
        print(f"angora-jax record: --out {out}: {why}; give a path in a folder you can write to.", file=sys.stderr)
        return EXIT_USAGE
    checkpoint = checkpoint_of(args.checkpoint)
    try:
        dataset = record_activity(args.run_dir, args.episodes, args.steps, args.seed, checkpoint, args.images,
                                  args.env_option)
    except ValueError as error:
        if isinstance(error, ConfigError | RunDirError):
            raise
        print(f"angora-jax record: {error}", file=sys.stderr)
        return EXIT_USAGE
    save_activity(dataset, out)
    layers = [n.removeprefix("activity_") for n in dataset.data_vars if n.startswith("activity_")]
    print(f"Recorded {counted(dataset.sizes['episode'], 'episode')} x {counted(dataset.sizes['time'], 'step')} of "
          f"{counted(len(layers), 'layer')} ({', '.join(layers)}) of the network at cycle {dataset.attrs['cycle']}: "
          f"{out}")
    return EXIT_OK

