"""Gymnasium's MuJoCo tasks (v5) as `MujocoTask`s: the same MJCF files (shipped inside `gymnasium`), observations,
rewards, termination rules, frame skips and start distributions, so that a policy's return means what it means in
the literature (Schulman et al. 2017; AngoraPy's Fig. 9). Actions are the actuators' controls in their `ctrlrange`,
exactly as Gymnasium passes them to MuJoCo (which clamps them); the control cost is computed on the action itself.

Ant and Humanoid also read the external forces on their bodies (`cfrc_ext`, contacts included), which Gymnasium
computes with `mj_rnePostConstraint` once after a policy step's physics: from the last Runge-Kutta stage, where RK4
leaves contacts, constraint forces and every derived position and velocity quantity, in C MuJoCo and in MJX alike.
Both paths do the same (`MujocoTask.body_dynamics`): C MuJoCo and MJX's JAX implementation call it after the step,
MuJoCo Warp at the end of each forward pass inside its step (`run_rne_postconstraint`), which RK4's last stage ends
with too.

Differences from Gymnasium that remain: task logic runs in float32 (Gymnasium: float64), and the random starts are
drawn with JAX's PRNG (same distributions, other numbers). Humanoid's model asks for the PGS constraint solver,
which MJX lacks (it has Newton and CG): `Humanoid` runs Newton on both paths, and Gymnasium's PGS on the C MuJoCo
twin only when asked (`solver="pgs"`). On the twin over 10 episodes of random actions (17-38 steps, until it falls),
Newton's joint positions stayed within 5e-6 of PGS's and its rewards within 1e-5; past the fall, open loop for 200
steps, 4 of 5 sequences stayed within 1e-5 and one parted after 100 steps (0.14). On MJX, Ant parts from its twin at
its feet's contacts: MuJoCo 4.0's C collision aligns a capsule-plane contact's first tangent with the capsule, MJX
3.17 takes fixed axes (in both implementations), and a pyramidal friction cone (Gymnasium's, in every model here)
turns with them. Ant's joint positions and velocities on MJX stay within 2e-5 of its twin's until the first contact
and are up to 2.6 apart 10 steps later (with elliptic cones, which the axes do not change: 1e-3). Humanoid is little
affected: its random-action episodes on MJX (JAX or Warp) stay within 1e-3 + 1e-4 x |value| of the twin. (Hopper's,
Walker2d's and HalfCheetah's contact states give the same accelerations on both, within 1e-13 in float64.)
`tests/test_locomotion.py` steps each task's C MuJoCo twin and Gymnasium's own v5 environment from the same
`qpos`/`qvel` with the same actions and compares observations and rewards step by step, and Humanoid on MJX against
its twin.
"""

from __future__ import annotations

import math
import os
import warnings
from dataclasses import dataclass

import gymnasium
import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from angora_jax.envs.core import Sensation
from angora_jax.envs.mjx_env import choose_impl
from angora_jax.envs.mujoco_task import MujocoTask, Snapshot, set_mjx_impl

ASSETS = os.path.join(os.path.dirname(gymnasium.__file__), "envs", "mujoco", "assets")


SOLVERS = {"newton": mujoco.mjtSolver.mjSOL_NEWTON, "cg": mujoco.mjtSolver.mjSOL_CG, "pgs": mujoco.mjtSolver.mjSOL_PGS}


def load_model(xml: str, impl: str = "auto", solver: str | None = None) -> mujoco.MjModel:
    """Compile one of Gymnasium's MuJoCo models (`gymnasium/envs/mujoco/assets/<xml>`) with its own options, asking
    for MJX implementation `impl` ("auto", "jax" or "warp") on the batched path.

    Args:
        solver: a constraint solver in `SOLVERS` instead of the model's (None: the model's).
    """
    spec = mujoco.MjSpec.from_file(os.path.join(ASSETS, xml))
    if solver is not None:
        if solver not in SOLVERS:
            raise ValueError(f"Unknown solver {solver!r}; choose one of {tuple(SOLVERS)}.")
        spec.option.solver = SOLVERS[solver]
    set_mjx_impl(spec, *choose_impl(impl))
    with warnings.catch_warnings():  # half_cheetah.xml's `settotalmass`: deprecated, still what Gymnasium compiles
        warnings.filterwarnings("ignore", message=".*settotalmass")
        return spec.compile()


