"""A run's training-mean return beside deterministic evaluations of its snapshots: is a drop in the training curve
the policy's, or only the sampling policy's over the episodes that happened to end in those cycles?

The training mean of a cycle averages the episodes that ended in it, acted with sampled actions; an evaluation
(`angora-jax evaluate RUN --checkpoint CYCLE`) runs a saved policy's mode on fresh episodes. Train with snapshots
(`checkpoint.snapshot_every=25`), evaluate each, then:

    angora-jax evaluate runs/hopper0 --checkpoint snapshots --path batched
    python benchmarks/snapshot_evaluations.py seed0=runs/hopper0 seed1=runs/hopper1 --name hopper_snapshots_h100

Per run and snapshot: the cycle's training-mean return and episode length (mean over the cycles since the previous
snapshot, so that a cycle in which few episodes ended does not stand alone), the policy's entropy, and the
evaluation's mean return, its standard error and mean episode length. Writes a table, a JSON with the runs' device
and versions (from their `sessions.jsonl`) and a PNG.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import statistics
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from common import RESULTS, markdown_table, write_json  # noqa: E402


def read_run(run_dir: Path) -> tuple[list[dict], dict[int, dict], dict]:
    """The run's metrics rows, its deterministic evaluations by cycle, and its first session (device, versions)."""
    metrics = run_dir / "metrics.jsonl"
    if not metrics.exists():
        raise SystemExit(f"{run_dir} has no metrics.jsonl: give run directories made by `angora-jax train`.")
    rows = [json.loads(line) for line in metrics.read_text().splitlines() if line.strip()]
    evaluations = {}
    for path in sorted((run_dir / "evaluation").glob("*.json")):
        record = json.loads(path.read_text())
        if not record.get("stochastic") and isinstance(record.get("cycle"), int):
            evaluations[record["cycle"]] = record
    if not evaluations:
        raise SystemExit(f"{run_dir} has no evaluations: run `angora-jax evaluate {run_dir} --checkpoint CYCLE` for "
                         "its snapshots first.")
    session = json.loads((run_dir / "sessions.jsonl").read_text().splitlines()[0])
    return rows, evaluations, session


def snapshot_rows(label: str, rows: list[dict], evaluations: dict[int, dict]) -> list[dict]:
    """One table row per evaluated snapshot; training means over the cycles since the previous snapshot."""
    by_cycle = {row["cycle"]: row for row in rows}
    table, previous = [], 0
    for cycle in sorted(evaluations):
        window = [by_cycle[c] for c in range(previous + 1, cycle + 1) if c in by_cycle]
        ended = [r for r in window if r.get("episodes", 1) > 0 and r.get("episode_return") is not None]
        summary = evaluations[cycle]["summary"]
        table.append({
            "run": label, "cycle": cycle, "env_steps": by_cycle[cycle]["env_steps"] if cycle in by_cycle else None,
            "training_return": statistics.fmean(r["episode_return"] for r in ended) if ended else None,
            "training_length": statistics.fmean(r["episode_length"] for r in ended) if ended else None,
            "entropy": by_cycle[cycle].get("entropy") if cycle in by_cycle else None,
            "evaluation_return": summary["episode_return"]["mean"],
            "evaluation_stderr": summary["episode_return"]["stderr"],
            "evaluation_length": summary["episode_length"]["mean"],
            "episodes": evaluations[cycle]["episodes"],
        })
        previous = cycle
    return table


def plot(runs: dict[str, tuple[list[dict], list[dict]]], title: str, path: str) -> None:
    figure, axis = plt.subplots(figsize=(8, 4.5))
    for i, (label, (rows, table)) in enumerate(runs.items()):
        colour = f"C{i}"
        axis.plot([r["cycle"] for r in rows], [r.get("episode_return") for r in rows], color=colour, alpha=0.5,
                  label=f"{label}: training mean (sampled actions)")
        axis.errorbar([r["cycle"] for r in table], [r["evaluation_return"] for r in table],
                      yerr=[r["evaluation_stderr"] for r in table], color=colour, marker="o", linestyle="--",
                      label=f"{label}: evaluation (mode)")
    axis.set_xlabel("cycle")
    axis.set_ylabel("episode return")
    axis.set_title(title)
    axis.grid(alpha=0.3)
    axis.legend(fontsize=7)
    figure.tight_layout()
    figure.savefig(path, dpi=120)
    plt.close(figure)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("runs", nargs="+", metavar="LABEL=RUN_DIR")
    parser.add_argument("--name", required=True,
                        help="results name: results/snapshot_evaluations/snapshot_evaluations_<name>.{json,png} "
                             "(NAME-2, ... when taken: nothing is replaced)")
    parser.add_argument("--out", default=os.path.join(RESULTS, "snapshot_evaluations"))
    args = parser.parse_args(argv)
    runs, run_dirs, sessions, tasks, table = {}, {}, {}, set(), []
    for spec in args.runs:
        label, _, run_dir = spec.rpartition("=")  # the last "=": a label may hold one (e.g. an override)
        if not label or not run_dir:
            raise SystemExit(f"Give runs as LABEL=RUN_DIR, got {spec!r}.")
        run_dirs[label] = run_dir
        rows, evaluations, session = read_run(Path(run_dir))
        runs[label] = (rows, snapshot_rows(label, rows, evaluations))
        sessions[label] = session
        tasks |= {record["task"] for record in evaluations.values()}
        table += runs[label][1]
    print(markdown_table(table, [("run", "run", "s"), ("cycle", "cycle", "d"), ("env_steps", "env steps", ",d"),
                                 ("training_return", "training mean return", ".0f"),
                                 ("training_length", "training mean length", ".0f"), ("entropy", "entropy", ".2f"),
                                 ("evaluation_return", "evaluation return", ".0f"),
                                 ("evaluation_stderr", "+- stderr", ".0f"),
                                 ("evaluation_length", "evaluation length", ".0f")]))
    first = next(iter(sessions.values()))
    date = datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds")
    record = {"benchmark": "snapshot_evaluations", "date": date,
              "device": first["devices"], "versions": first["versions"], "physics": first.get("physics"),
              "tasks": sorted(tasks),
              "runs": {label: {"run_dir": run_dirs[label], "snapshots": snapshots}
                       for label, (_, snapshots) in runs.items()}}
    os.makedirs(args.out, exist_ok=True)
    stem = write_json(os.path.join(args.out, f"snapshot_evaluations_{args.name}"), record, (".json", ".png"))
    plot(runs, f"{', '.join(sorted(tasks))}: training mean vs evaluated snapshots ({first['devices'][0]['kind']})",
         stem + ".png")
    print(f"wrote {stem}.json and {stem}.png")


if __name__ == "__main__":
    main()
