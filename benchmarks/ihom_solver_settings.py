"""Evidence for the cube scene's physics settings: dynamics error against the Gym scene's settings, and speed.

Dynamics error (C MuJoCo, float64, so it isolates the settings from float32 effects): every candidate and the
reference (`model.GYM_PHYSICS`: timestep 2 ms, 20 Newton iterations, 50 line-search iterations) start from the same
random initial cube poses and receive the same open-loop joint targets once per 0.08 s policy step: the initial pose's
targets plus a smoothed random walk of 30% of each actuator's half range, which keeps the cube in the hand while
the fingers push it about. Reported per horizon (1, 5, 25 policy steps = 0.08, 0.4, 2 s), as medians over episodes:
cube orientation error (rad) and position error (mm) against the reference, and how often the candidate disagrees
with the reference on whether the cube has dropped. The row `reference, perturbed 1e-6` is the reference run from
initial states moved by 1e-6: contact-rich dynamics are chaotic, so that is the floor no setting can beat. Also:
the deepest penetration (mm) seen, the cube's speed (mm/s) after resting 2 s on a still hand, and the largest cube
speed (m/s) under uniformly random relative actions (training's first policy; inf if the simulation blew up).

Speed: C MuJoCo physics steps/s on one thread, and with `--mjx-batch N` our batched MJX env steps/s on the
default JAX device (the training path; compiles once per setting).

    python benchmarks/ihom_solver_settings.py                                   # CPU: C MuJoCo only, ~1 min
    python benchmarks/ihom_solver_settings.py --mjx-batch 4096 --settings 0.002/20/50,0.004/4/8,0.008/4/8  # GPU
"""

from __future__ import annotations

import argparse
import dataclasses
import time

import jax
import mujoco
import numpy as np
from common import RESULTS, markdown_table, time_compiled, write_results

import angora_jax as aj
from angora_jax.envs.mujoco_task import start_physics
from angora_jax.envs.random_rollout import batched_reset, make_random_rollout
from angora_jax.envs.shadow_hand.ihom import angular_distance
from angora_jax.envs.shadow_hand.model import GYM_PHYSICS as GYM
from angora_jax.envs.shadow_hand.model import PhysicsSettings

CONTROL_DT = 0.08
HORIZONS = (1, 5, 25)
CANDIDATES = (
    GYM,
    PhysicsSettings(0.002, 4, 8),
    PhysicsSettings(0.004, 20, 50),
    PhysicsSettings(0.004, 4, 8),
    PhysicsSettings(0.004, 2, 4),
    PhysicsSettings(0.004, 1, 4),
    PhysicsSettings(0.005, 4, 8),
    PhysicsSettings(0.008, 20, 50),
    PhysicsSettings(0.008, 4, 8),
    PhysicsSettings(0.008, 2, 4),
    PhysicsSettings(0.01, 4, 8),
)


def make_env(settings: PhysicsSettings, backend: str):
    return aj.make("ShadowHandCube", physics=dataclasses.asdict(settings), backend=backend, touch=False)


def targets(task, episodes: int, steps: int, seed: int) -> np.ndarray:
    """Open-loop offsets of the joint targets, shape `(episodes, steps, nu)`: a smoothed random walk."""
    rng = np.random.default_rng(seed)
    walk = np.zeros((episodes, steps, task.model.nu))
    for t in range(1, steps):
        walk[:, t] = 0.7 * walk[:, t - 1] + 0.3 * rng.uniform(-1, 1, (episodes, task.model.nu))
    return 0.3 * walk * task._ctrl_half_range


