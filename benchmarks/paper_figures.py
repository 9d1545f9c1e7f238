"""The paper's benchmark figures as one command: Fig. 8 (classic control) and Fig. 9 (MuJoCo locomotion and the
hand's reach), each task x policy head x seed trained with its family's config (`classic`, `locomotion`,
`shadow_reach`; no per-task tuning, as in the paper), mean return against env steps and against cycles.

Per run: `angora_jax.train` in this process (with `--parallel`, in one of its own) with `--minutes` as its wall-
clock cap (the run stops after the first cycle past it, compile included). Per figure: one PNG, a panel per task
(top row: against env steps, bottom row: against cycles; per head the mean over seeds with the min-max band as far
as every seed ran, and each seed that ran further as a thin line), and in the JSON every curve (the return, the
task's own metrics such as reach's success, and training diagnostics), each run's wall time, final return (the
training mean over the last tenth of its cycles, with sampled actions) and its final policy's mode evaluated on
fresh episodes (`--evaluate`, 128 by default; return and task metrics), the wall seconds and env steps at which its
training mean first passed the task's target return (`common.TARGETS`), and,
per task, the heads compared over the seeds (mean and sample std of each run's return at the env steps that every run
of the task reached, so that heads of unequal speed are compared at equal samples; a head is better where Welch's
t-test against the runner-up gives p < 0.05, else the two are level; the verdict heads each panel; beside it the
final policies' modes, where every run of a head evaluated one). Tasks not
available here are listed as missing with the reason.

    python benchmarks/paper_figures.py --figure 9 --seeds 0 1 2 --minutes 4 --parallel 4   # one GPU, 4 runs at once
    python benchmarks/paper_figures.py --figure 8 --tasks CartPole --seeds 0 --smoke  # CPU smoke: tiny sizes

`--parallel N` trains N runs at a time, each in a process of its own (measured on one H100: four Ant and Humanoid runs
at once trained at 60,000-81,000 env steps/s each; 23 at once starved each other), spread round-robin over the
host's GPUs, one GPU per process, and writes one figure from them. Runs made by separate invocations (e.g. one
process per task, head and seed, or one per machine) are combined into one figure with `--merge`:

    python benchmarks/paper_figures.py --figure 9 --merge out/Hopper_gaussian_0.json out/Hopper_beta_0.json ...

A run given in two outputs is refused, unless `--replace` keeps the later one (e.g. a run made again alone where it
was starved before); the figure lists what was replaced. Outputs of different machines merge (each run keeps its
device, which its wall times belong to), outputs of different package versions do not.
"""

from __future__ import annotations

import argparse
import concurrent.futures
import json
import math
import os
import queue
import statistics
import subprocess
import sys
import tempfile
import time

import gymnasium
import jax
import matplotlib
import scipy.stats

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from common import RESULTS, TARGETS, device, markdown_table, versions, write_json  # noqa: E402

import angora_jax as aj  # noqa: E402
from angora_jax.envs.registry import is_gymnasium, list_tasks  # noqa: E402
from angora_jax.experiment import load_config, read_metrics, to_dict  # noqa: E402

# Figure -> (task, family config, heads). Discrete tasks have one head; continuous ones are compared.
CONTINUOUS = ("gaussian", "beta")
FIGURES = {
    "8": [("CartPole", "classic", ("categorical",)), ("Acrobot", "classic", ("categorical",)),
          ("MountainCar", "classic", ("categorical",)), ("Pendulum", "classic", CONTINUOUS),
          ("MountainCarContinuous", "classic", CONTINUOUS),
          ("gym:LunarLander-v3", "classic", ("categorical",))],  # on the host path: the box2d extra
    "9": [("InvertedPendulum", "locomotion", CONTINUOUS), ("InvertedDoublePendulum", "locomotion", CONTINUOUS),
          ("Reacher", "locomotion", CONTINUOUS), ("Swimmer", "locomotion", CONTINUOUS),
          ("Hopper", "locomotion", CONTINUOUS), ("Walker2d", "locomotion", CONTINUOUS),
          ("HalfCheetah", "locomotion", CONTINUOUS), ("Ant", "locomotion", CONTINUOUS),
          ("Humanoid", "locomotion", CONTINUOUS),
          ("ShadowHandReach", "shadow_reach", (*CONTINUOUS, "multicategorical")),
          ("ShadowHandFreeReach", "shadow_reach", (*CONTINUOUS, "multicategorical"))],
}
# A head is called better than the runner-up only where Welch's t-test over their seeds' returns gives p below this;
# otherwise the two are "level".
SIGNIFICANCE = 0.05
# Gymnasium ids of the classic tasks, for their registered reward thresholds; the locomotion tasks are `<task>-v5`.
GYMNASIUM_IDS = {"CartPole": "CartPole-v1", "Acrobot": "Acrobot-v1", "MountainCar": "MountainCar-v0",
                 "Pendulum": "Pendulum-v1", "MountainCarContinuous": "MountainCarContinuous-v0"}