class GymnasiumTask(MujocoTask):
    """What Gymnasium's MuJoCo tasks share: motors driven by the action as it is (bounds: `ctrlrange`), a start at
    rest at `qpos0` plus noise, and no control before the first action."""

    random_initial_qpos = True

    def __init__(self, model: mujoco.MjModel, frame_skip: int):
        self.model = model
        self.frame_skip = frame_skip  # physics steps per policy step
        self.dt = float(model.opt.timestep) * frame_skip  # s per policy step, as Gymnasium's `dt`

    def action_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        low, high = self.model.actuator_ctrlrange.T
        return low.astype(np.float32), high.astype(np.float32)

    def control(self, action: jax.Array, snap: Snapshot) -> jax.Array:
        return action

    def initial_control(self, snap: Snapshot) -> jax.Array:
        return jnp.zeros(self.model.nu, jnp.float32)

    def initial_info(self, key: jax.Array, snap: Snapshot) -> dict[str, jax.Array]:
        return {}

    def noisy(self, key: jax.Array, base: np.ndarray, scale: float, normal: bool = False) -> jax.Array:
        """`base` plus uniform noise in [-scale, scale] (or normal noise of std `scale`), as float32."""
        base = jnp.asarray(base, jnp.float32)
        if normal:
            return base + scale * jax.random.normal(key, base.shape)
        return base + jax.random.uniform(key, base.shape, minval=-scale, maxval=scale)


@dataclass(frozen=True)
class ContactCost:
    """Gymnasium's contact cost: min(weight x |F|^2, max_cost), F the external forces on all bodies (`cfrc_ext`,
    N m and N) clipped to `force_range` when given (Ant: the observation then sees them clipped too)."""

    weight: float
    force_range: tuple[float, float] | None = None
    max_cost: float = math.inf


@dataclass(frozen=True)
class Gait:
    """A task of moving forward along x (Gymnasium's Hopper, Walker2d, HalfCheetah, Swimmer, Ant, Humanoid).

    reward = forward_weight x (x velocity of `progress`) + healthy_reward when healthy - ctrl_cost x |action|^2
    - the contact cost (`contacts`; none when None). `progress`: "qpos" (qpos[0]), "torso" (the origin of body 1,
    `xpos`) or "mass_center" (the bodies' centre of mass, from `xipos`).
    Healthy: qpos[height] in `healthy_z` (bounds included when `healthy_z_closed`), qpos[2] (torso angle) in
    `healthy_angle`, every entry of (qpos, qvel)[2:] in `healthy_state` (None: not checked), every entry of (qpos,
    qvel) finite when `finite_state`; an unhealthy step terminates the episode.
    Observation: qpos[skip_qpos:] and qvel, clipped to +-clip_qvel when given, then the `dynamics` named (each of
    `cinert`, `cvel` without the world body, `qfrc_actuator` without the free joint's 6 dofs), then with `contacts`
    the contact cost's F without the world body. Start: qpos0 and zero velocities plus uniform noise of
    `reset_noise` (velocities: normal noise of that std when `normal_qvel_noise`).

    Attributes:
        solver: the constraint solver that both physics paths run instead of the model's (`SOLVERS`; None: the model's).
    """

    xml: str
    frame_skip: int
    ctrl_cost: float
    reset_noise: float
    skip_qpos: int = 1
    healthy_reward: float = 0.0
    height: int = 1
    healthy_z: tuple[float, float] | None = None
    healthy_z_closed: bool = False
    healthy_angle: tuple[float, float] | None = None
    healthy_state: tuple[float, float] | None = None
    finite_state: bool = False
    clip_qvel: float | None = None
    normal_qvel_noise: bool = False
    forward_weight: float = 1.0
    progress: str = "qpos"
    dynamics: tuple[str, ...] = ()
    contacts: ContactCost | None = None
    solver: str | None = None


GAITS = {
    "Hopper": Gait("hopper.xml", 4, 1e-3, 5e-3, healthy_reward=1.0, healthy_z=(0.7, math.inf),
                   healthy_angle=(-0.2, 0.2), healthy_state=(-100.0, 100.0), clip_qvel=10.0),
    "Walker2d": Gait("walker2d_v5.xml", 4, 1e-3, 5e-3, healthy_reward=1.0, healthy_z=(0.8, 2.0),
                     healthy_angle=(-1.0, 1.0), clip_qvel=10.0),
    "HalfCheetah": Gait("half_cheetah.xml", 5, 0.1, 0.1, normal_qvel_noise=True),
    "Swimmer": Gait("swimmer.xml", 4, 1e-4, 0.1, skip_qpos=2),
    "Ant": Gait("ant.xml", 5, 0.5, 0.1, skip_qpos=2, healthy_reward=1.0, height=2, healthy_z=(0.2, 1.0),
                healthy_z_closed=True, finite_state=True, normal_qvel_noise=True, progress="torso",
                contacts=ContactCost(5e-4, force_range=(-1.0, 1.0))),
    # MJX has no PGS, the solver humanoid.xml names (`solver`; the module's docstring says how far the two differ).
    "Humanoid": Gait("humanoid.xml", 5, 0.1, 1e-2, skip_qpos=2, healthy_reward=5.0, height=2, healthy_z=(1.0, 2.0),
                     forward_weight=1.25, progress="mass_center", dynamics=("cinert", "cvel", "qfrc_actuator"),
                     contacts=ContactCost(5e-7, max_cost=10.0), solver="newton"),
}
PROGRESS = ("qpos", "torso", "mass_center")


