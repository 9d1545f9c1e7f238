"""Checkpoint sizes on disk and save times: a config's fresh TrainState saved whole and lean (`checkpoint.lean`:
without the environments' states), through the run's own `Checkpoints`, with the bytes of each part of the state.

Two times per save, the median of `--repeats` saves into fresh folders: `blocking_seconds`, what training waits for
it (from `save` until it returns, the state copied to host memory; the files are written behind the next cycle), and
`save_seconds`, until the checkpoint is on disk with its manifest (`close`). A run saves its best checkpoint after
every cycle that beats the earlier ones, which while it learns is most cycles: the ratio of a whole save to a lean
one is what `checkpoint.lean` buys there.

    # the fast cube at 16,384 envs on MuJoCo Warp (its state is Warp's, whichever device makes it: the CPU works)
    python benchmarks/checkpoint_size.py shadow_ihom 'env.options.physics={impl: warp}'
    # CPU smoke size
    python benchmarks/checkpoint_size.py shadow_reach ppo.num_envs=8 ppo.minibatch_size=64

Prints a Markdown table and writes JSON (device, versions, config, rows) to
benchmarks/results/evaluation_and_checkpoints/checkpoint_size_<task>_<platform>.json or --out.
"""

from __future__ import annotations

import statistics
import tempfile
import time
from pathlib import Path

import jax
from common import config_parser, markdown_table, write_results

from angora_jax.experiment.checkpoint import Checkpoints
from angora_jax.experiment.config import load_config, to_dict, validate
from angora_jax.ppo.cycle import make_cycle


def folder_bytes(path: Path) -> int:
    return sum(f.stat().st_size for f in path.rglob("*") if f.is_file())


def tree_bytes(tree) -> int:
    return sum(leaf.nbytes for leaf in jax.tree.leaves(tree) if hasattr(leaf, "nbytes"))


def main() -> None:
    parser = config_parser(__doc__)
    parser.add_argument("--repeats", type=int, default=3, help="saves timed per kind (default 3; the median is kept)")
    parser.add_argument("--out", default=None,
                        help="JSON path (default: results/evaluation_and_checkpoints/checkpoint_size_<task>_<platform>"
                             ".json)")
    args = parser.parse_intermixed_args()
    config = load_config(args.config, args.overrides)
    env = validate(config)
    init, _ = make_cycle(env, None, config.ppo)
    state = jax.block_until_ready(init(jax.random.key(config.ppo.seed)))
    rows = []
    with tempfile.TemporaryDirectory() as folder:
        for kind, lean in (("whole", ()), ("lean", ("latest",))):
            seconds, blocking = [], []
            for repeat in range(max(args.repeats, 1)):
                checkpoints = Checkpoints(Path(folder) / f"{kind}{repeat}", config.checkpoint.__class__(lean=lean))
                start = time.perf_counter()
                assert checkpoints.save(state, {"env_steps": 0}, to_dict(config)) == ["latest"]  # cycle 0: due
                blocking.append(time.perf_counter() - start)
                checkpoints.close()
                seconds.append(time.perf_counter() - start)
            rows.append({"checkpoint": kind, "disk_mb": folder_bytes(Path(folder) / f"{kind}0") / 1e6,
                         "blocking_seconds": statistics.median(blocking), "save_seconds": statistics.median(seconds),
                         "blocking_seconds_each": blocking, "save_seconds_each": seconds})
    parts = {"environments (actor, discounted_return)": tree_bytes((state.actor, state.discounted_return)),
             "parameters": tree_bytes(state.params), "optimizer": tree_bytes(state.opt_state),
             "normalisers, key, cycle": tree_bytes((state.obs_stats, state.reward_stats, state.cycle))}
    for row in rows:
        row |= {"task": config.env.task, "num_envs": config.ppo.num_envs, "impl": env.physics_info().get("impl", "-")}
    rows[1]["fraction_of_whole"] = rows[1]["disk_mb"] / rows[0]["disk_mb"]
    rows[1]["save_time_fraction_of_whole"] = rows[1]["save_seconds"] / rows[0]["save_seconds"]
    print(markdown_table(rows, [("task", "task", "s"), ("impl", "physics", "s"), ("num_envs", "envs", ",d"),
                                ("checkpoint", "checkpoint", "s"), ("disk_mb", "MB on disk", ",.1f"),
                                ("fraction_of_whole", "of whole", ".3f"), ("blocking_seconds", "waited s", ".3f"),
                                ("save_seconds", "on disk s", ".3f"),
                                ("save_time_fraction_of_whole", "save time of whole", ".3f")]))
    for name, size in parts.items():
        print(f"  {name}: {size / 1e6:,.1f} MB in memory")
    path = write_results(f"checkpoint_size_{config.env.task}", {"config": to_dict(config), "state_mb": {
        name: size / 1e6 for name, size in parts.items()}}, rows, args.out, study="evaluation_and_checkpoints")
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
