"""Time to solve: wall time and env steps until a task metric first reaches a bar, over several seeds.

Runs `learning_curve.py` once per seed (a fresh process each, so every seed pays its own compile, as a user would)
with `--target` and `--stop-at-target`, then reports per seed and the mean and spread (sample std, min, max).
Unsolved seeds count as not solved within `--minutes`; the mean is over solved seeds only and says how many.
Every argument after `--` goes to learning_curve.py unchanged.

    # GPU (reach, the shipped configs/shadow_reach.yaml settings; success: all fingertips within 2 cm at episode end)
    python benchmarks/time_to_solve.py --seeds 0 1 2 --target metric/success=0.8 --minutes 3 -- \
        --task ShadowHandReach --num-envs 4096 --rollout-length 16 --minibatches 16 --width 256 --entropy-coef 0
    # CPU smoke
    python benchmarks/time_to_solve.py --seeds 0 1 --target episode_return=30 --minutes 1 -- --task CartPole
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile

from common import markdown_table, write_results

HERE = os.path.dirname(os.path.abspath(__file__))


def run_seed(seed: int, target: str, minutes: float, extra: list[str], folder: str) -> dict:
    """One learning_curve.py run; returns its config record (with `solved` when the bar was reached)."""
    out = os.path.join(folder, f"seed{seed}.json")
    command = [sys.executable, os.path.join(HERE, "learning_curve.py"), "--seed", str(seed), "--target", target,
               "--stop-at-target", "--minutes", str(minutes), "--cycles", "100000", "--out", out, *extra]
    subprocess.run(command, check=True)
    with open(out) as f:
        record = json.load(f)
    last = record["results"][-1]
    return {"seed": seed, **record["config"], "final_env_steps": last["env_steps"]}


def spread(values: list[float]) -> dict[str, float | None]:
    """Mean, sample std, min and max (None where undefined)."""
    if not values:
        return {"mean": None, "std": None, "min": None, "max": None}
    std = statistics.stdev(values) if len(values) > 1 else None
    return {"mean": statistics.fmean(values), "std": std, "min": min(values), "max": max(values)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--target", required=True, help="NAME=VALUE, e.g. metric/success=0.8")
    parser.add_argument("--minutes", type=float, default=5.0, help="give up on a seed after this much wall time")
    parser.add_argument("--out", default=None, help="JSON path (default: benchmarks/results/reach/)")
    parser.add_argument("--curves", default=None, help="folder to keep each seed's curve (JSON + PNG) in")
    args, extra = parser.parse_known_args()
    extra = [a for a in extra if a != "--"]
    with tempfile.TemporaryDirectory() as scratch:
        folder = args.curves or scratch
        os.makedirs(folder, exist_ok=True)
        runs = [run_seed(seed, args.target, args.minutes, extra, folder) for seed in args.seeds]
    rows = []
    for run in runs:
        solved = run.get("solved") or {}
        rows.append({"seed": run["seed"], "solved": bool(solved), "env_steps": solved.get("env_steps"),
                     "wall_seconds": solved.get("wall_seconds"), "steps_run": run["final_env_steps"]})
    done = [r for r in rows if r["solved"]]
    summary = {"target": args.target, "seeds": len(rows), "solved": len(done),
               "env_steps": spread([r["env_steps"] for r in done]),
               "wall_seconds": spread([r["wall_seconds"] for r in done])}
    task = runs[0]["task"]
    settings = {"target": args.target, "minutes_per_seed": args.minutes, "learning_curve_args": extra,
                "run_config": {k: v for k, v in runs[0].items() if k not in ("seed", "solved", "final_env_steps")},
                "summary": summary}
    path = write_results(f"time_to_solve_{task}", settings, rows, args.out, study="reach")
    print(markdown_table(rows, [("seed", "seed", "d"), ("solved", "solved", ""), ("env_steps", "env steps", ",d"),
                                ("wall_seconds", "wall s (incl. compile)", ".0f"), ("steps_run", "steps run", ",d")]))
    steps, wall = summary["env_steps"], summary["wall_seconds"]
    if done:
        print(f"{len(done)}/{len(rows)} seeds reached {args.target}: mean {steps['mean']:,.0f} env steps, "
              f"{wall['mean']:.0f} s wall (min {wall['min']:.0f}, max {wall['max']:.0f})")
    else:
        print(f"no seed reached {args.target} within {args.minutes} min")
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
