"""Hand physics: MJX throughput of stock and tuned Shadow-hand scenes and of the MyoHand on each MJX backend, and each
tuning's fidelity.

Configurations (`CONFIGS`, in priority order; `--configs` picks some, in the order given):
  reach-tuned     the ShadowHandReach scene: REACH_PHYSICS (5 ms, Newton 2 / line search 4), untouched geoms pruned,
                  no sensors
  cube-tuned      the ShadowHandCube scene: CUBE_PHYSICS (8 ms, 4/8), untouched geoms pruned, 97 touch sensors
  reach-stock     Gym reach.xml with the Gym settings (2 ms, 20/50), all its contacts and its 29 sensors (margins
                  zeroed and the floor removed, which MJX needs)
  cube-stock      Gym manipulate_block_touch_sensors.xml, Gym settings, all its contacts, its touch sensors (its
                  joint-position sensors, which repeat qpos, dropped as in the task)
  menagerie       the MuJoCo Menagerie Shadow hand tuned for MJX, shipped in mujoco-mjx (test_data/shadow_hand:
                  1 ms, Newton 1/4, impratio 10, contact caps 15, decimated fingertip meshes); a different hand
                  whose sphere falls to the floor, so raw throughput only, its 1 ms timestep counted in sim-s/s
  cube-tuned-contact-caps  cube-tuned with the Menagerie's MJX contact caps (`PhysicsSettings.contact_caps` 15);
                  C MuJoCo ignores them, so `--mjx-fidelity` checks them on MJX (cube poses after 2 s of the
                  open-loop targets, against cube-tuned on MJX)
  cube-tuned-condim3  cube-tuned with the Menagerie's contact dimension 3 (no torsional friction) for the cube and
                  fingertips instead of 4: 4 constraint rows per cube contact instead of 6
  reach-tuned-gym-contacts  REACH_PHYSICS with all Gym contacts (no sensors): what the pruning buys
  reach-tuned-gym-sensors  reach-tuned with the Gym scene's 29 sensors (24 joint positions, 5 touch): what
                  dropping them buys
  reach-tuned-no-finger-pairs  reach-tuned without the 19 explicit finger-finger pairs: what they cost
  myohand         the muscle-driven MyoHand as myo-sim 0.2.3 builds it (2 ms, Newton 100/50; needs the myo extra),
                  from MyoHandPose's episode starts, uniform random excitations in [0, 1]: throughput only
                  (benchmarks/myohand_fidelity.py compares its MJX implementations with C MuJoCo)
  myohand_reorient  the MyoHand palm up with MyoChallenge 2022's die on the palm (`MyoHandReorient`'s scene and
                  start, 10 ms policy steps): the hand's contacts with the die, on Warp only (MJX's JAX implementation
                  has no ellipsoid-box collision); timed runs of a few policy steps from the start keep the die on the
                  palm (random excitations throw it off after 0.15 s); throughput only. Issue 62's target: 1M physics
                  steps/s on one GPU at 16k+ envs: --configs myohand_reorient --impls warp --batch-sizes 16384,32768
`--physics reach:0.004/4/8,cube:0.004/4/8` adds configurations of the tuned scenes with other settings (timestep
s / Newton iterations / line-search iterations): the sweep behind REACH_PHYSICS and CUBE_PHYSICS.

Throughput: for each configuration and MJX backend (`impl="jax"`; `impl="warp"` for `--warp-configs`, by default the
tuned scenes and the MyoHand, when warp-lang is installed, otherwise a "skipped" row), in a subprocess of its own so
that device memory peaks do not accumulate, at each batch size in increasing order (so the running peak is the
current batch's): raw batched physics (`common.raw_mjx_rate`: `vmap(mjx.step)` in `lax.scan` from our tasks' episode
starts, fresh uniform random joint targets every policy step) as physics steps/s, policy steps/s and sim-s/s
(physics steps/s x timestep), compile seconds, setup seconds (the reset's compile and the first run, where Warp
builds its kernels), peak device memory (`peak_bytes_in_use`, where the backend reports it: GPUs; Warp's own scratch
allocations are not in it), XLA's memory for the program per environment (`compiled.memory_analysis()`, any device:
arguments, outputs and temporaries), and the scene's MJX sizes (contacts, constraint rows, KiB of one environment's
`mjx.Data`).

Fidelity, on C MuJoCo (float64, one thread: it isolates the scene and its settings from float32 effects), against
the stock scene of the same task:
  reach: fingertip position error (mm; mean and max over fingertips and policy steps) along the same
         `--fidelity-steps` open-loop policy steps of uniform random relative actions from the reach start.
  cube:  cube position (mm) and orientation (rad) error after 2 s (25 policy steps) of the same open-loop joint
         targets (the start's targets plus a smoothed random walk of 30% of each half range, which keeps the cube
         in the hand), medians over `--episodes` random cube starts, and how often the drop verdict disagrees; and,
         under uniform random relative actions (training's first policy) from the same starts, the drop rate within
         2 s and the largest cube speed (m/s; inf when the simulation blew up).

    python benchmarks/physics_throughput.py --configs reach-tuned,reach-stock     # CPU smoke run, tiny batches
    python benchmarks/physics_throughput.py --gpu                                 # GPU, about 8 minutes

`--gpu` measures reach-tuned and cube-tuned at 1k, 8k and 32k environments and the other configurations at 8k,
5 policy steps per timed run, best of 2, and stops starting configurations after `--max-minutes` (8 with `--gpu`):
what did not start gets a "skipped: time budget" row. On an H100 the stock scenes compile in 30-70 s each and the
tuned ones in 20-50 s; Warp compiles its kernels on first use (cached in ~/.cache/warp for the next run).
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import importlib.util
import json
import os
import subprocess
import sys
import time
from collections.abc import Callable

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from common import markdown_table, peak_memory_bytes, raw_mjx_rate, write_results

from angora_jax.envs.core import Sensation
from angora_jax.envs.mjx_env import WARP_REQUIREMENT, MjxEnv, jax_collision_gap, mjx_module
from angora_jax.envs.mujoco_task import MujocoTask, set_mjx_impl, start_physics
from angora_jax.envs.myohand.die import JAX_LACKS, load_hand_with_die
from angora_jax.envs.myohand.model import MYOHAND_PHYSICS, load_hand
from angora_jax.envs.myohand.pose import MyoHandPose
from angora_jax.envs.myohand.reorient import MyoHandReorient
from angora_jax.envs.shadow_hand import REACH_PHYSICS
from angora_jax.envs.shadow_hand.cube import CUBE_PHYSICS, load_cube_scene
from angora_jax.envs.shadow_hand.ihom import Ihom, angular_distance
from angora_jax.envs.shadow_hand.model import GYM_PHYSICS, PhysicsSettings, load_scene
from angora_jax.envs.shadow_hand.reach import Reach

mjx = mjx_module()
REACH_DT, CUBE_DT, MYOHAND_DT, REORIENT_DT = 0.02, 0.08, 0.02, 0.01  # s per policy step of the tasks
CUBE_HORIZON = 25  # policy steps of the cube fidelity checks (2 s)
MENAGERIE_SCENE = os.path.join(os.path.dirname(mjx.__file__), "test_data", "shadow_hand", "scene_right.xml")
GPU_SWEEP, GPU_COMPARE = "1024,8192,32768", "8192"
RESULT_PREFIX = "RESULT "


@dataclasses.dataclass(frozen=True)
class Config:
    """A scene to measure: `build(impl)` compiles it for an MJX implementation. task: "reach" or "cube" (compared
    with that task's stock scene), "myohand" or "myohand_reorient" (their episode starts, throughput only) or None
    (throughput only); sweep: measured at every batch size of the sweep; mjx_base: for a change that C MuJoCo cannot
    see, the configuration without it (`--mjx-fidelity` compares the two on MJX); jax_lacks: what MJX's JAX
    implementation cannot step in the scene ("" when nothing), which then runs on Warp only."""

    name: str
    task: str | None
    control_dt: float
    build: Callable[[str], mujoco.MjModel]
    sweep: bool = False
    mjx_base: str | None = None
    jax_lacks: str = ""


def reach_config(name: str, physics: PhysicsSettings, prune_contacts: bool = True, finger_pairs: bool = True,
                 sensors: tuple | None = (), sweep: bool = False) -> Config:
    def build(impl: str) -> mujoco.MjModel:
        def edit(spec: mujoco.MjSpec) -> None:
            for pair in [] if finger_pairs else list(spec.pairs):
                spec.delete(pair)
        return load_scene("reach.xml", edit, dataclasses.replace(physics, impl=impl), prune_contacts, sensors)
    return Config(name, "reach", REACH_DT, build, sweep)


def cube_config(name: str, physics: PhysicsSettings, prune_contacts: bool = True, max_condim: int = 6,
                sweep: bool = False, mjx_base: str | None = None) -> Config:
    def build(impl: str) -> mujoco.MjModel:
        model = load_cube_scene(True, dataclasses.replace(physics, impl=impl), prune_contacts)
        model.geom_condim[:] = np.minimum(model.geom_condim, max_condim)
        return model
    return Config(name, "cube", CUBE_DT, build, sweep, mjx_base)


def menagerie(impl: str) -> mujoco.MjModel:
    """The Menagerie Shadow hand scene as mujoco-mjx ships it, for MJX implementation `impl`."""
    spec = mujoco.MjSpec.from_file(MENAGERIE_SCENE)
    set_mjx_impl(spec, impl)
    return spec.compile()


def myohand(impl: str) -> mujoco.MjModel:
    """The stock MyoHand (`envs.myohand.model.load_hand`) for MJX implementation `impl`."""
    return load_hand(dataclasses.replace(MYOHAND_PHYSICS, impl=impl))


def myohand_die(impl: str) -> mujoco.MjModel:
    """The MyoHand with MyoChallenge 2022's die (`envs.myohand.die.load_hand_with_die`) for MJX implementation `impl`,
    with the scene's Warp budget."""
    return load_hand_with_die(dataclasses.replace(MYOHAND_PHYSICS, impl=impl))


CONFIGS = {c.name: c for c in (
    reach_config("reach-tuned", REACH_PHYSICS, sweep=True),
    cube_config("cube-tuned", CUBE_PHYSICS, sweep=True),
    reach_config("reach-stock", GYM_PHYSICS, prune_contacts=False, sensors=None),
    cube_config("cube-stock", GYM_PHYSICS, prune_contacts=False),
    Config("menagerie", None, REACH_DT, menagerie),
    cube_config("cube-tuned-contact-caps", dataclasses.replace(CUBE_PHYSICS, contact_caps=15), mjx_base="cube-tuned"),
    cube_config("cube-tuned-condim3", CUBE_PHYSICS, max_condim=3),
    reach_config("reach-tuned-gym-contacts", REACH_PHYSICS, prune_contacts=False),
    reach_config("reach-tuned-gym-sensors", REACH_PHYSICS, sensors=None),
    reach_config("reach-tuned-no-finger-pairs", REACH_PHYSICS, finger_pairs=False),
    Config("myohand", "myohand", MYOHAND_DT, myohand, sweep=True),
    Config("myohand_reorient", "myohand_reorient", REORIENT_DT, myohand_die, sweep=True, jax_lacks=JAX_LACKS),
)}


def extra_configs(text: str | None) -> list[Config]:
    """Configurations from `--physics`, e.g. 'cube:0.004/4/8' (task:timestep/iterations/ls_iterations)."""
    configs = []
    for item in (text or "").split(","):
        if not item:
            continue
        task, _, numbers = item.partition(":")
        make = {"reach": reach_config, "cube": cube_config}.get(task)
        usage = f"--physics {item!r}: expected reach|cube:timestep/iterations/ls_iterations, e.g. cube:0.004/4/8"
        try:
            timestep, iterations, ls = numbers.split("/")
            physics = PhysicsSettings(float(timestep), int(iterations), int(ls))
        except ValueError as error:
            raise SystemExit(f"{usage} ({error}).") from None
        if make is None:
            raise SystemExit(f"{usage} (unknown task {task!r}).")
        configs.append(make(f"{task} {float(timestep) * 1e3:g} ms {iterations}/{ls}", physics))
    return configs


class Idle(MujocoTask):
    """No task: a model's default pose and raw physics, for scenes without one of our tasks (the Menagerie hand)."""

    def __init__(self, model: mujoco.MjModel):
        self.model = model

    def initial_qpos(self, key: jax.Array) -> jax.Array:
        return jnp.asarray(self.model.qpos0, jnp.float32)

    def initial_info(self, key, snap):
        return {}

    def observe(self, snap, info):
        return Sensation.make(proprioception=snap.qpos)

    def evaluate(self, key, prev, snap, info):
        return jnp.zeros(()), jnp.zeros((), bool), info, {}

    def control(self, action, snap):
        return action


TASKS = {"reach": Reach, "cube": Ihom, "myohand": MyoHandPose, "myohand_reorient": MyoHandReorient, None: Idle}


# ---------------------------------------------------------------- throughput (run in a worker subprocess)

def scene_sizes(model: mujoco.MjModel) -> dict:
    """MJX (JAX implementation) sizes of one environment: contacts, constraint rows, KiB of `mjx.Data`; for a scene
    that MJX's JAX implementation cannot step, the Warp budget it states (`mjx_env.warp_sizes`) and no KiB."""
    if jax_collision_gap(model):
        return {"contacts": int(model.nconmax), "constraint_rows": int(model.njmax), "data_kib_per_env": None}
    data = mjx.make_data(model, impl="jax")
    return {"contacts": int(data._impl.contact.dist.shape[0]), "constraint_rows": int(data._impl.efc_J.shape[0]),
            "data_kib_per_env": sum(x.nbytes for x in jax.tree.leaves(data)) / 1024}


def throughput(config: Config, impl: str, batch: int, policy_steps: int, repeats: int) -> dict:
    """Raw batched MJX physics of `config` on the default device (`common.raw_mjx_rate`: fresh uniform random joint
    targets each policy step, from our tasks' episode starts): physics and policy steps/s, sim-s/s, compile s and
    XLA's memory for the program."""
    model = config.build(impl)
    env = MjxEnv(TASKS[config.task](model), round(config.control_dt / model.opt.timestep), 1000,
                 warp_max_envs=batch)
    begin = time.perf_counter()
    rate = raw_mjx_rate(env, batch, policy_steps, repeats)
    # What else the call took: the reset's compile and the first run, where Warp builds its kernels (at most
    # `repeats` timed runs follow, each at least as long as the rate says).
    setup_s = time.perf_counter() - begin - rate["compile_s"] - repeats * batch * policy_steps / rate["env_steps_per_s"]
    physics = rate["env_steps_per_s"] * env.frame_skip
    memory = rate["memory_bytes"]
    return {"timestep_ms": 1e3 * model.opt.timestep, "frame_skip": env.frame_skip, "compile_s": rate["compile_s"],
            "setup_s": setup_s, "physics_steps_per_s": physics, "policy_steps_per_s": rate["env_steps_per_s"],
            "sim_s_per_s": physics * model.opt.timestep,
            "xla_kib_per_env": memory / batch / 1024 if memory is not None else None}


def worker(args: argparse.Namespace) -> None:
    """Measure one configuration on one backend at each batch size; print one JSON line per batch size."""
    config = next(c for c in all_configs(args) if c.name == args.worker)
    sizes = scene_sizes(config.build("jax"))
    for batch in sorted(int(b) for b in args.batch_sizes.split(",")):
        row = {**throughput(config, args.impl, batch, args.policy_steps, args.repeats), **sizes}
        peak = peak_memory_bytes()
        row["peak_memory_gib"] = peak / 2**30 if peak else None
        print(RESULT_PREFIX + json.dumps({"batch": batch, **row}), flush=True)


def run_worker(config: Config, impl: str, batches: str, args: argparse.Namespace, timeout: float) -> list[dict]:
    """Run `worker` for one configuration and backend in a subprocess; failures become rows that say why."""
    command = [sys.executable, os.path.abspath(__file__), "--worker", config.name, "--impl", impl,
               "--batch-sizes", batches, "--policy-steps", str(args.policy_steps), "--repeats", str(args.repeats)]
    command += ["--physics", args.physics] if args.physics else []
    try:
        done = subprocess.run(command, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired as error:
        # TimeoutExpired holds the output read so far as bytes, even with text=True.
        stdout = error.stdout.decode(errors="replace") if isinstance(error.stdout, bytes) else error.stdout or ""
        done = subprocess.CompletedProcess(command, -1, stdout, f"timed out after {timeout:.0f} s")
    rows = [json.loads(line[len(RESULT_PREFIX):]) for line in done.stdout.splitlines()
            if line.startswith(RESULT_PREFIX)]
    measured = {r["batch"] for r in rows}
    reason = (done.stderr or "").strip().splitlines()[-1:] or [f"exit code {done.returncode}"]
    rows += [{"batch": int(b), "status": f"failed: {reason[0][:200]}"}
             for b in batches.split(",") if int(b) not in measured]
    return rows


# ---------------------------------------------------------------- fidelity (C MuJoCo, in the main process)

def relative_targets(model: mujoco.MjModel, data: mujoco.MjData, action: np.ndarray) -> np.ndarray:
    """The tasks' relative control: targets moved from the current joint positions by up to half the range."""
    low, high = model.actuator_ctrlrange.T
    return np.clip(data.actuator_length + action * (high - low) / 2, low, high)


@functools.cache
def fingertip_trajectory(config: Config, steps: int) -> np.ndarray:
    """Fingertip positions (m) after each of `steps` policy steps of uniform random relative actions (seed 0),
    shape `(steps, 5, 3)`."""
    model = config.build("jax")
    task = Reach(model)
    data = start_physics(task, np.asarray(task.initial_qpos(None), np.float64))
    frame_skip = round(config.control_dt / model.opt.timestep)
    tips = []
    for action in np.random.default_rng(0).uniform(-1, 1, (steps, model.nu)):
        data.ctrl[:] = relative_targets(model, data, action)
        mujoco.mj_step(model, data, nstep=frame_skip)
        tips.append(data.site_xpos[task.fingertip_ids].copy())
    return np.stack(tips)


def reach_fidelity(config: Config, stock: Config, steps: int) -> dict:
    error = np.linalg.norm(fingertip_trajectory(config, steps) - fingertip_trajectory(stock, steps), axis=-1)
    return {"tip_error_mean_mm": 1e3 * float(error.mean()), "tip_error_max_mm": 1e3 * float(error.max())}


def cube_episodes(task: Ihom, episodes: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Random cube starts `(episodes, nq)`, open-loop target offsets `(episodes, CUBE_HORIZON, nu)` (a smoothed random
    walk, in half ranges) and uniform random relative actions of the same shape, all from `seed`."""
    rng, walks = np.random.default_rng(seed), np.zeros((episodes, CUBE_HORIZON, task.model.nu))
    for t in range(1, CUBE_HORIZON):
        walks[:, t] = 0.7 * walks[:, t - 1] + 0.3 * rng.uniform(-1, 1, (episodes, task.model.nu))
    actions = rng.uniform(-1, 1, walks.shape)
    qposes = np.stack([np.asarray(task.initial_qpos(k), np.float64)
                       for k in jax.random.split(jax.random.key(seed), episodes)])
    return qposes, 0.3 * walks * task._ctrl_half_range, actions


@functools.cache
def cube_runs(config: Config, episodes: int, seed: int) -> list[dict]:
    """Per random start (`cube_episodes`): the cube pose after `CUBE_HORIZON` policy steps of open-loop joint targets
    (the start's plus the walk, which keeps the cube in the hand) and whether it dropped; and under the random
    relative actions, whether it dropped within the horizon and its largest speed (m/s)."""
    model = config.build("jax")
    task, frame_skip = Ihom(model), round(config.control_dt / model.opt.timestep)
    low, high = model.actuator_ctrlrange.T
    runs = []
    for qpos, walk, episode_actions in zip(*cube_episodes(task, episodes, seed), strict=True):
        data = start_physics(task, qpos)
        start_ctrl = data.ctrl.copy()
        for offset in walk:
            data.ctrl[:] = np.clip(start_ctrl + offset, low, high)
            mujoco.mj_step(model, data, nstep=frame_skip)
        run = {"pose": data.qpos[task.cube_qpos:task.cube_qpos + 7].copy(), "dropped": cube_dropped(task, data)}
        data, fastest, dropped = start_physics(task, qpos), 0.0, False
        for action in episode_actions:
            data.ctrl[:] = relative_targets(model, data, action)
            for _ in range(frame_skip):
                mujoco.mj_step(model, data)
                fastest = max(fastest, float(np.abs(data.qvel[task.cube_dof:task.cube_dof + 3]).max()))
            if not np.isfinite(data.qpos).all():
                fastest = float("inf")
            dropped = dropped or cube_dropped(task, data)
            if dropped or not np.isfinite(fastest):
                break
        runs.append({**run, "random_dropped": dropped, "random_max_speed": fastest})
    return runs


def cube_dropped(task: Ihom, data: mujoco.MjData) -> bool:
    return bool(data.qpos[task.cube_qpos + 2] < data.xpos[task.palm_id, 2])


def cube_fidelity(config: Config, stock: Config, episodes: int, seed: int) -> dict:
    runs, reference = cube_runs(config, episodes, seed), cube_runs(stock, episodes, seed)
    pairs = list(zip(runs, reference, strict=True))
    return {
        "cube_pos_err_mm": 1e3 * float(np.median([np.linalg.norm(r["pose"][:3] - s["pose"][:3]) for r, s in pairs])),
        "cube_rot_err_rad": float(np.median([float(angular_distance(r["pose"][3:], s["pose"][3:]))
                                             for r, s in pairs])),
        "drop_disagree": float(np.mean([r["dropped"] != s["dropped"] for r, s in pairs])),
        "random_drop_rate": float(np.mean([r["random_dropped"] for r in runs])),
        "stock_random_drop_rate": float(np.mean([s["random_dropped"] for s in reference])),
        "random_max_speed": float(max(r["random_max_speed"] for r in runs)),
    }


def mjx_cube_poses(config: Config, episodes: int, seed: int) -> np.ndarray:
    """Cube poses `(episodes, 7)` after the open-loop targets of `cube_runs`, on batched MJX (JAX implementation,
    float32, default device): the check of changes that only MJX sees."""
    model = config.build("jax")
    task, frame_skip = Ihom(model), round(config.control_dt / model.opt.timestep)
    qposes, walks, _ = cube_episodes(task, episodes, seed)
    data = jax.tree.map(lambda *x: jnp.stack(x), *[mjx.put_data(model, start_physics(task, q)) for q in qposes])
    mjx_model, start_ctrl = mjx.put_model(model), data.ctrl
    low, high = (jnp.asarray(x, jnp.float32) for x in model.actuator_ctrlrange.T)
    step = jax.vmap(mjx.step, (None, 0))

    def policy_step(data, offset):
        data = data.replace(ctrl=jnp.clip(start_ctrl + offset, low, high))
        return jax.lax.fori_loop(0, frame_skip, lambda _, d: step(mjx_model, d), data), None

    offsets = jnp.asarray(np.swapaxes(walks, 0, 1), jnp.float32)
    final = jax.jit(lambda d, o: jax.lax.scan(policy_step, d, o)[0])(data, offsets)
    return np.asarray(final.qpos[:, task.cube_qpos:task.cube_qpos + 7], np.float64)


def mjx_fidelity(config: Config, args: argparse.Namespace) -> dict:
    """An MJX-only change against the same scene without it, both on MJX: cube position (mm) and orientation (rad)
    errors after 2 s, medians over the starts."""
    poses, reference = (mjx_cube_poses(c, args.episodes, args.seed) for c in (config, CONFIGS[config.mjx_base]))
    return {"cube_pos_err_mm": 1e3 * float(np.median(np.linalg.norm(poses[:, :3] - reference[:, :3], axis=-1))),
            "cube_rot_err_rad": float(np.median([float(angular_distance(p[3:], r[3:]))
                                                 for p, r in zip(poses, reference, strict=True)])),
            "note": f"MJX-only change: checked on MJX against {config.mjx_base}"}


def fidelity(config: Config, args: argparse.Namespace) -> dict:
    if config.task is None:
        return {"note": "another hand: no fidelity check"}
    if config.task == "myohand":
        return {"note": "the stock MyoHand: benchmarks/myohand_fidelity.py compares MJX with C MuJoCo"}
    if config.task == "myohand_reorient":
        return {"note": "the MyoHand and its die: tests/test_myohand_reorient.py compares Warp with C MuJoCo"}
    if config.mjx_base:
        if args.mjx_fidelity:
            return mjx_fidelity(config, args)
        return {"note": "MJX-only change: C MuJoCo cannot check it (--mjx-fidelity does on MJX)"}
    stock = CONFIGS[f"{config.task}-stock"]
    if config.task == "reach":
        return reach_fidelity(config, stock, args.fidelity_steps)
    return cube_fidelity(config, stock, args.episodes, args.seed)


# ---------------------------------------------------------------- main

def all_configs(args: argparse.Namespace) -> list[Config]:
    return [*CONFIGS.values(), *extra_configs(args.physics)]


def chosen_configs(args: argparse.Namespace) -> list[Config]:
    known = {c.name: c for c in all_configs(args)}
    if not args.configs:
        return list(known.values())
    names = args.configs.split(",")
    unknown = [n for n in names if n not in known]
    if unknown:
        raise SystemExit(f"Unknown configurations {unknown}; known: {sorted(known)}.")
    return [known[n] for n in names] + extra_configs(args.physics)


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--configs", default=None, help=f"comma-separated, run in this order; all: {list(CONFIGS)}")
    parser.add_argument("--physics", default=None, help="extra configurations, e.g. 'reach:0.004/4/8,cube:0.01/4/8'")
    parser.add_argument("--impls", default="jax,warp", help="MJX backends")
    parser.add_argument("--warp-configs", default="reach-tuned,cube-tuned,myohand,myohand_reorient",
                        help="configurations measured on warp too ('all': every one)")
    parser.add_argument("--gpu", action="store_true", help=f"GPU sizes: --batch-sizes {GPU_SWEEP} --compare-batch "
                        f"{GPU_COMPARE} --policy-steps 5 --max-minutes 8")
    parser.add_argument("--batch-sizes", default=None, help="the tuned scenes' sweep (CPU default 4)")
    parser.add_argument("--compare-batch", default=None, help="batch size of the other configurations (CPU: 4)")
    parser.add_argument("--policy-steps", type=int, default=None, help="policy steps per timed run (CPU: 2)")
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--max-minutes", type=float, default=None, help="start no configuration after this")
    parser.add_argument("--no-throughput", action="store_true", help="fidelity only (C MuJoCo)")
    parser.add_argument("--mjx-fidelity", action="store_true",
                        help="check MJX-only changes (contact caps) on MJX against the scene without them")
    parser.add_argument("--fidelity-steps", type=int, default=50, help="open-loop policy steps of the reach check")
    parser.add_argument("--episodes", type=int, default=64, help="random cube starts of the cube checks")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default=None)
    parser.add_argument("--worker", default=None, help=argparse.SUPPRESS)
    parser.add_argument("--impl", default="jax", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    gpu = {"batch_sizes": GPU_SWEEP, "compare_batch": GPU_COMPARE, "policy_steps": 5, "max_minutes": 8.0}
    cpu = {"batch_sizes": "4", "compare_batch": "4", "policy_steps": 2, "max_minutes": None}
    for key, value in (gpu if args.gpu else cpu).items():
        if getattr(args, key) is None:
            setattr(args, key, value)
    return args


def measure_throughput(configs: list[Config], args: argparse.Namespace) -> list[dict]:
    warp = importlib.util.find_spec("warp") is not None
    warp_configs = {c.name for c in configs} if args.warp_configs == "all" else set(args.warp_configs.split(","))
    deadline = time.monotonic() + 60 * args.max_minutes if args.max_minutes else float("inf")
    rows = []
    for config in configs:
        for impl in args.impls.split(","):
            if impl == "warp" and config.name not in warp_configs:
                continue
            batches = args.batch_sizes if config.sweep else args.compare_batch
            base = {"config": config.name, "impl": impl}
            remaining = deadline - time.monotonic()
            if impl == "warp" and not warp:
                status = f"skipped: warp not installed (pip install {WARP_REQUIREMENT})"
            elif impl == "jax" and config.jax_lacks:
                status = f"skipped: MJX's JAX implementation lacks {config.jax_lacks}"
            elif remaining <= 0:
                status = f"skipped: time budget ({args.max_minutes:g} min)"
            else:
                found = run_worker(config, impl, batches, args, min(remaining + 60, 1e6))
                rows += [{**base, **r} for r in found]
                print(f"{config.name} [{impl}]: " + ", ".join(
                    f"{r['batch']} envs {r['sim_s_per_s']:,.0f} sim-s/s" if "sim_s_per_s" in r
                    else f"{r['batch']} envs {r['status']}" for r in found), flush=True)
                continue
            rows += [{**base, "batch": int(b), "status": status} for b in batches.split(",")]
    return rows


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    if args.worker:
        worker(args)
        return
    configs = chosen_configs(args)
    # Workers first: this process must not take device memory (or a GPU client) while they measure.
    rows = [] if args.no_throughput else measure_throughput(configs, args)
    fidelities = {}
    for config in configs:
        fidelities[config.name] = fidelity(config, args)
        print(f"{config.name} fidelity: {fidelities[config.name]}", flush=True)
    rows = rows or [{"config": c.name} for c in configs]
    for row in rows:
        row.update(fidelities[row["config"]])
    # The arguments first: the names measured (with --physics's) replace --configs's text, which may be empty.
    config = {**vars(args), "configs": [c.name for c in configs], "scenes": {c.name: c.task for c in configs},
              "menagerie_scene": MENAGERIE_SCENE}
    path = write_results("physics_throughput", config, rows, args.out, study="physics_throughput")
    print(markdown_table(rows, [
        ("config", "configuration", "s"), ("impl", "MJX", "s"), ("batch", "envs", "d"),
        ("timestep_ms", "dt ms", "g"), ("physics_steps_per_s", "physics steps/s", ",.0f"),
        ("policy_steps_per_s", "policy steps/s", ",.0f"), ("sim_s_per_s", "sim-s/s", ",.0f"),
        ("compile_s", "compile s", ".0f"), ("setup_s", "setup s", ".0f"),
        ("peak_memory_gib", "peak GiB", ".2f"), ("contacts", "contacts", "d"), ("constraint_rows", "rows", "d"),
        ("xla_kib_per_env", "XLA KiB/env", ",.0f"),
        ("tip_error_mean_mm", "tip err mean mm", ".2f"), ("tip_error_max_mm", "tip err max mm", ".2f"),
        ("cube_pos_err_mm", "cube pos err mm", ".2f"), ("cube_rot_err_rad", "cube rot err rad", ".3f"),
        ("drop_disagree", "drop disagree", ".2f"), ("random_drop_rate", "random drops", ".2f"),
        ("stock_random_drop_rate", "stock random drops", ".2f"), ("random_max_speed", "random max m/s", ".2f"),
        ("status", "status", "s"), ("note", "note", "s"),
    ]))
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
