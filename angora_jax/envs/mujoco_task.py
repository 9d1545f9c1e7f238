"""Task logic over a MuJoCo model, written once for both physics paths.

A `MujocoTask` reads the simulation only through a `Snapshot`, a small pytree of arrays whose fields have the
same names in `mjx.Data` (the batched GPU path) and `mujoco.MjData` (the eager CPU path). Its methods are pure
JAX functions, so the MJX environment calls them inside its compiled step and the CPU twin calls the same
functions, jitted for one environment, between calls to `mujoco.mj_step`.
"""

from __future__ import annotations

import abc
from typing import Any

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from flax import struct

from angora_jax.envs.cameras import CameraVision
from angora_jax.envs.core import ActionSpec, Env, Sensation, State, episode_limit
from angora_jax.envs.randomization import DELAY_KEY, INFO_KEY, ModelRandomizer

MJX_IMPLS = ("jax", "warp")
# Name of the MJCF custom text that names a model's MJX implementation: the compiled model is what the MJX path and
# its C MuJoCo twin share, so the choice travels with it (as MJX's own `max_contact_points` numeric does).
MJX_IMPL_TEXT = "angora_jax:mjx_impl"
MJX_IMPL_WHY_TEXT = "angora_jax:mjx_impl_why"
SNAPSHOT_FIELDS = ("time", "qpos", "qvel", "ctrl", "actuator_length", "actuator_force", "site_xpos", "xpos",
                   "xquat", "sensordata", "qfrc_constraint", "ten_length")
# What only tasks with `MujocoTask.body_dynamics` read (Gymnasium's Ant and Humanoid): a snapshot holds them only then,
# so the eager path of other tasks copies nothing more per step.
DYNAMICS_FIELDS = ("xipos", "cinert", "cvel", "qfrc_actuator", "cfrc_ext")
# What only muscle-driven tasks read (`MujocoTask.muscle_sense`, the MyoHand): actuator velocities (the muscles'
# lengthening rates) and activations, in snapshots only then.
MUSCLE_FIELDS = ("actuator_velocity", "act")
# Fields that `mjx.Data` keeps in its implementation's part (`data._impl`) rather than among its own.
_MJX_IMPL_FIELDS = ("cinert", "cfrc_ext", "actuator_velocity")


@struct.dataclass
class Snapshot:
    """What task logic may read of the simulation: `mjData` fields of the same name, as float32 arrays
    (time in s, positions in m, site/body arrays indexed by MuJoCo ids; `ten_length` `(ntendon,)` in m). The
    `DYNAMICS_FIELDS` are None unless the snapshot was taken with them: `xipos` (bodies' centres of mass,
    `(nbody, 3)` m), `cinert` (`(nbody, 10)` inertias and masses), `cvel` (`(nbody, 6)` velocities, rotation then
    translation) and `cfrc_ext` (`(nbody, 6)` external forces on each body, contacts included, torque then force, as
    `mj_rnePostConstraint` computes them; zero where it did not run), all three in MuJoCo's centre-of-mass frames,
    and `qfrc_actuator` (`(nv,)`). The `MUSCLE_FIELDS` are None unless taken: `actuator_velocity` (`(nu,)`, m/s for
    tendon actuators such as muscles) and `act` (`(na,)`, muscle activations in [0, 1])."""

    time: jax.Array
    qpos: jax.Array
    qvel: jax.Array
    ctrl: jax.Array
    actuator_length: jax.Array
    actuator_force: jax.Array
    site_xpos: jax.Array
    xpos: jax.Array
    xquat: jax.Array
    sensordata: jax.Array
    qfrc_constraint: jax.Array
    ten_length: jax.Array
    xipos: jax.Array | None = None
    cinert: jax.Array | None = None
    cvel: jax.Array | None = None
    qfrc_actuator: jax.Array | None = None
    cfrc_ext: jax.Array | None = None
    actuator_velocity: jax.Array | None = None
    act: jax.Array | None = None

    @classmethod
    def of(cls, data: Any, fields: tuple[str, ...] = SNAPSHOT_FIELDS) -> Snapshot:
        """Take a snapshot of `fields` of an `mjx.Data` or a `mujoco.MjData` (`MujocoTask.snapshot_fields`)."""
        return cls(**{f: jnp.asarray(np.copy(v) if isinstance(v, np.ndarray) else v, jnp.float32)
                      for f in fields for v in [_data_field(data, f)]})


def _data_field(data: Any, name: str) -> Any:
    if name in _MJX_IMPL_FIELDS and hasattr(data, "_impl"):
        return getattr(data._impl, name)
    return getattr(data, name)