# CPU smoke sizes: a few seconds per run.
SMOKE = ["ppo.num_envs=4", "ppo.rollout_length=16", "ppo.chunk_length=8", "ppo.minibatch_size=32",
         "ppo.num_epochs=1", "ppo.num_cycles=2"]


# Per-cycle training signals kept beside the return, to read why a curve rises and falls (e.g. Hopper's drops after
# its episodes reach the 1,000-step cap) without training again.
DIAGNOSTICS = ("episode_length", "episodes", "entropy", "approx_kl", "clip_fraction", "grad_norm", "value_loss",
               "explained_variance", "norm/reward_std", "norm/proprioception_std")


def finite_or_none(value: float | None) -> float | None:
    return value if value is not None and math.isfinite(value) else None


def train_one(task: str, config: str, head: str, seed: int, minutes: float, extra: list[str], root: str,
              episodes: int = 0) -> dict:
    """One run; its curve and timing, and with `episodes` > 0 its final policy's mode evaluated on that many
    episodes (`evaluation`): the training mean averages sampled actions over the episodes that ended in a cycle,
    which can fall while the learned policy does not (Hopper: `snapshot_evaluations.py`)."""
    overrides = [f"env.task={task}", f"ppo.head={head}", f"ppo.seed={seed}", f"logging.run_root={root}",
                 f"logging.run_name={task}-{head}-{seed}", "logging.progress=none", "logging.report=false",
                 "checkpoint.best_metric=null", *extra]
    start = time.perf_counter()
    run = aj.train(config, overrides, minutes=minutes)
    wall = time.perf_counter() - start
    rows = read_metrics(run.run_dir)
    rates = [r["steps_per_second"] for r in rows[1:]]  # the first cycle includes compilation
    curve = curve_of(rows)
    return {"task": task, "config": config, "head": head, "seed": seed, "device": device()["kind"],
            "wall_seconds": wall,
            "compile_seconds": rows[0].get("compile_seconds"), "cycles": len(rows), "env_steps": rows[-1]["env_steps"],
            "env_steps_per_second": statistics.median(rates) if rates else None,
            "final_return": tail_mean(curve["episode_return"]),
            "target": first_past(curve, TARGETS.get(task)),
            "evaluation": evaluate_mode(run.run_dir, episodes) if episodes > 0 else None, "curve": curve}


def curve_of(rows: list[dict]) -> dict[str, list]:
    """Per-cycle series from a run's metric rows: env steps, cycle, seconds since the run began, the return, the
    task's own metrics (`metric/<name>`, e.g. reach's success: the measure a task is judged by where its return is
    only the means) and `DIAGNOSTICS`; None where a cycle ended no episode."""
    begin = rows[0]["time"] - rows[0]["seconds"]
    task_metrics = sorted({name for row in rows for name in row if name.startswith("metric/")})
    return {"env_steps": [r["env_steps"] for r in rows], "cycle": [r["cycle"] for r in rows],
            "seconds": [r["time"] - begin for r in rows],
            **{name: [finite_or_none(r.get(name)) for r in rows]
               for name in ("episode_return", *task_metrics, *DIAGNOSTICS)}}


def evaluate_mode(run_dir: str, episodes: int) -> dict:
    """The final policy's deterministic return over `episodes` fresh episodes, all at once on the training path, and
    the mean of each task metric at the episodes' ends (`metric/<name>`, e.g. reach's success rate)."""
    result = aj.evaluate(run_dir, "latest", episodes=episodes, path="batched", save=False)
    summary = result.summary
    return {"episodes": episodes, "return": summary["episode_return"]["mean"],
            "return_stderr": summary["episode_return"]["stderr"],
            "episode_length": summary["episode_length"]["mean"], "seconds": result.meta["wall_seconds"],
            **{name: summary[name]["mean"] for name in summary if name.startswith("metric/")}}


