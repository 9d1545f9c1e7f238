"""In-hand cube reorientation learning curves (paper Fig. 7, left) from the `metrics.jsonl` of runs trained in pieces.

A long run is trained in pieces shorter than a job's time limit (`angora-jax train ... --minutes 9`, then
`angora-jax resume RUN_DIR --minutes 9` in each later job on the same machine). The run directory's metrics.jsonl
then already holds every cycle; pieces saved from different places (e.g. copied back after each job) are joined here:
give a run's files in the order they were written, and a later file's rows replace an earlier one's for the same
cycles (a resumed piece recomputes the cycles after its checkpoint). Two clocks: `train_seconds` sums the cycles' own
wall seconds (the compiled cycle, the first of each piece with its compilation); `wall_seconds` is what the clock on
the wall showed, the time between consecutive cycles' log lines (the cycle plus its metrics, progress line and
checkpoint saves), the first cycle of each piece counted by its own seconds: starting a process, building Warp's
kernels and restoring the checkpoint between pieces are not counted.

For each run it reports the env steps and wall time at which the training-mean CGR (`metric/goals_reached` over
the episodes that ended in a cycle) first reached 1, 5, 10, 20 and 30, and the ratio of those to AngoraPy's (paper:
1,187,512,320 samples, 96 h on 384 CPU cores and 32 GPUs, for a training mean of about 30). The plot overlays the
runs against env steps (with the paper's endpoint) and against wall minutes. A run that started from another's
policy (`ppo.init_from`, e.g. fine-tuned to read a pose estimator) continues that run's curve with `--continues
LABEL=BASE`: its env steps and times count from where BASE's rows end. `--before LABEL=MINUTES` adds wall time that
run's route spent elsewhere first (e.g. pretraining the estimator), for comparisons at equal wall time.

Seeds: runs given under the same label are seeds of one recipe. For each milestone the label then gets the mean and
the 95% confidence interval (Student's t) over the seeds that reached it, and the plot draws the seeds' mean with its
band while every seed runs, and each seed to its own end; `--seeds N` refuses a label with another number of runs
(a crashed seed must not shrink the statistics silently). Every run also gets its stability: the peak of its
training-mean CGR (a 5-cycle rolling mean), its last value (the mean of the last 5 cycles), their ratio
(`fraction_of_peak`), how long it trained past the peak, and how many times its time to CGR 30 it trained in all
(`solve_time_multiple`). The JSON's `curves` map each label to its runs, one list of per-cycle rows each.

Scaling: `--devices LABEL=N` says a label's runs trained on N GPUs. The JSON's `scaling` then gives, per such label,
the mean time to CGR 30 over its seeds that reached it, on the wall clock (compile included) and without the cycles'
compile seconds, and `time_to_solve_efficiency` (and `..._compiled`) against the label with the fewest devices:
T_base x N_base / (T x N), 1 when N GPUs solve N times faster. Start-up before the first cycle (imports, Warp's kernel
builds) is not in the metrics; add it per label with `--before` (benchmarks/startup_time.sh measures it).

    python benchmarks/ihom_curve.py fast=runs/fast/metrics.jsonl paper=runs/paper/metrics.jsonl \\
        --device "NVIDIA H100 80GB HBM3" --name ShadowHandCube_h100
    python benchmarks/ihom_curve.py fast=runs/s0 fast=runs/s1 fast=runs/s2 fast=runs/s3 fast=runs/s4 --seeds 5 \\
        --device "NVIDIA H200" --name fast_seeds_h200
    python benchmarks/ihom_curve.py one=runs/ihom-1gpu two=runs/ihom-2gpu four=runs/ihom-4gpu \\
        --devices one=1 --devices two=2 --devices four=4 --device "NVIDIA H200" --name scaling_h200
"""

from __future__ import annotations

import argparse
import datetime
import json
import math
import os
from pathlib import Path

import matplotlib
import numpy as np
import scipy.stats

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from common import markdown_table, rolling_peak, study_folder, write_json  # noqa: E402

