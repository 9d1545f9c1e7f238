"""Recurrent cells over a training chunk, looped step by step (what a CPU runs) or unrolled whole (what a GPU runs):
one config's PPO cycle compiled and timed both ways in one process, everything else the same.

    python benchmarks/cell_unroll.py shadow_reach ppo.network.name=cortical ppo.network.cell=gru   # CPU, small
    python benchmarks/cell_unroll.py shadow_ihom_cortical ppo.num_envs=4096 ppo.minibatch_size=4096  # GPU

`angora_jax.nets.models.unrolled_steps` chooses per device; this script sets each way in turn. Prints a Markdown
table and writes JSON under benchmarks/results/cube_cortical/ (device, versions, config): compile seconds, seconds
per cycle, env steps/s and simulated seconds per wall second of each way, and the unrolled way's ratios to the
loop's.
"""

from __future__ import annotations

from unittest import mock

from common import config_parser, markdown_table, train_rate, write_results

from angora_jax.experiment.config import load_config, to_dict, validate
from angora_jax.nets import models

# Steps per loop iteration for a chunk of `length` steps.
WAYS = {"loop": lambda length: 1, "unrolled": lambda length: length}


def main(argv: list[str] | None = None) -> None:
    parser = config_parser(__doc__)
    parser.add_argument("--repeats", type=int, default=3, help="timed cycles per way")
    parser.add_argument("--out", default=None,
                        help="JSON path (default: results/cube_cortical/cell_unroll_<platform>.json)")
    args = parser.parse_args(argv)
    config = load_config(args.config, args.overrides)
    env = validate(config)
    ppo = config.ppo
    chosen = "unrolled" if models.unrolled_steps(ppo.chunk_length) > 1 else "loop"
    rows = []
    for way, steps in WAYS.items():
        with mock.patch.object(models, "unrolled_steps", steps):
            rate = train_rate(env, ppo, args.repeats)
        rows.append({"way": way, "this_device_runs": way == chosen, "compile_s": rate["compile_s"],
                     "cycle_s": ppo.num_envs * ppo.rollout_length / rate["env_steps_per_s"],
                     "env_steps_per_s": rate["env_steps_per_s"], "sim_s_per_s": rate["env_steps_per_s"] * env.dt})
        print(f"{way}: compiled in {rate['compile_s']:.1f} s, {rate['env_steps_per_s']:,.0f} env steps/s", flush=True)
    loop, unrolled = rows
    for name in ("compile_s", "cycle_s"):
        unrolled[f"{name}_over_loop"] = unrolled[name] / loop[name]
    print(markdown_table(rows, [
        ("way", "cells over a chunk", "s"), ("this_device_runs", "this device runs it", ""),
        ("compile_s", "compile s", ".1f"), ("cycle_s", "s per cycle", ".3f"),
        ("env_steps_per_s", "env steps/s", ",.0f"), ("sim_s_per_s", "sim s/s", ",.1f"),
        ("compile_s_over_loop", "compile / loop's", ".2f"), ("cycle_s_over_loop", "cycle / loop's", ".2f")]))
    path = write_results("cell_unroll", {"config": args.config, "overrides": args.overrides, "repeats": args.repeats,
                                         "resolved": to_dict(config)}, rows, args.out, study="cube_cortical")
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
