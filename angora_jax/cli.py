"""The `angora-jax` command: train, resume, evaluate and compare runs.

angora-jax train cartpole                       train configs/cartpole.yaml into runs/<name>/
angora-jax train cartpole ppo.network.name=lstm logging.run_name=lstm
angora-jax resume runs/lstm                     continue from the latest checkpoint, exactly
angora-jax check runs/lstm                      is the run intact (checkpoints, metrics), what would resume do
angora-jax evaluate runs/lstm                   episode statistics of the best checkpoint (CPU path), JSON + PNG
angora-jax render runs/lstm --out lstm.mp4      a video of an episode (MuJoCo tasks)
angora-jax export runs/lstm --out lstm.msgpack  the policy in one file, for aj.load_policy without the run
angora-jax report runs/lstm runs/other          PNG curves + index.html comparing runs
angora-jax monitor runs/lstm runs/other         the same page while runs train, served on http://127.0.0.1:8000
angora-jax list-configs                         the shipped configs (train one by name from any directory)
angora-jax doctor                               versions, devices, physics choice, rendering: what to install
angora-jax record runs/lstm --out act.nc        every layer's activity with the task variables (xarray, NetCDF)
angora-jax analyze decode act.nc                ridge R^2 of each variable from each layer, against noise
angora-jax analyze similarity act.nc --condition metric_goal_distance    RDMs per layer (RSA), compared
angora-jax analyze dynamics act.nc --run runs/cortical --recurrent network.PMC
                                                PCA per layer; fixed points of a recurrent area (--inputs
                                                network.PMC_in: the layer feeding a cell outside a graph)
angora-jax analyze timescales act.nc             activity autocorrelation and timescale per layer
angora-jax analyze crosscorrelation act.nc       which layer's leading component leads which, over lags
angora-jax analyze decode act.nc --lags 0 4 8    decode each variable k steps after the activity
angora-jax analyze tuning act.nc --layer network.SSC_2 --variable metric_goal_distance
angora-jax analyze sindy act.nc --layer network.PMC.1 --inputs network.PMC_in
                                                equations of a layer's dynamics in its leading components
angora-jax analyze ablate runs/lstm --lesion network.SSC_2 --silence goal    task outcomes under lesions
angora-jax analyze visual act.nc --run runs/pixels   a pixel agent's visual area: filters, saliency, preferred stimuli
angora-jax pretrain-vision --out encoder.msgpack    a visual encoder that sees the cube's pose, from renders
"""

from __future__ import annotations

import argparse
import errno
import math
import sys
import time
from pathlib import Path

import jax
import numpy as np
import yaml

from angora_jax.envs import list_tasks, make
from angora_jax.envs.random_rollout import batched_reset, episode_mean, make_random_rollout
from angora_jax.envs.rendering import CAMERAS, RenderError
from angora_jax.experiment import (
    ConfigError,
    RunDirError,
    TrainingInterrupted,
    TrainingRun,
    evaluation,
    list_configs,
    load_agent,
    read_metrics,
    resume,
    snapshot_cycles,
    train,
)
from angora_jax.experiment.config import load_config, to_dict, validate
from angora_jax.experiment.config_reference import reference_markdown
from angora_jax.experiment.distributed import ProcessFailed, initialize, is_main_process
from angora_jax.experiment.run_check import check_run
from angora_jax.experiment.runner import signals_exit_while_preparing
from angora_jax.nets import list_networks
from angora_jax.ppo import TrainingDivergedError, list_heads
from angora_jax.vision.estimator import ORIENTATIONS


def run_random(task: str, num_envs: int, num_steps: int, seed: int) -> dict[str, float]:
    """Roll out a random policy in `num_envs` batched environments for `num_steps` policy steps under one jit and
    print compile time, throughput and rewards. Returns the printed numbers."""
    env = make(task).sized_for(num_envs)
    rollout = jax.jit(make_random_rollout(env, num_envs, num_steps))
    reset = jax.jit(batched_reset, static_argnums=(0, 2))
    key = jax.random.key(seed)
    start = time.perf_counter()
    state = reset(env, key, num_envs)
    compiled = rollout.lower(state, key).compile()
    compile_s = time.perf_counter() - start
    start = time.perf_counter()
    state, rewards, dones, metrics = jax.block_until_ready(compiled(state, key))
    wall = time.perf_counter() - start
    steps_per_s = num_envs * num_steps / wall
    result = {
        "compile_s": compile_s,
        "env_steps_per_s": steps_per_s,
        "sim_s_per_s": steps_per_s * env.dt,
        "mean_reward": float(np.mean(rewards)),
        "episodes_ended": float(np.sum(dones)),
    }
    for name, values in metrics.items():
        result[f"episode_{name}"] = float(episode_mean(values, dones))
    print(f"{task}: random policy, {num_envs} envs x {num_steps} steps on {jax.devices()[0].platform}")
    for name, value in result.items():
        print(f"  {name:>24}: {value:,.4g}")
    return result


EXIT_OK, EXIT_FAILED, EXIT_USAGE = 0, 1, 2


def seed(text: str) -> int:
    """An argparse type: a seed, a whole number from 0 to 2**32 - 1 (what jax.random.key distinguishes)."""
    if not text.isdigit() or int(text) >= 2**32:
        raise argparse.ArgumentTypeError(f"must be a whole number from 0 to {2**32 - 1:,}, got {text[:40]!r}")
    return int(text)


def positive_int(text: str) -> int:
    """An argparse type: a whole number >= 1 (argparse then exits with code 2 and names the option)."""
    if not text.isdigit() or int(text) < 1:
        raise argparse.ArgumentTypeError(f"must be a whole number >= 1, got {text!r}")
    return int(text)


