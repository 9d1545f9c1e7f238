"""In-hand object manipulation (IHOM): turn a cube in the palm-up hand to a sequence of goal orientations.

After AngoraPy's `ManipulateBlock` and OpenAI's Dactyl task. A goal is a target orientation (unit quaternion,
position ignored). It is reached when the cube's angular distance to it is at most `success_angle` (eta, default
0.4 rad); then a new goal is drawn and the goal timer restarts. Goals are drawn as in AngoraPy's "xyz" mode: a
rotation by an angle uniform in [-pi, pi] about an axis uniform in [-1, 1]^3, independent of the cube's pose.
Consecutive goals reached (CGR) is the metric `goals_reached` at the episode's end.

Episode rules, checked after every policy step:

- drop: the cube's centre is below the palm's centre -> terminated (the cube is gone; nothing follows);
- goal timer: `steps_per_goal` policy steps without reaching the current goal (8 s at the default 0.08 s per step)
  -> terminated with `timer="terminal"` (the default, as in AngoraPy and Gym's hand tasks), or truncated with
  `timer="truncation"` (the value is bootstrapped, as if the episode could go on);
- cap: `max_goals` (50) goals reached -> truncated: the episode is cut only to bound evaluation, the task itself
  would go on, so the value is bootstrapped.

Why the goal timer is terminal. The timer is part of the task: a goal not reached in time ends the attempt, the
score (CGR) is final, and no later reward can follow. A truncation tells the learner the opposite, that the MDP would
go on, so the value after a timeout is bootstrapped from the next state. Under a per-step cost that inverts the
task: with a -0.1 step penalty and gamma 0.998, holding the cube forever is worth about -0.1 / (1 - 0.998) = -50,
dropping it a terminal -20, so dropping at once is optimal whenever goals are not yet reached (measured: drop rate
1.00 after 55 cycles on one H100). Made terminal, holding until the timer is worth at most the reward of those 100
steps, and the returns are ordered as the task intends: reach a goal > hold > drop (`tests/test_ihom.py` computes
the returns of these behaviours under each preset's reward and gamma and checks the order). Because the timer now
decides the value, the value function sees it: `asymmetric` holds the share of the goal's time left and of the goal
cap reached (the policy does not need them and does not see them).

Start: AngoraPy drops the cube onto the flat hand and lets it settle before the first observation, re-drawing a
start that does not rest on the palm. Settling on every reset would cost the batched step its physics steps (the
auto-reset computes a fresh start at every step), so `settled_starts` settles a fixed pool of random starts once, in
C MuJoCo, at construction; a reset picks one with its key, on both physics paths alike.

Reward (`IhomReward` coefficients), with d the angular distance to the goal in rad and dt the policy step in s:

    r = progress * (d(t-1) - d(t)) + orientation * dt * (1 - d(t) / pi) + success_bonus * success
        - drop_penalty * dropped - step_penalty - force_multiplier * sum(actuator_force[2:] ** 2)
        - tendon_stress_multiplier * 116 * sum(ten_length ** 2)
Both distances are to the goal that was active during the step; after a success the next step measures progress to
the new goal from the pose where the old one was reached. `REWARD_PRESETS`: "paper" is AngoraPy's MANIPULATE_BASE
(the paper's eq. 1-2: progress, +5 per goal, -20 for a drop; AngoraPy calls it `default`); "penalized_force" and
"penalized_anatomy" are AngoraPy's presets of the same names (its `--rcon`), which add costs of the actuator forces
and of the tendons' stretch; "dense" adds an absolute orientation term (MuJoCo
Playground's LEAP cube rewards 5 x a linear tolerance of the angle per second) and pays 25 per goal.

The recipe that learns (`configs/shadow_ihom.yaml`; the README's "In-hand cube reorientation" section compares it
with AngoraPy, Dactyl, IsaacGymEnvs and MuJoCo Playground and gives the measurements). Progress alone telescopes to
at most pi per goal and averages zero under random turning, so a policy that holds the cube still loses nothing; the
dense term pays for every step spent nearer the goal, and with the terminal timer a goal not reached ends that pay.
Reaching the goal is worth more than hovering near it: the bonus (25) exceeds what the lost orientation reward of a
new, distant goal costs. The policy sees the rotation it must make (`relative_goal`, as IsaacGymEnvs' and
Playground's policies do) instead of having to compute it from two quaternions; and absolute joint targets learned
about 5x faster than targets moved step by step (`control="target"`) in a side-by-side run on one H100.
"""

