"""Batched environment throughput of a task against raw MJX and single-threaded C MuJoCo.

For each batch size: our `vmap(env.step)` under `lax.scan` (random actions, auto-reset, task logic), and raw
`vmap(mjx.step)` on the same model with the same number of physics steps; the ratio is our overhead. Also C MuJoCo
`mj_step` on one CPU thread, and our eager CPU twin. Throughput is given as physics steps/s, policy (env) steps/s
and simulated seconds per wall second (physics steps/s x timestep), the unit that is fair across control rates.

    python benchmarks/env_throughput.py --batch-sizes 1,8,32 --steps 20          # CPU, small
    python benchmarks/env_throughput.py --batch-sizes 1024,4096,16384 --steps 100  # GPU
    python benchmarks/env_throughput.py --task ShadowHandCube --batch-sizes 1024,4096,8192,16384 --steps 20  # GPU
"""

from __future__ import annotations

import argparse
import json
import time

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from common import env_step_rate, markdown_table, peak_memory_bytes, raw_mjx_rate, write_results

import angora_jax as aj


def c_mujoco(env, task: str, options: dict, seconds: float) -> dict:
    """Single-threaded C MuJoCo `mj_step` with uniform random controls, and our eager CPU twin, `seconds` each."""
    model = env.task.model
    data = mujoco.MjData(model)
    rng = np.random.default_rng(0)
    low, high = model.actuator_ctrlrange.T
    steps, start = 0, time.perf_counter()
    while time.perf_counter() - start < seconds:
        data.ctrl[:] = rng.uniform(low, high)
        mujoco.mj_step(model, data, nstep=env.frame_skip)
        steps += env.frame_skip
    raw = steps / (time.perf_counter() - start)
    cpu = aj.make(task, backend="cpu", **options)
    state = cpu.reset(jax.random.key(0))
    state = cpu.step(state, jnp.zeros(model.nu))
    policy_steps, start = 0, time.perf_counter()
    while time.perf_counter() - start < seconds:
        if float(state.done):
            state = cpu.reset(jax.random.key(policy_steps))
        state = cpu.step(state, jnp.asarray(rng.uniform(-1, 1, model.nu), jnp.float32))
        policy_steps += 1
    twin = policy_steps * env.frame_skip / (time.perf_counter() - start)
    return {"c_mujoco_physics_steps_per_s": raw, "cpu_twin_physics_steps_per_s": twin}


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--task", default="ShadowHandReach")
    parser.add_argument("--options", default="{}", help='task options as JSON, e.g. \'{"touch": false}\'')
    parser.add_argument("--batch-sizes", default="1,8,32")
    parser.add_argument("--steps", type=int, default=20, help="policy steps per environment per timed run")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--repeats", type=int, default=3, help="timed runs after compiling; the best counts")
    parser.add_argument("--c-seconds", type=float, default=2.0,
                        help="seconds of C MuJoCo and of the eager CPU twin, each, on one thread")
    parser.add_argument("--out", default=None,
                        help="JSON path (default: results/env_train_throughput/env_throughput_<platform>.json)")
    args = parser.parse_args(argv)

    options = json.loads(args.options)
    env = aj.make(args.task, **options)
    timestep = float(env.task.model.opt.timestep)
    single = c_mujoco(env, args.task, options, args.c_seconds)
    rows = []
    for batch in (int(b) for b in args.batch_sizes.split(",")):
        mine = env_step_rate(env, batch, args.steps, args.repeats, args.seed)
        raw = raw_mjx_rate(env, batch, args.steps, args.repeats, args.seed)
        physics = mine["env_steps_per_s"] * env.frame_skip
        row = {
            "task": args.task, "batch": batch,
            "physics_steps_per_s": physics,
            "env_steps_per_s": mine["env_steps_per_s"],
            "sim_s_per_s": physics * timestep,
            "raw_mjx_physics_steps_per_s": raw["env_steps_per_s"] * env.frame_skip,
            "ours_over_raw_mjx": mine["env_steps_per_s"] / raw["env_steps_per_s"],
            "ours_over_c_mujoco_1_thread": physics / single["c_mujoco_physics_steps_per_s"],
            "compile_s": mine["compile_s"], "raw_mjx_compile_s": raw["compile_s"],
            "peak_memory_gib": (peak_memory_bytes() or 0) / 2**30 or None,
        }
        rows.append(row)
        print(f"batch {batch}: {row['env_steps_per_s']:.0f} env steps/s, "
              f"ratio to raw MJX {row['ours_over_raw_mjx']:.2f}", flush=True)
    config = {"task": args.task, "options": options, "steps": args.steps, "frame_skip": env.frame_skip,
              "timestep_s": timestep, "control_dt_s": env.dt, "solver_iterations": int(env.task.model.opt.iterations),
              "ls_iterations": int(env.task.model.opt.ls_iterations), **single}
    path = write_results("env_throughput", config, rows, args.out, study="env_train_throughput")
    print(markdown_table(rows, [
        ("batch", "envs", "d"), ("env_steps_per_s", "env steps/s", ",.0f"),
        ("physics_steps_per_s", "physics steps/s", ",.0f"), ("sim_s_per_s", "sim-s/s", ",.1f"),
        ("raw_mjx_physics_steps_per_s", "raw MJX physics steps/s", ",.0f"),
        ("ours_over_raw_mjx", "ours / raw MJX", ".2f"),
        ("ours_over_c_mujoco_1_thread", "ours / C MuJoCo 1 thread", ".1f"),
        ("compile_s", "compile s", ".1f"), ("peak_memory_gib", "peak GiB", ".2f"),
    ]))
    print(f"C MuJoCo, 1 thread: {single['c_mujoco_physics_steps_per_s']:,.0f} physics steps/s "
          f"({single['c_mujoco_physics_steps_per_s'] * timestep:.1f} sim-s/s); eager CPU twin: "
          f"{single['cpu_twin_physics_steps_per_s']:,.0f} physics steps/s")
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