def simulate(task, qpos: np.ndarray, offsets: np.ndarray, frame_skip: int) -> dict[str, np.ndarray]:
    """Cube poses after every policy step `(steps, 7)`, drop flags and the deepest penetration (m)."""
    model = task.model
    data = start_physics(task, qpos)
    low, high = model.actuator_ctrlrange.T
    start_ctrl = data.ctrl.copy()
    poses, drops, deepest = [], [], 0.0
    for offset in offsets:
        data.ctrl[:] = np.clip(start_ctrl + offset, low, high)
        for _ in range(frame_skip):
            mujoco.mj_step(model, data)
            if data.ncon:
                deepest = max(deepest, -data.contact.dist[:data.ncon].min())
        poses.append(data.qpos[task.cube_qpos:task.cube_qpos + 7].copy())
        drops.append(data.qpos[task.cube_qpos + 2] < data.xpos[task.palm_id, 2])
    return {"poses": np.array(poses), "drops": np.array(drops), "deepest": deepest}


def resting_speed(task, qpos: np.ndarray, frame_skip: int, seconds: float = 2.0) -> float:
    """Cube speed (m/s) after `seconds` on a hand that holds its initial targets."""
    data = start_physics(task, qpos)
    mujoco.mj_step(task.model, data, nstep=round(seconds / CONTROL_DT) * frame_skip)
    return float(np.linalg.norm(data.qvel[task.cube_dof:task.cube_dof + 3]))


def run_all(env, qposes: np.ndarray, offsets: np.ndarray) -> list[dict]:
    return [simulate(env.task, q, o, env.frame_skip) for q, o in zip(qposes, offsets, strict=True)]


def errors(runs: list[dict], reference: list[dict]) -> dict[str, float]:
    row, pairs = {}, list(zip(runs, reference, strict=True))
    for h in HORIZONS:
        pos = [np.linalg.norm(r["poses"][h - 1, :3] - ref["poses"][h - 1, :3]) for r, ref in pairs]
        rot = [float(angular_distance(r["poses"][h - 1, 3:], ref["poses"][h - 1, 3:])) for r, ref in pairs]
        row[f"rot_err_{h}"] = float(np.median(rot))
        row[f"pos_err_mm_{h}"] = 1e3 * float(np.median(pos))
    row["drop_disagree"] = float(np.mean([r["drops"][-1] != ref["drops"][-1] for r, ref in pairs]))
    row["dropped_at_end"] = float(np.mean([r["drops"][-1] for r in runs]))
    row["deepest_mm"] = 1e3 * float(np.median([r["deepest"] for r in runs]))
    return row


def random_action_stability(env, episodes: int = 8, steps: int = 25) -> float:
    """Largest cube speed (m/s) under uniformly random relative actions (training's first policy), until the drop;
    inf when the state became non-finite."""
    task, model = env.task, env.task.model
    rng, (low, high), fastest = np.random.default_rng(1), model.actuator_ctrlrange.T, 0.0
    for episode in range(episodes):
        data = start_physics(task, np.asarray(task.initial_qpos(jax.random.key(episode)), np.float64))
        for _ in range(steps):
            action = rng.uniform(-1, 1, model.nu)
            data.ctrl[:] = np.clip(data.actuator_length + action * task._ctrl_half_range, low, high)
            for _ in range(env.frame_skip):
                mujoco.mj_step(model, data)
                fastest = max(fastest, float(np.abs(data.qvel[task.cube_dof:task.cube_dof + 3]).max()))
            if not np.isfinite(data.qpos).all():
                return float("inf")
            if data.qpos[task.cube_qpos + 2] < data.xpos[task.palm_id, 2]:
                break
    return fastest


def c_mujoco_speed(env, seconds: float = 1.5) -> float:
    """Physics steps/s of `mj_step` on one thread from the first episode's start, random joint targets."""
    model, data = env.task.model, start_physics(env.task, np.asarray(env.task.initial_qpos(jax.random.key(0))))
    rng, low, high = np.random.default_rng(0), *model.actuator_ctrlrange.T
    steps, start = 0, time.perf_counter()
    while time.perf_counter() - start < seconds:
        data.ctrl[:] = rng.uniform(low, high)
        mujoco.mj_step(model, data, nstep=env.frame_skip)
        steps += env.frame_skip
    return steps / (time.perf_counter() - start)


