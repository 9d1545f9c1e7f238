"""How does a trained policy hold up as domain randomization widens? Each run's policy is evaluated on the same held-out
episodes (deterministic actions, the batched path of `angora-jax evaluate --path batched`) under a reference
randomization scaled by each width:

    python benchmarks/robustness.py runs/ihom runs/ihom_randomized:best --label plain --label randomized \
        --widths 0 0.5 1 1.5 2 --episodes 480

Width w scales each range of the reference about the nominal model (a factor of 1): a scale range [lo, hi] becomes
[1 - w (1 - lo), 1 + w (hi - 1)] (its minimum clipped at 0, or at 0.05 for keys that must stay positive), a noise
standard deviation s becomes w s, a delay range [lo, hi] of policy steps [round(w lo), round(w hi)]. Width 0 is the
unrandomized task (zero-width ranges give it bit for bit), width 1
the reference itself. The reference is `env.options.randomization` of configs/shadow_ihom_randomized.yaml unless
`--ranges` gives a YAML or JSON mapping (a file or inline text); keys of the cube are left out for tasks without
one.

`--each` also evaluates every range of the reference alone (the others off), scaled by each width as above: which
factor costs the policy most. Those rows and lines are labelled "<run> (<key> only)".

The metric (default: the cube's `metric/goals_reached`, CGR; reach's `metric/success`; else the episode return) is
tabled per run and width as mean, median and standard error over episodes. Writes JSON with the device, versions and
configuration (`results/robustness/robustness_<task>_<platform>.json` unless `--out`), and a PNG beside it: the
metric's mean against the width, one line per run, with a band of one standard error.
"""

from __future__ import annotations

import argparse
import json
import textwrap
from pathlib import Path

import matplotlib
import yaml

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from common import markdown_table, write_results  # noqa: E402

from angora_jax.envs.randomization import CUBE_KEYS, DELAYS, NOISES, POSITIVE_SCALES  # noqa: E402
from angora_jax.experiment.agent import run_source  # noqa: E402
from angora_jax.experiment.config import load_config  # noqa: E402
from angora_jax.experiment.evaluation import evaluate  # noqa: E402
from angora_jax.experiment.run_dir import read_run_config  # noqa: E402

REFERENCE_CONFIG = "shadow_ihom_randomized"
# Widths past 1 can take a scale's minimum below 0; a quantity that must stay positive (the cube's mass and size)
# keeps at least this fraction of its nominal value.
POSITIVE_FLOOR = 0.05
METRICS = ("metric/goals_reached", "metric/success")


def scaled(ranges: dict, width: float) -> dict:
    """The randomization `ranges` (`randomization` option keys) scaled by `width` about the nominal model (module
    docstring); width 0 gives zero-width ranges at 1, zero noise and no delay."""
    out = {}
    for key, value in ranges.items():
        if key in NOISES:
            out[key] = width * float(value)
        elif key in DELAYS:
            out[key] = [round(width * value[0]), round(width * value[1])]
        else:
            # w x + (1 - w), the same as 1 - w (1 - x), is exact at widths 0 (1) and 1 (the reference's x).
            floor = POSITIVE_FLOOR if key in POSITIVE_SCALES else 0.0
            lo = max(width * float(value[0]) + (1 - width), floor)
            out[key] = [lo, max(width * float(value[1]) + (1 - width), lo)]
    return out


def reference_ranges(text: str | None) -> tuple[dict, str]:
    """The reference ranges and where they came from: `text` as a YAML/JSON file or inline mapping, or the ranges of
    configs/shadow_ihom_randomized.yaml when None."""
    if text is None:
        return dict(load_config(REFERENCE_CONFIG).env.options["randomization"]), f"configs/{REFERENCE_CONFIG}.yaml"
    source = Path(text).read_text() if Path(text).is_file() else text
    ranges = yaml.safe_load(source)
    if not isinstance(ranges, dict):
        raise SystemExit(f"--ranges must be a mapping of randomization keys to ranges, got {ranges!r}.")
    return ranges, text


def plot(rows: list[dict], labels: list[str], metric: str, title: str, path: Path) -> None:
    figure, axis = plt.subplots(figsize=(7, 4.5))
    for i, label in enumerate(labels):
        mine = [row for row in rows if row["run"] == label]
        widths = [row["width"] for row in mine]
        mean = [row["mean"] for row in mine]
        stderr = [row["stderr"] for row in mine]
        # Error bars rather than a band: a comparison at one width has no band to draw.
        axis.errorbar(widths, mean, yerr=stderr, marker="o", capsize=4, color=f"C{i}", label=label)
    axis.set_xlabel("randomization width (1: the reference ranges)")
    axis.set_ylabel(f"{metric}, mean +- s.e.")
    # A run folder or config path can be long; wrapped, the title stays inside the figure.
    axis.set_title(textwrap.fill(title, 90), fontsize=9)
    axis.grid(alpha=0.3)
    axis.legend()
    figure.tight_layout()
    figure.savefig(path, dpi=120)
    plt.close(figure)