from __future__ import annotations

import dataclasses
import hashlib
from typing import Protocol

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from angora_jax.envs.cameras import CameraVision
from angora_jax.envs.coefficients import Coefficients
from angora_jax.envs.core import Sensation
from angora_jax.envs.mujoco_task import Snapshot
from angora_jax.envs.shadow_hand.cube import CUBE_JOINT
from angora_jax.envs.shadow_hand.hand import HandTask
from angora_jax.envs.shadow_hand.model import HAND_JOINT_PREFIX


class PoseReader(Protocol):
    """What the cube task needs of a pose estimator (`angora_jax.vision.PoseEstimator` is one): the cameras it reads
    (names, in the order of the frames' camera axis), their frame size in pixels, the renderer its training frames
    came from ("cpu": OpenGL, "warp", or None), and `(B, cameras, size, size, 3)` uint8 frames -> the cube's position
    `(B, 3)` (m, world frame) and orientation `(B, 4)` (quaternion w x y z)."""

    cameras: tuple[str, ...]
    size: int
    renderer: str | None

    def __call__(self, frames: jax.Array) -> tuple[jax.Array, jax.Array]: ...

# Gym HandManipulateBlock starts from the flat, open hand (all joints 0) with the cube a few cm above the palm.
# Std (m) of the cube's initial position noise, as in AngoraPy/Gym.
INITIAL_POSITION_NOISE = 0.005
# Settling a start: physics steps held still (AngoraPy lets 10 x 2 ms pass; the cube dropped from a few cm needs more
# to come to rest), and what counts as resting on the palm: centre at least this high above the palm's centre (m,
# the cube's half size is 0.025) and slower than this (m/s).
SETTLE_SECONDS = 0.4
RESTING_HEIGHT = 0.015
RESTING_SPEED = 0.05
TIMERS = ("terminal", "truncation")
# Settled starts by (model content, hand pose, count, seed): settling takes seconds and every `make` compiles a new
# but identical model.
_STARTS: dict[tuple[str, bytes, int, int], np.ndarray] = {}


@dataclasses.dataclass(frozen=True)
class IhomReward(Coefficients):
    """Reward coefficients (defaults: AngoraPy's MANIPULATE_BASE, the "paper" preset). Angles in rad.

    Attributes:
        progress: weight of the decrease of the angular distance to the goal over one step.
        orientation: reward per second of simulated time for the cube's orientation, times (1 - d / pi): 1 at the goal,
            0 facing away (MuJoCo Playground's dense term, linear in the angle); 0 in AngoraPy.
        success_bonus: added on the step a goal is reached.
        drop_penalty: subtracted on the step the cube drops.
        step_penalty: subtracted on every step (a time cost); 0 in AngoraPy.
        force_multiplier: weight of the squared actuator forces (wrist excluded), a metabolic cost; 0 in AngoraPy.
        tendon_stress_multiplier: weight of the tendons' squared lengths (m^2) times `TENDON_STRESS_SCALE`, AngoraPy's
            anatomical cost (its `calculate_tendon_stress_penalty`, scaled to the force cost's average size).
    """

    progress: float = 1.0
    orientation: float = 0.0
    success_bonus: float = 5.0
    drop_penalty: float = 20.0
    step_penalty: float = 0.0
    force_multiplier: float = 0.0
    tendon_stress_multiplier: float = 0.0


# AngoraPy's scaling of the tendon cost to the force cost's average under random play (its reward.py).
TENDON_STRESS_SCALE = 116.0

REWARD_PRESETS = {
    "paper": IhomReward(),
    "dense": IhomReward(orientation=5.0, success_bonus=25.0),
    "penalized_force": IhomReward(force_multiplier=0.001),
    "penalized_anatomy": IhomReward(force_multiplier=0.01, tendon_stress_multiplier=0.01),
}


def quat_mul(a: jax.Array, b: jax.Array) -> jax.Array:
    """Hamilton product of quaternions (w, x, y, z), shape `(..., 4)`."""
    aw, av = a[..., :1], a[..., 1:]
    bw, bv = b[..., :1], b[..., 1:]
    w = aw * bw - jnp.sum(av * bv, axis=-1, keepdims=True)
    return jnp.concatenate([w, aw * bv + bw * av + jnp.cross(av, bv)], axis=-1)


