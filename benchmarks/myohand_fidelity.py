"""Do MJX's two implementations step the MyoHand's muscles and tendon wraps as C MuJoCo does?

The stock MyoHand (`envs.myohand.model.load_hand`: myo-sim 0.2.3, 2 ms, Newton 100/50) is stepped from the same
states with the same excitations in C MuJoCo (float64, the reference), MJX's JAX implementation and MJX's Warp
implementation (float32 both; Warp runs on the CPU when there is no GPU). Each environment starts at rest from joint
angles drawn uniformly within the joints' ranges (as MyoHandPose starts) and gets excitations drawn uniformly in
[0, 1], held for 10 physics steps (one 20 ms policy step). Per implementation and horizon (physics steps), the largest
difference from C MuJoCo over all environments and steps up to it: joint angles (rad), tendon lengths (m) and muscle
forces (N, and as a share of the largest force C MuJoCo reached); and the tendon whose length differs most after the
first physics step.

    python benchmarks/myohand_fidelity.py                       # 4 envs x 500 physics steps (1 s), both impls
    python benchmarks/myohand_fidelity.py --envs 16 --steps 2500 --impls jax

Writes results/myohand/myohand_fidelity_<platform>.json unless --out says otherwise.
"""

from __future__ import annotations

import argparse
import time

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from common import markdown_table, write_results

from angora_jax.envs.mjx_env import local_device, mjx_module, quiet_iteration_caps, require_warp, warp_sizes
from angora_jax.envs.myohand.model import load_hand
from angora_jax.envs.myohand.pose import MyoHandPose

FIELDS = ("qpos", "ten_length", "actuator_force")
HOLD = 10  # physics steps per drawn excitation: one 20 ms policy step of MyoHandPose


def inputs(model: mujoco.MjModel, envs: int, steps: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Initial joint angles `(envs, nq)` (MyoHandPose's draw) and excitations `(steps, envs, nu)`, each held for
    `HOLD` physics steps."""
    key = jax.random.key(seed)
    qpos = np.asarray(jax.vmap(MyoHandPose(model).initial_qpos)(jax.random.split(key, envs)), np.float64)
    held = np.random.default_rng(seed).uniform(0.0, 1.0, (-(-steps // HOLD), envs, model.nu))
    return qpos, np.repeat(held, HOLD, axis=0)[:steps]


def c_mujoco(model: mujoco.MjModel, qpos: np.ndarray, ctrl: np.ndarray) -> dict[str, np.ndarray]:
    """C MuJoCo's trajectories: each field `(steps, envs, size)` after every physics step."""
    steps, envs = ctrl.shape[:2]
    out = {f: np.zeros((steps, envs, getattr(mujoco.MjData(model), f).size)) for f in FIELDS}
    for env in range(envs):
        data = mujoco.MjData(model)
        data.qpos[:] = qpos[env]
        mujoco.mj_forward(model, data)
        for t in range(steps):
            data.ctrl[:] = ctrl[t, env]
            mujoco.mj_step(model, data)
            for f in FIELDS:
                out[f][t, env] = getattr(data, f)
    return out


def mjx(model: mujoco.MjModel, impl: str, qpos: np.ndarray, ctrl: np.ndarray) -> tuple[dict[str, np.ndarray], float]:
    """MJX's trajectories on implementation `impl` (as `c_mujoco`), and the seconds compiling and running took."""
    mjx_lib = mjx_module()
    envs = qpos.shape[0]
    sizes = {}
    if impl == "warp":
        require_warp()
        sizes = warp_sizes(model, envs)
    device = local_device(impl)
    mjx_model = mjx_lib.put_model(model, device=device, impl=impl)
    if impl == "warp":
        mjx_model = quiet_iteration_caps(mjx_model)
    data0 = mjx_lib.make_data(model, device=device, impl=impl, **sizes)

    def start(q):
        return mjx_lib.forward(mjx_model, data0.replace(qpos=q))

    def physics_step(data, c):
        data = jax.vmap(lambda d, u: mjx_lib.step(mjx_model, d.replace(ctrl=u)))(data, c)
        return data, {f: getattr(data, f) for f in FIELDS}

    begin = time.perf_counter()
    data = jax.jit(jax.vmap(start))(jnp.asarray(qpos, jnp.float32))
    _, out = jax.jit(lambda d, c: jax.lax.scan(physics_step, d, c))(data, jnp.asarray(ctrl, jnp.float32))
    out = jax.device_get(out)
    return {f: np.asarray(v, np.float64) for f, v in out.items()}, time.perf_counter() - begin


def differences(model: mujoco.MjModel, reference: dict[str, np.ndarray], other: dict[str, np.ndarray],
                horizon: int) -> dict[str, float | str]:
    """Largest absolute differences over the first `horizon` physics steps, per field; forces also relative to the
    largest force; and the tendon whose length differs most after the first step (a wrap that differs shows there,
    before the trajectories part)."""
    diff = {f: float(np.abs(other[f][:horizon] - reference[f][:horizon]).max()) for f in FIELDS}
    largest = float(np.abs(reference["actuator_force"][:horizon]).max())
    first = np.abs(other["ten_length"][0] - reference["ten_length"][0]).max(axis=0)
    return {"max_joint_angle_diff_rad": diff["qpos"], "max_tendon_length_diff_m": diff["ten_length"],
            "max_muscle_force_diff_n": diff["actuator_force"], "largest_muscle_force_n": largest,
            "max_muscle_force_diff_share": diff["actuator_force"] / largest,
            "first_step_worst_tendon": model.tendon(int(first.argmax())).name,
            "first_step_worst_tendon_diff_m": float(first.max())}


def main(argv: list[str] | None = None) -> int:
    """Run the comparison with command-line `argv` (default: sys.argv); write the JSON and print a table."""
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--envs", type=int, default=4)
    parser.add_argument("--steps", type=int, default=500, help="physics steps of 2 ms (default 500: 1 s)")
    parser.add_argument("--impls", default="jax,warp", help="MJX implementations, comma-separated")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default=None, help="JSON path (default: results/myohand/myohand_fidelity_<platform>)")
    args = parser.parse_args(argv)
    model = load_hand()
    qpos, ctrl = inputs(model, args.envs, args.steps, args.seed)
    reference = c_mujoco(model, qpos, ctrl)
    horizons = sorted({h for h in (10, 100, 500, args.steps) if h <= args.steps})
    rows = []
    for impl in args.impls.split(","):
        trajectories, seconds = mjx(model, impl, qpos, ctrl)
        rows += [{"impl": impl, "physics_steps": h, "seconds_compile_and_run": seconds,
                  **differences(model, reference, trajectories, h)} for h in horizons]
    config = {"model": "myo-sim 0.2.3 MyoHand (stock)", "timestep_s": float(model.opt.timestep),
              "iterations": int(model.opt.iterations), "ls_iterations": int(model.opt.ls_iterations),
              "envs": args.envs, "steps": args.steps, "seed": args.seed, "excitation_hold_steps": HOLD,
              "reference": "C MuJoCo, float64"}
    path = write_results("myohand_fidelity", config, rows, args.out, study="myohand")
    print(markdown_table(rows, [("impl", "impl", "s"), ("physics_steps", "steps", "d"),
                                ("max_joint_angle_diff_rad", "joint rad", ".2e"),
                                ("max_tendon_length_diff_m", "tendon m", ".2e"),
                                ("max_muscle_force_diff_n", "force N", ".2e"),
                                ("max_muscle_force_diff_share", "force share", ".2e")]))
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