class MujocoTask(abc.ABC):
    """Goal, observation, reward and termination of a task on one MuJoCo model.

    Subclasses hold only static configuration (ids resolved from the model, coefficients) and implement pure
    functions of snapshots and the task's `info` dict. Attributes: `model` (the compiled `mujoco.MjModel`,
    shared by both physics paths), `metric_names`.
    """

    model: mujoco.MjModel
    metric_names: tuple[str, ...] = ()
    # When False, `initial_qpos` ignores its key and the initial physics are computed once, in C MuJoCo.
    random_initial_qpos: bool = False
    # The body that cameras look at when rendering (None: the model's centre).
    camera_body: str | None = None
    # Camera images in `Sensation.vision` (`envs.cameras`): the physics backends render them after `observe`, whose
    # own vision must then be empty; the model must hold the cameras (`rendering.add_cameras`).
    vision: CameraVision | None = None
    # Whether the task reads `DYNAMICS_FIELDS`: its snapshots then hold them, and both physics paths compute
    # `cfrc_ext` after each policy step's physics as Gymnasium does (`mj_rnePostConstraint`, once after the last physics
    # step). Off, none of it costs anything.
    body_dynamics: bool = False
    # Whether `perceive` passes the camera frames on as the vision modality (the policy sees images), or the task
    # reads them into other observations.
    frames_in_vision: bool = True
    # Domain randomization (`envs.randomization`): model fields drawn per environment at reset, action and observation
    # noise per step; both physics paths apply it. None: the task as its model says.
    randomizer: ModelRandomizer | None = None
    # Whether the task reads `MUSCLE_FIELDS` (muscle velocities and activations): its snapshots then hold them.
    muscle_sense: bool = False

    @property
    def snapshot_fields(self) -> tuple[str, ...]:
        """The `Snapshot` fields the task reads."""
        return (SNAPSHOT_FIELDS + (DYNAMICS_FIELDS if self.body_dynamics else ())
                + (MUSCLE_FIELDS if self.muscle_sense else ()))

    def snapshot(self, data: Any) -> Snapshot:
        """`Snapshot.of(data)` with the fields the task reads."""
        return Snapshot.of(data, self.snapshot_fields)

    @abc.abstractmethod
    def initial_qpos(self, key: jax.Array) -> jax.Array:
        """Joint positions at the start of an episode, shape `(nq,)`."""

    def start_qpos(self, pose_key: jax.Array, task_key: jax.Array) -> jax.Array:
        """Joint positions at the start of an episode `(nq,)`, given both of its reset's keys: `pose_key`'s and the one
        `initial_info` draws the task's state (a goal) from. Both physics paths call this; by default it is
        `initial_qpos(pose_key)`. A task whose start depends on its goal overrides it (`MyoHandPose`'s
        `start_spread`), drawing the goal again from `task_key` as `initial_info` will."""
        return self.initial_qpos(pose_key)

    def initial_qvel(self, key: jax.Array) -> jax.Array:
        """Joint velocities at the start of an episode, shape `(nv,)` (at rest unless a task says otherwise; used
        with `random_initial_qpos`). `key` is derived from `initial_qpos`'s key."""
        return jnp.zeros(self.model.nv, jnp.float32)

    def action_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Lower and upper bounds of a policy action, each `(nu,)`: [-1, 1] unless the task acts in its own units."""
        return -np.ones(self.model.nu, np.float32), np.ones(self.model.nu, np.float32)

    @abc.abstractmethod
    def initial_info(self, key: jax.Array, snap: Snapshot) -> dict[str, jax.Array]:
        """Task state at the start of an episode (e.g. a sampled goal), given the initial snapshot."""

    @abc.abstractmethod
    def observe(self, snap: Snapshot, info: dict[str, jax.Array]) -> Sensation:
        """The agent's observation of the current snapshot."""

    @abc.abstractmethod
    def evaluate(
        self, key: jax.Array, prev: Snapshot, snap: Snapshot, info: dict[str, jax.Array]
    ) -> tuple[jax.Array, jax.Array, dict[str, jax.Array], dict[str, jax.Array]]:
        """Judge one policy step from `prev` to `snap`: return (reward, terminated, next info, metrics)."""

    @abc.abstractmethod
    def control(self, action: jax.Array, snap: Snapshot) -> jax.Array:
        """Map a policy action to `ctrl` (shape `(nu,)`), given the snapshot the action was chosen in."""

    def initial_control(self, snap: Snapshot) -> jax.Array:
        """`ctrl` that holds the initial pose: position actuators target their current lengths."""
        low, high = self.model.actuator_ctrlrange.T.astype(np.float32)
        return jnp.clip(snap.actuator_length, low, high)

    def task_variables(self, snap: Snapshot, info: dict[str, jax.Array]) -> dict[str, jax.Array]:
        """`Env.task_variables` of the snapshot: named vectors in SI units; none unless the task names some."""
        return {}

    def task_variable_labels(self) -> dict[str, tuple[str, ...]]:
        """A name per component of those `task_variables` whose components have one (e.g. each muscle's), which
        recordings keep as coordinates; none by default."""
        return {}

    def perceive(self, obs: Sensation, frames: jax.Array, info: dict[str, jax.Array]) -> Sensation:
        """`obs` (from `observe`) completed with the camera `frames` of the same state (`vision`'s uint8
        `frame_shape`), which the physics backends render after `observe`: by default the frames are the vision
        modality. A task that reads them itself (e.g. through a pose estimator) overrides this and sets
        `frames_in_vision` to False."""
        return obs.replace(vision=frames)

    def begin(self, key: jax.Array, snap: Snapshot) -> tuple[dict[str, jax.Array], Sensation]:
        """Start an episode from `snap`: return (info, observation)."""
        info = self.initial_info(key, snap)
        return info, self.observe(snap, info)

    def advance(
        self, key: jax.Array, prev: Snapshot, snap: Snapshot, info: dict[str, jax.Array]
    ) -> tuple[Sensation, jax.Array, jax.Array, dict[str, jax.Array], dict[str, jax.Array]]:
        """Everything after the physics of one step: return (observation, reward, terminated, info, metrics)."""
        reward, terminated, info, metrics = self.evaluate(key, prev, snap, info)
        return self.observe(snap, info), reward, terminated, info, metrics


