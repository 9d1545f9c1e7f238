"""Can MyoHandPose be solved within its 2 s episodes, and which joints keep the error? An oracle that knows the model.

The task is `MyoHandPose` (MyoSuite's myoHandPoseRandom-v0: starts uniform in every joint's range, targets uniform in
the ASL digit ranges, 100 policy steps of 20 ms, success when the pose error over the 23 joints is below 0.7 rad on
more than 5 steps) on its C MuJoCo twin (`aj.make("MyoHandPose", backend="cpu")`: the same reset, target draw, step
and metrics as the MJX path, float64 physics). Three controllers set the 39 excitations once per policy step:

- `zero`: no excitation (the hand falls and relaxes under gravity, joint damping and passive muscle forces);
- `random`: excitations drawn uniformly in [0, 1] at every step;
- `oracle`: it reads the full state and the model. A PD law gives the joint accelerations wanted,
  `qacc = kp (target - qpos) - kd qvel` (`kp` in 1/s^2, `kd` in 1/s, the same for every joint); `mj_inverse` turns
  them into the generalized forces needed (mass matrix, gravity and Coriolis, joint damping, joint limits), and
  bounded least squares (`scipy.optimize.lsq_linear`) finds activations `a` in [0, 1] whose muscle forces
  `F = gain(l, v) a + bias(l, v)` (MuJoCo's own muscle gain and passive bias at the current lengths and velocities)
  produce those forces through the moment arms. The misfit is weighed in joint accelerations (the forces' misfit
  through the inverse mass matrix), so a finger's joint counts as much as the forearm's, and `effort` times the squared
  activations is added as a tie-breaker among the many muscle combinations that do the same.

What the oracle neglects: the activations wanted are sent as excitations, and MuJoCo's activation dynamics reach them
only with a lag (time constants of 10 ms rising and 40 ms falling, scaled by the activation) within the 20 ms step;
the force capacity and the moment arms are those at the step's start, held for its 10 physics steps. Passive muscle
forces (MuJoCo's muscle bias) are compensated, not neglected. It is greedy: each step it asks for the acceleration
that the PD law wants now, and plans no path. The gains (kp 400, kd 160: overdamped, which the activation lag needs)
were the best of four settings on 8 tuning episodes (seeds 10000-10007, apart from the held-out seeds).

Scenarios (each episode's start and target; the task's own reset, target draw and step in all):

- `task`: MyoSuite's task as it is;
- `hold`: the same targets, the hand placed on its target at rest (can it stay there?);
- `near`: the same targets, the hand placed `NEAR_DISTANCE` (1 rad of pose error) from its target in a random
  direction, clipped to the joints' ranges, at rest (how far does the oracle's pull reach?);
- `reachable`: the task's starts, but targets the hand is known to reach (`reachable_posture` of
  `angora_jax/envs/myohand/reachable.py`: where a constant random excitation brings it in 2 s; the seeds are the
  episodes', not the bank's rows), farther from the starts than the task's: can the oracle steer at all within 2 s?

Prints a table (success rate, the pose error at the episode's end and its minimum over the episode, per controller
and scenario) and the per-joint residual at the episode's end, and writes
results/myohand/myohand_pose_oracle_<platform>.json:

    python benchmarks/myohand_pose_oracle.py                     # 100 episodes, seeds 20000-20099
    python benchmarks/myohand_pose_oracle.py --episodes 10 --runs oracle/task,oracle/near --kp 400 --kd 80
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from collections.abc import Callable

import jax
import mujoco
import numpy as np
from common import markdown_table, write_results
from scipy.optimize import lsq_linear

import angora_jax as aj
from angora_jax.envs.myohand.reachable import EXCITATION_MAX, reachable_posture

# Seeds of the held-out episodes: far from the small seeds that training and the tests use.
FIRST_SEED = 20_000
# Where each episode starts and what it aims at (the module docstring): MyoSuite's task; the same targets with the
# hand placed on them at rest, or NEAR_DISTANCE from them; and postures the hand is known to reach, from the task's
# starts.
SCENARIOS = ("task", "hold", "near", "reachable")
# How far from its target a "near" episode starts (rad, the pose error's norm, before clipping to the joints' ranges).
NEAR_DISTANCE = 1.0
RUNS = ("zero/task", "random/task", "oracle/task", "zero/hold", "oracle/hold", "zero/near", "oracle/near",
        "zero/reachable", "oracle/reachable")
# The joints (names without the hand's "_r") of each part of the hand, for the residual's shares.
JOINT_GROUPS = {"forearm rotation": ("pro_sup",), "wrist": ("deviation", "flexion"),
                "thumb": ("cmc_flexion", "cmc_abduction", "mp_flexion", "ip_flexion"),
                **{finger: (f"mcp{digit}_flexion", f"mcp{digit}_abduction", f"pm{digit}_flexion", f"md{digit}_flexion")
                   for digit, finger in ((2, "index"), (3, "middle"), (4, "ring"), (5, "little"))}}

Controller = Callable[[mujoco.MjModel, mujoco.MjData, np.ndarray], np.ndarray]


@dataclasses.dataclass(frozen=True)
class OracleGains:
    """The oracle's PD law and effort weight.

    Attributes:
        kp: stiffness, joint acceleration wanted per rad of error (1/s^2); the same for every joint.
        kd: damping, joint deceleration wanted per rad/s of velocity (1/s).
        effort: weight of the squared activations beside the squared acceleration misfit ((rad/s^2)^2 per unit
            activation squared); small, a tie-breaker among muscle combinations that do the same.
    """

    kp: float = 400.0
    kd: float = 160.0
    effort: float = 1.0


def muscle_capacity(model: mujoco.MjModel, data: mujoco.MjData) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The muscles' moment arms and force capacity at `data`'s lengths and velocities (position and velocity stages
    computed).

    Returns:
        moment `(nv, nu)`: generalized force per unit actuator force (m for these tendon muscles); gain `(nu,)`:
        active force at full activation (N, negative: pulling); bias `(nu,)`: passive force (N, negative), so that
        a muscle's force is `gain * act + bias` and the joints feel `moment @ force`.
    """
    moment = np.zeros((model.nu, model.nv))
    mujoco.mju_sparse2dense(moment, data.actuator_moment, data.moment_rownnz, data.moment_rowadr,
                            data.moment_colind)
    gain = np.array([mujoco.mju_muscleGain(data.actuator_length[i], data.actuator_velocity[i],
                                           model.actuator_lengthrange[i], model.actuator_acc0[i],
                                           model.actuator_gainprm[i, :9]) for i in range(model.nu)])
    bias = np.array([mujoco.mju_muscleBias(data.actuator_length[i], model.actuator_lengthrange[i],
                                           model.actuator_acc0[i], model.actuator_biasprm[i, :9])
                     for i in range(model.nu)])
    return moment.T, gain, bias


