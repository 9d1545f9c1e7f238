"""How fast is evaluation on the eager CPU path with many episodes at a time? One checkpoint, the same episodes
evaluated with several (batch, workers) settings: episodes run at once and threads stepping the C MuJoCo physics.
Each setting first runs one batch of episodes to compile, then the timed episodes (the best of --repeats runs, as
other work on the machine slows some); per-episode results must be identical across settings (the table says so).

    python benchmarks/evaluation_speed.py runs/reach --episodes 48 --settings 1x1 16x1 16x2
    python benchmarks/evaluation_speed.py runs/reach --episodes 480 --settings 1x1 16x1 16x16 64x16   # 16 cores
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from common import markdown_table, write_results

import angora_jax as aj
from angora_jax.envs.eager_batch import EagerBatch
from angora_jax.experiment.agent import Agent
from angora_jax.experiment.episodes import agent_policy, episode_keys, on_host, run_episodes


def timed(agent: Agent, batch: int, workers: int, episodes: int, seed: int,
          repeats: int) -> tuple[float, dict[str, np.ndarray]]:
    """Seconds for `episodes` episodes (the best of `repeats` runs, compilation excluded) and their per-episode
    results."""
    with on_host(), EagerBatch(agent.env, batch, workers) as envs:
        policy = agent_policy(agent)
        run_episodes(envs, policy, agent.initial_carry(batch), *episode_keys(seed + 1, batch))  # compiles
        best = float("inf")
        for _ in range(repeats):
            start = time.perf_counter()
            results = run_episodes(envs, policy, agent.initial_carry(batch), *episode_keys(seed, episodes))
            best = min(best, time.perf_counter() - start)
        return best, results


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("run_dir")
    parser.add_argument("--checkpoint", default="latest")
    parser.add_argument("--episodes", type=int, default=48)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--settings", nargs="+", default=["1x1", "16x1", "16x2"], metavar="BATCHxWORKERS")
    parser.add_argument("--repeats", type=int, default=3, help="timed runs per setting; the best counts")
    parser.add_argument("--out", default=None,
                        help="JSON path (default: results/evaluation_and_checkpoints/evaluation_speed_<task>_<platform>"
                             ".json)")
    args = parser.parse_args(argv)
    agent = aj.load_agent(args.run_dir, int(args.checkpoint) if args.checkpoint.isdigit() else args.checkpoint)
    rows, first = [], None
    for setting in args.settings:
        batch, workers = (int(x) for x in setting.split("x"))
        seconds, results = timed(agent, batch, workers, args.episodes, args.seed, args.repeats)
        first = first or (seconds, results)
        steps = results["episode_length"].sum()
        rows.append({"batch": batch, "workers": workers, "seconds": seconds, "episodes_per_s": args.episodes / seconds,
                     "env_steps_per_s": steps / seconds, "speedup": first[0] / seconds,
                     "identical": all(np.array_equal(results[k], first[1][k]) for k in results)})
    config = {"task": agent.config.env.task, "network": agent.config.ppo.network.name, "episodes": args.episodes,
              "mean_episode_length": float(first[1]["episode_length"].mean()), "actions": "mode",
              "timing": f"best of {args.repeats} runs, compilation excluded (one batch of other episodes runs first)"}
    path = write_results(f"evaluation_speed_{agent.config.env.task}", config, rows, args.out,
                         study="evaluation_and_checkpoints")
    print(markdown_table(rows, [("batch", "batch", "d"), ("workers", "workers", "d"), ("seconds", "seconds", ".2f"),
                                ("episodes_per_s", "episodes/s", ".2f"), ("env_steps_per_s", "env steps/s", ".0f"),
                                ("speedup", "speed-up", ".2f"), ("identical", "same episodes", "")]))
    print(f"Written: {path}")


if __name__ == "__main__":
    main()
