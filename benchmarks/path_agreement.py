"""Do evaluation and training agree? One checkpoint evaluated on the batched MJX path (what training runs: jitted,
every episode at once, `make_evaluate`) and on the eager C MuJoCo CPU path (`angora_jax.evaluate`, many episodes at
a time on the host's cores), the same episodes on both (episode i starts from the same key), mode actions.

Per quantity (episode return, length, each task metric at the episode's end): the mean and its standard error on each
path, the difference of the means in standard errors of the difference (sqrt(se_mjx^2 + se_cpu^2)), and PASS when
every quantity differs by less than --bound (default 3) of them, else FAIL (exit code 1). The paired standard error
(of the mean of per-episode differences) is shown too: how closely the two physics track each other.

    angora-jax train shadow_reach ppo.num_envs=4 ppo.rollout_length=16 ppo.chunk_length=8 ppo.minibatch_size=32 \\
        ppo.num_epochs=1 ppo.num_cycles=2 logging.run_name=reach          # a tiny run, if you have none
    python benchmarks/path_agreement.py runs/reach --episodes 32           # CPU smoke size
    python benchmarks/path_agreement.py runs/<trained reach run> --checkpoint best --episodes 480   # GPU machine
"""

from __future__ import annotations

import argparse
import sys
import time

import jax
from common import markdown_table, write_results

import angora_jax as aj
from angora_jax.experiment.evaluation import DEFAULT_BATCH, agreement
from angora_jax.ppo.evaluate import make_evaluate


def main(argv: list[str] | None = None) -> int:
    """Run the comparison with command-line `argv` (default: sys.argv); return the exit code, 0 for PASS."""
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("run_dir")
    parser.add_argument("--checkpoint", default="latest", help="best, latest or a cycle number (default: latest)")
    parser.add_argument("--episodes", type=int, default=32)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--bound", type=float, default=3.0, help="PASS below this many standard errors (default 3)")
    parser.add_argument("--batch", type=int, default=DEFAULT_BATCH, help="CPU path: episodes at a time")
    parser.add_argument("--workers", type=int, default=1, help="CPU path: threads stepping C MuJoCo physics")
    parser.add_argument("--out", default=None,
                        help="JSON path (default: results/path_agreement/path_agreement_<task>_<platform>)")
    args = parser.parse_args(argv)
    checkpoint = int(args.checkpoint) if args.checkpoint.isdigit() else args.checkpoint

    try:
        cpu = aj.evaluate(args.run_dir, checkpoint, episodes=args.episodes, seed=args.seed, save=False,
                          batch=args.batch, workers=args.workers)
    except (FileNotFoundError, ValueError) as error:  # no such run or checkpoint, a damaged one, a bad option
        print(f"path_agreement.py: {error}", file=sys.stderr)
        return 2
    agent = aj.load_agent(args.run_dir, checkpoint)
    start = time.perf_counter()
    evaluate = make_evaluate(agent.env, agent.network, agent.config.ppo, args.episodes, per_episode=True)
    mjx = jax.device_get(evaluate(agent.state, jax.random.key(args.seed)))
    mjx_s = time.perf_counter() - start

    rows = []
    for name, cpu_values in cpu.episodes.items():
        stats = agreement(mjx[name], cpu_values, args.bound)
        rows.append({"quantity": name, "mjx_mean": stats["mean_a"], "mjx_stderr": stats["stderr_a"],
                     "cpu_mean": stats["mean_b"], "cpu_stderr": stats["stderr_b"], "diff": stats["diff"],
                     "stderr_diff": stats["stderr_diff"], "diff_in_stderr": stats["diff_in_stderr"],
                     "stderr_paired": stats["stderr_paired"], "agree": stats["agree"]})
    failed = [row["quantity"] for row in rows if not row["agree"]]
    verdict = "FAIL" if failed else "PASS"
    config = {"task": agent.config.env.task, "network": agent.config.ppo.network.name, "cycle": agent.cycle,
              "checkpoint": args.checkpoint, "episodes": args.episodes, "seed": args.seed, "actions": "mode",
              "bound_in_stderr": args.bound, "verdict": verdict,
              "mjx_device": str(jax.devices()[0]), "mjx_seconds_with_compile": mjx_s,
              "cpu_batch": cpu.meta["batch"], "cpu_workers": cpu.meta["workers"],
              "cpu_seconds_with_compile": cpu.meta["wall_seconds"]}
    path = write_results(f"path_agreement_{agent.config.env.task}", config, rows, args.out, study="path_agreement")
    print(markdown_table(rows, [("quantity", "quantity", ""), ("mjx_mean", "MJX mean", ".5g"),
                                ("mjx_stderr", "MJX stderr", ".3g"), ("cpu_mean", "CPU mean", ".5g"),
                                ("cpu_stderr", "CPU stderr", ".3g"), ("diff_in_stderr", "diff / stderr", ".3f"),
                                ("stderr_paired", "paired stderr", ".3g")]))
    print(f"MJX ({jax.devices()[0].platform}, {args.episodes} episodes at once): {mjx_s:.1f} s with compilation; "
          f"C MuJoCo ({cpu.meta['batch']} at a time, physics threads: {cpu.meta['workers']}): "
          f"{cpu.meta['wall_seconds']:.1f} s with compilation.")
    if failed:
        print(f"FAIL: {', '.join(failed)} differ by {args.bound:g} or more standard errors of the difference.")
    else:
        print(f"PASS: every quantity's MJX and CPU means differ by less than {args.bound:g} standard errors of the "
              f"difference ({args.episodes} episodes each).")
    print(f"Written: {path}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
