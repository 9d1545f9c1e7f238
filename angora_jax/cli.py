"""The `angora-jax` command."""

from __future__ import annotations

import argparse
import sys
import time

import jax
import numpy as np

from angora_jax.envs import list_tasks, make
from angora_jax.envs.random_rollout import batched_reset, episode_mean, make_random_rollout


def run_random(task: str, num_envs: int, num_steps: int, seed: int) -> dict[str, float]:
    """Roll out a random policy in `num_envs` batched environments for `num_steps` policy steps under one jit and
    print compile time, throughput and rewards. Returns the printed numbers."""
    env = make(task)
    rollout = jax.jit(make_random_rollout(env, num_envs, num_steps))
    reset = jax.jit(batched_reset, static_argnums=(0, 2))
    key = jax.random.key(seed)
    start = time.perf_counter()
    state = reset(env, key, num_envs)
    compiled = rollout.lower(state, key).compile()
    compile_s = time.perf_counter() - start
    start = time.perf_counter()
    state, rewards, dones, metrics = jax.block_until_ready(compiled(state, key))
    wall = time.perf_counter() - start
    steps_per_s = num_envs * num_steps / wall
    result = {
        "compile_s": compile_s,
        "env_steps_per_s": steps_per_s,
        "sim_s_per_s": steps_per_s * env.dt,
        "mean_reward": float(np.mean(rewards)),
        "episodes_ended": float(np.sum(dones)),
    }
    for name, values in metrics.items():
        result[f"episode_{name}"] = float(episode_mean(values, dones))
    print(f"{task}: random policy, {num_envs} envs x {num_steps} steps on {jax.devices()[0].platform}")
    for name, value in result.items():
        print(f"  {name:>24}: {value:,.4g}")
    return result


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="angora-jax", description=__doc__)
    commands = parser.add_subparsers(dest="command", required=True)
    run = commands.add_parser("run", help="roll out a random policy in a batch of environments (smoke test)")
    run.add_argument("--task", default="ShadowHandReach", help="task name (see list-tasks)")
    run.add_argument("--num-envs", type=int, default=8)
    run.add_argument("--steps", type=int, default=100, help="policy steps per environment")
    run.add_argument("--seed", type=int, default=0)
    commands.add_parser("list-tasks", help="print the registered task names")
    args = parser.parse_args(argv)
    if args.command == "list-tasks":
        print("\n".join(list_tasks()))
        return 0
    try:
        run_random(args.task, args.num_envs, args.steps, args.seed)
    except ValueError as error:
        print(f"angora-jax: {error}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