class MujocoEnv(Env):
    """What the MJX environment and its C MuJoCo twin share: `task` run with `frame_skip` physics steps of
    `task.model.opt.timestep` s per policy step; actions are float32, shape `(nu,)`, within `task.action_bounds()`."""

    def __init__(self, task: MujocoTask, frame_skip: int, max_episode_steps: int):
        if frame_skip < 1:
            raise ValueError(f"frame_skip must be >= 1, got {frame_skip}.")
        self.task = task
        self.frame_skip = frame_skip
        self.max_episode_steps = episode_limit(max_episode_steps)
        self.dt = float(task.model.opt.timestep) * frame_skip
        self.metric_names = task.metric_names
        low, high = task.action_bounds()
        self.action_spec = ActionSpec(low=jnp.asarray(low, jnp.float32), high=jnp.asarray(high, jnp.float32))

    def _begin_task(self, key: jax.Array, task_key: jax.Array, snap: Snapshot,
                    factors: dict[str, jax.Array]) -> tuple[dict[str, jax.Array], Sensation]:
        """`task.begin(task_key, snap)` of a reset from `key`, randomized: the drawn model `factors` and action delay
        held in the episode's info, observation noise added (pure JAX)."""
        info, obs = self.task.begin(task_key, snap)
        randomizer = self.task.randomizer
        if randomizer is None:
            return info, obs
        info = info | {INFO_KEY: factors}
        if randomizer.delays:
            info[DELAY_KEY] = randomizer.delay_state(key, self.task.initial_control(snap))
        return info, self._with_physics(randomizer.noisy_observation(obs, key), info)

    def _control_task(self, action: jax.Array, key: jax.Array, snap: Snapshot,
                      info: dict[str, jax.Array]) -> tuple[jax.Array, dict[str, jax.Array]]:
        """`task.control(action, snap)` of a step with `key`, randomized: the action with the randomization's action
        noise, the control delayed by the episode's action delay; returns the control the physics receive and `info`
        with the delay's state advanced (both as the task gives them without randomization; pure JAX)."""
        randomizer = self.task.randomizer
        if randomizer is None:
            return self.task.control(action, snap), info
        control = self.task.control(randomizer.noisy_action(action, key, self.action_spec.low, self.action_spec.high),
                                    snap)
        if not randomizer.delays:
            return control, info
        control, delay = randomizer.delayed(control, info[DELAY_KEY])
        return control, info | {DELAY_KEY: delay}

    def _advance_task(self, key: jax.Array, prev: Snapshot, snap: Snapshot, info: dict[str, jax.Array]):
        """`task.advance` of a step with `key`, randomized: the held model factors and delay state pass by the task,
        observation noise is added (pure JAX)."""
        randomizer = self.task.randomizer
        if randomizer is None:
            return self.task.advance(key, prev, snap, info)
        held = {k: v for k, v in info.items() if k in (INFO_KEY, DELAY_KEY)}
        task_info = {k: v for k, v in info.items() if k not in held}
        obs, reward, terminated, task_info, metrics = self.task.advance(key, prev, snap, task_info)
        return self._with_physics(randomizer.noisy_observation(obs, key), held), reward, terminated, task_info | held, \
            metrics

    def _with_physics(self, obs: Sensation, info: dict[str, Any]) -> Sensation:
        """`obs` with the episode's drawn physics (held in `info`) after its `asymmetric` inputs, when the value
        function sees them (`ModelRandomizer.physics_inputs`)."""
        randomizer = self.task.randomizer
        if not randomizer.value_sees_physics:
            return obs
        physics = randomizer.physics_inputs(info[INFO_KEY], info.get(DELAY_KEY))
        return obs.replace(asymmetric=jnp.concatenate([obs.asymmetric, physics]))

    def physics_info(self, num_envs: int | None = None) -> dict[str, Any]:
        return {"engine": "C MuJoCo (eager)", "device": "host CPU", "timestep_s": float(self.task.model.opt.timestep),
                "frame_skip": self.frame_skip}

    @property
    def sees_images(self) -> bool:
        return self.task.vision is not None and self.task.frames_in_vision

    def task_variables(self, state: State) -> dict[str, jax.Array]:
        return self.task.task_variables(self.task.snapshot(state.physics), state.info)

    def observation_shapes(self) -> Sensation:
        """As `Env.observation_shapes`; with camera vision, without rendering (blank frames, `perceive`d)."""
        if self.task.vision is None:
            return super().observation_shapes()
        data = mujoco.MjData(self.task.model)
        mujoco.mj_forward(self.task.model, data)
        snap = self.task.snapshot(data)
        frames = jnp.zeros(self.task.vision.frame_shape, jnp.uint8)

        def first_observation(key):
            info, obs = self.task.begin(key, snap)
            return self.task.perceive(obs, frames, info)

        return jax.eval_shape(first_observation, jax.random.key(0))