def _within(x: jax.Array, bounds: tuple[float, float] | None, closed: bool = False) -> jax.Array:
    if bounds is None:
        return jnp.bool_(True)
    low, high = bounds
    return jnp.all((low <= x) & (x <= high) if closed else (low < x) & (x < high))


class Locomotion(GymnasiumTask):
    """A `Gait` on its model; metric `x_position` (m travelled along x at the step: qpos[0]). solver: the
    constraint solver instead of the gait's (`SOLVERS`; "pgs" runs on the C MuJoCo twin only)."""

    metric_names = ("x_position",)

    def __init__(self, gait: Gait, impl: str = "auto", solver: str | None = None):
        if gait.progress not in PROGRESS:
            raise ValueError(f"Unknown progress {gait.progress!r}; choose one of {PROGRESS}.")
        super().__init__(load_model(gait.xml, impl, solver or gait.solver), gait.frame_skip)
        self.gait = gait
        self.body_dynamics = bool(gait.dynamics) or gait.contacts is not None or gait.progress == "mass_center"

    def initial_qpos(self, key: jax.Array) -> jax.Array:
        return self.noisy(key, self.model.qpos0, self.gait.reset_noise)

    def initial_qvel(self, key: jax.Array) -> jax.Array:
        return self.noisy(key, np.zeros(self.model.nv), self.gait.reset_noise, self.gait.normal_qvel_noise)

    def observe(self, snap: Snapshot, info: dict[str, jax.Array]) -> Sensation:
        gait = self.gait
        qvel = snap.qvel if gait.clip_qvel is None else jnp.clip(snap.qvel, -gait.clip_qvel, gait.clip_qvel)
        features = [snap.qpos[gait.skip_qpos:], qvel]
        # The world body's rows are constant; the free joint's actuator forces are zero (v5 leaves both out).
        features += [snap.qfrc_actuator[6:] if name == "qfrc_actuator" else getattr(snap, name)[1:].ravel()
                     for name in gait.dynamics]
        if gait.contacts is not None:
            features.append(self.contact_forces(snap)[1:].ravel())
        return Sensation.make(proprioception=jnp.concatenate(features))

    def contact_forces(self, snap: Snapshot) -> jax.Array:
        """The contact cost's F: `cfrc_ext` (`(nbody, 6)`), clipped to the cost's `force_range` when it has one."""
        force_range = self.gait.contacts.force_range
        return snap.cfrc_ext if force_range is None else jnp.clip(snap.cfrc_ext, *force_range)

    def contact_cost(self, snap: Snapshot) -> jax.Array:
        """Gymnasium's contact cost of `snap` (0 without the gait's `contacts`)."""
        contacts = self.gait.contacts
        if contacts is None:
            return jnp.float32(0.0)
        return jnp.minimum(contacts.weight * jnp.sum(self.contact_forces(snap) ** 2), contacts.max_cost)

    def forward_position(self, snap: Snapshot) -> jax.Array:
        """The x (m) whose velocity is rewarded, as the gait's `progress` says."""
        if self.gait.progress == "torso":
            return snap.xpos[1, 0]
        if self.gait.progress == "mass_center":
            mass = self.model.body_mass.astype(np.float32)  # kg per body
            return mass @ snap.xipos[:, 0] / mass.sum()
        return snap.qpos[0]

    def healthy(self, snap: Snapshot) -> jax.Array:
        gait = self.gait
        state = jnp.concatenate([snap.qpos, snap.qvel])
        healthy = (_within(snap.qpos[gait.height], gait.healthy_z, gait.healthy_z_closed)
                   & _within(snap.qpos[2], gait.healthy_angle) & _within(state[2:], gait.healthy_state))
        return healthy & jnp.all(jnp.isfinite(state)) if gait.finite_state else healthy

    def evaluate(self, key, prev: Snapshot, snap: Snapshot, info):
        gait = self.gait
        velocity = (self.forward_position(snap) - self.forward_position(prev)) / self.dt
        healthy = self.healthy(snap)
        reward = (gait.forward_weight * velocity + gait.healthy_reward * healthy
                  - gait.ctrl_cost * jnp.sum(snap.ctrl**2) - self.contact_cost(snap))
        terminated = jnp.logical_not(healthy) if gait.healthy_reward else jnp.bool_(False)
        return reward, terminated, info, {"x_position": snap.qpos[0]}


