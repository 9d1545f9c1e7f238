"""A training run's learning curve: PPO on a task, one JSON row per cycle and a PNG of return and task metrics.

The JSON is rewritten after every cycle and the PNG every 30 s (plotting costs more than a GPU cycle), and
`--minutes` stops the run after that much wall time, so a run cut short by a time limit still leaves its curve.
`--target metric/success=0.8` records the first cycle whose value reaches the bar (env steps and wall seconds,
compile included: time to solve) and `--stop-at-target` ends the run there. Compiled programs are kept in the
persistent compilation cache, as `angora-jax train` keeps them (`angora_jax.experiment.compilation_cache`;
ANGORA_JAX_CACHE=off to compile everything): a second run of the same settings reads them, and its JSON records how
many programs were read from the cache and how many compiled.

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
from common import markdown_table, write_results  # noqa: E402

from angora_jax.envs import make  # noqa: E402
from angora_jax.experiment import compilation_cache  # noqa: E402
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


def parse_target(text: str | None) -> tuple[str | None, float]:
    """`NAME=VALUE` -> (NAME, VALUE); None -> (None, nan). Exits with a usage message when malformed."""
    if text is None:
        return None, float("nan")
    name, _, value = text.partition("=")
    try:
        return name, float(value)
    except ValueError:
        raise SystemExit(f"--target must be NAME=VALUE, e.g. metric/success=0.8; got {text!r}") from None


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
    parser.add_argument("--width", type=int, default=None, help="hidden width of the network (its default if unset)")
    parser.add_argument("--init-log-std", type=float, default=-1.0)
    parser.add_argument("--entropy-coef", type=float, default=0.01)
    parser.add_argument("--gamma", type=float, default=0.99)
    parser.add_argument("--options", default="{}", help="task options as JSON, e.g. '{\"touch\": false}'")
    parser.add_argument("--minutes", type=float, default=None, help="stop after this much wall time")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--target", default=None, help="NAME=VALUE, e.g. metric/success=0.8: record time to reach it")
    parser.add_argument("--stop-at-target", action="store_true", help="stop once --target is reached")
    parser.add_argument("--out", default=None, help="JSON path; the PNG goes beside it")
    args = parser.parse_args()

    config = PPOConfig(
        seed=args.seed, num_cycles=args.cycles, num_envs=args.num_envs,
        rollout_length=args.rollout_length, chunk_length=16, num_epochs=args.epochs,
        minibatch_size=args.num_envs * args.rollout_length // args.minibatches, learning_rate=args.learning_rate,
        head=args.head, init_log_std=args.init_log_std, entropy_coef=args.entropy_coef, gamma=args.gamma,
        network=NetworkConfig(name=args.model, width=args.width),
    )
    target_name, target_value = parse_target(args.target)
    options = json.loads(args.options)
    settings = {"task": args.task, "options": options, "target": args.target, **dataclasses.asdict(config)}
    settings["compilation_cache_dir"] = str(compilation_cache.enable())
    start, rows, path, plotted = time.perf_counter(), [], None, 0.0
    title = f"{args.task}, {args.model}, {args.num_envs} envs, seed {args.seed}"
    for _, metrics in training_cycles(config, make(args.task, **options)):
        now = time.perf_counter() - start
        rows.append({k: v for k, v in metrics.items() if isinstance(v, int | float)})
        if len(rows) == 1:
            settings["compilation_cache"] = compilation_cache.counts()
        settings["wall_seconds"] = now
        reached = target_name is not None and metrics.get(target_name, float("nan")) >= target_value
        if reached and "solved" not in settings:
            settings["solved"] = {"cycle": len(rows), "env_steps": metrics["env_steps"], "wall_seconds": now}
        path = write_results(f"learning_curve_{args.task}", settings, rows, args.out, study="reach")
        if now - plotted > 30:
            plot(rows, title, os.path.splitext(path)[0] + ".png")
            plotted = now
        print(f"cycle {len(rows)}: {metrics['env_steps']:,} steps, return {metrics['episode_return']:.2f}", flush=True)
        out_of_time = args.minutes is not None and now > 60 * args.minutes
        if out_of_time or (reached and args.stop_at_target):
            break
    png = os.path.splitext(path)[0] + ".png"
    plot(rows, title, png)
    if target_name is not None:
        print(f"target {args.target}: {settings.get('solved', 'not reached')}")
    columns = [("cycle", "cycle", "d"), ("env_steps", "env steps", ",d"), ("seconds", "cycle s", ".1f"),
               ("episode_return", "return", ".2f")]
    columns += [(k, k.removeprefix("metric/"), ".3f") for k in sorted(rows[0]) if k.startswith("metric/")]
    shown = rows[:: max(1, len(rows) // 12)]
    print(markdown_table(shown if shown[-1] is rows[-1] else [*shown, rows[-1]], columns))
    print(f"wrote {path} and {png}")


if __name__ == "__main__":
    main()