def quat_conjugate(q: jax.Array) -> jax.Array:
    return q * jnp.array([1.0, -1.0, -1.0, -1.0])


def rotation_between(current: jax.Array, goal: jax.Array) -> jax.Array:
    """The unit quaternion that turns `current` into `goal` (goal * current^-1), with w >= 0 (q and -q are the
    same rotation; a canonical sign keeps it a continuous input)."""
    q = quat_mul(goal, quat_conjugate(current))
    q = q / jnp.linalg.norm(q, axis=-1, keepdims=True)
    return jnp.where(q[..., :1] < 0, -q, q)


def angular_distance(current: jax.Array, goal: jax.Array) -> jax.Array:
    """Rotation angle (rad, in [0, pi]) between two orientations. atan2 keeps small angles exact in float32, where
    AngoraPy's 2 * arccos(w) loses them (and it counts q and -q as 2 pi apart)."""
    q = rotation_between(current, goal)
    return 2.0 * jnp.arctan2(jnp.linalg.norm(q[..., 1:], axis=-1), q[..., 0])


def random_rotation(key: jax.Array) -> jax.Array:
    """AngoraPy's "xyz" rotation: angle uniform in [-pi, pi] about an axis uniform in [-1, 1]^3; w >= 0."""
    angle_key, axis_key = jax.random.split(key)
    angle = jax.random.uniform(angle_key, (), minval=-jnp.pi, maxval=jnp.pi)
    axis = jax.random.uniform(axis_key, (3,), minval=-1.0, maxval=1.0)
    axis = axis / jnp.linalg.norm(axis)
    q = jnp.concatenate([jnp.cos(angle / 2)[None], jnp.sin(angle / 2) * axis])
    return jnp.where(q[0] < 0, -q, q)


def about_axis(axis: int, angle: jax.Array | float) -> jax.Array:
    """The quaternion of a rotation by `angle` rad about world axis `axis` (0: x, 1: y, 2: z)."""
    half = jnp.asarray(angle, jnp.float32) / 2
    return jnp.concatenate([jnp.cos(half)[None], jnp.sin(half) * jnp.eye(3)[axis]])


def axis_aligned_rotations() -> np.ndarray:
    """The 24 rotations that map the cube's faces onto the world axes (w >= 0), shape `(24, 4)`: AngoraPy's
    TestCaseManipulateBlock set. Six faces up (none, +-90 degrees about x, +-90 and 180 about y), each turned by 0,
    +-90 and 180 degrees about z."""
    faces = [(0, 0.0), (0, np.pi / 2), (0, -np.pi / 2), (1, np.pi / 2), (1, -np.pi / 2), (1, np.pi)]
    turns = [0.0, np.pi / 2, -np.pi / 2, np.pi]
    rotations = np.array([quat_mul(about_axis(*face), about_axis(2, turn)) for turn in turns for face in faces])
    return np.where(rotations[:, :1] >= 0, rotations, -rotations).astype(np.float32)


# Where each episode's goals come from (`Ihom`'s `goals`).
GOAL_SETS = ("random", "test_set")


def rotation_matrix(q: jax.Array) -> jax.Array:
    """The rotation matrix of unit quaternion `q` (w, x, y, z), flattened row by row: shape `(..., 9)`. Unlike the
    quaternion it is continuous and unique (q and -q give the same matrix), which makes it the better network input."""
    w, x, y, z = jnp.moveaxis(q, -1, 0)
    return jnp.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
                      2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
                      2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], axis=-1)