CGR = "metric/goals_reached"
MILESTONES = (1, 5, 10, 20, 30)
# AngoraPy's IHOM run (Weidler et al. 2023): samples, wall hours and hardware, for a training-mean CGR of about 30.
PAPER = {"samples": 1_187_512_320, "hours": 96.0, "hardware": "384 CPU cores + 32 GPUs (P100)", "cgr": 30.0}
# The CGR whose time-to-solve scaling is reported (issue 60's "time to CGR 30").
SOLVED = 30
# Cycles in the rolling mean that stability is judged on: one cycle's training mean moves by a few CGR.
SMOOTH = 5


def read_pieces(paths: list[str]) -> list[dict]:
    """The rows of one run's metrics files (run directories or metrics.jsonl paths), joined by cycle: a later file's
    row replaces an earlier one's; rows come back sorted by cycle with `train_seconds`, `wall_seconds` and
    `compiled_seconds` (the wall clock less the cycles' compile seconds) added, all cumulative."""
    by_cycle: dict[int, dict] = {}
    for path in paths:
        file = Path(path) / "metrics.jsonl" if Path(path).is_dir() else Path(path)
        if not file.exists():
            hint = " (the label ends at the first '=': a label cannot hold one)" if "=" in path else ""
            raise SystemExit(f"No metrics file {file}: give a run directory or its metrics.jsonl{hint}.")
        for line in file.read_text().splitlines():
            if line.strip():
                row = json.loads(line)
                by_cycle[int(row["cycle"])] = row
    return with_clocks([by_cycle[cycle] for cycle in sorted(by_cycle)])


def with_clocks(records: list[dict]) -> list[dict]:
    """Per-cycle records in cycle order (metrics.jsonl rows, or `train`'s `on_cycle` records as they come), with the
    cumulative `train_seconds`, `wall_seconds` and `compiled_seconds` of `read_pieces` added: a cycle that does not
    follow the one before it, or that compiled, starts a piece and counts by its own seconds."""
    rows, train, wall, compiling, previous = [], 0.0, 0.0, 0.0, None
    for row in records:
        cycle = int(row["cycle"])
        train += row["seconds"]
        compiling += row.get("compile_seconds") or 0.0
        same_piece = previous is not None and previous["cycle"] == cycle - 1 and "compile_seconds" not in row
        wall += row["time"] - previous["time"] if same_piece else row["seconds"]
        rows.append({**row, "train_seconds": train, "wall_seconds": wall, "compiled_seconds": wall - compiling})
        previous = row
    return rows


def first_reaching(rows: list[dict], bar: float, metric: str = CGR) -> dict | None:
    """The first row whose training mean of `metric` (the CGR unless named) is at least `bar`, None when none is."""
    return next((r for r in rows if r.get(metric) is not None and r[metric] >= bar), None)


def milestones(rows: list[dict]) -> list[dict]:
    """For each CGR bar: the first cycle whose training-mean CGR reaches it, its env steps, training, wall and compiled
    minutes (None when never reached), and the ratios of AngoraPy's samples and wall time to ours."""
    found = []
    for bar in MILESTONES:
        row = first_reaching(rows, bar)
        entry = {"cgr": bar, "cycle": None, "env_steps": None, "train_minutes": None, "wall_minutes": None,
                 "compiled_minutes": None}
        if row is not None:
            entry.update(cycle=row["cycle"], env_steps=row["env_steps"], train_minutes=row["train_seconds"] / 60,
                         wall_minutes=row["wall_seconds"] / 60, compiled_minutes=row["compiled_seconds"] / 60)
            if bar >= PAPER["cgr"]:
                entry["paper_samples_ratio"] = PAPER["samples"] / row["env_steps"]
                entry["paper_wall_ratio"] = PAPER["hours"] * 3600 / row["wall_seconds"]
        found.append(entry)
    return found


