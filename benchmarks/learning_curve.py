"""A training run's learning curve: PPO on a task, one JSON row per cycle and a PNG of return and task metrics.

The JSON and PNG are rewritten after every cycle, and `--minutes` stops the run after that much wall time, so a
run cut short by a time limit still leaves its curve.

    python benchmarks/learning_curve.py --task ShadowHandReach --num-envs 2048 --cycles 200 --minutes 6  # GPU
    python benchmarks/learning_curve.py --task CartPole --num-envs 16 --cycles 30                          # CPU
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import time

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from common import RESULTS, markdown_table, write_results  # noqa: E402

from angora_jax.envs import make  # noqa: E402
from angora_jax.ppo import NetworkConfig, PPOConfig  # noqa: E402
from angora_jax.ppo.train import training_cycles  # noqa: E402


def plot(history: list[dict], title: str, path: str) -> None:
    """Episode return and every `metric/*` against env steps, one panel each."""
    keys = ["episode_return"] + sorted(k for k in history[0] if k.startswith("metric/"))
    fig, axes = plt.subplots(1, len(keys), figsize=(4 * len(keys), 3.2), squeeze=False)
    steps = [row["env_steps"] for row in history]
    for ax, key in zip(axes[0], keys, strict=True):
        ax.plot(steps, [row[key] for row in history], marker=".")
        ax.set_xlabel("env steps")
        ax.set_title(key.removeprefix("metric/"))
        ax.grid(alpha=0.3)
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--task", default="CartPole")
    parser.add_argument("--model", default="simple")
    parser.add_argument("--head", default="auto")
    parser.add_argument("--num-envs", type=int, default=16)
    parser.add_argument("--cycles", type=int, default=30)
    parser.add_argument("--rollout-length", type=int, default=32)
    parser.add_argument("--minibatches", type=int, default=4)
    parser.add_argument("--epochs", type=int, default=4)
    parser.add_argument("--learning-rate", type=float, default=3e-4)
    parser.add_argument("--init-log-std", type=float, default=-1.0)
    parser.add_argument("--entropy-coef", type=float, default=0.01)
    parser.add_argument("--gamma", type=float, default=0.99)
    parser.add_argument("--options", default="{}", help="task options as JSON, e.g. '{\"touch\": false}'")
    parser.add_argument("--minutes", type=float, default=None, help="stop after this much wall time")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default=None, help="JSON path; the PNG goes beside it")
    args = parser.parse_args()

    config = PPOConfig(
        seed=args.seed, num_cycles=args.cycles, num_envs=args.num_envs,
        rollout_length=args.rollout_length, chunk_length=16, num_epochs=args.epochs,
        minibatch_size=args.num_envs * args.rollout_length // args.minibatches, learning_rate=args.learning_rate,
        head=args.head, init_log_std=args.init_log_std, entropy_coef=args.entropy_coef, gamma=args.gamma,
        network=NetworkConfig(name=args.model),
    )
    options = json.loads(args.options)
    settings = {"task": args.task, "options": options, **dataclasses.asdict(config)}
    start, rows, path, png = time.perf_counter(), [], None, None
    for _, metrics in training_cycles(config, make(args.task, **options)):
        rows.append({k: v for k, v in metrics.items() if isinstance(v, int | float)})
        settings["wall_seconds"] = time.perf_counter() - start
        path = write_results(f"learning_curve_{args.task}", settings, rows, args.out)
        png = os.path.splitext(path)[0] + ".png"
        plot(rows, f"{args.task}, {args.model}, {args.num_envs} envs", png)
        print(f"cycle {len(rows)}: {metrics['env_steps']:,} steps, return {metrics['episode_return']:.2f}", flush=True)
        if args.minutes is not None and time.perf_counter() - start > 60 * args.minutes:
            break
    columns = [("cycle", "cycle", "d"), ("env_steps", "env steps", ",d"), ("seconds", "cycle s", ".1f"),
               ("episode_return", "return", ".2f")]
    columns += [(k, k.removeprefix("metric/"), ".3f") for k in sorted(rows[0]) if k.startswith("metric/")]
    shown = rows[:: max(1, len(rows) // 12)]
    print(markdown_table(shown if shown[-1] is rows[-1] else [*shown, rows[-1]], columns))
    print(f"wrote {path} and {png} (results folder: {RESULTS})")


if __name__ == "__main__":
    main()
