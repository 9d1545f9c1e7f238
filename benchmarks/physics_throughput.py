"""Physics settings of a Shadow-hand scene: MJX throughput against faithfulness to the stock settings.

Each variant changes the solver iterations, line-search iterations, solver type and physics timestep (with the frame
skip that keeps the policy step's duration). For each: raw batched `vmap(mjx.step)` physics steps/s, policy steps/s
and sim-s/s (physics steps/s x timestep), compile time and peak memory on the default device; and, on C MuJoCo
(float64), the fingertip error against the stock settings after the same open-loop sequence of policy actions.

    python benchmarks/physics_throughput.py --batch-sizes 8 --steps 4                 # CPU smoke run
    python benchmarks/physics_throughput.py --batch-sizes 4096,16384 --steps 20       # GPU
"""

from __future__ import annotations

import argparse
import dataclasses

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from common import markdown_table, peak_memory_bytes, time_compiled, write_results
from mujoco import mjx

from angora_jax.envs.mujoco_task import Snapshot, start_physics
from angora_jax.envs.shadow_hand import REACH_PHYSICS
from angora_jax.envs.shadow_hand.model import GYM_PHYSICS, PhysicsSettings, load_scene
from angora_jax.envs.shadow_hand.reach import Reach

POLICY_DT = 0.02  # s per policy step, as in the reach tasks


@dataclasses.dataclass(frozen=True)
class Variant:
    name: str
    physics: PhysicsSettings
    solver: int = mujoco.mjtSolver.mjSOL_NEWTON

    @property
    def frame_skip(self) -> int:
        return self.physics.frame_skip(POLICY_DT)

    @property
    def timestep(self) -> float:
        return self.physics.timestep

    def model(self) -> mujoco.MjModel:
        model = load_scene("reach.xml", physics=self.physics)
        model.opt.solver = self.solver
        return model


VARIANTS = (
    Variant("stock (Newton 20/50, 2 ms)", GYM_PHYSICS),
    Variant("Newton 4/8, 2 ms", PhysicsSettings(0.002, 4, 8)),
    Variant("Newton 1/4, 2 ms", PhysicsSettings(0.002, 1, 4)),
    Variant("CG 4/8, 2 ms", PhysicsSettings(0.002, 4, 8), solver=mujoco.mjtSolver.mjSOL_CG),
    Variant("Newton 4/8, 4 ms", PhysicsSettings(0.004, 4, 8)),
    Variant("Newton 2/4, 5 ms (REACH_PHYSICS)", REACH_PHYSICS),
)


def fingertip_trajectory(variant: Variant, actions: np.ndarray) -> np.ndarray:
    """Fingertip positions (m) after each policy step of `actions` on C MuJoCo, shape `(T, 5, 3)`."""
    model = variant.model()
    task = Reach(model)
    data = start_physics(task, np.asarray(task.initial_qpos(None), np.float64))
    tips = []
    for action in actions:
        data.ctrl[:] = np.asarray(task.control(jnp.asarray(action), Snapshot.of(data)), np.float64)
        mujoco.mj_step(model, data, nstep=variant.frame_skip)
        tips.append(data.site_xpos[task.fingertip_ids].copy())
    return np.stack(tips)


def throughput(variant: Variant, batch: int, steps: int, repeats: int) -> dict:
    """Raw batched MJX physics steps/s with fresh uniform controls every policy step."""
    model = variant.model()
    task = Reach(model)
    mjx_model = mjx.put_model(model)
    start = mjx.put_data(model, start_physics(task, np.asarray(task.initial_qpos(None), np.float64)))
    data = jax.tree.map(lambda x: jnp.broadcast_to(x, (batch, *x.shape)), start)
    low, high = (jnp.asarray(x, jnp.float32) for x in model.actuator_ctrlrange.T)

    def policy_step(data, key):
        data = data.replace(ctrl=jax.random.uniform(key, (batch, model.nu), minval=low, maxval=high))
        step = jax.vmap(mjx.step, (None, 0))
        return jax.lax.fori_loop(0, variant.frame_skip, lambda _, d: step(mjx_model, d), data), None

    def rollout(data, key):
        return jax.lax.scan(policy_step, data, jax.random.split(key, steps))[0]

    compile_s, wall, _ = time_compiled(rollout, data, jax.random.key(0), repeats=repeats)
    physics = batch * steps * variant.frame_skip / wall
    return {"compile_s": compile_s, "physics_steps_per_s": physics, "policy_steps_per_s": physics / variant.frame_skip,
            "sim_s_per_s": physics * variant.timestep}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--batch-sizes", default="8")
    parser.add_argument("--steps", type=int, default=4, help="policy steps per timed run")
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--fidelity-steps", type=int, default=50, help="open-loop policy steps for the fidelity check")
    parser.add_argument("--out", default=None)
    args = parser.parse_args()

    actions = np.random.default_rng(0).uniform(-1, 1, (args.fidelity_steps, 20)).astype(np.float32)
    reference = fingertip_trajectory(VARIANTS[0], actions)
    rows = []
    for variant in VARIANTS:
        error = np.linalg.norm(fingertip_trajectory(variant, actions) - reference, axis=-1)
        for batch in (int(b) for b in args.batch_sizes.split(",")):
            row = {"variant": variant.name, "batch": batch, "frame_skip": variant.frame_skip,
                   "fingertip_error_mean_mm": 1e3 * float(error.mean()),
                   "fingertip_error_max_mm": 1e3 * float(error.max()),
                   **throughput(variant, batch, args.steps, args.repeats),
                   "peak_memory_gib": (peak_memory_bytes() or 0) / 2**30 or None}
            rows.append(row)
            print(f"{variant.name} @ {batch}: {row['sim_s_per_s']:,.0f} sim-s/s", flush=True)
    stock = {r["batch"]: r["physics_steps_per_s"] * 0.002 for r in rows if r["variant"] == VARIANTS[0].name}
    for row in rows:
        row["speedup_sim_s"] = row["sim_s_per_s"] / stock[row["batch"]]
    config = {"scene": "reach.xml (Gym hand, margins zeroed, floor removed)", "policy_dt_s": POLICY_DT,
              "fidelity": f"{args.fidelity_steps} open-loop policy steps of uniform relative actions, C MuJoCo",
              **vars(args)}
    path = write_results("physics_throughput", config, rows, args.out)
    print(markdown_table(rows, [
        ("variant", "variant", "s"), ("batch", "envs", "d"), ("physics_steps_per_s", "physics steps/s", ",.0f"),
        ("policy_steps_per_s", "policy steps/s", ",.0f"), ("sim_s_per_s", "sim-s/s", ",.0f"),
        ("speedup_sim_s", "x stock", ".1f"), ("fingertip_error_mean_mm", "tip error mean mm", ".2f"),
        ("fingertip_error_max_mm", "tip error max mm", ".2f"), ("compile_s", "compile s", ".1f"),
        ("peak_memory_gib", "peak GiB", ".2f"),
    ]))
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