def mjx_speed(settings: PhysicsSettings, batch: int, steps: int) -> dict[str, float]:
    env = make_env(settings, "mjx")
    state = jax.jit(batched_reset, static_argnums=(0, 2))(env, jax.random.key(0), batch)
    compile_s, wall, _ = time_compiled(make_random_rollout(env, batch, steps), state, jax.random.key(1), repeats=2)
    return {"mjx_env_steps_per_s": batch * steps / wall, "mjx_compile_s": compile_s}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--episodes", type=int, default=16)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--settings", default=None,
                        help="only these candidates, e.g. '0.002/20/50,0.008/4/8' (timestep/iterations/ls)")
    parser.add_argument("--mjx-batch", type=int, default=0, help="also time batched MJX with this many envs")
    parser.add_argument("--mjx-steps", type=int, default=20, help="policy steps per timed MJX rollout")
    parser.add_argument("--out", default=None)
    args = parser.parse_args()

    steps = max(HORIZONS)
    ref_env = make_env(GYM, "cpu")
    keys = jax.random.split(jax.random.key(args.seed), args.episodes)
    qposes = np.stack([np.asarray(ref_env.task.initial_qpos(k), np.float64) for k in keys])
    offsets = targets(ref_env.task, args.episodes, steps, args.seed)
    reference = run_all(ref_env, qposes, offsets)
    rows = [{"setting": "reference, perturbed 1e-6", **errors(run_all(ref_env, qposes + 1e-6, offsets), reference)}]
    chosen = CANDIDATES
    if args.settings:
        chosen = [PhysicsSettings(float(t), int(i), int(ls))
                  for t, i, ls in (item.split("/") for item in args.settings.split(","))]
    for settings in chosen:
        env = make_env(settings, "cpu")
        row = {"setting": f"dt {settings.timestep * 1e3:g} ms, it {settings.iterations}, ls {settings.ls_iterations}",
               **dataclasses.asdict(settings), "frame_skip": env.frame_skip,
               **errors(run_all(env, qposes, offsets), reference),
               "resting_speed_mm_s": 1e3 * float(np.median([resting_speed(env.task, q, env.frame_skip)
                                                             for q in qposes[:4]])),
               "random_action_max_speed": random_action_stability(env),
               "c_mujoco_physics_steps_per_s": c_mujoco_speed(env)}
        row["c_mujoco_env_steps_per_s"] = row["c_mujoco_physics_steps_per_s"] / env.frame_skip
        if args.mjx_batch:
            row |= mjx_speed(settings, args.mjx_batch, args.mjx_steps)
        rows.append(row)
        print(row["setting"], {k: round(v, 4) for k, v in row.items() if isinstance(v, float)}, flush=True)
    config = {"episodes": args.episodes, "seed": args.seed, "control_dt_s": CONTROL_DT, "horizons": HORIZONS,
              "reference": dataclasses.asdict(GYM), "mjx_batch": args.mjx_batch, "mjx_steps": args.mjx_steps}
    path = write_results("ihom_solver_settings", config, rows, args.out)
    columns = [("setting", "setting", "s"), ("frame_skip", "frame skip", "d")]
    columns += [(f"rot_err_{h}", f"rot err {h} (rad)", ".3f") for h in HORIZONS]
    columns += [(f"pos_err_mm_{h}", f"pos err {h} (mm)", ".2f") for h in HORIZONS]
    columns += [("drop_disagree", "drop disagree", ".2f"), ("dropped_at_end", "dropped", ".2f"),
                ("deepest_mm", "deepest mm", ".2f"), ("resting_speed_mm_s", "rest mm/s", ".2f"),
                ("random_action_max_speed", "random max m/s", ".2f"),
                ("c_mujoco_env_steps_per_s", "C env steps/s", ",.0f"),
                ("mjx_env_steps_per_s", "MJX env steps/s", ",.0f"), ("mjx_compile_s", "MJX compile s", ".0f")]
    print(markdown_table(rows, columns))
    print(f"wrote {path} (results folder: {RESULTS})")


if __name__ == "__main__":
    main()