def mean_interval(values: list[float]) -> dict:
    """n, mean and the 95% confidence interval's half width (Student's t; None for fewer than 2 values)."""
    if not values:
        return {"n": 0, "mean": None, "ci95": None}
    half = float(scipy.stats.t.ppf(0.975, len(values) - 1) * scipy.stats.sem(values)) if len(values) > 1 else None
    return {"n": len(values), "mean": float(np.mean(values)), "ci95": half}


def seed_milestones(seeds: list[list[dict]]) -> list[dict]:
    """Per CGR bar over a recipe's seeds (each a run's `milestones`): how many reached it, and the mean and 95%
    interval of env steps, training and wall minutes over those that did."""
    summary = []
    for bar, entries in zip(MILESTONES, zip(*seeds, strict=True), strict=True):
        reached = [e for e in entries if e["cycle"] is not None]
        row = {"cgr": bar, "num_seeds": len(entries), "reached": len(reached)}
        for key in ("env_steps", "train_minutes", "wall_minutes", "compiled_minutes"):
            row[key] = mean_interval([e[key] for e in reached])
        summary.append(row)
    return summary


def scaling(per_run: dict[str, list[list[dict]]], devices: dict[str, int], bar: int = SOLVED) -> list[dict]:
    """Time-to-solve scaling: for each label given a device count, the mean over its seeds that reached CGR `bar` of
    the wall minutes to it (compile included) and of the compiled minutes (without the cycles' compile seconds), and
    the efficiency against the label with the fewest devices, T_base * N_base / (T * N): 1 when N devices solve N
    times faster. None where no seed of a label reached the bar."""
    rows = []
    for label, count in sorted(devices.items(), key=lambda item: item[1]):
        reached = [found for found in (next(m for m in run if m["cgr"] == bar) for run in per_run[label])
                   if found["cycle"] is not None]
        rows.append({"label": label, "devices": count, "cgr": bar, "num_seeds": len(per_run[label]),
                     "reached": len(reached),
                     **{key: float(np.mean([m[key] for m in reached])) if reached else None
                        for key in ("wall_minutes", "compiled_minutes")}})
    base = rows[0] if rows else None
    for row in rows:
        for key, name in (("wall_minutes", "time_to_solve_efficiency"),
                          ("compiled_minutes", "time_to_solve_efficiency_compiled")):
            known = base[key] is not None and row[key] is not None
            row[name] = base[key] * base["devices"] / (row[key] * row["devices"]) if known else None
    return rows


def stability(rows: list[dict]) -> dict:
    """The peak of the training-mean CGR's rolling mean over `SMOOTH` cycles, the cycle and wall minutes where it
    was, the mean of the last `SMOOTH` cycles, their ratio (`fraction_of_peak`), the cycles and wall minutes trained
    past the peak, and `solve_time_multiple`: the run's wall minutes over those to the first training mean of
    `SOLVED` (issue 60 asks for 2; None when never reached)."""
    cgr = np.array([math.nan if r.get(CGR) is None else r[CGR] for r in rows])
    if len(cgr) < SMOOTH or np.isnan(cgr).all():
        return {"peak": None}
    top, peak, final = rolling_peak(cgr, SMOOTH)
    at_peak, last = rows[top], rows[-1]
    solved = first_reaching(rows, SOLVED)
    return {"peak": peak, "peak_cycle": at_peak["cycle"], "peak_wall_minutes": at_peak["wall_seconds"] / 60,
            "final": final, "fraction_of_peak": final / peak if peak > 0 else None,
            "cycles_past_peak": last["cycle"] - at_peak["cycle"],
            "wall_minutes_past_peak": (last["wall_seconds"] - at_peak["wall_seconds"]) / 60,
            "solve_time_multiple": last["wall_seconds"] / solved["wall_seconds"] if solved else None}


