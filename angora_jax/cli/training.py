"""Training verbs: `train` a new run, `resume` one, `check` that one is intact."""

from __future__ import annotations

import argparse
import math
import sys
from typing import TYPE_CHECKING

from angora_jax.cli.arguments import (
    EXIT_OK,
    EXIT_USAGE,
    add_distributed_flags,
    add_time_limit,
    bounded_int,
    checkpoint_of,
    config_with_imports,
)
from angora_jax.wording import counted

if TYPE_CHECKING:
    from angora_jax.experiment import TrainingRun

# The handlers import what they run (JAX, the trainer) inside them: the parser, which every command builds, and
# `--help` need none of it.


def add_train(commands: argparse._SubParsersAction) -> None:
    """The `train` verb: its arguments and its handler."""
    train = commands.add_parser("train", help="train a new run from a YAML config (see list-configs)")
    train.add_argument("config", help="YAML path or the name of a shipped config (e.g. cartpole; see list-configs)")
    train.add_argument("overrides", nargs="*", default=[], metavar="KEY=VALUE",  # a default: argparse names it optional
                       help="e.g. ppo.num_cycles=20 ppo.network.name=lstm")
    add_time_limit(train)
    add_distributed_flags(train)
    train.set_defaults(handler=command_train)


def add_resume(commands: argparse._SubParsersAction) -> None:
    """The `resume` verb: its arguments and its handler."""
    resume = commands.add_parser("resume", help="continue a run from its latest checkpoint (bit for bit from a full "
                                                "one, the default; --exact insists)")
    resume.add_argument("run_dir", help="the run directory to continue (runs/<name>)")
    resume.add_argument(
        "--exact", action="store_true",
        help="refuse to continue unless bit for bit: a lean latest checkpoint (checkpoint.lean), or one saved on "
             "another device count with MuJoCo Warp, otherwise continues with fresh environments")
    resume.add_argument(
        "--from", dest="start_from", default="latest", metavar="CHECKPOINT",
        help="continue from this checkpoint instead of the latest: best or a cycle number (the records, checkpoints, "
             "evaluations and videos after it are moved aside, never deleted); for a damaged or missing latest "
             "checkpoint")
    resume.add_argument(
        "--from-scratch", action="store_true",
        help="train the run again from cycle 0 with its config; the earlier metrics, checkpoints, report, videos and "
             "evaluations move to RUN_DIR/previous-N/")
    resume.add_argument(
        "--num-cycles", type=bounded_int(1, 2**31 - 1, "the cycle counter is a 32-bit integer"), default=None,
        metavar="N",
        help="train to N cycles in all instead of the run's ppo.num_cycles (recorded in its config.yaml): to train a "
             "finished run longer, or stop one sooner")
    resume.add_argument(
        "--no-stop-at", action="store_true",
        help="train on past the run's ppo.stop_at (removed from its config.yaml), to its ppo.num_cycles")
    resume.add_argument(
        "--force", action="store_true",
        help="take over the run's writer lock even when it is held on another host: only when that process is "
             "certainly gone (its job ended)")
    add_time_limit(resume)
    add_distributed_flags(resume)
    resume.set_defaults(handler=command_resume)


def add_check(commands: argparse._SubParsersAction) -> None:
    """The `check` verb: its arguments and its handler."""
    check = commands.add_parser(
        "check", help="verify a run directory (checkpoints against their manifests, metrics.jsonl, config, lock) and "
                      "say what resume would do; exit 2 when something is damaged")
    check.add_argument("run_dir", help="the run directory to check (nothing in it is changed without --restore-config)")
    check.add_argument(
        "--restore-config", action="store_true",
        help="write a damaged or missing config.yaml again from the copy saved with the newest intact checkpoint "
             "(the damaged file is kept beside it as config.yaml.damaged), or put back task and learning settings "
             "(env, ppo) edited after training (kept as config.yaml.edited)")
    check.set_defaults(handler=command_check)


