"""Training throughput: environment steps consumed per wall second by the compiled PPO cycle, against the raw
batched env-step rate at the same batch size (random actions, same `lax.scan` over `vmap(env.step)`).

    python benchmarks/train_throughput.py --task CartPole --num-envs 64 256 --model simple lstm

Prints a Markdown table and writes JSON (device, versions, config, numbers) under benchmarks/results/. Compile time
is measured separately (ahead-of-time lowering + compilation) and excluded from the rates.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import importlib.metadata
import json
import pathlib
import platform
import time

import jax

import angora_jax.envs.classic  # noqa: F401  (registers the classic tasks)
from angora_jax.envs.core import Env
from angora_jax.envs.registry import make
from angora_jax.ppo import NetworkConfig, PPOConfig, make_cycle

RESULTS = pathlib.Path(__file__).parent / "results"
PACKAGES = ("jax", "jaxlib", "flax", "optax", "distrax", "mujoco", "mujoco-mjx")


def random_actions(env: Env, key: jax.Array, num_envs: int) -> jax.Array:
    spec = env.action_spec
    if spec.discrete:
        return jax.random.randint(key, (num_envs,), 0, spec.num_actions)
    return jax.random.uniform(key, (num_envs, spec.size), minval=spec.low, maxval=spec.high)


def time_compiled(fn, arg, repeats: int, next_arg=lambda out: out) -> tuple[float, float]:
    """Compile the jitted `fn` for `arg` ahead of time, then time `repeats` chained calls, each fed
    `next_arg(previous output)`; returns (compile seconds, seconds per call)."""
    start = time.perf_counter()
    compiled = fn.lower(arg).compile()
    compile_seconds = time.perf_counter() - start
    out = jax.block_until_ready(compiled(arg))  # warm-up: first-call allocations
    start = time.perf_counter()
    for _ in range(repeats):
        out = compiled(next_arg(out))
    jax.block_until_ready(out)
    return compile_seconds, (time.perf_counter() - start) / repeats


def raw_env_rate(env: Env, num_envs: int, steps: int, repeats: int) -> dict[str, float]:
    """Env steps per second of a jitted scan of `steps` batched random-action steps."""

    @jax.jit
    def run(carry):
        state, key = carry

        def body(state, key):
            return jax.vmap(env.step)(state, random_actions(env, key, num_envs)), None

        key, scan_key = jax.random.split(key)
        state, _ = jax.lax.scan(body, state, jax.random.split(scan_key, steps))
        return state, key

    state = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.key(0), num_envs))
    compile_seconds, seconds = time_compiled(run, (state, jax.random.key(1)), repeats)
    return {"compile_seconds": compile_seconds, "steps_per_second": num_envs * steps / seconds}


def train_rate(env: Env, config: PPOConfig, repeats: int) -> dict[str, float]:
    """Env steps consumed per second by the full cycle (rollout + GAE + all minibatch updates)."""
    init, cycle = make_cycle(env, None, config)
    state = init(jax.random.key(config.seed))
    compile_seconds, seconds = time_compiled(cycle, state, repeats, next_arg=lambda out: out[0])
    return {"compile_seconds": compile_seconds, "steps_per_second": config.num_envs * config.rollout_length / seconds}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="CartPole")
    parser.add_argument("--num-envs", type=int, nargs="+", default=[64])
    parser.add_argument("--model", nargs="+", default=["simple", "lstm"])
    parser.add_argument("--rollout-length", type=int, default=128)
    parser.add_argument("--chunk-length", type=int, default=16)
    parser.add_argument("--epochs", type=int, default=3)
    parser.add_argument("--minibatches", type=int, default=4, help="minibatches per epoch")
    parser.add_argument("--repeats", type=int, default=5, help="timed cycles per configuration")
    args = parser.parse_args()

    env = make(args.task)
    rows = []
    for num_envs in args.num_envs:
        raw = raw_env_rate(env, num_envs, args.rollout_length, args.repeats)
        for model in args.model:
            config = PPOConfig(
                task=args.task,
                num_envs=num_envs,
                rollout_length=args.rollout_length,
                chunk_length=args.chunk_length,
                num_epochs=args.epochs,
                minibatch_size=num_envs * args.rollout_length // args.minibatches,
                network=NetworkConfig(name=model),
            ).validate_for(env)
            trained = train_rate(env, config, args.repeats)
            rows.append(
                {
                    "task": args.task,
                    "model": model,
                    "num_envs": num_envs,
                    "raw_env_steps_per_second": raw["steps_per_second"],
                    "train_steps_per_second": trained["steps_per_second"],
                    "ratio": trained["steps_per_second"] / raw["steps_per_second"],
                    "raw_compile_seconds": raw["compile_seconds"],
                    "train_compile_seconds": trained["compile_seconds"],
                    "config": dataclasses.asdict(config),
                }
            )

    print("| task | model | envs | raw env steps/s | train steps/s | ratio | compile train (s) | compile raw (s) |")
    print("|---|---|---:|---:|---:|---:|---:|---:|")
    for r in rows:
        print(
            f"| {r['task']} | {r['model']} | {r['num_envs']} | {r['raw_env_steps_per_second']:,.0f} | "
            f"{r['train_steps_per_second']:,.0f} | {r['ratio']:.1%} | {r['train_compile_seconds']:.1f} | "
            f"{r['raw_compile_seconds']:.1f} |"
        )

    device = jax.devices()[0]
    versions = {}
    for package in PACKAGES:
        try:
            versions[package] = importlib.metadata.version(package)
        except importlib.metadata.PackageNotFoundError:
            versions[package] = None
    stamp = datetime.datetime.now(datetime.UTC).strftime("%Y%m%dT%H%M%SZ")
    record = {
        "benchmark": "train_throughput",
        "time": stamp,
        "device": {"platform": device.platform, "kind": device.device_kind, "count": jax.device_count()},
        "host": {"python": platform.python_version(), "machine": platform.machine(), "processor": platform.processor()},
        "versions": versions,
        "args": vars(args),
        "results": rows,
    }
    RESULTS.mkdir(parents=True, exist_ok=True)
    path = RESULTS / f"train_throughput-{args.task}-{device.platform}-{stamp}.json"
    path.write_text(json.dumps(record, indent=2))
    print(f"\nwrote {path}")


if __name__ == "__main__":
    main()