def set_mjx_impl(spec: mujoco.MjSpec, impl: str, why: str = "") -> None:
    """Ask for MJX implementation `impl` ("jax" or "warp") in the model compiled from `spec`; `why` says how it was
    chosen (shown when a run starts and by `angora-jax doctor`). A later call replaces an earlier one's choice (a
    scene that adds what one implementation cannot step chooses again)."""
    if impl not in MJX_IMPLS:
        raise ValueError(f"Unknown MJX implementation impl={impl!r}; choose one of {MJX_IMPLS}.")
    for name in (MJX_IMPL_TEXT, MJX_IMPL_WHY_TEXT):
        if spec.text(name) is not None:
            spec.delete(spec.text(name))
    if impl != "jax":
        spec.add_text(name=MJX_IMPL_TEXT, data=impl)
    if why:
        spec.add_text(name=MJX_IMPL_WHY_TEXT, data=why)


def mjx_impl(model: mujoco.MjModel) -> str:
    """The MJX implementation `model` asks for (`set_mjx_impl`); "jax" when it names none."""
    return _model_text(model, MJX_IMPL_TEXT) or "jax"


def mjx_impl_why(model: mujoco.MjModel) -> str:
    """How the model's MJX implementation was chosen, as `set_mjx_impl` recorded it ("" when it did not)."""
    return _model_text(model, MJX_IMPL_WHY_TEXT)


def _model_text(model: mujoco.MjModel, name: str) -> str:
    text = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_TEXT, name)
    if text < 0:
        return ""
    start = model.text_adr[text]
    return bytes(model.text_data[start:start + model.text_size[text] - 1]).decode()


def start_physics(task: MujocoTask, qpos: np.ndarray, data: mujoco.MjData | None = None,
                  qvel: np.ndarray | None = None, model: mujoco.MjModel | None = None) -> mujoco.MjData:
    """C MuJoCo data at an episode's start: `qpos` (and `qvel`, else at rest) set, kinematics computed, `ctrl` as
    `task.initial_control` says. Resets and reuses `data` when given; `model` replaces `task.model` (a randomized
    copy of it)."""
    model = task.model if model is None else model
    if data is None:
        data = mujoco.MjData(model)
    mujoco.mj_resetData(model, data)
    data.qpos[:] = qpos
    if qvel is not None:
        data.qvel[:] = qvel
    mujoco.mj_forward(model, data)
    data.ctrl[:] = np.asarray(task.initial_control(task.snapshot(data)), np.float64)
    return data


def step_physics(task: MujocoTask, data: mujoco.MjData, frame_skip: int, model: mujoco.MjModel | None = None) -> None:
    """Advance C MuJoCo `data` by `frame_skip` physics steps of `task`'s model or of `model` (a randomized copy of it),
    one policy step, then compute its `cfrc_ext` when the task reads it (`MujocoTask.body_dynamics`), as Gymnasium's
    MuJoCo environments do."""
    model = task.model if model is None else model
    mujoco.mj_step(model, data, nstep=frame_skip)
    if task.body_dynamics:
        mujoco.mj_rnePostConstraint(model, data)