def start_distributed(args: argparse.Namespace) -> None:
    from angora_jax.experiment import ConfigError

    if args.distributed:
        # JAX waits silently (5 minutes, then a C++ abort) for processes that never join: say what is waited for.
        where = args.coordinator or "the cluster's coordinator"
        of = f"process {args.process_id} of {args.num_processes}" if args.num_processes is not None else "a process"
        print(f"Joining the jax.distributed job at {where} as {of} (waiting up to {args.join_minutes:g} minutes for "
              "all of them) ...", file=sys.stderr, flush=True)
        from angora_jax.experiment.distributed import initialize

        try:
            initialize(args.coordinator, args.num_processes, args.process_id, args.local_devices,
                       join_seconds=60 * args.join_minutes, command=args.command)
        except ConfigError:  # already says what to do
            raise
        except ValueError as error:  # JAX's checks of the job's settings, before it connects to anything
            raise ConfigError(
                f"--distributed could not set up the job: {error} Outside a cluster that JAX detects (SLURM, Open "
                "MPI, Kubernetes), give --coordinator HOST:PORT, --num-processes N and --process-id I to every "
                "process (examples/multi_gpu_host.sh); under SLURM, start it with srun (examples/slurm_train.sh)."
            ) from error
    elif any(value is not None for value in (args.coordinator, args.num_processes, args.process_id,
                                             args.local_devices)) or args.join_minutes != 5.0:
        raise ConfigError("--coordinator, --num-processes, --process-id, --local-devices and --join-minutes set up a "
                          "jax.distributed job: add --distributed (or leave them out for a single process).")


def command_train(args: argparse.Namespace) -> int:
    start_distributed(args)
    config = config_with_imports(args)  # first: a mistyped name or key is told without importing the trainer
    from angora_jax.experiment.distributed import is_main_process
    from angora_jax.experiment.runner import signals_exit_while_preparing, train

    with signals_exit_while_preparing():
        run = train(config, minutes=args.minutes)
    if is_main_process():
        print_finished(run)
    return EXIT_OK


def command_resume(args: argparse.Namespace) -> int:
    from angora_jax.experiment.distributed import is_main_process
    from angora_jax.experiment.runner import resume, signals_exit_while_preparing

    start_distributed(args)
    with signals_exit_while_preparing():
        run = resume(args.run_dir, minutes=args.minutes, exact=args.exact, start_from=checkpoint_of(args.start_from),
                     from_scratch=args.from_scratch, force=args.force, num_cycles=args.num_cycles,
                     no_stop_at=args.no_stop_at)
    if is_main_process():
        print_finished(run)
    return EXIT_OK


def command_check(args: argparse.Namespace) -> int:
    from angora_jax.experiment.run_check import check_run, restore_config

    if args.restore_config:
        print(restore_config(args.run_dir))
    found = check_run(args.run_dir)
    print(f"{args.run_dir}:\n" + found.format())
    return EXIT_USAGE if found.problems else EXIT_OK


def print_finished(run: TrainingRun) -> None:
    from angora_jax.experiment.monitor import read_metrics
    from angora_jax.experiment.run_dir import read_run_config

    cycle = int(run.state.cycle)
    print(f"Run {run.run_dir}: {counted(cycle, 'cycle')} done ({len(run.history)} in this session).")
    if run.stopped_at is not None:
        print(f"Stopped early at cycle {cycle}, as ppo.stop_at asks: {run.stopped_at}. To train on past it: "
              f"angora-jax resume {run.run_dir} --no-stop-at")
    if not run.finished:
        print(f"Stopped at the time limit (--minutes) with a checkpoint of cycle {cycle}; continue with: "
              f"angora-jax resume {run.run_dir}")
    elif not run.history and run.stopped_at is None:
        print(f"It was already complete; to train it longer: angora-jax resume {run.run_dir} --num-cycles N")
    records = read_metrics(run.run_dir)
    # The task's own measure too (the best checkpoint's): where a step costs reward, longer and better episodes can
    # score a lower return, and the first cycle's episodes start part-way through (ppo/cycle.py, the episode clocks).
    shown = read_run_config(run.run_dir).checkpoint.best_metric
    for name in dict.fromkeys(["episode_return", shown]):
        values = [r[name] for r in records if isinstance(r.get(name), float | int) and math.isfinite(r[name])]
        if len(values) >= 2:
            tenth = max(1, len(values) // 10)
            first, last = sum(values[:tenth]) / tenth, sum(values[-tenth:]) / tenth
            if name == "episode_return":
                print(f"Episode return: {first:.1f} in the first tenth of cycles, {last:.1f} in the last tenth.")
            else:
                print(f"{name}: {first:.4g} in the first tenth of cycles, {last:.4g} in the last tenth.")
    report = run.run_dir / "report" / "index.html"
    if report.exists():
        print(f"Report: {report}")
    print(f"Next: angora-jax evaluate {run.run_dir}   |   from angora_jax import load_agent")