def oracle(gains: OracleGains) -> Controller:
    """The oracle controller (the module docstring): `(model, data, target) -> excitations (nu,)` in [0, 1]."""
    scratch: dict[int, mujoco.MjData] = {}

    def control(model: mujoco.MjModel, data: mujoco.MjData, target: np.ndarray) -> np.ndarray:
        # A scratch copy keeps the environment's own data (its solver warm start included) untouched.
        work = scratch.setdefault(id(model), mujoco.MjData(model))
        work.qpos[:], work.qvel[:], work.act[:] = data.qpos, data.qvel, data.act
        work.qacc[:] = gains.kp * (target - data.qpos) - gains.kd * data.qvel
        mujoco.mj_inverse(model, work)
        moment, gain, bias = muscle_capacity(model, work)
        # Misfit in joint accelerations: M^-1 (moment (gain a + bias) - qfrc_inverse).
        forces = np.vstack([(moment * gain).T, work.qfrc_inverse - moment @ bias])
        accelerations = np.zeros_like(forces)
        mujoco.mj_solveM(model, work, accelerations, forces)
        per_activation, wanted = accelerations[:-1].T, accelerations[-1]
        rows = np.vstack([per_activation, np.sqrt(gains.effort) * np.eye(model.nu)])
        return lsq_linear(rows, np.concatenate([wanted, np.zeros(model.nu)]), bounds=(0.0, 1.0)).x

    return control


def zero(model: mujoco.MjModel, data: mujoco.MjData, target: np.ndarray) -> np.ndarray:
    """No excitation."""
    return np.zeros(model.nu)


def uniform(seed: int) -> Controller:
    """Excitations drawn uniformly in [0, 1] at every step (numpy generator seeded with `seed`)."""
    rng = np.random.default_rng(seed)
    return lambda model, data, target: rng.uniform(0.0, 1.0, model.nu)


