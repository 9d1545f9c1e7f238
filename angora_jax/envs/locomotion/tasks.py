"""Gymnasium's MuJoCo tasks (v5) as `MujocoTask`s: the same MJCF files (shipped inside `gymnasium`), observations,
rewards, termination rules, frame skips and start distributions, so that a policy's return means what it means in
the literature (Schulman et al. 2017; AngoraPy's Fig. 9). Actions are the actuators' controls in their `ctrlrange`,
exactly as Gymnasium passes them to MuJoCo (which clamps them); the control cost is computed on the action itself.

Differences from Gymnasium that remain: task logic runs in float32 (Gymnasium: float64), and the random starts are
drawn with JAX's PRNG (same distributions, other numbers). `tests/test_locomotion.py` steps each task's C MuJoCo twin
and Gymnasium's own v5 environment from the same `qpos`/`qvel` with the same actions and compares observations and
rewards step by step.
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


def load_model(xml: str, impl: str = "auto") -> mujoco.MjModel:
    """Compile one of Gymnasium's MuJoCo models (`gymnasium/envs/mujoco/assets/<xml>`) with its own options, asking
    for MJX implementation `impl` ("auto", "jax" or "warp") on the batched path."""
    spec = mujoco.MjSpec.from_file(os.path.join(ASSETS, xml))
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
class Gait:
    """A task of moving forward along x (Gymnasium's Hopper, Walker2d, HalfCheetah, Swimmer).

    reward = forward_weight x (x velocity of qpos[0]) + healthy_reward when healthy - ctrl_cost x |action|^2.
    Healthy: qpos[1] (height) in `healthy_z`, qpos[2] (torso angle) in `healthy_angle`, every entry of
    (qpos, qvel)[2:] in `healthy_state` (None: not checked); an unhealthy step terminates the episode.
    Observation: qpos[skip_qpos:] and qvel, clipped to +-clip_qvel when given. Start: qpos0 and zero velocities plus
    uniform noise of `reset_noise` (velocities: normal noise of that std when `normal_qvel_noise`).
    """

    xml: str
    frame_skip: int
    ctrl_cost: float
    reset_noise: float
    skip_qpos: int = 1
    healthy_reward: float = 0.0
    healthy_z: tuple[float, float] | None = None
    healthy_angle: tuple[float, float] | None = None
    healthy_state: tuple[float, float] | None = None
    clip_qvel: float | None = None
    normal_qvel_noise: bool = False
    forward_weight: float = 1.0


GAITS = {
    "Hopper": Gait("hopper.xml", 4, 1e-3, 5e-3, healthy_reward=1.0, healthy_z=(0.7, math.inf),
                   healthy_angle=(-0.2, 0.2), healthy_state=(-100.0, 100.0), clip_qvel=10.0),
    "Walker2d": Gait("walker2d_v5.xml", 4, 1e-3, 5e-3, healthy_reward=1.0, healthy_z=(0.8, 2.0),
                     healthy_angle=(-1.0, 1.0), clip_qvel=10.0),
    "HalfCheetah": Gait("half_cheetah.xml", 5, 0.1, 0.1, normal_qvel_noise=True),
    "Swimmer": Gait("swimmer.xml", 4, 1e-4, 0.1, skip_qpos=2),
}


def _within(x: jax.Array, bounds: tuple[float, float] | None) -> jax.Array:
    if bounds is None:
        return jnp.bool_(True)
    return jnp.all((bounds[0] < x) & (x < bounds[1]))


class Locomotion(GymnasiumTask):
    """A `Gait` on its model; metric `x_position` (m travelled along x at the step)."""

    metric_names = ("x_position",)

    def __init__(self, gait: Gait, impl: str = "auto"):
        super().__init__(load_model(gait.xml, impl), gait.frame_skip)
        self.gait = gait

    def initial_qpos(self, key: jax.Array) -> jax.Array:
        return self.noisy(key, self.model.qpos0, self.gait.reset_noise)

    def initial_qvel(self, key: jax.Array) -> jax.Array:
        return self.noisy(key, np.zeros(self.model.nv), self.gait.reset_noise, self.gait.normal_qvel_noise)

    def observe(self, snap: Snapshot, info: dict[str, jax.Array]) -> Sensation:
        qvel = snap.qvel if self.gait.clip_qvel is None else jnp.clip(snap.qvel, -self.gait.clip_qvel,
                                                                      self.gait.clip_qvel)
        return Sensation.make(proprioception=jnp.concatenate([snap.qpos[self.gait.skip_qpos:], qvel]))

    def healthy(self, snap: Snapshot) -> jax.Array:
        gait = self.gait
        state = jnp.concatenate([snap.qpos, snap.qvel])[2:]
        return (_within(snap.qpos[1], gait.healthy_z) & _within(snap.qpos[2], gait.healthy_angle)
                & _within(state, gait.healthy_state))

    def evaluate(self, key, prev: Snapshot, snap: Snapshot, info):
        gait = self.gait
        velocity = (snap.qpos[0] - prev.qpos[0]) / self.dt
        healthy = self.healthy(snap)
        reward = (gait.forward_weight * velocity + gait.healthy_reward * healthy
                  - gait.ctrl_cost * jnp.sum(snap.ctrl**2))
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
