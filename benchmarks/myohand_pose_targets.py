"""How far MyoHandPose's evaluation targets lie from the targets its training drew: is `reachable_held_out` near the
training part of the reachable bank, and are MyoSuite's targets (`asl`) inside the reachable set at all?

For each query set (the bank's held-out rows; `--asl` targets of MyoSuite's draw, keys split from `--seed`) the
distance (rad, the task's pose error: Euclidean over the 23 joints) to the nearest posture of the bank's training
part, as percentiles and the share within the success threshold (0.7 rad). C MuJoCo is not needed: the bank is
`angora_jax/envs/myohand/reachable.py`'s file, and MyoSuite's draw is the task's own `draw_target`.

    python benchmarks/myohand_pose_targets.py            # writes results/myohand/myohand_pose_targets_cpu.json
"""

from __future__ import annotations

import argparse

import jax
import numpy as np
from common import markdown_table, write_results
from sklearn.metrics import pairwise_distances_argmin_min

from angora_jax.envs.myohand.model import load_hand
from angora_jax.envs.myohand.pose import POSE_THRESHOLD, MyoHandPose
from angora_jax.envs.myohand.reachable import HELD_OUT, bank_part


def summary(name: str, distances: np.ndarray) -> dict:
    p10, p50, p90 = np.percentile(distances, [10, 50, 90])
    return {"queries": name, "count": len(distances), "median_rad": float(p50), "p10_rad": float(p10),
            "p90_rad": float(p90), "min_rad": float(distances.min()),
            "share_within_threshold": float(np.mean(distances < POSE_THRESHOLD))}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--asl", type=int, default=1024, help="MyoSuite targets drawn (default: 1024)")
    parser.add_argument("--seed", type=int, default=0, help="key of MyoSuite's draws (default: 0)")
    parser.add_argument("--out", default=None, help="JSON path (default: results/myohand/)")
    args = parser.parse_args()

    training, held_out = (bank_part(held_out=part).astype(np.float64) for part in (False, True))
    task = MyoHandPose(load_hand(myosuite_frame=True))
    asl = np.asarray(jax.vmap(task.draw_target)(jax.random.split(jax.random.key(args.seed), args.asl)), np.float64)
    rows = [summary("reachable_held_out", pairwise_distances_argmin_min(held_out, training)[1]),
            summary("asl (MyoSuite's draw)", pairwise_distances_argmin_min(asl, training)[1])]
    print(f"Distance to the nearest of the bank's {len(training)} training targets (rad; success below "
          f"{POSE_THRESHOLD}):")
    print(markdown_table(rows, [("queries", "queries", "s"), ("count", "count", "d"), ("p10_rad", "10th pct.", ".3f"),
                                ("median_rad", "median", ".3f"), ("p90_rad", "90th pct.", ".3f"),
                                ("min_rad", "min", ".3f"), ("share_within_threshold", "within 0.7 rad", ".3f")]))
    config = {"asl_draws": args.asl, "seed": args.seed, "bank_rows": len(training) + len(held_out),
              "held_out_rows": HELD_OUT, "threshold_rad": POSE_THRESHOLD}
    path = write_results("myohand_pose_targets", config, rows, args.out, study="myohand")
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