def main(argv: list[str] | None = None) -> dict:
    """Run the comparison; returns the written record."""
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("runs", nargs="+", metavar="RUN_DIR[:CHECKPOINT]",
                        help="trained runs, each at its best checkpoint unless :latest or :<cycle> follows")
    parser.add_argument("--label", action="append", default=[],
                        help="a name per run, in order (repeat; default: the run directory's name)")
    parser.add_argument("--widths", type=float, nargs="+", default=[0.0, 0.5, 1.0, 1.5, 2.0])
    parser.add_argument("--episodes", type=int, default=480, help="held-out episodes per run and width")
    parser.add_argument("--seed", type=int, default=0, help="the episodes' seed, the same for every run and width")
    parser.add_argument("--ranges", default=None,
                        help=f"reference randomization: a YAML/JSON file or inline mapping (default: "
                             f"{REFERENCE_CONFIG}'s env.options.randomization)")
    parser.add_argument("--each", action="store_true",
                        help="also evaluate each range of the reference alone, the others off: which costs most")
    parser.add_argument("--metric", default=None,
                        help=f"per-episode quantity to compare (default: the first of {METRICS} the task has, else "
                             "episode_return)")
    parser.add_argument("--out", default=None,
                        help="JSON path (default: results/robustness/robustness_<task>_<platform>.json); the PNG goes "
                             "beside it")
    args = parser.parse_args(argv)
    if args.label and len(args.label) != len(args.runs):
        parser.error(f"give one --label per run: {len(args.runs)} runs, {len(args.label)} labels.")
    if any(not w >= 0 for w in args.widths):
        parser.error(f"widths must be >= 0, got {args.widths}.")
    runs = [run_source(spec) for spec in args.runs]
    labels = args.label or [Path(run_dir).name for run_dir, _ in runs]
    configs = [read_run_config(run_dir) for run_dir, _ in runs]
    tasks = {config.env.task for config in configs}
    if len(tasks) != 1:
        parser.error(f"the runs must share one task, got {sorted(tasks)}.")
    task = tasks.pop()
    reference, source = reference_ranges(args.ranges)
    if task != "ShadowHandCube":
        dropped = [key for key in reference if key in CUBE_KEYS]
        reference = {key: value for key, value in reference.items() if key not in CUBE_KEYS}
        if dropped:
            print(f"{task} has no cube: left out of the reference: {dropped}")

    # None: all of the reference's ranges together; a key: that range alone.
    subsets = [None, *(reference if args.each else [])]
    rows, metric, lines = [], args.metric, []
    for (run_dir, checkpoint), label, config in zip(runs, labels, configs, strict=True):
        for only in subsets:
            line = label if only is None else f"{label} ({only} only)"
            lines.append(line)
            for width in args.widths:
                ranges = scaled(reference if only is None else {only: reference[only]}, width)
                result = evaluate(run_dir, checkpoint, args.episodes, seed=args.seed, save=False, path="batched",
                                  env_overrides=[f"randomization={json.dumps(ranges)}"])
                if metric is None:
                    metric = next((name for name in METRICS if name in result.episodes), "episode_return")
                stats, returns = result.summary[metric], result.summary["episode_return"]
                rows.append({
                    "run": line, "run_dir": str(run_dir), "checkpoint": checkpoint, "cycle": result.meta["cycle"],
                    "trained_randomization": config.env.options.get("randomization"), "only": only,
                    "width": width, "ranges": ranges, "metric": metric, "mean": stats["mean"],
                    "median": stats["median"], "stderr": stats["stderr"], "std": stats["std"],
                    "return_mean": returns["mean"], "return_stderr": returns["stderr"],
                    "length_mean": result.summary["episode_length"]["mean"], "physics": result.meta["physics"],
                    "wall_seconds": result.meta["wall_seconds"], "per_episode": result.episodes[metric].tolist(),
                    "per_episode_return": result.episodes["episode_return"].tolist(),
                })
                print(f"{line} width {width:g}: {metric} {stats['mean']:.4g} +- {stats['stderr']:.3g} "
                      f"({result.meta['wall_seconds']:.1f} s)", flush=True)

    config = {"task": task, "metric": metric, "widths": args.widths, "episodes": args.episodes, "seed": args.seed,
              "actions": "mode (deterministic)", "path": "batched", "reference_ranges": reference,
              "reference_source": source, "each": args.each,
              "scaling": "scale [lo, hi] -> [max(1 - w (1 - lo), floor), 1 + w (hi - 1)], floor 0 (0.05 for "
                         f"{list(POSITIVE_SCALES)}); noise s -> w s; delay [lo, hi] -> [round(w lo), round(w hi)]",
              "runs": [{"label": label, "run_dir": str(run_dir), "checkpoint": checkpoint}
                       for (run_dir, checkpoint), label in zip(runs, labels, strict=True)]}
    path = Path(write_results(f"robustness_{task}", config, rows, args.out, study="robustness"))
    print(markdown_table(rows, [("run", "run", "s"), ("width", "width", "g"), ("mean", f"{metric} mean", ".3f"),
                                ("median", "median", ".3g"), ("stderr", "s.e.", ".3f"),
                                ("return_mean", "return mean", ".4g")]))
    plot(rows, lines, metric, f"{task}: {args.episodes} held-out episodes per point, reference {source}",
         path.with_suffix(".png"))
    print(f"Written: {path} and {path.with_suffix('.png')}")
    return json.loads(path.read_text())


if __name__ == "__main__":
    main()
