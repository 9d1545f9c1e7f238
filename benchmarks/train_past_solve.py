"""Train a run past its solve time, then evaluate its `best` and `latest` checkpoints: issue 60's stability protocol
(train for twice the time to a training-mean CGR of 30, then set the two checkpoints side by side on held-out
episodes) as one command, the way the committed runs of benchmarks/results/cube_* were made.

Trains CONFIG with its overrides as `angora-jax train` does (`angora_jax.train`, a new run directory, one process)
and watches each cycle's record: once the run's wall clock reaches `--multiple` times its wall time to the first
cycle whose training `--metric` reached `--bar`, it stops the run as Ctrl-C does, after that cycle and with its
checkpoint. The clock is benchmarks/ihom_curve.py's (compile included, start-up before the first cycle not). A run
that never reaches the bar ends at its `ppo.num_cycles` or at `--minutes`, and is still evaluated. Then both
checkpoints run `--episodes` held-out episodes (`angora-jax evaluate RUN --checkpoint best|latest --path batched`,
files under RUN/evaluation), and a table gives, per checkpoint, the metric's mean with its standard error and
median, beside where the bar was reached, where the run stopped and the share of its peak it ended with
(`fraction_of_peak`, 5-cycle means). With `--out`, the same as JSON, with the device and versions.

    python benchmarks/train_past_solve.py shadow_ihom ppo.seed=2 ppo.num_cycles=5000 logging.run_name=ihom-seed2
    CUDA_VISIBLE_DEVICES=1 python benchmarks/train_past_solve.py shadow_ihom ppo.seed=3 ppo.num_cycles=5000 ...
    python benchmarks/ihom_curve.py seeds=runs/ihom-seed2 seeds=runs/ihom-seed3 --seeds 2 --device "NVIDIA H200"

Set `ppo.num_cycles` high enough for the multiple (the run ends there otherwise). A Ctrl-C of your own stops the run
as always and evaluates nothing; `angora-jax resume RUN` continues it.
"""

from __future__ import annotations

import datetime
import math
import os
import signal
import sys
from pathlib import Path

from common import config_parser, device, markdown_table, rolling_peak, versions, write_json
from ihom_curve import CGR, SMOOTH, first_reaching, with_clocks

import angora_jax as aj
from angora_jax.cli.errors import os_error_message
from angora_jax.experiment import ConfigError, RunDirError, TrainingInterrupted, load_config, validate
from angora_jax.experiment.config import best_metric_choices
from angora_jax.wording import did_you_mean

CHECKPOINTS = ("best", "latest")


def should_stop(rows: list[dict], metric: str, bar: float, multiple: float) -> bool:
    """Whether a run whose records so far are `rows` (with `with_clocks`' clocks) has trained `multiple` times its wall
    time to the first cycle whose `metric` reached `bar`."""
    reached = first_reaching(rows, bar, metric)
    return reached is not None and rows[-1]["wall_seconds"] >= multiple * reached["wall_seconds"]


def summary(rows: list[dict], metric: str, bar: float) -> dict:
    """Where the bar was first reached and where the run stopped (cycle, env steps, wall minutes), the multiple of the
    first that the second is, and the 5-cycle peak of the metric, its last 5-cycle mean and their ratio."""
    reached, last = first_reaching(rows, bar, metric), rows[-1]
    values = [row.get(metric, math.nan) for row in rows]
    # Cycles in which no episode ended have no value; a run stopped before any did has no peak.
    known = any(math.isfinite(value) for value in values)
    top, peak, final = rolling_peak(values, min(SMOOTH, len(values))) if known else (None, None, None)
    return {"reached_cycle": reached and reached["cycle"], "reached_env_steps": reached and reached["env_steps"],
            "reached_wall_minutes": reached and reached["wall_seconds"] / 60,
            "stopped_cycle": last["cycle"], "stopped_env_steps": last["env_steps"],
            "stopped_wall_minutes": last["wall_seconds"] / 60,
            "solve_time_multiple": last["wall_seconds"] / reached["wall_seconds"] if reached else None,
            "peak": peak, "peak_cycle": None if top is None else rows[top]["cycle"], "final": final,
            "fraction_of_peak": final / peak if peak else None}