def band(seeds: list[list[dict]], x: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`(grid, mean, half width)` of the seeds' CGR against `x` (env_steps or wall_seconds), each seed interpolated
    on a grid up to where the shortest ends."""
    end = min(rows[-1][x] for rows in seeds)
    grid = np.linspace(min(rows[0][x] for rows in seeds), end, 200)
    curves = np.array([np.interp(grid, [r[x] for r in rows], [math.nan if r.get(CGR) is None else r[CGR]
                                                               for r in rows]) for rows in seeds])
    half = scipy.stats.t.ppf(0.975, len(seeds) - 1) * scipy.stats.sem(curves, axis=0)
    return grid, curves.mean(axis=0), half


def figure(runs: dict[str, list[list[dict]]], title: str) -> plt.Figure:
    """CGR against env steps (log scale, the paper's endpoint marked) and against wall minutes; drop share of
    episode ends and goal distance against env steps. A label of several seeds is drawn as their mean with its 95%
    band in the CGR panels, while every seed still runs, and as thin lines per seed in every panel, each to its own
    end (a seed stopped at CGR 30 by `ppo.stop_at`, or by a time limit, ends the band but not the others' lines)."""
    fig, axes = plt.subplots(1, 4, figsize=(18, 4))
    for label, seeds in runs.items():
        color = None
        if len(seeds) > 1:
            named = f"{label} ({len(seeds)} seeds, mean and 95% CI while all run; thin: each seed)"
            for ax, x, scale in ((axes[0], "env_steps", 1), (axes[1], "wall_seconds", 60)):
                grid, mean, half = band(seeds, x)
                (line,) = ax.plot(grid / scale, mean, label=named, color=color)
                color = line.get_color()
                # A CGR is never below 0; with few seeds Student's t makes the interval reach far past it.
                ax.fill_between(grid / scale, np.maximum(mean - half, 0.0), mean + half, alpha=0.25, color=color)
        for rows in seeds:
            steps = [r["env_steps"] for r in rows]
            minutes = [r["wall_seconds"] / 60 for r in rows]

            def values(key, rows=rows):
                return [math.nan if r.get(key) is None else r[key] for r in rows]

            width = 0.6 if len(seeds) > 1 else 1.5
            (line,) = axes[0].plot(steps, values(CGR), color=color, linewidth=width,
                                   label=label if len(seeds) == 1 else None)
            color = line.get_color()
            axes[1].plot(minutes, values(CGR), color=color, linewidth=width)
            axes[2].plot(steps, values("metric/dropped"), color=color, linewidth=width)
            axes[3].plot(steps, values("metric/goal_distance"), color=color, linewidth=width)
    axes[0].scatter([PAPER["samples"]], [PAPER["cgr"]], marker="*", s=150, color="k", zorder=3,
                    label=f"AngoraPy (paper): {PAPER['cgr']:g} at {PAPER['samples']:.3g}")
    axes[0].set_xscale("log")
    for ax, (xlabel, ylabel) in zip(axes, [("env steps", "training-mean CGR"), ("wall minutes", "CGR"),
                                           ("env steps", "share of episode ends that are drops"),
                                           ("env steps", "goal distance at episode end (rad)")], strict=True):
        ax.set_xlabel(xlabel)
        ax.set_ylabel(ylabel)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.suptitle(title)
    fig.tight_layout()
    return fig


def plot(runs: dict[str, list[list[dict]]], title: str, path: str) -> None:
    """`figure` saved as a PNG at `path`."""
    fig = figure(runs, title)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("runs", nargs="+", metavar="LABEL=PATH[,PATH...]",
                        help="a run's label and its metrics files or run directories, in the order written")
    parser.add_argument("--device", required=True, help="the device the runs trained on, e.g. 'NVIDIA H100 80GB HBM3'")
    parser.add_argument("--name", default="ShadowHandCube", help="results/<study>/ihom_curve_<name>.json and .png "
                             "(NAME-2, NAME-3, ... when taken: nothing is replaced)")
    parser.add_argument("--study", default="cube_one_gpu",
                        help="the results folder the curve belongs to (cube_one_gpu, cube_multi_gpu, cube_paper, "
                             "cube_cortical, cube_pixels; default: %(default)s)")
    parser.add_argument("--continues", action="append", default=[], metavar="LABEL=BASE",
                        help="run LABEL started from run BASE's last policy: its steps and times follow BASE's")
    parser.add_argument("--before", action="append", default=[], metavar="LABEL=MINUTES",
                        help="wall minutes that run LABEL's route spent outside the runs given, before it (e.g. "
                             "pretraining its pose estimator): added to its wall clock")
    parser.add_argument("--note", default="", help="free text stored with the results (e.g. what else shared the GPU)")
    parser.add_argument("--seeds", type=int, metavar="N",
                        help="each label must have exactly N runs (its seeds), or nothing is written")
    parser.add_argument("--devices", action="append", default=[], metavar="LABEL=N",
                        help="the label's runs trained on N GPUs: adds time-to-solve scaling against the label "
                             "with the fewest (repeat per label)")
    args = parser.parse_args(argv)
    runs: dict[str, list[list[dict]]] = {}
    for spec in args.runs:
        label, sep, paths = spec.partition("=")
        if not sep or not label or not paths:
            raise SystemExit(f"Run {spec!r} must look like LABEL=PATH[,PATH...].")
        runs.setdefault(label, []).append(read_pieces(paths.split(",")))
    if args.seeds is not None:
        wrong = {label: len(seeds) for label, seeds in runs.items() if len(seeds) != args.seeds}
        if wrong:
            raise SystemExit(f"--seeds {args.seeds}: " + ", ".join(f"{label!r} has {n}" for label, n in wrong.items())
                             + " run(s); give each label's every seed, or a --seeds that matches.")
    continues = dict(spec.partition("=")[::2] for spec in args.continues)
    for label, base in continues.items():
        if label not in runs or base not in runs:
            raise SystemExit(f"--continues {label}={base}: both must be labels of the runs given ({', '.join(runs)}).")
        if len(runs[base]) > 1:
            raise SystemExit(f"--continues {label}={base}: {base!r} has several seeds; a run continues one run.")
        end = runs[base][0][-1]
        runs[label] = [[{**r, **{k: r[k] + end[k] for k in ("env_steps", "train_seconds", "wall_seconds")}}
                        for r in rows] for rows in runs[label]]
    before = {}
    for spec in args.before:
        label, _, minutes = spec.partition("=")
        try:
            before[label] = float(minutes)
        except ValueError:
            raise SystemExit(f"--before {spec!r} must look like LABEL=MINUTES.") from None
        if label not in runs:
            raise SystemExit(f"--before {spec}: {label!r} is not a label of the runs given ({', '.join(runs)}).")
        runs[label] = [[{**r, "wall_seconds": r["wall_seconds"] + 60.0 * before[label]} for r in rows]
                       for rows in runs[label]]
    devices = {}
    for spec in args.devices:
        label, _, count = spec.partition("=")
        if not count.isdigit() or int(count) < 1:
            raise SystemExit(f"--devices {spec!r} must look like LABEL=N with N a device count of at least 1.")
        if label not in runs:
            raise SystemExit(f"--devices {spec}: {label!r} is not a label of the runs given ({', '.join(runs)}).")
        devices[label] = int(count)
    per_run = {label: [milestones(rows) for rows in seeds] for label, seeds in runs.items()}
    scaled = scaling(per_run, devices)
    summary = {label: found[0] for label, found in per_run.items() if len(found) == 1}
    over_seeds = {label: seed_milestones(found) for label, found in per_run.items() if len(found) > 1}
    stable = {label: [stability(rows) for rows in seeds] for label, seeds in runs.items()}
    stem = os.path.join(study_folder(args.study), f"ihom_curve_{args.name}")
    record = {"benchmark": "ihom_curve", "date": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
              "training_device": args.device, "note": args.note, "continues": continues, "before_minutes": before,
              "paper": PAPER,
              "milestones": summary, "seed_milestones": over_seeds,
              "seed_milestones_per_run": {label: found for label, found in per_run.items() if len(found) > 1},
              "stability": stable, "scaling": scaled,
              "curves": {label: [[{k: r.get(k) for k in ("cycle", "env_steps", "train_seconds", "wall_seconds",
                                                          "steps_per_second", "learning_rate",
                                                          "episode_return", "episode_length", CGR, "metric/dropped",
                                                          "metric/timed_out", "metric/goal_distance", "entropy")}
                                  for r in rows] for rows in seeds] for label, seeds in runs.items()}}
    # The repository keeps no file over 2 MiB: the curves of many long runs are written without indentation.
    indent = 1 if len(json.dumps(record, indent=1)) < 2 * 2**20 else None
    stem = write_json(stem, record, (".json", ".png"), indent=indent)
    plot(runs, f"ShadowHandCube (IHOM) on {args.device}", stem + ".png")
    for label, seeds in runs.items():
        for rows, held in zip(seeds, stable[label], strict=True):
            last = rows[-1]
            print(f"{label}: {last['cycle']} cycles, {last['env_steps']:,} env steps, {last['train_seconds'] / 60:.1f} "
                  f"min training, {last['wall_seconds'] / 60:.1f} min wall, last training-mean CGR {last.get(CGR):.2f}")
            if held["peak"] is not None:
                print(f"  peak {held['peak']:.1f} (5-cycle mean) at cycle {held['peak_cycle']}, last "
                      f"{held['final']:.1f} ({100 * (held['fraction_of_peak'] or 0):.0f}% of the peak) after "
                      f"{held['cycles_past_peak']} cycles ({held['wall_minutes_past_peak']:.1f} wall min) past it"
                      + (f"; trained {held['solve_time_multiple']:.2f} times its time to CGR {SOLVED}"
                         if held["solve_time_multiple"] else ""))
        if label in over_seeds:
            print(markdown_table([{"cgr": row["cgr"], "reached": f"{row['reached']}/{row['num_seeds']}",
                                   **{key: show(row[key]) for key in ("env_steps", "train_minutes", "wall_minutes")}}
                                  for row in over_seeds[label]],
                                 [("cgr", "CGR", "d"), ("reached", "seeds reached", "s"),
                                  ("env_steps", "env steps (mean +- 95% CI)", "s"),
                                  ("train_minutes", "training min", "s"), ("wall_minutes", "wall min", "s")]))
            continue
        print(markdown_table(summary[label], [("cgr", "CGR", "d"), ("cycle", "cycle", "d"),
                                              ("env_steps", "env steps", ",d"),
                                              ("train_minutes", "training min", ".1f"),
                                              ("wall_minutes", "wall min", ".1f"),
                                              ("paper_samples_ratio", "paper samples / ours", ".1f"),
                                              ("paper_wall_ratio", "paper wall / ours", ".0f")]))
    if scaled:
        print(markdown_table([{**row, "reached": f"{row['reached']}/{row['num_seeds']}"} for row in scaled],
                             [("label", "run", "s"), ("devices", "GPUs", "d"), ("reached", "seeds reached", "s"),
                              ("wall_minutes", f"wall min to CGR {SOLVED}", ".1f"),
                              ("compiled_minutes", "without compiles", ".1f"),
                              ("time_to_solve_efficiency", "efficiency", ".2f"),
                              ("time_to_solve_efficiency_compiled", "efficiency without compiles", ".2f")]))
    print(f"wrote {stem}.json and {stem}.png")
    return 0


def show(value: dict) -> str:
    """`mean +- half width` of a `mean_interval`, '-' when no seed reached it."""
    if value["mean"] is None:
        return "-"
    digits = ",.0f" if value["mean"] > 1000 else ".1f"
    half = "" if value["ci95"] is None else f" +- {value['ci95']:{digits}}"
    return f"{value['mean']:{digits}}{half}"


if __name__ == "__main__":
    raise SystemExit(main())