def run_episode(env: aj.Env, control: Controller, seed: int, scenario: str = "task") -> dict[str, np.ndarray | float]:
    """One episode of `env` (the C MuJoCo twin) from `jax.random.key(seed)`, in `scenario` (`SCENARIOS`).

    Returns:
        success (0 or 1: in "task" the task's own metric at the episode's end, otherwise the same rule applied here:
        pose error below the task's threshold on more than its `success_steps` steps), pose_error `(steps,)` (rad,
        after each step), start_error and end_error `(njnt,)` (target minus joint angles at the start and the end,
        rad).
    """
    state = env.reset(jax.random.key(seed))
    target = np.asarray(state.info["target"], np.float64)
    if scenario in ("hold", "near"):
        direction = np.random.default_rng(seed).standard_normal(env.model.nq)
        offset = NEAR_DISTANCE * direction / np.linalg.norm(direction) if scenario == "near" else 0.0
        env.data.qpos[:] = np.clip(target + offset, *env.model.jnt_range.T)
        env.data.qvel[:] = 0.0
        mujoco.mj_forward(env.model, env.data)
    elif scenario == "reachable":
        target = reachable_posture(env.model, seed)
    start = target - env.data.qpos
    errors = []
    while not bool(state.done):
        state = env.step(state, control(env.model, env.data, target))
        own = float(np.linalg.norm(target - env.data.qpos))
        errors.append(float(state.metrics["pose_error"]) if scenario == "task" else own)
    errors = np.asarray(errors)
    success = (float(state.metrics["success"]) if scenario == "task"
               else float(np.sum(errors < env.task.pose_threshold) > env.task.success_steps))
    return {"success": success, "pose_error": errors, "start_error": start, "end_error": target - env.data.qpos}


def percentiles(values: np.ndarray) -> dict[str, float]:
    """Mean and the 10th, 50th and 90th percentiles of `values`."""
    p10, p50, p90 = np.percentile(values, [10, 50, 90])
    return {"mean": float(np.mean(values)), "p10": float(p10), "median": float(p50), "p90": float(p90)}


def summarize(episodes: list[dict], joint_names: list[str], threshold: float, steps_per_half_second: int) -> dict:
    """The success rate, the pose error's distributions (rad), its median every half second (after steps
    `steps_per_half_second`, twice that, ...) and the per-joint residual of `episodes`."""
    end = np.array([e["pose_error"][-1] for e in episodes])
    minimum = np.array([e["pose_error"].min() for e in episodes])
    residual = np.array([e["end_error"] for e in episodes])
    start = np.array([e["start_error"] for e in episodes])
    first = [np.flatnonzero(e["pose_error"] < threshold) for e in episodes]
    first = [f[0] + 1 for f in first if f.size]
    squared = (residual ** 2).mean(axis=0)

    def per_joint(values: np.ndarray) -> dict[str, float]:
        return dict(zip(joint_names, values.tolist(), strict=True))

    return {"episodes": len(episodes), "success_rate": float(np.mean([e["success"] for e in episodes])),
            "solved_step_share": float(np.mean([np.mean(e["pose_error"] < threshold) for e in episodes])),
            "first_solved_step_median": float(np.median(first)) if first else None,
            "start_error": percentiles(np.linalg.norm(start, axis=1)), "end_error": percentiles(end),
            "min_error": percentiles(minimum),
            "median_error_every_half_second": np.median(
                [e["pose_error"][steps_per_half_second - 1::steps_per_half_second] for e in episodes], axis=0).tolist(),
            "joint_rms_start_rad": per_joint(np.sqrt((start ** 2).mean(axis=0))),
            "joint_rms_end_rad": per_joint(np.sqrt(squared)),
            "joint_share_of_end_squared_error": per_joint(squared / squared.sum()),
            "group_share_of_end_squared_error": {
                group: float(sum(squared[joint_names.index(name)] for name in names) / squared.sum())
                for group, names in JOINT_GROUPS.items()}}