@dataclasses.dataclass(frozen=True)
class PoseNoise:
    """Noise on the cube's pose as the policy sees it, drawn afresh every step (AngoraPy's NoisyManipulateBlock), in a
    pose estimator's units; the value function's asymmetric inputs then hold the true pose too. The defaults are
    AngoraPy's, its pose estimator's measured error.

    Attributes:
        position: m, the length of a displacement in a uniformly random direction (AngoraPy: 3.71 mm).
        rotation: rad, the standard deviation of a rotation angle whose share about the x, y and z axes is drawn
            uniformly (AngoraPy: pi / 36, 5 degrees).
    """

    position: float = 0.00371
    rotation: float = float(np.pi / 36)

    def __post_init__(self):
        if not (self.position >= 0 and self.rotation >= 0):
            raise ValueError(f"pose_noise needs position >= 0 (m) and rotation >= 0 (rad), got {self}.")

    @classmethod
    def from_options(cls, options: dict[str, float]) -> PoseNoise:
        """From the `pose_noise` option; a ValueError naming the fields for an unknown one."""
        unknown = sorted(set(options) - {"position", "rotation"})
        if unknown:
            raise ValueError(f"Unknown pose_noise fields {unknown}; known: position (m), rotation (rad).")
        return cls(**{k: float(v) for k, v in options.items()})

    def apply(self, key: jax.Array, pose: jax.Array) -> jax.Array:
        """`pose` (position 3 in m, quaternion 4) with noise drawn from `key`."""
        angle_key, share_key, direction_key = jax.random.split(key, 3)
        shares = jax.random.uniform(share_key, (3,))
        angles = shares / jnp.sum(shares) * self.rotation * jax.random.normal(angle_key)
        # About x, then y, then z, as AngoraPy composes them.
        noise = quat_mul(quat_mul(about_axis(0, angles[0]), about_axis(1, angles[1])), about_axis(2, angles[2]))
        direction = jax.random.normal(direction_key, (3,))
        position = pose[:3] + self.position * direction / jnp.linalg.norm(direction)
        return jnp.concatenate([position, quat_mul(pose[3:], noise)])


# `pose_noise`'s key is drawn from each step's key on a stream of its own, so that the goals stay those of a run
# without noise.
POSE_NOISE_STREAM = 1


