"""Where a run's wall time between cycles goes: the seconds between one cycle's record and the next's, less the
cycle's own seconds, by what was saved after the cycle (a best checkpoint, a latest, a snapshot, nothing), read from
finished runs' `metrics.jsonl` and `config.yaml`.

    python benchmarks/checkpoint_cost.py full=RUN_A lean=RUN_B [--device "NVIDIA H200"] [--name NAME]

A run saves its best checkpoint after every cycle whose `checkpoint.best_metric` beats all earlier ones, which while
it learns is most cycles; whether that save is full or lean (`checkpoint.lean`) decides what it costs. The gap also
holds the metrics line and the progress line, which cycles without a save show. The last cycle of each piece (before
a restart) is left out: the next record's gap holds a process start and compile. Prints a table and writes JSON to
benchmarks/results/evaluation_and_checkpoints/checkpoint_cost_<name>.json or --out.
"""

from __future__ import annotations

import argparse
import math
import statistics
from pathlib import Path

from common import markdown_table, write_results

from angora_jax.experiment.checkpoint import improves
from angora_jax.experiment.config import load_config
from angora_jax.experiment.monitor import read_metrics

KINDS = ("best", "latest", "snapshot")
ORDER = (*KINDS, "none")


def saves_after(rows: list[dict], config) -> list[tuple[dict, set[str]]]:
    """Each record but the last with the checkpoint kinds saved after its cycle (the best by the run's own rule,
    `checkpoint.improves`) and its `gap`: a record's time is taken before the cycle's saves, so
    they fall between it and the next cycle, whose own seconds are taken out. A record before a piece's first cycle
    (a restart: that cycle carries `compile_seconds`) or before a gap in the cycles gets none."""
    checkpoint, best, out = config.checkpoint, None, []
    for row, following in zip(rows, rows[1:], strict=False):
        value = row.get(checkpoint.best_metric, math.nan) if checkpoint.best_metric else math.nan
        kinds = set()
        if improves(value, best, checkpoint.best_mode):
            best = value
            kinds.add("best")
        if row["cycle"] % checkpoint.every == 0:
            kinds.add("latest")
        if checkpoint.snapshot_every and row["cycle"] % checkpoint.snapshot_every == 0:
            kinds.add("snapshot")
        if following["cycle"] == row["cycle"] + 1 and "compile_seconds" not in following:
            out.append((row | {"gap": following["time"] - row["time"] - following["seconds"]}, kinds))
    return out


def run_rows(label: str, run_dir: Path) -> list[dict]:
    config = load_config(run_dir / "config.yaml")
    cycles = saves_after(read_metrics(run_dir), config)
    lean = ", ".join(config.checkpoint.lean) or "none"
    wall = sum(row["gap"] + row["seconds"] for row, _ in cycles)  # each cycle with the saves after it
    rows = []
    saved = ["+".join(kind for kind in KINDS if kind in kinds) or "none" for _, kinds in cycles]
    for label_saved in sorted(set(saved), key=lambda name: [ORDER.index(kind) for kind in name.split("+")]):
        gaps = [row["gap"] for (row, _), name in zip(cycles, saved, strict=True) if name == label_saved]
        rows.append({"run": label, "lean": lean, "saved": label_saved, "cycles": len(gaps),
                     "median_gap_s": statistics.median(gaps), "mean_gap_s": statistics.fmean(gaps),
                     "share_of_wall": sum(gaps) / wall, "cycle_s": statistics.median(r["seconds"] for r, _ in cycles)})
    saving = [row["gap"] for (row, _), name in zip(cycles, saved, strict=True) if name != "none"]
    rows.append({"run": label, "lean": lean, "saved": "any", "cycles": len(saving),
                 "median_gap_s": statistics.median(saving), "mean_gap_s": statistics.fmean(saving),
                 "share_of_wall": sum(saving) / wall, "cycle_s": rows[-1]["cycle_s"]})
    return rows


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("runs", nargs="+", help="LABEL=RUN_DIR: a run directory (or a copy of its config.yaml and "
                                                "metrics.jsonl)")
    parser.add_argument("--device", default=None, help="the GPU the runs trained on, as the JSON should name it")
    parser.add_argument("--name", default="runs", help="the JSON's name: checkpoint_cost_<name>.json")
    parser.add_argument("--out", default=None)
    args = parser.parse_args(argv)
    rows = []
    for spec in args.runs:
        label, _, folder = spec.partition("=")
        if not folder:
            parser.error(f"{spec!r}: give LABEL=RUN_DIR")
        rows += run_rows(label, Path(folder))
    print(markdown_table(rows, [("run", "run", "s"), ("lean", "lean kinds", "s"), ("saved", "saved after", "s"),
                                ("cycles", "cycles", ",d"), ("median_gap_s", "median gap s", ".3f"),
                                ("mean_gap_s", "mean gap s", ".3f"), ("share_of_wall", "share of wall", ".3f"),
                                ("cycle_s", "cycle s", ".2f")]))
    path = write_results(f"checkpoint_cost_{args.name}", {"runs": args.runs, "trained_on": args.device}, rows,
                         args.out, study="evaluation_and_checkpoints")
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
