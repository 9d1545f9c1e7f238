"""Postures the MyoHand reaches by itself: the target bank of `MyoHandPose(targets="reachable")`.

MyoSuite's pose targets draw each joint on its own, and many of the combinations ask for what the long multi-joint
muscles resist: a controller that knows the model succeeds on 15% of them, but on 85% of postures the hand makes
itself (`benchmarks/results/myohand/README.md`). A reachable posture is where the hand comes to rest after
`SETTLE_SECONDS` of a constant excitation drawn uniformly in [0, `EXCITATION_MAX`] per muscle, from joint angles drawn
uniformly within their ranges, on the default model (`model.MYOHAND_PHYSICS`) standing in MyoSuite's frame, as the
pose task's hand does. Row i of the bank is seed i (`reachable_posture`), so the bank is reproducible and any row can
be checked; the last `HELD_OUT` rows are drawn only by `targets="reachable_held_out"`, for evaluations on targets
training never saw.

Regenerate (about 5 CPU minutes): `python -m angora_jax.envs.myohand.reachable [--workers 2]`.
"""

from __future__ import annotations

import argparse
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import mujoco
import numpy as np

BANK_FILE = Path(__file__).with_name("reachable_postures.npz")
BANK_SIZE = 8192
HELD_OUT = 1024
EXCITATION_MAX = 0.3
SETTLE_SECONDS = 2.0


def reachable_posture(model: mujoco.MjModel, seed: int) -> np.ndarray:
    """The joint angles `(nq,)` (rad) where `model`'s hand rests after `SETTLE_SECONDS` of a constant excitation drawn
    in [0, `EXCITATION_MAX`] per muscle, from angles drawn uniformly within the joints' ranges (numpy generator seeded
    with `seed`)."""
    rng = np.random.default_rng(seed)
    data = mujoco.MjData(model)
    data.qpos[:] = rng.uniform(model.jnt_range[:, 0], model.jnt_range[:, 1])
    data.ctrl[:] = rng.uniform(0.0, EXCITATION_MAX, model.nu)
    mujoco.mj_step(model, data, nstep=round(SETTLE_SECONDS / model.opt.timestep))
    return data.qpos.copy()


def make_bank(model: mujoco.MjModel, size: int = BANK_SIZE, workers: int = 1) -> np.ndarray:
    """`reachable_posture(model, i)` for i in 0..size-1, as float32 `(size, nq)` (rad), on `workers` threads (MuJoCo
    steps without the GIL; the rows do not depend on the number of threads)."""
    with ThreadPoolExecutor(workers) as pool:
        return np.stack(list(pool.map(lambda seed: reachable_posture(model, seed), range(size)))).astype(np.float32)


def load_bank() -> np.ndarray:
    """The shipped bank, float32 `(BANK_SIZE, 23)` (rad, the MyoHand's joint order)."""
    with np.load(BANK_FILE) as bank:
        postures = bank["postures"]
    if postures.shape[0] != BANK_SIZE:
        raise ValueError(f"{BANK_FILE} holds {postures.shape[0]} postures, not {BANK_SIZE}: regenerate it with "
                         "python -m angora_jax.envs.myohand.reachable.")
    return postures


def bank_part(held_out: bool) -> np.ndarray:
    """The rows of the shipped bank that training draws (all but the last `HELD_OUT`), or with `held_out` those last
    rows, float32 `(rows, 23)` (rad)."""
    postures = load_bank()
    return postures[-HELD_OUT:] if held_out else postures[:-HELD_OUT]


def main(argv: list[str] | None = None) -> None:
    from angora_jax.envs.myohand.model import load_hand

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--workers", type=int, default=2, help="threads stepping C MuJoCo (default: 2)")
    parser.add_argument("--out", type=Path, default=BANK_FILE, help=f"the bank to write (default: {BANK_FILE})")
    args = parser.parse_args(argv)
    postures = make_bank(load_hand(myosuite_frame=True), workers=args.workers)
    np.savez_compressed(args.out, postures=postures, excitation_max=EXCITATION_MAX, settle_seconds=SETTLE_SECONDS,
                        mujoco_version=mujoco.__version__)
    print(f"{args.out}: {len(postures)} postures")


if __name__ == "__main__":
    main()