def main(argv: list[str] | None = None) -> int:
    """Run the command; exit codes: 0 done, 1 training diverged or another process of the run failed, 2 bad usage
    or config, a second writer, a damaged file or a full disk (nothing saved before is changed), 128 + signal number
    (130 Ctrl-C, 143 SIGTERM) when training was interrupted after saving a checkpoint."""
    cli = parser()
    args, extra = cli.parse_known_args(argv)
    if extra:
        if hasattr(args, "overrides") and all("=" in item and not item.startswith("-") for item in extra):
            args.overrides = [*args.overrides, *extra]  # overrides after the options: `train CFG --distributed a=1`
        else:
            cli.error(f"unrecognized arguments: {' '.join(extra)}")
    try:
        return args.handler(args)
    except (ConfigError, RunDirError, FileNotFoundError) as error:
        # The system's own FileNotFoundError names a path and an errno; ours carry their whole message.
        system = isinstance(error, FileNotFoundError) and error.errno is not None
        print(f"angora-jax {args.command}: {os_error_message(error) if system else error}", file=sys.stderr)
        return EXIT_USAGE
    except OSError as error:  # a full disk, a read-only or lost mount, permissions: the machine's, not a bug
        print(f"angora-jax {args.command}: {os_error_message(error)}", file=sys.stderr)
        return EXIT_USAGE
    except TrainingInterrupted as stop:
        print(f"angora-jax {args.command}: {stop}", file=sys.stderr)
        return 128 + stop.signum
    except (TrainingDivergedError, ProcessFailed) as error:
        print(f"angora-jax {args.command}: {error}", file=sys.stderr)
        return EXIT_FAILED


# What to do about the errors the operating system reports, by errno.
OS_ERROR_FIXES = {
    errno.ENOSPC: "free space on that disk (or move the run root to a larger one)",
    errno.EDQUOT: "free space within your disk quota (or move the run root)",
    errno.EROFS: "the file system is read-only: choose a writable place (logging.run_root, --out)",
    errno.EACCES: "you may not write or read there: choose another place or fix its permissions",
    errno.EPERM: "you may not write or read there: choose another place or fix its permissions",
    errno.ENAMETOOLONG: "shorten the path or name",
    errno.EIO: "the disk or network file system failed: check the mount, then retry",
    errno.ENOTDIR: "a part of the path is a file, not a folder: fix the path",
    errno.EISDIR: "the path is a folder: give a file",
    errno.EEXIST: "a file is in the way where a folder must be made: choose another path (logging.run_root, --out)",
    errno.ENOENT: "a folder on the way does not exist or cannot be made there: check the path",
}


def os_error_message(error: OSError) -> str:
    """An OSError as one sentence: what failed, on which file, and the fix; a run interrupted this way keeps what it
    saved before (`angora-jax check RUN_DIR`, then `resume`)."""
    where = f" ({error.filename})" if error.filename else ""
    fix = OS_ERROR_FIXES.get(error.errno, "fix the cause and retry")
    during_a_run = error.errno in (errno.ENOSPC, errno.EDQUOT, errno.EIO)
    return f"{error.strerror or error}{where}: {fix}." + (
        " A run stopped by it keeps every checkpoint saved before: `angora-jax check RUN_DIR` shows them, "
        "`angora-jax resume RUN_DIR` continues." if during_a_run else "")