def main(argv: list[str] | None = None) -> int:
    """Run the controllers and scenarios with command-line `argv` (default: sys.argv); print the tables, write the
    JSON."""
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--first-seed", type=int, default=FIRST_SEED)
    parser.add_argument("--max-episode-steps", type=int, default=100, help="policy steps of 20 ms (the task's 100)")
    parser.add_argument("--kp", type=float, default=OracleGains.kp, help="PD stiffness (1/s^2)")
    parser.add_argument("--kd", type=float, default=OracleGains.kd, help="PD damping (1/s)")
    parser.add_argument("--effort", type=float, default=OracleGains.effort, help="weight of squared activations")
    parser.add_argument("--runs", default=",".join(RUNS),
                        help="controller/scenario pairs, comma-separated (controllers: zero, random, oracle; "
                             f"scenarios: {', '.join(SCENARIOS)})")
    parser.add_argument("--out", default=None,
                        help="JSON path (default: results/myohand/myohand_pose_oracle_<platform>.json)")
    args = parser.parse_args(argv)
    if args.episodes < 1 or args.max_episode_steps < 25:
        parser.exit(2, f"--episodes must be >= 1 and --max-episode-steps >= 25 (half a second), got {args.episodes} "
                       f"and {args.max_episode_steps}.\n")
    gains = OracleGains(args.kp, args.kd, args.effort)
    makers = {"zero": lambda seed: zero, "random": uniform, "oracle": lambda seed: oracle(gains)}
    runs = [tuple(run.split("/")) for run in args.runs.split(",")]
    wrong = [run for run in runs if len(run) != 2 or run[0] not in makers or run[1] not in SCENARIOS]
    if wrong:
        parser.exit(2, f"--runs: cannot read {['/'.join(run) for run in wrong]}; write controller/scenario pairs, "
                       f"e.g. {RUNS[0]}, with controllers {sorted(makers)} and scenarios {list(SCENARIOS)}.\n")
    env = aj.make("MyoHandPose", backend="cpu", max_episode_steps=args.max_episode_steps)
    joint_names = [env.model.joint(i).name.removesuffix("_r") for i in range(env.model.njnt)]
    seeds = list(range(args.first_seed, args.first_seed + args.episodes))
    rows = []
    for name, scenario in runs:
        begin = time.perf_counter()
        control = makers[name](args.first_seed)
        episodes = [run_episode(env, control, seed, scenario) for seed in seeds]
        rows.append({"controller": name, "scenario": scenario,
                     **summarize(episodes, joint_names, env.task.pose_threshold,
                                 round(0.5 / (env.frame_skip * env.model.opt.timestep))),
                     "seconds": time.perf_counter() - begin})
    config = {"task": "MyoHandPose (C MuJoCo twin)", "episodes": args.episodes, "seeds": [seeds[0], seeds[-1]],
              "control_dt_s": env.frame_skip * float(env.model.opt.timestep),
              "max_episode_steps": env.max_episode_steps, "pose_threshold_rad": env.task.pose_threshold,
              "success_steps": env.task.success_steps, "oracle": dataclasses.asdict(gains),
              "random_excitation_seed": args.first_seed, "reachable_excitation_max": EXCITATION_MAX}
    path = write_results("myohand_pose_oracle", config, rows, args.out, study="myohand")
    print(markdown_table([{**r, "run": f"{r['controller']}/{r['scenario']}", "start": r["start_error"]["median"],
                           "end_median": r["end_error"]["median"], "end_p90": r["end_error"]["p90"],
                           "min_median": r["min_error"]["median"], "min_p10": r["min_error"]["p10"],
                           "at_1s": r["median_error_every_half_second"][1]} for r in rows],
                         [("run", "controller/scenario", "s"), ("success_rate", "success", ".2f"),
                          ("at_1s", "error median at 1 s", ".2f"),
                          ("solved_step_share", "solved steps", ".2f"), ("start", "start error median", ".2f"),
                          ("end_median", "end error median", ".2f"), ("end_p90", "end p90", ".2f"),
                          ("min_median", "min error median", ".2f"), ("min_p10", "min p10", ".2f")]))
    print()
    print(markdown_table([{"joint": j, "start": rows[0]["joint_rms_start_rad"][j],
                           **{f"{r['controller']}/{r['scenario']}": r["joint_rms_end_rad"][j] for r in rows}}
                          for j in joint_names],
                         [("joint", "joint", "s"), ("start", f"start rms ({rows[0]['scenario']})", ".2f")]
                         + [(f"{r['controller']}/{r['scenario']}", f"{r['controller']}/{r['scenario']}", ".2f")
                            for r in rows]))
    print()
    print(markdown_table([{"run": f"{r['controller']}/{r['scenario']}", **r["group_share_of_end_squared_error"]}
                          for r in rows],
                         [("run", "share of the end's squared error", "s")]
                         + [(group, group, ".2f") for group in JOINT_GROUPS]))
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