class InvertedPendulum(GymnasiumTask):
    """Balance a pole on a cart: reward 1 per step; the episode ends when |pole angle| > 0.2 rad or the state is not
    finite. Observation (qpos, qvel); start: qpos0 and rest plus uniform noise of 0.01."""

    def __init__(self, impl: str = "auto"):
        super().__init__(load_model("inverted_pendulum.xml", impl), frame_skip=2)

    def initial_qpos(self, key):
        return self.noisy(key, self.model.qpos0, 0.01)

    def initial_qvel(self, key):
        return self.noisy(key, np.zeros(self.model.nv), 0.01)

    def observe(self, snap, info):
        return Sensation.make(proprioception=jnp.concatenate([snap.qpos, snap.qvel]))

    def evaluate(self, key, prev, snap, info):
        obs = self.observe(snap, info).proprioception
        terminated = jnp.logical_not(jnp.all(jnp.isfinite(obs))) | (jnp.abs(obs[1]) > 0.2)
        return jnp.where(terminated, 0.0, 1.0), terminated, info, {}


class InvertedDoublePendulum(GymnasiumTask):
    """Balance two poles on a cart: reward 10 while the tip is above 1 m, minus 0.01 x^2 + (y - 2)^2 of the tip's
    position (x, y) and 1e-3 w1^2 + 5e-3 w2^2 of the hinges' speeds; the episode ends when the tip's height y <= 1.
    Observation: cart x, sin and cos of the hinge angles, velocities and the cart's constraint force (clipped to 10).
    Start: qpos0 plus uniform noise of 0.1, velocities normal with std 0.1."""

    def __init__(self, impl: str = "auto"):
        super().__init__(load_model("inverted_double_pendulum.xml", impl), frame_skip=5)

    def initial_qpos(self, key):
        return self.noisy(key, self.model.qpos0, 0.1)

    def initial_qvel(self, key):
        return self.noisy(key, np.zeros(self.model.nv), 0.1, normal=True)

    def observe(self, snap, info):
        features = [snap.qpos[:1], jnp.sin(snap.qpos[1:]), jnp.cos(snap.qpos[1:]), jnp.clip(snap.qvel, -10, 10),
                    jnp.clip(snap.qfrc_constraint, -10, 10)[:1]]
        return Sensation.make(proprioception=jnp.concatenate(features))

    def evaluate(self, key, prev, snap, info):
        x, _, y = snap.site_xpos[0]
        terminated = y <= 1
        penalty = 0.01 * x**2 + (y - 2) ** 2 + 1e-3 * snap.qvel[1] ** 2 + 5e-3 * snap.qvel[2] ** 2
        return jnp.where(terminated, 0.0, 10.0) - penalty, terminated, info, {}


class Reacher(GymnasiumTask):
    """Bring a two-link arm's fingertip to a target drawn uniformly in a disk of radius 0.2 m: reward -(distance)
    - |action|^2 per step, never terminating. Observation: cos and sin of the arm's angles, the target's position,
    the arm's velocities and fingertip - target (x, y). Metric `distance` (m, at the step)."""

    metric_names = ("distance",)

    def __init__(self, impl: str = "auto"):
        super().__init__(load_model("reacher.xml", impl), frame_skip=2)
        self.fingertip = self.model.body("fingertip").id
        self.target = self.model.body("target").id

    def initial_qpos(self, key):
        arm_key, radius_key, angle_key = jax.random.split(key, 3)
        qpos = self.noisy(arm_key, self.model.qpos0, 0.1)
        radius = 0.2 * jnp.sqrt(jax.random.uniform(radius_key))
        angle = jax.random.uniform(angle_key, minval=-jnp.pi, maxval=jnp.pi)
        return qpos.at[-2:].set(radius * jnp.stack([jnp.cos(angle), jnp.sin(angle)]))

    def initial_qvel(self, key):
        return self.noisy(key, np.zeros(self.model.nv), 0.005).at[-2:].set(0.0)

    def observe(self, snap, info):
        theta = snap.qpos[:2]
        features = [jnp.cos(theta), jnp.sin(theta), snap.qpos[2:], snap.qvel[:2],
                    (snap.xpos[self.fingertip] - snap.xpos[self.target])[:2]]
        return Sensation.make(proprioception=jnp.concatenate(features))

    def evaluate(self, key, prev, snap, info):
        distance = jnp.linalg.norm(snap.xpos[self.fingertip] - snap.xpos[self.target])
        return -distance - jnp.sum(snap.ctrl**2), jnp.bool_(False), info, {"distance": distance}
