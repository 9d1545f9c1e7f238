"""Do the two evaluation paths agree? One checkpoint, the same episodes (same reset keys, mode actions) evaluated on
the batched MJX path (`Agent.evaluate`) and on the eager C MuJoCo path (`angora_jax.evaluate`); per quantity, the
difference of the means in units of the CPU mean's standard error.

    angora-jax train shadow_reach ppo.num_envs=4 ppo.rollout_length=16 ppo.chunk_length=8 ppo.minibatch_size=32 \
        ppo.num_epochs=1 ppo.num_cycles=2 logging.run_name=reach          # a tiny run, if you have none
    python benchmarks/path_agreement.py runs/reach --episodes 32
"""

from __future__ import annotations

import argparse
import time

from common import markdown_table, write_results

import angora_jax as aj


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("run_dir")
    parser.add_argument("--episodes", type=int, default=32)
    parser.add_argument("--checkpoint", default="latest")
    args = parser.parse_args()
    run_dir = args.run_dir
    start = time.perf_counter()
    cpu = aj.evaluate(run_dir, args.checkpoint, episodes=args.episodes, save=False)
    cpu_s = time.perf_counter() - start
    agent = aj.load_agent(run_dir, args.checkpoint)
    start = time.perf_counter()
    mjx = agent.evaluate(num_envs=args.episodes, seed=0)
    mjx_s = time.perf_counter() - start
    rows = []
    for name, stats in cpu.summary.items():
        diff = mjx[name] - stats["mean"]
        rows.append({"quantity": name, "mjx_mean": mjx[name], "cpu_mean": stats["mean"], "cpu_stderr": stats["stderr"],
                     "diff": diff, "diff_in_stderr": diff / stats["stderr"] if stats["stderr"] > 0 else None})
    config = {"task": agent.config.env.task, "network": agent.config.ppo.network.name,
              "num_envs_trained": agent.config.ppo.num_envs, "cycle": agent.cycle, "episodes": args.episodes,
              "actions": "mode",
              "cpu_seconds_with_compile": cpu_s, "mjx_seconds_with_compile": mjx_s}
    path = write_results(f"path_agreement_{agent.config.env.task}", config, rows)
    print(markdown_table(rows, [("quantity", "quantity", ""), ("mjx_mean", "MJX mean", ".5g"),
                                ("cpu_mean", "CPU mean", ".5g"), ("cpu_stderr", "CPU stderr", ".3g"),
                                ("diff_in_stderr", "diff / stderr", ".3f")]))
    print(f"Written: {path}")


if __name__ == "__main__":
    main()
