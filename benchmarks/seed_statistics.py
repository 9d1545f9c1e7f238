"""Seed statistics of trained runs: when each run's training mean of a task metric first reached a bar, where its
curve peaked and how long it trained past the peak, and its held-out evaluations (`angora-jax evaluate` JSONs in
RUN_DIR/evaluation), per run and over each group of seeds (runs whose configs differ only in `ppo.seed`, as
`angora-jax report` groups them).

Minutes are wall minutes from each session's start (sessions.jsonl, so a compile counts), added up over the sessions
of a resumed run. The peak is that of the mean over `--smooth` consecutive cycles; "past the peak" is how long the
run trained after it and how far that mean fell by the end.

    python benchmarks/seed_statistics.py runs/seed1 runs/seed2 runs/seed3 --metric metric/success --bar 0.9 \\
        --out benchmarks/results/myohand/myohand_pose_seeds_h200.json
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
from pathlib import Path

import numpy as np
from common import markdown_table, rolling_peak, write_results

from angora_jax.experiment.report import RunRecord, load_run, seed_groups
from angora_jax.experiment.run_dir import read_sessions


def session_minutes(rows: list[dict], sessions: list[dict]) -> np.ndarray:
    """Wall minutes at each row since the run's first session started, compile included, the time between sessions
    left out: a row belongs to the last session that started before it was written."""
    starts = sorted(s["time"] for s in sessions) or [rows[0]["time"] - rows[0].get("seconds", 0.0)]
    owner = np.searchsorted(starts, [row["time"] for row in rows], side="right") - 1
    owner = np.maximum(owner, 0)
    elapsed = np.array([row["time"] for row in rows]) - np.array(starts)[owner]
    lengths = [elapsed[owner == i].max(initial=0.0) for i in range(len(starts))]
    offsets = np.concatenate([[0.0], np.cumsum(lengths)[:-1]])
    return (offsets[owner] + elapsed) / 60.0


def run_statistics(run: RunRecord, metric: str, bar: float, smooth: int) -> dict:
    """One run's row: seed, network, minutes, env steps, the bar, the peak, past the peak, env steps/s and every
    evaluation's mean of `metric` with its standard error."""
    rows = [row for row in run.rows if not math.isnan(row.get(metric, math.nan))]
    if not rows:
        raise SystemExit(f"seed_statistics: {run.path} recorded no {metric}.")
    sessions = read_sessions(run.path)
    minutes = session_minutes(rows, sessions)
    values = np.array([row[metric] for row in rows])
    cycles = [row["cycle"] for row in rows]
    peak, peak_value, final = rolling_peak(values, min(smooth, len(values)))
    reached = np.flatnonzero(values >= bar)
    evaluations = {}
    for path in sorted(Path(run.path, "evaluation").glob("*.json")):
        record = json.loads(path.read_text())
        if metric in record.get("summary", {}):
            label = " ".join([record["checkpoint"], *record.get("env_overrides", [])])
            evaluations[label] = {"cycle": record["cycle"], "episodes": record["episodes"],
                                  "mean": record["summary"][metric]["mean"],
                                  "stderr": record["summary"][metric]["stderr"], "file": path.name}
    ppo = run.config["ppo"]
    return {
        "run": run.name, "seed": ppo.get("seed"), "network": ppo.get("network", {}).get("name"),
        "device": sessions[0]["devices"][0]["kind"] if sessions and sessions[0].get("devices") else None,
        "sessions": max(1, len(sessions)), "minutes": float(minutes[-1]), "cycles": cycles[-1],
        "env_steps": rows[-1]["env_steps"],
        "steps_per_second": float(np.median([row["steps_per_second"] for row in rows[1:]] or [math.nan])),
        "bar_minutes": float(minutes[reached[0]]) if reached.size else None,
        "bar_cycle": cycles[reached[0]] if reached.size else None,
        "peak": peak_value, "peak_cycle": cycles[peak], "peak_minutes": float(minutes[peak]),
        "final": final, "minutes_past_peak": float(minutes[-1] - minutes[peak]),
        "evaluations": evaluations,
    }


def spread(values: list[float]) -> dict:
    """Mean, sample standard deviation, min and max of `values` (std None for one value)."""
    return {"n": len(values), "mean": statistics.fmean(values),
            "std": statistics.stdev(values) if len(values) > 1 else None, "min": min(values), "max": max(values)}


def group_statistics(rows: list[dict]) -> dict:
    """Over a group's seeds: minutes to the bar (of the runs that reached it, with how many did), the peak, the
    final mean, and each evaluation label's mean that every seed has."""
    reached = [row["bar_minutes"] for row in rows if row["bar_minutes"] is not None]
    shared = set.intersection(*(set(row["evaluations"]) for row in rows))
    return {
        "runs": [row["run"] for row in rows], "seeds": [row["seed"] for row in rows],
        "reached_bar": f"{len(reached)} of {len(rows)}",
        "bar_minutes": spread(reached) if reached else None,
        "peak": spread([row["peak"] for row in rows]), "final": spread([row["final"] for row in rows]),
        "evaluations": {label: spread([row["evaluations"][label]["mean"] for row in rows]) for label in sorted(shared)},
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("runs", nargs="+", help="run directories (config.yaml, metrics.jsonl, sessions.jsonl)")
    parser.add_argument("--metric", default="metric/success", help="the task metric (default: metric/success)")
    parser.add_argument("--bar", type=float, default=0.9, help="the training mean to reach (default: 0.9)")
    parser.add_argument("--smooth", type=int, default=10, help="cycles in the running mean of the peak")
    parser.add_argument("--out", required=True, help="the JSON to write, in the runs' study folder: "
                                                    "results/<study>/<name>.json")
    args = parser.parse_args(argv)
    runs = [load_run(run) for run in args.runs]
    rows = [run_statistics(run, args.metric, args.bar, args.smooth) for run in runs]
    row_of = {id(run): row for run, row in zip(runs, rows, strict=True)}
    groups = [group_statistics([row_of[id(run)] for run in group]) for group in seed_groups(runs)]
    print(markdown_table(rows, [("run", "run", ""), ("network", "network", ""), ("seed", "seed", ""),
                                ("minutes", "minutes", ".2f"), ("bar_minutes", f"{args.metric} >= {args.bar} at",
                                                                ".2f"),
                                ("peak", "peak", ".3f"), ("peak_minutes", "at", ".2f"), ("final", "final", ".3f"),
                                ("minutes_past_peak", "minutes past it", ".2f"),
                                ("steps_per_second", "env steps/s", ",.0f")]))
    for row in rows:
        for label, evaluation in row["evaluations"].items():
            print(f"{row['run']}: {label} (cycle {evaluation['cycle']}, {evaluation['episodes']} episodes): "
                  f"{evaluation['mean']:.3f} +- {evaluation['stderr']:.3f}")
    for group in groups:
        for label, values in group["evaluations"].items():
            std = "-" if values["std"] is None else f"{values['std']:.3f}"
            print(f"seeds {group['seeds']}: {label}: mean {values['mean']:.3f}, std {std}, "
                  f"{values['min']:.3f}-{values['max']:.3f}")
    config = {"runs": args.runs, "metric": args.metric, "bar": args.bar, "smooth": args.smooth}
    path = write_results("seed_statistics", config, rows, args.out, study="seeds", extra={"groups": groups})
    print(f"Wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