def first_past(curve: dict, target: float | None) -> dict | None:
    """Where a run's training mean return first reached `target`: {"return", "seconds", "env_steps", "cycle"}
    (`reached` false and the three None when it never did); None for a task without a target."""
    if target is None:
        return None
    for i, value in enumerate(curve["episode_return"]):
        if value is not None and value >= target:
            return {"return": target, "reached": True, "seconds": curve["seconds"][i],
                    "env_steps": curve["env_steps"][i], "cycle": curve["cycle"][i]}
    return {"return": target, "reached": False, "seconds": None, "env_steps": None, "cycle": None}


def gymnasium_threshold(task: str) -> float | None:
    """The reward threshold that Gymnasium registers for `task` (None where it registers none, or for a task that
    is not Gymnasium's)."""
    env_id = task.removeprefix("gym:") if task.startswith("gym:") else GYMNASIUM_IDS.get(task, f"{task}-v5")
    try:
        threshold = gymnasium.spec(env_id).reward_threshold
    except gymnasium.error.Error:
        return None
    return None if threshold is None else float(threshold)


def tail_mean(returns: list[float | None]) -> float | None:
    """The mean training return over the last tenth of the cycles in which episodes ended (a cycle in which none did
    has no return: e.g. a solved InvertedPendulum's episodes all last 1,000 steps and end together); None if none."""
    ended = [x for x in returns if x is not None and math.isfinite(x)]
    return statistics.fmean(ended[-max(1, len(ended) // 10):]) if ended else None


def return_at(run: dict, env_steps: int) -> float | None:
    """A run's return at `env_steps`: `tail_mean` of its cycles up to that point."""
    curve = run["curve"]
    return tail_mean([x for x, n in zip(curve["episode_return"], curve["env_steps"], strict=True) if n <= env_steps])


def compare_heads(runs: list[dict]) -> dict:
    """Per head: mean and sample std over seeds of the return at `env_steps`, the most env steps that every run
    reached, and how many of its runs ended at or above Gymnasium's reward threshold (`passed`, when the task has
    one), and, where each of its runs evaluated its final policy's mode (`--evaluate`), their mean and sample std
    (`mode`, with the mean of each task metric: a held InvertedPendulum or a solved reach ends few episodes while
    training, which leaves the training mean stale). `highest` and `runner_up`: the heads with the highest and
    second-highest means; `p_value`: Welch's t-test between their seeds; `better`: `highest` where p <
    `SIGNIFICANCE`, "level" where not, None where either has fewer than 2 seeds (no test) or the task has one head."""
    env_steps = min(run["env_steps"] for run in runs)
    heads = {}
    for run in runs:
        heads.setdefault(run["head"], []).append(return_at(run, env_steps))
    heads = {h: v for h, v in heads.items() if None not in v}
    stats = {h: {"mean": statistics.fmean(v), "std": statistics.stdev(v) if len(v) > 1 else 0.0, "seeds": len(v)}
             for h, v in heads.items()}
    threshold = gymnasium_threshold(runs[0]["task"])
    if threshold is not None:
        for head in stats:
            stats[head]["passed"] = sum(run["final_return"] is not None and run["final_return"] >= threshold
                                        for run in runs if run["head"] == head)
    for head in stats:
        evaluations = [run.get("evaluation") for run in runs if run["head"] == head]
        if all(evaluations):
            modes = [e["return"] for e in evaluations]
            metrics = {k: statistics.fmean(e[k] for e in evaluations)
                       for k in evaluations[0] if k.startswith("metric/")}
            stats[head]["mode"] = {"mean": statistics.fmean(modes),
                                   "std": statistics.stdev(modes) if len(modes) > 1 else 0.0, **metrics}
    ranked = sorted(stats, key=lambda h: stats[h]["mean"], reverse=True)
    highest, runner_up = ranked[:2] if len(ranked) > 1 else (None, None)
    p_value, better = None, None
    if highest is not None and min(len(heads[highest]), len(heads[runner_up])) > 1:
        p_value = welch_p_value(heads[highest], heads[runner_up])
        better = highest if p_value < SIGNIFICANCE else "level"
    return {"env_steps": env_steps, "gymnasium_threshold": threshold, "heads": stats, "highest": highest,
            "runner_up": runner_up, "p_value": p_value, "better": better}


def welch_p_value(a: list[float], b: list[float]) -> float:
    """Two-sided p-value of Welch's t-test (unequal variances) between two heads' seed returns; where neither
    varies (e.g. both solved CartPole at 500 every seed), 1 for equal means and 0 for unequal ones."""
    if statistics.pvariance(a) == statistics.pvariance(b) == 0.0:
        return 1.0 if statistics.fmean(a) == statistics.fmean(b) else 0.0
    return float(scipy.stats.ttest_ind(a, b, equal_var=False).pvalue)


def verdict(comparison: dict) -> str:
    """The comparison in words, for the figure and the table: "beta > gaussian (p=0.003)", "beta ~ gaussian: level
    (p=0.41)", "beta highest (too few seeds to test)", or "" for a task with one head."""
    highest, runner_up, p_value = comparison["highest"], comparison["runner_up"], comparison["p_value"]
    if highest is None:
        return ""
    if comparison["better"] is None:
        return f"{highest} highest (too few seeds to test)"
    if comparison["better"] == "level":
        return f"{highest} ~ {runner_up}: level (p={p_value:.2g})"
    return f"{highest} > {runner_up} (p={p_value:.2g})"


def plot_figure(figure: str, runs: list[dict], comparison: dict, path: str, where: str) -> None:
    """A panel per task (top row: against env steps, bottom row: against cycles): per head the mean over seeds
    with the min-max band as far as every seed ran, then each seed that ran further as a thin line of its own; the
    heads' comparison (`verdict`) under the task's name."""
    tasks = list(dict.fromkeys(r["task"] for r in runs))
    colours = {head: f"C{i}" for i, head in enumerate(dict.fromkeys(r["head"] for r in runs))}  # one per head
    fig, axes = plt.subplots(2, len(tasks), figsize=(3.4 * len(tasks), 5.8), squeeze=False)
    for col, task in enumerate(tasks):
        for row, x in enumerate(("env_steps", "cycle")):
            ax = axes[row][col]
            for head in dict.fromkeys(r["head"] for r in runs if r["task"] == task):
                curves = [r["curve"] for r in runs if r["task"] == task and r["head"] == head]
                length = min(len(c[x]) for c in curves)
                xs = curves[0][x][:length]
                ys = [[c["episode_return"][i] for c in curves if c["episode_return"][i] is not None]
                      for i in range(length)]
                keep = [i for i, y in enumerate(ys) if y]
                ax.plot([xs[i] for i in keep], [statistics.fmean(ys[i]) for i in keep], color=colours[head],
                        label=f"{head} ({len(curves)})")
                ax.fill_between([xs[i] for i in keep], [min(ys[i]) for i in keep], [max(ys[i]) for i in keep],
                                alpha=0.2, color=colours[head])
                for curve in curves:
                    beyond = [i for i in range(length - 1, len(curve[x])) if curve["episode_return"][i] is not None]
                    if len(beyond) > 1:
                        ax.plot([curve[x][i] for i in beyond], [curve["episode_return"][i] for i in beyond],
                                color=colours[head], linewidth=0.6, alpha=0.7)
            ax.set_xlabel("env steps" if x == "env_steps" else "cycles")
            ax.grid(alpha=0.3)
            if row == 0:
                ax.set_title(f"{task}\n{verdict(comparison[task])}", fontsize="small")
            if col == 0:
                ax.set_ylabel("mean episode return")
        axes[0][col].legend(fontsize="x-small", title="head (seeds)", title_fontsize="x-small")
    fig.suptitle(f"Fig. {figure}: {where}")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def write_figure(figure: str, runs: list[dict], missing: dict, config: dict, name: str, out: str,
                 made_on: tuple[dict, dict] | None = None) -> None:
    """Compare heads, plot, write `<out>/<name>.{png,json}` and print the table. made_on: (device, versions) of
    the machines that trained the runs (default: this one; a device field in which they differ lists each value)."""
    where, made_with = made_on or (device(), versions())
    comparison = {task: compare_heads([r for r in runs if r["task"] == task])
                  for task in dict.fromkeys(r["task"] for r in runs)}
    os.makedirs(out, exist_ok=True)
    record = {"benchmark": "paper_figures", "figure": figure, "device": where, "versions": made_with,
              "config": config, "comparison": comparison, "missing": missing, "runs": runs}
    # Not indented: Fig. 9's curves, diagnostics and task metrics indented pass 2 MiB.
    png = write_json(os.path.join(out, name), record, (".json", ".png"), indent=None) + ".png"
    kind = where["kind"]
    plot_figure(figure, runs, comparison, png, kind if isinstance(kind, str) else " and ".join(kind))
    table = [{"task": r["task"], "head": r["head"], "seed": r["seed"], "device": r["device"],
              "final": r["final_return"],
              "steps": r["env_steps"], "wall": r["wall_seconds"],
              "target": (r.get("target") or {}).get("seconds") or math.nan,
              "mode": (r.get("evaluation") or {}).get("return"),
              "metrics": metrics_text(r.get("evaluation") or {}) or "-"} for r in runs]
    print(markdown_table(table, [("task", "task", ""), ("head", "head", ""), ("seed", "seed", "d"),
                                 ("device", "device", ""), ("final", "final return", ".1f"),
                                 ("steps", "env steps", ",d"), ("wall", "wall s", ".0f"),
                                 ("target", "s to target", ".0f"), ("mode", "final policy's mode", ".1f"),
                                 ("metrics", "its task metrics", "")]))
    for task, result in comparison.items():
        print(f"{task} at {result['env_steps']:,} env steps: {verdict(result) or 'one head'}; " + ", ".join(
            f"{h} {s['mean']:.1f} +- {s['std']:.1f} ({s['seeds']} seed{'s' if s['seeds'] > 1 else ''}"
            + (f", {s['passed']} ended past Gymnasium's {result['gymnasium_threshold']:g})" if "passed" in s else ")")
            for h, s in result["heads"].items()))
        modes = [", ".join(filter(None, (f"{h} {s['mode']['mean']:.1f} +- {s['mode']['std']:.1f}",
                                         metrics_text(s["mode"]))))
                 for h, s in result["heads"].items() if "mode" in s]
        if modes:
            print("  final policies' modes: " + "; ".join(modes))
    if missing:
        print("missing: " + "; ".join(f"{t} ({why})" for t, why in missing.items()))
    print(f"wrote {png} and {png[:-4]}.json")


def metrics_text(values: dict) -> str:
    """The task metrics among `values` (`metric/<name>` keys) as "success 0.98, goal_distance 0.012"."""
    return ", ".join(f"{k.removeprefix('metric/')} {v:.3g}" for k, v in values.items() if k.startswith("metric/"))


def merge(figure: str, paths: list[str], name: str, out: str, replace: bool = False) -> None:
    """One figure from the runs recorded in earlier outputs of this script (`paths`, all of `figure`, made with
    the same versions of the packages that decide the numbers). Final returns and times to the targets are taken
    again from the curves (`tail_mean`, `first_past`), so that outputs of earlier versions of this script count
    alike. Outputs of different machines may be merged: the heads are compared at equal env steps, and each run
    keeps the name of the device that trained it (`device`), which its wall times belong to. A run (task, head,
    seed) found twice is refused, as it would count twice, unless `replace`: then the later path's run is kept and
    the figure lists the earlier one as `replaced`."""
    records = []
    for path in paths:
        with open(path) as file:
            records.append(json.load(file))
        if records[-1]["figure"] != figure:
            raise SystemExit(f"{path} holds Fig. {records[-1]['figure']}, not Fig. {figure}: merge one figure at "
                             "a time (--figure).")
        first, this = deciding(records[0]["versions"]), deciding(records[-1]["versions"])
        # compared on the packages both name: results written before warp-lang was recorded still merge
        if any(first[package] != this[package] for package in first.keys() & this.keys()):
            raise SystemExit(f"{path} was made with {this}, {paths[0]} with {first}: merge runs of one set of "
                             "versions.")
    runs, seen, replaced = {}, {}, []
    for path, record in zip(paths, records, strict=True):
        for run in record["runs"]:
            key = (run["task"], run["head"], run["seed"])
            if key in seen:
                if not replace:
                    raise SystemExit(f"{' '.join(map(str, key))} is in {seen[key]} and in {path}: a run merged "
                                     "twice would count twice; give each run once, or pass --replace to keep the "
                                     "later one.")
                replaced.append({"task": key[0], "head": key[1], "seed": key[2], "dropped": seen[key], "kept": path})
            seen[key] = path
            runs[key] = {**run, "device": run.get("device", record["device"]["kind"]),
                         "final_return": tail_mean(run["curve"]["episode_return"]),
                         "target": first_past(run["curve"], TARGETS.get(run["task"]))}
    missing = {task: why for record in records for task, why in record["missing"].items()}
    # The configs of the outputs merged, by file name; an output that was itself a merge lends its own entries.
    config = {"merged": {}, "replaced": replaced}
    for path, record in zip(paths, records, strict=True):
        config["merged"] |= record["config"].get("merged") or {os.path.basename(path): record["config"]}
        config["replaced"] = record["config"].get("replaced", []) + config["replaced"]
    # A field's values over the outputs; an output that was itself a merge of unlike devices holds a list.
    made_on = {}
    for key in records[0]["device"]:
        values = []
        for record in records:
            value = record["device"][key]
            values += value if isinstance(value, list) else [value]
        values = list(dict.fromkeys(values))
        made_on[key] = values[0] if len(values) == 1 else values
    write_figure(figure, list(runs.values()), missing, config, name, out, (made_on, records[0]["versions"]))


def deciding(made_with: dict) -> dict:
    """The versions that decide a figure's numbers: all of `versions()` but Brax's, which this script never runs
    (not installed: None, written "absent" by earlier versions of this script)."""
    return {package: None if version == "absent" else version for package, version in made_with.items()
            if package != "brax"}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--figure", choices=[*FIGURES, "all"], default="all")
    parser.add_argument("--tasks", nargs="*", help="only these tasks (default: all of the figure's)")
    parser.add_argument("--heads", nargs="*", help="only these heads (default: each task's)")
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    parser.add_argument("--minutes", type=float, default=4.0, help="wall-clock cap per run (default: 4)")
    parser.add_argument("--evaluate", type=int, default=128, metavar="EPISODES",
                        help="evaluate each run's final policy (its mode) on this many episodes; 0: none "
                             "(default: 128)")
    parser.add_argument("--parallel", type=int, default=1, metavar="N",
                        help="train N runs at a time, each in its own process, spread over the GPUs (default: 1, "
                             "one after another in this process)")
    parser.add_argument("--smoke", action="store_true", help="tiny sizes, for a CPU check of the script")
    parser.add_argument("--name", default=None, help="results name (default: paper_fig<N>_<platform>)")
    parser.add_argument("--out", default=os.path.join(RESULTS, "paper_figures"),
                        help="folder for the PNG and JSON (default: benchmarks/results/paper_figures)")
    parser.add_argument("--merge", nargs="+", metavar="JSON",
                        help="train nothing: combine the runs of these earlier outputs into one figure")
    parser.add_argument("--replace", action="store_true",
                        help="with --merge: a run found in several outputs is taken from the last of them")
    parser.add_argument("overrides", nargs="*", help="key.sub=value overrides for every run")
    args = parser.parse_args()
    extra = [*(SMOKE if args.smoke else []), *args.overrides]
    if args.parallel > 1 or args.merge:
        # This process trains nothing: it must not take most of each GPU's memory from the processes that do.
        os.environ["XLA_PYTHON_CLIENT_PREALLOCATE"] = "false"
    platform = device()["platform"]
    if args.parallel < 1:
        raise SystemExit(f"--parallel must be >= 1, got {args.parallel}.")
    if args.merge:
        if args.figure == "all":
            raise SystemExit("--merge combines one figure: name it with --figure 8 or --figure 9.")
        merge(args.figure, args.merge, args.name or f"paper_fig{args.figure}_{platform}", args.out, args.replace)
        return
    for figure in FIGURES if args.figure == "all" else [args.figure]:
        jobs, missing = figure_jobs(figure, args.tasks, args.heads, args.seeds)
        if args.parallel > 1:
            runs, failed = train_in_processes(figure, jobs, args)
            if failed and not runs:
                raise SystemExit("Every run failed:\n" + "\n".join(f"{job}: {why}" for job, why in failed.items()))
            missing |= failed
            for run in runs:
                report(run)
        else:
            runs = []
            with tempfile.TemporaryDirectory() as root:
                for job in jobs:
                    runs.append(train_one(*job, args.minutes, extra, root, args.evaluate))
                    report(runs[-1])
        if not runs:
            continue
        families = {r["config"]: to_dict(load_config(r["config"], extra)) for r in runs}
        config = {"seeds": args.seeds, "minutes": args.minutes, "overrides": extra, "families": families,
                  "parallel": args.parallel}
        write_figure(figure, runs, missing, config, args.name or f"paper_fig{figure}_{platform}", args.out)


def report(run: dict) -> None:
    print(f"{run['task']} {run['head']} seed {run['seed']}: return {run['final_return']} after "
          f"{run['env_steps']:,} steps, {run['wall_seconds']:.0f} s", flush=True)


def figure_jobs(figure: str, tasks: list[str] | None, heads: list[str] | None,
                seeds: list[int]) -> tuple[list[tuple[str, str, str, int]], dict[str, str]]:
    """The figure's runs to make, (task, family config, head, seed), limited to `tasks` and `heads` when given,
    and the tasks that cannot run here with the reason."""
    jobs, missing = [], {}
    for task, config, task_heads in FIGURES[figure]:
        if tasks and task not in tasks:
            continue
        if task not in list_tasks() and not is_gymnasium(task):
            missing[task] = "not registered"
            continue
        jobs += [(task, config, head, seed) for head in task_heads if not heads or head in heads for seed in seeds]
    return jobs, missing


def gpu_slots(parallel: int, ordinals: list[int], visible: str | None) -> list[str | None]:
    """The `CUDA_VISIBLE_DEVICES` of each of `parallel` process slots, spread round-robin over the GPUs that this
    process sees (`ordinals`, JAX's local hardware ids; `visible`, this process's own `CUDA_VISIBLE_DEVICES`, which
    those ids index into where it is set). None for every slot where there is no GPU."""
    if not ordinals:
        return [None] * parallel
    names = [name.strip() for name in visible.split(",")] if visible else [str(o) for o in ordinals]
    return [names[ordinals[slot % len(ordinals)]] for slot in range(parallel)]


def train_in_processes(figure: str, jobs: list[tuple[str, str, str, int]],
                       args: argparse.Namespace) -> tuple[list[dict], dict[str, str]]:
    """Each run in a process of its own (this script for that one run), `args.parallel` at a time, as one GPU
    trains several small models faster together than one after another. On a host of several GPUs the processes
    are spread over them (`gpu_slots`: each process sees one GPU). JAX in each process allocates device memory as it
    needs it instead of most of it up front. Returns the runs and, for each run that failed, the last lines of its
    log."""
    environment = {**os.environ, "XLA_PYTHON_CLIENT_PREALLOCATE": "false"}
    ordinals = [d.local_hardware_id for d in jax.local_devices() if d.platform == "gpu"]
    slots = queue.Queue()
    for gpu in gpu_slots(args.parallel, ordinals, os.environ.get("CUDA_VISIBLE_DEVICES")):
        slots.put(gpu)
    with tempfile.TemporaryDirectory() as folder:
        def one(index: int, job: tuple[str, str, str, int]) -> tuple[int, int]:
            task, _, head, seed = job
            command = [sys.executable, os.path.abspath(__file__), "--figure", figure, "--tasks", task, "--heads",
                       head, "--seeds", str(seed), "--minutes", str(args.minutes), "--evaluate", str(args.evaluate),
                       *(["--smoke"] if args.smoke else []), "--out", folder, "--name", f"run{index}",
                       *args.overrides]
            gpu = slots.get()
            try:
                with open(os.path.join(folder, f"run{index}.log"), "w") as log:
                    return index, subprocess.run(command, stdout=log, stderr=subprocess.STDOUT, env=environment | (
                        {} if gpu is None else {"CUDA_VISIBLE_DEVICES": gpu})).returncode
            finally:
                slots.put(gpu)

        with concurrent.futures.ThreadPoolExecutor(args.parallel) as pool:
            codes = dict(pool.map(lambda item: one(*item), enumerate(jobs)))
        runs, failed = [], {}
        for index, (task, _, head, seed) in enumerate(jobs):
            if codes[index] == 0:
                with open(os.path.join(folder, f"run{index}.json")) as file:
                    runs += json.load(file)["runs"]
            else:
                with open(os.path.join(folder, f"run{index}.log")) as file:
                    tail = " | ".join(file.read().strip().splitlines()[-3:])
                failed[f"{task} {head} seed {seed}"] = f"the run failed (exit code {codes[index]}): {tail}"
    return runs, failed

if __name__ == "__main__":
    main()
