"""What drawing actions costs per policy head, as the rollout draws them: a jitted `lax.scan` of `--rollout-length`
steps, each sampling one action per environment with `vmap(head.sample)` (per-environment keys) and scoring it with
`head.log_prob`, for `--num-envs` environments of a task's action space. Head parameters are fixed random rows, so
that nothing but the heads is timed.

Reported per head: seconds per rollout's draws (best of `--repeats`), the ratio to the Gaussian head's, and the
number of while loops in one draw's program (on the CPU, JAX's random bits add rolled loops of their own: compare
with the Gaussian's count). The Beta head samples through `jax.random.gamma`, a rejection
sampler (a while loop per draw); on a GPU a while loop sends its condition to the host every iteration, which is
cheap alone and slow when other processes share the GPU.

    python benchmarks/head_sampling.py --task HalfCheetah --num-envs 8192   # GPU: locomotion.yaml's batch
"""

from __future__ import annotations

import argparse

import jax
import jax.numpy as jnp
from common import markdown_table, measure_compiled, write_results

from angora_jax.envs.registry import make
from angora_jax.ppo.distributions import PolicyHead, make_head

HEADS = ("gaussian", "beta", "multicategorical")


def draws(head: PolicyHead, num_envs: int, rollout_length: int) -> tuple:
    """The rollout's action draws for one head: (function of (params, key) -> actions, its arguments)."""

    def rollout(params: jax.Array, key: jax.Array) -> jax.Array:
        def step(keys, _):
            keys, action_keys = jnp.moveaxis(jax.vmap(jax.random.split)(keys), 1, 0)
            action = jax.vmap(head.sample)(params, action_keys)
            return keys, (action, head.log_prob(params, action))

        return jax.lax.scan(step, jax.random.split(key, num_envs), None, length=rollout_length)[1]

    params = jax.random.normal(jax.random.key(0), (num_envs, head.num_params))
    return rollout, (params, jax.random.key(1))


def while_loops(head: PolicyHead, params: jax.Array) -> int:
    """While loops in the lowered program of one draw for every row of `params`."""
    keys = jax.random.split(jax.random.key(0), params.shape[0])
    return jax.jit(jax.vmap(head.sample)).lower(params, keys).as_text().count("stablehlo.while")


def measure(task: str, num_envs: int, rollout_length: int, repeats: int) -> list[dict]:
    """One row per head: seconds per rollout's draws, env steps per second of drawing alone, while loops."""
    action_spec = make(task).action_spec
    rows = []
    for name in HEADS:
        head = make_head(name, action_spec)
        fn, args = draws(head, num_envs, rollout_length)
        m = measure_compiled(fn, *args, repeats=repeats)
        rows.append({"head": name, "seconds": m.seconds, "compile_s": m.compile_s,
                     "draws_per_s": num_envs * rollout_length / m.seconds, "while_loops": while_loops(head, args[0])})
    gaussian = next(r["seconds"] for r in rows if r["head"] == "gaussian")
    for row in rows:
        row["over_gaussian"] = row["seconds"] / gaussian
    return rows


def main(argv: list[str] | None = None) -> str:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--task", default="HalfCheetah", help="whose action space (default: HalfCheetah, 6 actions)")
    parser.add_argument("--num-envs", type=int, default=8192)
    parser.add_argument("--rollout-length", type=int, default=16)
    parser.add_argument("--repeats", type=int, default=20)
    parser.add_argument("--out", default=None,
                        help="JSON path (default: results/env_train_throughput/head_sampling_<platform>.json)")
    args = parser.parse_args(argv)
    rows = measure(args.task, args.num_envs, args.rollout_length, args.repeats)
    path = write_results("head_sampling", {"task": args.task, "num_envs": args.num_envs,
                                           "rollout_length": args.rollout_length, "repeats": args.repeats},
                         rows, args.out, study="env_train_throughput")
    print(markdown_table(rows, [("head", "head", ""), ("seconds", "s per rollout's draws", ".5f"),
                                ("over_gaussian", "x Gaussian's", ".2f"), ("draws_per_s", "draws/s", ",.0f"),
                                ("while_loops", "while loops per draw", "d"), ("compile_s", "compile s", ".2f")]))
    print(f"wrote {path}")
    return path


if __name__ == "__main__":
    main()