def parser() -> argparse.ArgumentParser:
    top = argparse.ArgumentParser(prog="angora-jax", description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    commands = top.add_subparsers(dest="command", required=True)

    train = commands.add_parser("train", help="train a new run from a YAML config (see list-configs)")
    train.add_argument("config", help="YAML path or the name of a shipped config (e.g. cartpole; see list-configs)")
    train.add_argument("overrides", nargs="*", metavar="KEY=VALUE", help="e.g. ppo.num_cycles=20 ppo.network.name=lstm")
    add_time_limit(train)
    add_distributed_flags(train)
    train.set_defaults(handler=command_train)

    resume = commands.add_parser("resume", help="continue a run from its latest checkpoint, exactly")
    resume.add_argument("run_dir")
    resume.add_argument(
        "--exact", action="store_true",
        help="refuse to continue unless bit for bit: a lean latest checkpoint (checkpoint.lean), or one saved on "
             "another device count with MuJoCo Warp, otherwise continues with fresh environments")
    resume.add_argument(
        "--from", dest="start_from", default="latest", metavar="CHECKPOINT",
        help="continue from this checkpoint instead of the latest: best or a cycle number (the records and "
             "checkpoints after it are moved aside, never deleted); for a damaged or missing latest checkpoint")
    resume.add_argument(
        "--from-scratch", action="store_true",
        help="train the run again from cycle 0 with its config; the earlier metrics, checkpoints and report move to "
             "RUN_DIR/previous-N/")
    resume.add_argument(
        "--force", action="store_true",
        help="take over the run's writer lock even when it is held on another host: only when that process is "
             "certainly gone (its job ended)")
    add_time_limit(resume)
    add_distributed_flags(resume)
    resume.set_defaults(handler=command_resume)

    check = commands.add_parser(
        "check", help="verify a run directory (checkpoints against their manifests, metrics.jsonl, config, lock) and "
                      "say what resume would do; exit 2 when something is damaged")
    check.add_argument("run_dir")
    check.set_defaults(handler=command_check)

    evaluate = commands.add_parser(
        "evaluate", help="episode statistics of a trained policy (eager CPU path or batched); JSON + box plot"
    )
    evaluate.add_argument("run_dir")
    evaluate.add_argument("--checkpoint", default="best",
                          help="best, latest, a cycle number, or snapshots: each snapshot the run keeps in turn, "
                               "to follow its policy over training (default: best)")
    evaluate.add_argument("--episodes", "--num-envs", type=positive_int, default=480,
                          help="episodes to run (default: 480)")
    evaluate.add_argument("--seed", type=seed, default=0)
    evaluate.add_argument(
        "--stochastic", "--sample", action="store_true", help="sample actions instead of taking the mode"
    )
    evaluate.add_argument("--batch", type=positive_int, default=evaluation.DEFAULT_BATCH,
                          help="episodes run at once (default: %(default)s); results do not depend on it")
    evaluate.add_argument("--path", choices=evaluation.PATHS, default="cpu",
                          help="cpu: the eager C MuJoCo path (default); batched: all episodes at once on the "
                               "training path (MJX, the GPU when there is one)")
    evaluate.add_argument("--workers", type=positive_int, default=1,
                          help="threads stepping C MuJoCo physics (default: 1); results do not depend on it")
    add_env_option(evaluate)
    evaluate.set_defaults(handler=command_evaluate)

    render = commands.add_parser("render", help="a video of a trained policy (or random actions) on a MuJoCo task")
    render.add_argument("run_dir", nargs="?", help="the run whose policy acts; leave out with --task")
    render.add_argument("--out", required=True, help="video path: .mp4 (imageio-ffmpeg) or .gif; never overwritten")
    render.add_argument("--task", help="render this task with random actions instead of a run's policy")
    render.add_argument("--checkpoint", default="best", help="best, latest or a cycle number (default: best)")
    render.add_argument("--episodes", type=positive_int, default=1)
    render.add_argument("--camera", default="front", choices=sorted(CAMERAS), help="view of the hand (default: front)")
    render.add_argument("--width", type=positive_int, default=320)
    render.add_argument("--height", type=positive_int, default=240)
    render.add_argument("--seed", type=seed, default=0)
    render.add_argument("--stochastic", action="store_true", help="sample actions instead of taking the mode")
    render.set_defaults(handler=command_render)

    export = commands.add_parser("export", help="a trained policy in one file (aj.load_policy reads it)")
    export.add_argument("run_dir", help="the run whose policy is exported")
    export.add_argument("--out", required=True, help="the file to write (msgpack); never overwritten")
    export.add_argument("--checkpoint", default="best", help="best, latest or a cycle number (default: best)")
    export.set_defaults(handler=command_export)

    report = commands.add_parser("report", help="PNG learning curves and an HTML page comparing runs")
    report.add_argument("run_dirs", nargs="+", metavar="RUN_DIR")
    report.add_argument(
        "--out", default=None, help="default: RUN_DIR/report for one run, else report/ beside the first run"
    )
    report.set_defaults(handler=command_report)

    record = commands.add_parser("record", help="every layer's activity with inputs, actions and task variables, "
                                                "as NetCDF (angora_jax.analysis)")
    record.add_argument("run_dir")
    record.add_argument("--out", required=True, help="NetCDF file to write (never overwritten)")
    record.add_argument("--episodes", type=positive_int, default=64)
    record.add_argument("--steps", type=positive_int, default=None,
                        help="policy steps (default: until every episode has ended, at most the episode length)")
    record.add_argument("--checkpoint", default="best", help="best, latest or a cycle number (default: best)")
    record.add_argument("--seed", type=seed, default=0)
    add_env_option(record)
    record.add_argument("--images", action="store_true", help="keep the camera images of a task that sees through "
                        "cameras (large; needed to replay the recording through another network)")
    record.set_defaults(handler=command_record)

    analyze = commands.add_parser("analyze", help="analyses of a recording (see angora-jax record)")
    analyses = analyze.add_subparsers(dest="analysis", required=True)
    decoding = analyses.add_parser("decode", help="ridge R^2 of each variable from each layer vs a noise baseline")
    decoding.add_argument("recording", help="a NetCDF file from angora-jax record")
    decoding.add_argument("--layers", nargs="*", help="layer names (default: all)")
    decoding.add_argument("--variables", nargs="*", help="variables (default: every input_*, task_* and metric_*)")
    decoding.add_argument("--folds", type=positive_int, default=5)
    decoding.add_argument("--lags", nargs="*", type=int, default=None,
                          help="policy steps k: decode the variable k steps after the activity (k < 0: before), "
                               "e.g. --lags -4 0 4 8 16")
    decoding.add_argument("--out", default=None, help="heat map PNG (default: beside the recording)")
    decoding.set_defaults(handler=command_decode)

    def analysis(name: str, help: str) -> argparse.ArgumentParser:
        parser = analyses.add_parser(name, help=help)
        parser.add_argument("recording", help="a NetCDF file from angora-jax record")
        parser.add_argument("--out", default=None, help=f"PNG (default: beside the recording, *.{name}.png)")
        parser.set_defaults(handler=command_analysis)
        return parser

    similar = analysis("similarity", "representational similarity (RSA): RDMs per layer over bins of a variable")
    similar.add_argument("--condition", required=True, help="variable whose quantile bins are the conditions")
    similar.add_argument("--feature", type=int, default=None, help="component of a vector condition variable")
    similar.add_argument("--bins", type=positive_int, default=8)
    similar.add_argument("--layers", nargs="*", help="layer names (default: all)")
    similar.add_argument("--variables", nargs="*", default=[], help="variables to compare with as model RDMs")
    dynamics = analysis("dynamics", "PCA per layer; with --run, fixed points of a recurrent layer")
    dynamics.add_argument("--layers", nargs="*", help="layer names (default: all)")
    dynamics.add_argument("--components", type=positive_int, default=10)
    dynamics.add_argument("--run", default=None, help="the recorded run (for fixed points)")
    dynamics.add_argument("--checkpoint", default="best", help="the recorded checkpoint (default: best)")
    dynamics.add_argument("--recurrent", default=None, help="recurrent layer, e.g. network.PMC")
    dynamics.add_argument("--inputs", nargs="+", default=None,
                          help="the recorded layer(s) feeding it, e.g. network.PMC_in (default, for an area of a "
                               "brain-area graph: its inputs as the graph lists them)")
    scales = analysis("timescales", "activity autocorrelation and intrinsic timescale per layer")
    scales.add_argument("--layers", nargs="*", help="layer names (default: all)")
    scales.add_argument("--max-lag", type=positive_int, default=20, help="policy steps (default: 20)")
    crosscorrelation = analysis("crosscorrelation", "correlation of layers' leading components over lags")
    crosscorrelation.add_argument("--layers", nargs="*", help="layer names (default: all)")
    crosscorrelation.add_argument("--max-lag", type=positive_int, default=20, help="policy steps (default: 20)")
    seeing = analysis("visual", "inside the visual area: filters, feature maps, saliency, preferred stimuli")
    seeing.add_argument("--run", required=True, help="the recorded run (one that sees camera images)")
    seeing.add_argument("--checkpoint", default="best", help="the recorded checkpoint (default: best)")
    seeing.add_argument("--frames", type=positive_int, default=4, help="frames of the first episode (default: 4)")
    seeing.add_argument("--camera", type=int, default=0, help="which camera's frames (default: 0, the first)")
    seeing.add_argument("--units", type=positive_int, default=4, help="units per layer to show (default: 4)")
    seeing.add_argument("--steps", type=positive_int, default=256, help="steps of activation maximization")
    add_env_option(seeing)
    tuning = analysis("tuning", "unit responses as functions of a task variable")
    tuning.add_argument("--layer", required=True)
    tuning.add_argument("--variable", required=True)
    tuning.add_argument("--feature", type=int, default=None, help="component of a vector variable")
    tuning.add_argument("--bins", type=positive_int, default=10)
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
    ablate = analyses.add_parser("ablate", help="task outcomes of a run with areas, modalities or units silenced")
    ablate.add_argument("run_dir")
    ablate.add_argument("--lesion", nargs="*", default=[], metavar="AREA", help="dense layers or areas to silence")
    ablate.add_argument("--silence", nargs="*", default=[], metavar="MODALITY", help="input modalities to silence")
    ablate.add_argument("--fraction", nargs="*", default=[], metavar="AREA:F",
                        help="silence a random fraction F of an area's units, e.g. network.M1:0.5")
    ablate.add_argument("--episodes", type=positive_int, default=256)
    ablate.add_argument("--checkpoint", default="best", help="best, latest or a cycle number (default: best)")
    ablate.add_argument("--out", default=None, help="PNG and NetCDF (default: RUN_DIR/ablation.png)")
    ablate.set_defaults(handler=command_ablate)

    monitor = commands.add_parser("monitor", help="the HTML report of runs while they train, regenerated and served")
    monitor.add_argument("run_dirs", nargs="+", metavar="RUN_DIR")
    monitor.add_argument("--out", default=None, help="where the page is written (default: as for report)")
    monitor.add_argument("--every", type=positive_float, default=30.0, help="seconds between updates (default: 30)")
    monitor.add_argument("--port", type=int, default=8000, help="HTTP port (default: 8000; 0: any free port)")
    monitor.add_argument("--host", default="127.0.0.1",
                         help="address to serve on (default: this machine only; 0.0.0.0 for the network)")
    monitor.add_argument("--no-serve", action="store_true", help="only rewrite the page on disk (open it yourself)")
    monitor.set_defaults(handler=command_monitor)

    vision = commands.add_parser("pretrain-vision", help="render random hand and cube poses and train a visual "
                                                         "encoder to see the cube's pose (angora_jax.vision)")
    vision.add_argument("--out", required=True, help="file for the trained encoder (a component; the whole pose "
                                                     "network goes beside it, suffix .pose.msgpack; never overwritten)")
    vision.add_argument("--samples", type=positive_int, default=20000, help="renders (default: 20000)")
    vision.add_argument("--size", type=positive_int, default=64, help="image width and height in pixels")
    vision.add_argument("--cameras", nargs="+", default=["front", "side", "top"], choices=sorted(CAMERAS))
    vision.add_argument("--renderer", default="cpu", choices=["cpu", "warp"],
                        help="cpu: mujoco.Renderer (OpenGL); warp: MuJoCo Warp's batched ray tracer (GPU)")
    vision.add_argument("--encoder", default="cornet_z", help="cornet_z or impala")
    vision.add_argument("--widths", type=positive_int, nargs="+", default=None, help="channels per stage")
    vision.add_argument("--features", type=positive_int, default=256)
    vision.add_argument("--steps", type=positive_int, default=5000, help="Adam steps (default: 5000)")
    vision.add_argument("--batch", type=positive_int, default=64)
    vision.add_argument("--orientation", default="6d", choices=list(ORIENTATIONS),
                        help="how the pose head outputs the cube's orientation (default: 6d, continuous)")
    vision.add_argument("--seed", type=seed, default=0)
    vision.set_defaults(handler=command_pretrain_vision)

    config = commands.add_parser("config", help="show the config a run would use, every key resolved")
    config_commands = config.add_subparsers(dest="config_command", required=True)
    show = config_commands.add_parser("show", help="print the resolved config (YAML) of CONFIG with the overrides, "
                                                   "checked as train checks it, without running anything")
    show.add_argument("config", help="YAML path or the name of a shipped config (see list-configs)")
    show.add_argument("overrides", nargs="*", metavar="KEY=VALUE", help="e.g. ppo.num_envs=64")
    show.set_defaults(handler=command_config_show)
    reference = config_commands.add_parser("reference", help="print every config key with its type, default and "
                                                             "description (Markdown; docs/config.md)")
    reference.set_defaults(handler=lambda args: print(reference_markdown(), end="") or EXIT_OK)
    configs = commands.add_parser("list-configs", help="print the shipped configs and what each trains")
    configs.set_defaults(handler=command_list_configs)
    doctor = commands.add_parser("doctor", help="what this machine gives angora_jax and what to install")
    doctor.set_defaults(handler=command_doctor)

    tasks = commands.add_parser("list-tasks", help="print the registered task names")
    tasks.set_defaults(handler=lambda args: print("\n".join(list_tasks()) + "\nAny Gymnasium environment: gym:<id>, "
                                                  "simulated on the host (e.g. gym:LunarLander-v3)") or EXIT_OK)
    models = commands.add_parser("list-models", help="print the registered networks and policy heads")
    models.set_defaults(handler=command_list_models)

    run = commands.add_parser("run", help="roll out a random policy in a batch of environments (smoke test)")
    run.add_argument("--task", default="ShadowHandReach", help="task name (see list-tasks)")
    run.add_argument("--num-envs", type=positive_int, default=8)
    run.add_argument("--steps", type=positive_int, default=100, help="policy steps per environment")
    run.add_argument("--seed", type=seed, default=0)
    run.set_defaults(handler=command_run)
    return top


def positive_float(text: str) -> float:
    value = float(text)
    if not value > 0:
        raise argparse.ArgumentTypeError(f"must be > 0, got {text}")
    return value


def add_env_option(command: argparse.ArgumentParser) -> None:
    command.add_argument("--env-option", action="append", default=[], metavar="KEY=VALUE",
                         help="a task option that differs from the run's (repeatable; the network must still fit "
                              "the observations), e.g. pose_estimator=encoder.pose.msgpack for the cube")


def add_time_limit(command: argparse.ArgumentParser) -> None:
    command.add_argument(
        "--minutes", type=positive_float,
        help="stop after the first cycle that ends past this wall time (compile included), with a checkpoint; "
             "'angora-jax resume RUN_DIR' continues exactly (train in pieces shorter than a job's time limit)")


def add_distributed_flags(command: argparse.ArgumentParser) -> None:
    """--distributed and its optional settings (left out, they come from the cluster, e.g. SLURM)."""
    command.add_argument(
        "--distributed", action="store_true",
        help="join a jax.distributed job, one process per GPU (under SLURM each takes the GPU of its local rank; "
             "elsewhere give --local-devices); see examples/slurm_train.sh")
    command.add_argument("--coordinator", help="host:port of process 0 (default: from the cluster environment)")
    command.add_argument("--num-processes", type=positive_int,
                         help="processes in the job (default: from the cluster)")
    command.add_argument("--process-id", type=non_negative_int, help="this process's index (default: from the cluster)")
    command.add_argument("--local-devices", type=device_ids, metavar="IDS",
                         help="this process's GPUs on its host, e.g. 0 or 2,3 (default: from the cluster, else all)")


def non_negative_int(text: str) -> int:
    """An argparse type: a whole number >= 0."""
    if not text.isdigit():
        raise argparse.ArgumentTypeError(f"must be a whole number >= 0, got {text!r}")
    return int(text)


def device_ids(text: str) -> list[int]:
    """An argparse type: comma-separated device indices, e.g. "0" or "2,3"."""
    return [non_negative_int(part.strip()) for part in text.split(",")]


def start_distributed(args: argparse.Namespace) -> None:
    if args.distributed:
        initialize(args.coordinator, args.num_processes, args.process_id, args.local_devices)
    elif any(value is not None for value in (args.coordinator, args.num_processes, args.process_id,
                                             args.local_devices)):
        raise ConfigError("--coordinator, --num-processes, --process-id and --local-devices set up a jax.distributed "
                          "job: add --distributed (or leave them out for a single process).")


def command_train(args: argparse.Namespace) -> int:
    start_distributed(args)
    with signals_exit_while_preparing():
        run = train(args.config, args.overrides, minutes=args.minutes)
    if is_main_process():
        print_finished(run)
    return EXIT_OK


def command_resume(args: argparse.Namespace) -> int:
    start_distributed(args)
    with signals_exit_while_preparing():
        run = resume(args.run_dir, minutes=args.minutes, exact=args.exact, start_from=checkpoint_of(args.start_from),
                     from_scratch=args.from_scratch, force=args.force)
    if is_main_process():
        print_finished(run)
    return EXIT_OK


def command_check(args: argparse.Namespace) -> int:
    found = check_run(args.run_dir)
    print(f"{args.run_dir}:\n" + found.format())
    return EXIT_USAGE if found.problems else EXIT_OK


def print_finished(run: TrainingRun) -> None:
    cycle = int(run.state.cycle)
    print(f"Run {run.run_dir}: {cycle} cycles done ({len(run.history)} in this session).")
    if run.stopped_at is not None:
        print(f"Stopped early at cycle {cycle}, as ppo.stop_at asks: {run.stopped_at}.")
    if not run.finished:
        print(f"Stopped at the time limit (--minutes) with a checkpoint of cycle {cycle}; continue with: "
              f"angora-jax resume {run.run_dir}")
    returns = [r["episode_return"] for r in read_metrics(run.run_dir) if math.isfinite(r["episode_return"])]
    if len(returns) >= 2:
        tenth = max(1, len(returns) // 10)
        first, last = sum(returns[:tenth]) / tenth, sum(returns[-tenth:]) / tenth
        print(f"Episode return: {first:.1f} in the first tenth of cycles, {last:.1f} in the last tenth.")
    report = run.run_dir / "report" / "index.html"
    if report.exists():
        print(f"Report: {report}")
    print(f"Next: angora-jax evaluate {run.run_dir}   |   from angora_jax import load_agent")


def command_evaluate(args: argparse.Namespace) -> int:
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
                                     env_overrides=args.env_option)
        meta = result.meta
        actions = "sampled" if args.stochastic else "deterministic (mode)"
        threads = f", {meta['workers']} threads stepping physics" if meta["workers"] > 1 else ""
        print(f"{args.run_dir}, checkpoint of cycle {meta['cycle']}, {args.episodes} episodes on {meta['physics']} "
              f"({meta['batch']} at a time{threads}), {actions} actions, {meta['wall_seconds']:.1f} s:")
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
    from angora_jax.experiment.export import export_policy

    try:
        out = export_policy(args.run_dir, args.out, checkpoint_of(args.checkpoint))
    except FileExistsError as error:
        print(f"angora-jax export: {error}", file=sys.stderr)
        return EXIT_USAGE
    print(f"Policy: {out} (load it with angora_jax.load_policy)")
    return EXIT_OK


def report_dir(run_dirs: list[str], out: str | None) -> Path:
    """Where a report of `run_dirs` goes: `out`, else RUN_DIR/report for one run, else report/ beside the first."""
    first = Path(run_dirs[0])
    return Path(out) if out else (first / "report" if len(run_dirs) == 1 else first.parent / "report")


def command_report(args: argparse.Namespace) -> int:
    from angora_jax.experiment.report import write_report  # matplotlib only when a report is made

    print(f"Report: {write_report(args.run_dirs, report_dir(args.run_dirs, args.out))}")
    return EXIT_OK


def command_monitor(args: argparse.Namespace) -> int:
    from angora_jax.experiment.live_report import LiveReport

    out = report_dir(args.run_dirs, args.out)
    try:
        live = LiveReport(args.run_dirs, out, args.every, None if args.no_serve else args.port, args.host)
    except OSError as error:
        print(f"angora-jax monitor: cannot serve on {args.host}:{args.port} ({error}); pick another --port "
              "(0: any free one) or use --no-serve.", file=sys.stderr)
        return EXIT_USAGE
    with live:
        where = live.url or (out / "index.html").resolve().as_uri()
        print(f"Monitoring {len(args.run_dirs)} run(s): {where} (updated every {args.every:g} s; Ctrl-C stops the "
              "monitor, never the runs)", flush=True)
        try:
            live.wait()
        except KeyboardInterrupt:
            print("Monitor stopped.")
    return EXIT_OK


def checkpoint_of(text: str) -> str | int:
    """A --checkpoint argument: "best", "latest" or a cycle number."""
    return int(text) if text.isdigit() else text


def refused_existing(command: str, out: Path, what: str) -> bool:
    """True (after saying so on stderr) when `out` exists: outputs are never overwritten."""
    if out.exists():
        print(f"angora-jax {command}: {out} exists; {what} are never overwritten: give another --out.", file=sys.stderr)
    return out.exists()


def command_record(args: argparse.Namespace) -> int:
    from angora_jax.analysis import record_activity, save_activity

    out = Path(args.out)
    if refused_existing("record", out, "recordings"):
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
    print(f"Recorded {dataset.sizes['episode']} episodes x {dataset.sizes['time']} steps of {len(layers)} layers "
          f"({', '.join(layers)}): {out}")
    return EXIT_OK


def command_decode(args: argparse.Namespace) -> int:
    from angora_jax.analysis import decode, plot_decoding

    def summary(result):
        for lag in (result["lag"].values if "lag" in result.dims else [None]):
            at = result if lag is None else result.sel(lag=lag)
            for layer in result["layer"].values:
                yield ("" if lag is None else f"lag {lag}: ") + f"{layer}: " + ", ".join(
                    f"{v} {at['r2'].sel(layer=layer, variable=v).item():.2f} "
                    f"(noise {at['baseline'].sel(layer=layer, variable=v).item():.2f})"
                    for v in result["variable"].values)

    return _analyze(args, lambda data: decode(data, args.layers, args.variables, args.folds, lags=args.lags),
                    plot_decoding, summary, stem="decoding")


def command_analysis(args: argparse.Namespace) -> int:
    """similarity, dynamics, timescales, crosscorrelation, tuning and sindy of a recording."""
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
                raise ValueError("The recording kept no camera images: record it with angora-jax record RUN_DIR "
                                 "--images.")
            cameras = data["input_vision"].sizes["camera"]
            if not 0 <= args.camera < cameras:
                raise ValueError(f"--camera must be in [0, {cameras}): the recording has {cameras} cameras.")
            images = data["input_vision"].values[0, : args.frames, args.camera]
            agent = load_agent(args.run, checkpoint_of(args.checkpoint), args.env_option)
            return analysis.visual_analysis(agent, images, args.units, args.steps)
        if args.analysis == "sindy":
            return analysis.sindy(data, args.layer, args.components, args.inputs, not args.continuous, args.degree,
                                  args.threshold, args.horizon, args.held_out)
        if (args.run is None) != (args.recurrent is None) or (args.inputs is not None and args.run is None):
            raise ValueError("Fixed points need --run and --recurrent together, and --inputs only with them (not "
                             "needed for a recurrent area of a brain-area graph: its inputs come from the recording).")
        if args.run:
            checkpoint = checkpoint_of(args.checkpoint)
            fixed.update(analysis.agent_fixed_points(load_agent(args.run, checkpoint), data, args.recurrent,
                                                     args.inputs))
        return analysis.principal_components(data, args.layers, args.components)

    def plot(result, path):
        if args.analysis == "dynamics":
            analysis.plot_dynamics(result, path, fixed or None)
        else:
            {"similarity": analysis.plot_similarity, "timescales": analysis.plot_timescales,
             "crosscorrelation": analysis.plot_cross_correlation, "visual": analysis.plot_visual,
             "tuning": analysis.plot_tuning, "sindy": analysis.plot_sindy}[args.analysis](result, path)

    def summary(result):
        if args.analysis == "similarity":
            yield f"Layer x layer RDM similarity (Spearman):\n{result['layer_similarity'].to_pandas().round(2)}"
            if "model_similarity" in result:
                yield f"Layer x variable (Spearman):\n{result['model_similarity'].to_pandas().round(2)}"
        elif args.analysis == "crosscorrelation":
            yield f"Lag of the peak |correlation| (s; > 0: the row leads):\n{result['peak_lag'].to_pandas().round(3)}"
        elif args.analysis == "timescales":
            yield from (f"{layer}: timescale median {result['timescale_median'].sel(layer=layer).item():.3g} s"
                        for layer in result["layer"].values)
        elif args.analysis == "visual":
            yield from (f"{layer}: preferred stimuli drive units 0-{len(result['unit']) - 1} to " + ", ".join(
                f"{a:.3g}" for a in result["preferred_activation"].sel(layer=layer).values)
                for layer in result["layer"].values)
        elif args.analysis == "tuning":
            strength = result["strength"].values
            yield f"eta^2 of {args.variable} per unit: median {np.median(strength):.2f}, max {strength.max():.2f}"
        elif args.analysis == "sindy":
            yield from result["equation"].values
            error, baseline = result["simulation_error"].values[-1], result["baseline_error"].values[-1]
            yield (f"Held out ({result.attrs['held_out_episodes']} episodes): one-step R^2 "
                   f"{float(result['r2_one_step']):.3f} (next = current {float(result['baseline_r2_one_step']):.3f}); "
                   f"RMSE after {args.horizon} steps {error:.3g} (next = current {baseline:.3g}) PC1 std")
        else:
            yield from (f"{layer}: {result['dimensionality'].sel(layer=layer).item()} components for 90% of the "
                        f"variance, participation ratio {result['participation_ratio'].sel(layer=layer).item():.1f}"
                        for layer in result["layer"].values)
            if fixed:
                yield (f"{args.recurrent}: {int(fixed['fixed'].sum())} of {len(fixed['fixed'])} starts reached a "
                       f"fixed point; largest |eigenvalue| median {np.median(np.abs(fixed['eigenvalues'][:, 0])):.3f}")

    return _analyze(args, compute, plot, summary)


def _analyze(args: argparse.Namespace, compute, plot, summary, stem: str | None = None) -> int:
    """Read the recording, compute, write `<out>.png` and `<out>.nc` (default: `<recording>.<stem or the
    analysis>.png`), print the summary; usage errors exit 2."""
    import xarray as xr

    recording = Path(args.recording)
    if not recording.is_file():
        raise FileNotFoundError(f"No recording {recording}; make one with angora-jax record RUN_DIR --out FILE.")
    out = Path(args.out) if args.out else recording.with_suffix(f".{stem or args.analysis}.png")
    try:
        data = xr.load_dataset(recording)
    except (ValueError, OSError, TypeError) as error:  # xarray's and its readers' ways to say "not NetCDF"
        print(f"angora-jax analyze {args.analysis}: {recording} is not a recording that this machine can read (a "
              f"NetCDF file from angora-jax record): {type(error).__name__}: {str(error).splitlines()[0]}. Make one "
              "with angora-jax record RUN_DIR --out FILE.nc.", file=sys.stderr)
        return EXIT_USAGE
    try:
        result = compute(data)
    except ValueError as error:
        print(f"angora-jax analyze {args.analysis}: {error}", file=sys.stderr)
        return EXIT_USAGE
    plot(result, str(out))
    result.to_netcdf(out.with_suffix(".nc"), engine="scipy")
    for line in summary(result):
        print(line)
    print(f"Plot: {out}; numbers: {out.with_suffix('.nc')}")
    return EXIT_OK


def command_ablate(args: argparse.Namespace) -> int:
    from angora_jax.analysis import ablation, lesion_area, lesion_fraction, plot_ablation, silence_modality

    checkpoint = checkpoint_of(args.checkpoint)
    agent = load_agent(args.run_dir, checkpoint)
    try:
        lesions = {f"-{area}": lesion_area(agent, area) for area in args.lesion}
        lesions |= {f"-{modality} input": silence_modality(agent, modality) for modality in args.silence}
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
    out = Path(args.out) if args.out else Path(args.run_dir) / "ablation.png"
    best = (agent.config.checkpoint.best_metric or "").removeprefix("metric/")
    outcome = best if best in result["outcome"] else "episode_return"  # the run's own measure of success
    plot_ablation(result, outcome, str(out))
    result.to_netcdf(out.with_suffix(".nc"), engine="scipy")
    for name in result["lesion"].values:
        print(f"{name:>24}: " + ", ".join(f"{o} {result['mean'].sel(lesion=name, outcome=o).item():.3g} +- "
                                          f"{result['sem'].sel(lesion=name, outcome=o).item():.2g}"
                                          for o in result["outcome"].values))
    print(f"Plot ({outcome}): {out}; numbers: {out.with_suffix('.nc')}")
    return EXIT_OK


def command_pretrain_vision(args: argparse.Namespace) -> int:
    import json
    import os

    from angora_jax.nets.components import save_component
    from angora_jax.nets.visual import VISUAL_ENCODERS
    from angora_jax.vision import pretrain_pose_encoder, render_pose_dataset
    from angora_jax.vision.dataset import check_pose_renders
    from angora_jax.vision.pretrain import pose_network

    out = Path(args.out)
    estimator_out, numbers_out = out.with_suffix(".pose.msgpack"), out.with_suffix(".json")
    outputs = ((out, "components"), (estimator_out, "pose estimators"), (numbers_out, "numbers"))
    if any(refused_existing("pretrain-vision", file, what) for file, what in outputs):
        return EXIT_USAGE
    if numbers_out == out:
        print(f"angora-jax pretrain-vision: --out {out}: the numbers (.json) would overwrite the encoder there; give "
              "an --out ending in .msgpack.", file=sys.stderr)
        return EXIT_USAGE
    if args.encoder not in VISUAL_ENCODERS:
        print(f"angora-jax pretrain-vision: unknown encoder {args.encoder!r}; choose one of {sorted(VISUAL_ENCODERS)}.",
              file=sys.stderr)
        return EXIT_USAGE
    # The outputs are written after hours of rendering and training: their folder is checked first (the folders
    # missing under the nearest existing one are made then).
    folder = next(parent for parent in out.absolute().parents if parent.exists())
    if not folder.is_dir() or not os.access(folder, os.W_OK):
        why = "is not writable" if folder.is_dir() else "is a file"
        print(f"angora-jax pretrain-vision: --out {out}: {folder} {why}; give a file in a folder you can write to.",
              file=sys.stderr)
        return EXIT_USAGE
    options = {"features": args.features} | ({"widths": tuple(args.widths)} if args.widths else {})
    try:
        if args.samples < 2:
            raise ValueError(f"--samples must be at least 2 (a tenth, at least one, is held out to measure the "
                             f"encoder on), got {args.samples}.")
        if args.batch > args.samples:
            raise ValueError(f"--batch ({args.batch}) must be at most --samples ({args.samples}).")
        check_pose_renders(args.samples, tuple(args.cameras), args.size, args.size, args.renderer)
        pose_network(args.encoder, options, args.orientation, (len(args.cameras), args.size, args.size, 3))
    except (ValueError, ModuleNotFoundError) as error:
        print(f"angora-jax pretrain-vision: {error}", file=sys.stderr)
        return EXIT_USAGE
    start = time.perf_counter()
    try:
        dataset = render_pose_dataset(args.samples, tuple(args.cameras), args.size, args.size, seed=args.seed,
                                      renderer=args.renderer)
    except RenderError as error:
        print(f"angora-jax pretrain-vision: {error} Or render with MuJoCo Warp on a GPU: --renderer warp.",
              file=sys.stderr)
        return EXIT_USAGE
    rendered = time.perf_counter() - start
    train, test = dataset.split(0.1)
    result = pretrain_pose_encoder(train, test, args.encoder, options, args.steps, args.batch, seed=args.seed,
                                   orientation=args.orientation)
    save_component(result.params, "encoder", out)
    result.estimator.save(estimator_out)
    report = {"encoder": args.encoder, "options": options, "cameras": args.cameras, "size": args.size,
              "renderer": args.renderer, "samples": args.samples, "device": str(jax.devices()[0].device_kind),
              "render_seconds": rendered, "train_seconds": result.seconds, "steps": args.steps,
              "orientation": args.orientation, "batch": args.batch, "learning_rate": result.learning_rate,
              **result.errors,
              "loss": result.history}
    numbers_out.write_text(json.dumps(report, indent=1))
    errors = result.errors
    print(f"Rendered {len(dataset)} samples x {len(args.cameras)} cameras in {rendered:.0f} s; trained {args.steps} "
          f"steps in {result.seconds:.0f} s. Held-out ({errors['test_samples']}): position "
          f"{errors['position_mm_median']:.1f} mm median ({errors['position_mm_p90']:.1f} p90), orientation "
          f"{errors['orientation_deg_median']:.1f} deg median ({errors['orientation_deg_p90']:.1f} p90).")
    print(f"Encoder: {out} (load with network.pretrained); the whole pose network: {estimator_out} "
          f"(angora_jax.vision.PoseEstimator.load); numbers: {numbers_out}")
    return EXIT_OK


def command_config_show(args: argparse.Namespace) -> int:
    config = load_config(args.config, args.overrides)
    validate(config)
    print(f"# {args.config} {' '.join(args.overrides)}".rstrip() + ": what `angora-jax train` would use")
    print(yaml.safe_dump(to_dict(config), sort_keys=False), end="")
    return EXIT_OK


def command_list_configs(args: argparse.Namespace) -> int:
    shipped = list_configs()
    width = max(map(len, shipped))
    for name, description in shipped.items():
        print(f"{name:<{width}}  {description}")
    print("Train one with: angora-jax train NAME [key.sub=value ...]")
    return EXIT_OK


def command_doctor(args: argparse.Namespace) -> int:
    from angora_jax.experiment.doctor import diagnose

    found = diagnose()
    print(found.format())
    return EXIT_FAILED if found.problems else EXIT_OK


def command_list_models(args: argparse.Namespace) -> int:
    print("networks (ppo.network.name):", ", ".join(list_networks()))
    print("policy heads (ppo.head):", ", ".join(["auto", *list_heads()]))
    return EXIT_OK


def command_run(args: argparse.Namespace) -> int:
    try:
        run_random(args.task, args.num_envs, args.steps, args.seed)
    except ValueError as error:
        print(f"angora-jax: {error}", file=sys.stderr)
        return EXIT_USAGE
    return EXIT_OK


if __name__ == "__main__":
    sys.exit(main())
