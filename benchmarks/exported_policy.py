"""Does an exported policy reproduce `evaluate`? Run it in a fresh process, as its user would: `aj.load_policy(FILE)`
and a plain loop of `policy.act` and the task's `step`, one episode per environment on the seeds `evaluate` used.

EVALUATION is the JSON `angora-jax evaluate RUN_DIR --path batched` wrote (its seed and episode count are reused);
the loop draws the same start states (`make_evaluate`'s keys), acts with the head's mode and counts each metric at
the episode's end. The table gives each quantity's mean on both sides, the share of episodes equal to the float, and
`agreement` (difference of means over its standard error; the physics is chaotic over thousands of contact steps,
so two programs that round differently part ways in some episodes: equal means, not equal episodes, are the claim).

    angora-jax export runs/cube --out cube.msgpack
    angora-jax evaluate runs/cube --path batched --episodes 480
    python benchmarks/exported_policy.py cube.msgpack runs/cube/evaluation/best-cycle252-mode-seed0-batched.json
"""

from __future__ import annotations

import argparse
import json
import time

import jax
import numpy as np
from common import markdown_table, write_results

import angora_jax as aj
from angora_jax.experiment.evaluation import agreement


def run_exported(path: str, episodes: int, seed: int) -> dict[str, np.ndarray]:
    """Per-episode return, length and metrics at the episode's end of the exported policy at `path`: `episodes`
    environments started from `make_evaluate`'s keys for `seed`, stepped until every episode has ended."""
    policy = aj.load_policy(path)
    env = policy.agent.env.sized_for(episodes)
    reset_key, _ = jax.random.split(jax.random.key(seed))
    states = jax.jit(jax.vmap(env.reset))(jax.random.split(reset_key, episodes))
    act, step = jax.jit(policy.act), jax.jit(jax.vmap(env.step))
    carry = policy.initial_carry(episodes)
    running = np.ones(episodes, bool)
    totals = {"episode_return": np.zeros(episodes), "episode_length": np.zeros(episodes)}
    totals |= {f"metric/{name}": np.zeros(episodes) for name in env.metric_names}
    for _ in range(env.max_episode_steps):
        carry, action = act(carry, states.obs)
        states = step(states, action)
        done, metrics = np.asarray(states.done) > 0, jax.device_get(states.metrics)
        totals["episode_return"] += running * np.asarray(states.reward)
        totals["episode_length"] += running
        for name, value in metrics.items():
            totals[f"metric/{name}"] += (running & done) * np.asarray(value)
        running &= ~done
        if not running.any():
            break
    return totals


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("policy", help="a file written by angora-jax export")
    parser.add_argument("evaluation", help="the JSON of angora-jax evaluate --path batched of the same checkpoint")
    parser.add_argument("--out",
                        help="result JSON (default: results/evaluation_and_checkpoints/exported_policy_<platform>"
                             ".json)")
    args = parser.parse_args(argv)
    with open(args.evaluation) as file:
        reference = json.load(file)
    if reference.get("path") != "batched" or reference.get("stochastic"):
        raise SystemExit(f"{args.evaluation} is not a deterministic batched evaluation: run angora-jax evaluate "
                         "RUN_DIR --path batched (the loop here starts episodes as that path does).")
    start = time.perf_counter()
    ours = run_exported(args.policy, reference["episodes"], reference["seed"])
    wall = time.perf_counter() - start
    rows = []
    for name, values in reference["per_episode"].items():
        theirs = np.asarray(values)
        rows.append({"quantity": name, "evaluate": float(theirs.mean()), "exported": float(ours[name].mean()),
                     "equal_episodes": float(np.mean(np.isclose(theirs, ours[name], rtol=1e-5, atol=1e-6))),
                     **agreement(theirs, ours[name])})
    print(markdown_table(rows, [("quantity", "quantity", ""), ("evaluate", "evaluate mean", ".3f"),
                                ("exported", "exported mean", ".3f"), ("equal_episodes", "equal episodes", ".1%"),
                                ("diff_in_stderr", "difference / s.e.", ".2f"), ("agree", "agree", "")]))
    config = {"policy": args.policy, "evaluation": args.evaluation, "cycle": reference["cycle"],
              "task": reference["task"], "episodes": reference["episodes"], "seed": reference["seed"],
              "wall_seconds": wall}
    print("wrote", write_results("exported_policy", config, rows, args.out, study="evaluation_and_checkpoints"))


if __name__ == "__main__":
    main()