class Ihom(HandTask):
    """Cube reorientation on the cube scene (`load_cube_scene`), one policy step lasting `dt` s.

    Observation (sizes for the Gym hand; touch only when the model has touch sensors):
      proprioception (48): hand joint positions (rad) and velocities (rad/s), 24 each;
      touch (97 or 0): touch sensor readings (N, contact normal forces summed over each sensor zone);
      vision (7): the cube's pose in place of vision, position (m, world) and orientation quaternion (w, x, y, z);
        with `vision` (camera settings, `envs.cameras.CameraVision`) camera images instead, uint8
        `(cameras, height, width, channels)`, and the pose moves to `asymmetric` (the value function's); with
        `pose_estimator` (a `vision.PoseEstimator`, which sets `vision` to its cameras) the pose that the estimator
        reads from those images, as OpenAI's Dactyl fed its policy: every input keeps the pose task's shape, so a
        network trained on the true pose reads the estimate unchanged;
      goal (4, or 13 with `relative_goal`): the goal quaternion; with `relative_goal` also the rotation from the
        cube's orientation to the goal as a 3 x 3 matrix (world frame, flattened), the error the hand must undo
        (it reveals the cube's orientation, so it cannot go with camera vision; with a pose estimator it is the
        rotation from the estimated orientation);
      asymmetric (27, +7 with camera vision; value function only): fingertip positions (15, m), rotation from cube to
        goal (4, quaternion), cube linear velocity (3, m/s, world frame), angular velocity (3, rad/s, cube frame),
        the share of the goal timer left and the share of `max_goals` reached (then the cube's pose).
    Info: goal (4,), goal_steps (int32, steps spent on the current goal), goals_reached (int32), time_out (bool).
    Metrics: goals_reached (CGR so far), dropped (1 on the step the cube dropped), timed_out (1 on the step the goal
    timer ran out), goal_distance (rad).

    control / action_scale: see `HandTask`. Under "absolute" (the default) and "target" a zero action keeps the cube
    on the palm; under "position" (AngoraPy's) the hand sags and drops it within about 0.5 s.
    start_pool: number of settled starts (`settled_starts`), drawn once from a fixed seed.
    """

    metric_names = ("goals_reached", "dropped", "timed_out", "goal_distance")
    random_initial_qpos = True

    def __init__(self, model: mujoco.MjModel, reward: IhomReward = IhomReward(), success_angle: float = 0.4,
                 steps_per_goal: int = 100, max_goals: int = 50, dt: float = 0.08, timer: str = "terminal",
                 relative_goal: bool = False, control: str = "absolute", action_scale: float = 0.2,
                 start_pool: int = 512, vision: CameraVision | None = None,
                 pose_estimator: PoseReader | None = None, freeze_wrist: bool = False,
                 pose_noise: PoseNoise | None = None, goals: str = "random"):
        if success_angle <= 0 or steps_per_goal < 1 or max_goals < 1 or dt <= 0 or start_pool < 1:
            raise ValueError(f"Ihom needs success_angle > 0, steps_per_goal >= 1, max_goals >= 1, dt > 0 and "
                             f"start_pool >= 1, got {success_angle}, {steps_per_goal}, {max_goals}, {dt}, "
                             f"{start_pool}.")
        if timer not in TIMERS:
            raise ValueError(f"Unknown goal timer semantics {timer!r}; choose one of {TIMERS}.")
        if vision is not None and relative_goal and pose_estimator is None:
            raise ValueError("relative_goal shows the rotation from the cube to the goal, which reveals the cube's "
                             "orientation that camera vision should have to see: set relative_goal: false.")
        if pose_estimator is not None and vision is None:
            raise ValueError("A pose estimator reads camera frames: give the cameras it was trained on as `vision`.")
        hand_joints = [j for j in range(model.njnt) if model.joint(j).name.startswith(HAND_JOINT_PREFIX)]
        super().__init__(model, control=control, action_scale=action_scale,
                         initial_qpos={model.joint(j).name: 0.0 for j in hand_joints}, vision=vision,
                         freeze_wrist=freeze_wrist)
        if pose_noise is not None and vision is not None:
            raise ValueError("pose_noise applies to the true pose the policy sees; with camera vision or a pose "
                             "estimator there is none to add it to.")
        self.pose_noise = pose_noise
        if goals not in GOAL_SETS:
            raise ValueError(f"Unknown goals {goals!r}; choose one of {GOAL_SETS}.")
        self.goals = goals
        self._test_goals = axis_aligned_rotations()
        self.reward_config = reward
        self.success_angle = success_angle
        self.steps_per_goal = steps_per_goal
        self.max_goals = max_goals
        self.dt = dt
        self.timer = timer
        self.relative_goal = relative_goal
        self.pose_estimator = pose_estimator
        self.frames_in_vision = pose_estimator is None
        cube = model.joint(CUBE_JOINT)
        self.cube_qpos = int(cube.qposadr[0])
        self.cube_dof = int(cube.dofadr[0])
        self.starts = self.settled_starts(start_pool)

    def cube_pose(self, snap: Snapshot) -> jax.Array:
        """Cube position (m) and orientation quaternion, shape `(7,)`."""
        return snap.qpos[self.cube_qpos:self.cube_qpos + 7]

    def cube_quat(self, snap: Snapshot) -> jax.Array:
        return snap.qpos[self.cube_qpos + 3:self.cube_qpos + 7]

    def dropped(self, snap: Snapshot) -> jax.Array:
        """True when the cube's centre is below the palm's centre (AngoraPy's drop test)."""
        return snap.qpos[self.cube_qpos + 2] < snap.xpos[self.palm_id, 2]

    def random_start(self, key: jax.Array) -> jax.Array:
        """An unsettled start, qpos `(nq,)`: the flat hand and the cube above the palm (Gym's start), turned by a
        random rotation, position noise 5 mm."""
        turn_key, shift_key = jax.random.split(key)
        qpos = jnp.asarray(self._qpos0)
        start = self._qpos0[self.cube_qpos:self.cube_qpos + 7]
        quat = quat_mul(jnp.asarray(start[3:]), random_rotation(turn_key))
        pos = start[:3] + INITIAL_POSITION_NOISE * jax.random.normal(shift_key, (3,))
        return qpos.at[self.cube_qpos:self.cube_qpos + 7].set(jnp.concatenate([pos, quat / jnp.linalg.norm(quat)]))

    def settled_starts(self, count: int, seed: int = 0, max_draws: int = 8) -> np.ndarray:
        """`count` starts, qpos `(count, nq)` float32, each a `random_start` let fall onto the hand and settle for
        `SETTLE_SECONDS` in C MuJoCo with the hand holding its pose, re-drawn (up to `max_draws` times) until the
        cube rests on the palm (`RESTING_HEIGHT`, `RESTING_SPEED`). Deterministic for a seed (and cached)."""
        model = self.model
        content = np.empty(mujoco.mj_sizeModel(model), np.uint8)
        mujoco.mj_saveModel(model, None, content)
        cache_key = (hashlib.sha1(content.tobytes()).hexdigest(), self._qpos0.tobytes(), count, seed)
        if cache_key in _STARTS:
            return _STARTS[cache_key]
        data = mujoco.MjData(model)
        steps = max(1, round(SETTLE_SECONDS / model.opt.timestep))
        draw = jax.jit(jax.vmap(self.random_start))
        keys = jax.random.split(jax.random.key(seed), (max_draws, count))
        candidates = np.asarray(draw(keys.reshape(-1)), np.float64).reshape(max_draws, count, -1)
        starts = []
        for i in range(count):
            for attempt in range(max_draws):
                mujoco.mj_resetData(model, data)
                data.qpos[:] = candidates[attempt, i]
                mujoco.mj_forward(model, data)
                data.ctrl[:] = np.clip(data.actuator_length, *model.actuator_ctrlrange.T)
                mujoco.mj_step(model, data, nstep=steps)
                height = data.qpos[self.cube_qpos + 2] - data.xpos[self.palm_id, 2]
                speed = np.linalg.norm(data.qvel[self.cube_dof:self.cube_dof + 3])
                if height > RESTING_HEIGHT and speed < RESTING_SPEED:
                    break
            else:
                raise RuntimeError(f"No start of {max_draws} draws came to rest on the palm (start {i}); the scene's "
                                   "physics settings may be unstable.")
            starts.append(data.qpos.copy())
        _STARTS[cache_key] = np.asarray(starts, np.float32)
        return _STARTS[cache_key]

    def initial_qpos(self, key: jax.Array) -> jax.Array:
        """One of the settled starts, picked by `key`."""
        return jnp.asarray(self.starts)[jax.random.randint(key, (), 0, len(self.starts))]

    def initial_info(self, key: jax.Array, snap: Snapshot) -> dict[str, jax.Array]:
        info = {"goal": self.sample_goal(key), "goal_steps": jnp.zeros((), jnp.int32),
                "goals_reached": jnp.zeros((), jnp.int32), "time_out": jnp.zeros((), bool)}
        return self._with_noise_key(info, key)

    def sample_goal(self, key: jax.Array) -> jax.Array:
        """A goal orientation (quaternion): any rotation (AngoraPy's "xyz"), or with `goals="test_set"` one of the
        24 axis-aligned ones (`axis_aligned_rotations`), so that runs are compared on a fixed set of goals."""
        if self.goals == "random":
            return random_rotation(key)
        return jnp.asarray(self._test_goals)[jax.random.randint(key, (), 0, len(self._test_goals))]

    def _with_noise_key(self, info: dict[str, jax.Array], key: jax.Array) -> dict[str, jax.Array]:
        """`info` with the key of this step's pose noise, when the task has some."""
        if self.pose_noise is None:
            return info
        return info | {"pose_noise_key": jax.random.key_data(jax.random.fold_in(key, POSE_NOISE_STREAM))}

    def observe(self, snap: Snapshot, info: dict[str, jax.Array]) -> Sensation:
        cube_velocity = snap.qvel[self.cube_dof:self.cube_dof + 6]
        to_goal = rotation_between(self.cube_quat(snap), info["goal"])
        clocks = jnp.stack([1.0 - info["goal_steps"] / self.steps_per_goal, info["goals_reached"] / self.max_goals])
        privileged = [self.fingertips(snap).reshape(-1), to_goal, cube_velocity, clocks]
        pose = self.cube_pose(snap)  # a pose estimator's reading replaces it (`perceive`)
        seen_to_goal = to_goal
        if self.vision is not None and self.frames_in_vision:  # the backend renders the frames into vision
            privileged, pose = privileged + [pose], jnp.zeros((0,), jnp.float32)
        elif self.pose_noise is not None:  # the policy sees a noisy pose, the value function also the true one
            privileged = privileged + [pose]
            pose = self.pose_noise.apply(jax.random.wrap_key_data(info["pose_noise_key"]), pose)
            seen_to_goal = rotation_between(pose[3:], info["goal"])
        return Sensation.make(proprioception=self.proprioception(snap), touch=self.touch(snap),
                              vision=pose, goal=self.goal_input(seen_to_goal, info["goal"]),
                              asymmetric=jnp.concatenate(privileged))

    def goal_input(self, to_goal: jax.Array, goal: jax.Array) -> jax.Array:
        """The goal modality: the goal quaternion, with `relative_goal` followed by the rotation `to_goal` (a
        quaternion from the cube's orientation, true or estimated, to the goal) as a flattened 3 x 3 matrix."""
        return jnp.concatenate([goal, rotation_matrix(to_goal)]) if self.relative_goal else goal

    def perceive(self, obs: Sensation, frames: jax.Array, info: dict[str, jax.Array]) -> Sensation:
        """With a pose estimator, the pose it reads from `frames` in `vision` (and the relative goal from its
        orientation); otherwise the frames themselves."""
        if self.pose_estimator is None:
            return super().perceive(obs, frames, info)
        position, quaternion = self.pose_estimator(frames[None])
        goal = self.goal_input(rotation_between(quaternion[0], info["goal"]), info["goal"])
        return obs.replace(vision=jnp.concatenate([position[0], quaternion[0]]), goal=goal)

    def task_variables(self, snap: Snapshot, info: dict[str, jax.Array]) -> dict[str, jax.Array]:
        """The hand's (`HandTask.task_variables`) and the cube's: cube_position (3, m, world), cube_orientation (4,
        quaternion w x y z), cube_rotation (9, its rotation matrix row by row), cube_velocity (3, m/s, world),
        cube_angular_velocity (3, rad/s, cube frame), goal_orientation (4, quaternion), quaternion_to_goal (4, the
        rotation from the cube's orientation to the goal, w >= 0, as the value function reads it) and
        rotation_to_goal (9, its rotation matrix row by row, as the policy's relative goal gives it), whether the
        policy sees them or camera images. Decode rotations as matrices: q and -q are one rotation, so a network
        that reads a quaternion of the other sign (a pose estimator's) holds the orientation while no linear readout
        gives the simulator's q, and the canonical w >= 0 flips x, y and z at half a turn from the goal."""
        pose, velocity = self.cube_pose(snap), snap.qvel[self.cube_dof:self.cube_dof + 6]
        to_goal = rotation_between(pose[3:], info["goal"])
        return super().task_variables(snap, info) | {
            "cube_position": pose[:3], "cube_orientation": pose[3:], "cube_rotation": rotation_matrix(pose[3:]),
            "cube_velocity": velocity[:3], "cube_angular_velocity": velocity[3:], "goal_orientation": info["goal"],
            "quaternion_to_goal": to_goal, "rotation_to_goal": rotation_matrix(to_goal)}

    def evaluate(self, key, prev, snap, info):
        c = self.reward_config
        goal = info["goal"]
        before = angular_distance(self.cube_quat(prev), goal)
        distance = angular_distance(self.cube_quat(snap), goal)
        success = distance <= self.success_angle
        dropped = self.dropped(snap)
        force = jnp.sum(snap.actuator_force[2:] ** 2)
        stress = TENDON_STRESS_SCALE * jnp.sum(snap.ten_length ** 2)
        reward = (c.progress * (before - distance) + c.orientation * self.dt * (1.0 - distance / jnp.pi)
                  + c.success_bonus * success - c.drop_penalty * dropped - c.step_penalty - c.force_multiplier * force
                  - c.tendon_stress_multiplier * stress)
        goals_reached = info["goals_reached"] + success.astype(jnp.int32)
        goal_steps = jnp.where(success, 0, info["goal_steps"] + 1)
        timer_ran_out = jnp.logical_and(goal_steps >= self.steps_per_goal, jnp.logical_not(dropped))
        terminal_timer = self.timer == "terminal"
        terminated = jnp.logical_or(dropped, jnp.logical_and(timer_ran_out, terminal_timer))
        cut = jnp.logical_or(goals_reached >= self.max_goals, jnp.logical_and(timer_ran_out, not terminal_timer))
        next_info = {
            "goal": jnp.where(success, self.sample_goal(key), goal),
            "goal_steps": goal_steps,
            "goals_reached": goals_reached,
            "time_out": jnp.logical_and(cut, jnp.logical_not(terminated)),
        }
        metrics = {"goals_reached": goals_reached, "dropped": dropped, "timed_out": timer_ran_out,
                   "goal_distance": distance}
        return reward, terminated, self._with_noise_key(next_info, key), metrics