def main(argv: list[str] | None = None) -> int:
    """Exit codes as angora-jax train's: 0 done, 2 a bad config or argument, a run directory in the way or a full
    disk (the message says which, nothing saved is changed), 128 + signal number for your own Ctrl-C (the run is
    saved; nothing is evaluated)."""
    try:
        return _train_past_solve(argv)
    except TrainingInterrupted as stop:
        print(f"train_past_solve: {stop}", file=sys.stderr)
        return 128 + stop.signum
    except (ConfigError, RunDirError) as error:
        print(f"train_past_solve: {error}", file=sys.stderr)
        return 2
    except OSError as error:
        print(f"train_past_solve: {os_error_message(error)}", file=sys.stderr)
        return 2


def _train_past_solve(argv: list[str] | None) -> int:
    parser = config_parser(__doc__)
    parser.add_argument("--metric", default=CGR, help="the training metric whose bar marks the solve (default: CGR)")
    parser.add_argument("--bar", type=float, default=30.0, help="the solve: the metric's first training mean >= bar")
    parser.add_argument("--multiple", type=float, default=2.05,
                        help="stop at this many times the wall time to the bar (default 2.05: at least 2 with the "
                             "cycle that crosses it)")
    parser.add_argument("--episodes", type=int, default=480, help="held-out episodes per checkpoint (default 480)")
    parser.add_argument("--minutes", type=float, default=None, help="a time limit for the training, as for train")
    parser.add_argument("--out", default=None, help="also write the summary as JSON to this path (a file there is "
                        "never replaced: NAME-2.json, ... instead)")
    args = parser.parse_args(argv)
    if args.multiple <= 0 or args.episodes <= 0:
        parser.error("--multiple and --episodes must be positive")

    # A misspelt metric would be found only after the whole run, which it would never stop: checked first.
    config = load_config(args.config, args.overrides)
    metrics = best_metric_choices(validate(config))
    if args.metric not in metrics:
        raise ConfigError(f"--metric {args.metric!r} is not a training metric of {config.env.task}."
                          f"{did_you_mean(args.metric, metrics)} Choose one of: {', '.join(metrics)}.")
    rows: list[dict] = []
    stopped_here = []

    def watch(record: dict) -> None:
        rows[:] = with_clocks([*rows, record])
        if not stopped_here and should_stop(rows, args.metric, args.bar, args.multiple):
            stopped_here.append(record["cycle"])
            # The run's own stop: saved after this cycle, then TrainingInterrupted.
            os.kill(os.getpid(), signal.SIGINT)

    try:
        run_dir = aj.train(config, on_cycle=watch, minutes=args.minutes).run_dir
    except TrainingInterrupted as interrupted:
        if not stopped_here:
            raise
        run_dir = interrupted.run_dir
    if not rows:
        print(f"{run_dir}: no cycle trained, nothing to evaluate.")
        return 1
    result = {"run": str(run_dir), "metric": args.metric, "bar": args.bar, "multiple": args.multiple,
              **summary(rows, args.metric, args.bar), "evaluations": {}}
    for checkpoint in CHECKPOINTS:
        evaluation = aj.evaluate(run_dir, checkpoint=checkpoint, episodes=args.episodes, path="batched")
        stats = evaluation.summary[args.metric.removeprefix("eval/")]  # the held-out episodes' own name
        result["evaluations"][checkpoint] = {"cycle": evaluation.meta["cycle"], "mean": stats["mean"],
                                             "stderr": stats["stderr"], "median": stats["median"],
                                             "json": str(evaluation.json_path)}
    print(markdown_table([{"what": "reached the bar", "cycle": result["reached_cycle"],
                           "minutes": result["reached_wall_minutes"]},
                          {"what": "stopped" + (f" ({result['fraction_of_peak']:.3f} of the peak {result['peak']:.2f})"
                                                if result["fraction_of_peak"] is not None else ""),
                           "cycle": result["stopped_cycle"], "minutes": result["stopped_wall_minutes"]},
                          *({"what": f"{name}: {args.metric} {e['mean']:.2f} +- {e['stderr']:.2f}, median "
                                     f"{e['median']:g}", "cycle": e["cycle"]}
                            for name, e in result["evaluations"].items())],
                         [("what", "", "s"), ("cycle", "cycle", "d"), ("minutes", "wall minutes", ".2f")]))
    if args.out:
        record = {"benchmark": "train_past_solve",
                  "date": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
                  "device": device(), "versions": versions(),
                  "config": {"config": args.config, "overrides": args.overrides}, "results": [result]}
        stem, suffix = os.path.splitext(args.out)
        Path(stem).parent.mkdir(parents=True, exist_ok=True)
        print(f"wrote {write_json(stem, record, (suffix or '.json',)) + (suffix or '.json')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
