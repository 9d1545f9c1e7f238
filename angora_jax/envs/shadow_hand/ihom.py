"""In-hand object manipulation (IHOM): turn a cube in the palm-up hand to a sequence of goal orientations.

After AngoraPy's `ManipulateBlock` and OpenAI's Dactyl task. A goal is a target orientation (unit quaternion,
position ignored). It is reached when the cube's angular distance to it is at most `success_angle` (eta, default
0.4 rad); then a new goal is drawn and the goal timer restarts. Goals are drawn as in AngoraPy's "xyz" mode: a
rotation by an angle uniform in [-pi, pi] about an axis uniform in [-1, 1]^3, independent of the cube's pose.

Episode rules, checked after every policy step:
- drop: the cube's centre is below the palm's centre -> `terminated` (a true terminal state: the cube is gone);
- goal timer: `steps_per_goal` policy steps without reaching the current goal (8 s at the default 0.08 s per
  step) -> truncated, via `info["time_out"]`: the MDP itself would go on (the agent could still reach the goal),
  so the value is bootstrapped, not cut to 0;
- cap: `max_goals` (50) goals reached -> truncated too, for the same reason.
Consecutive goals reached (CGR) is the metric `goals_reached` at the episode's end.

Reward (`IhomReward` coefficients on a fixed prototype), with d the angular distance to the goal in rad:
    r = progress * (d(t-1) - d(t)) + success_bonus * success - drop_penalty * dropped - step_penalty
        - force_multiplier * sum(actuator_force[2:] ** 2)
Both distances are to the goal that was active during the step; after a success the next step measures progress
to the new goal from the pose where the old one was reached.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from angora_jax.envs.coefficients import Coefficients
from angora_jax.envs.core import Sensation
from angora_jax.envs.mujoco_task import Snapshot
from angora_jax.envs.shadow_hand.cube import CUBE_JOINT
from angora_jax.envs.shadow_hand.hand import HandTask
from angora_jax.envs.shadow_hand.model import HAND_JOINT_PREFIX

# Gym HandManipulateBlock starts from the flat, open hand (all joints 0): the cube then rests on the palm 2.7 cm
# above the palm's centre. (AngoraPy's flexed reach pose tilts this palm so far that the cube rests below it.)
# Std (m) of the cube's initial position noise, as in AngoraPy/Gym.
INITIAL_POSITION_NOISE = 0.005


@dataclasses.dataclass(frozen=True)
class IhomReward(Coefficients):
    """Reward coefficients (AngoraPy's MANIPULATE_BASE plus the issue's per-step cost). Angles in rad.

    progress: weight of the decrease of the angular distance to the goal over one step.
    success_bonus: added on the step a goal is reached.
    drop_penalty: subtracted on the step the cube drops.
    step_penalty: subtracted on every step (time cost).
    force_multiplier: weight of the squared actuator forces (wrist excluded), a metabolic cost; 0 in AngoraPy.
    """

    progress: float = 1.0
    success_bonus: float = 5.0
    drop_penalty: float = 20.0
    step_penalty: float = 0.1
    force_multiplier: float = 0.0


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


class Ihom(HandTask):
    """Cube reorientation on the cube scene (`load_cube_scene`).

    Observation (sizes for the Gym hand; touch only when the model has touch sensors):
      proprioception (48): hand joint positions (rad) and velocities (rad/s), 24 each;
      touch (97 or 0): touch sensor readings (N, contact normal forces summed over each sensor zone);
      vision (7): the cube's pose in place of vision, position (m, world) and orientation quaternion (w, x, y, z);
      goal (4): the goal quaternion;
      asymmetric (25, value function only): fingertip positions (15, m), rotation from cube to goal (4,
        quaternion), cube linear velocity (3, m/s, world frame) and angular velocity (3, rad/s, cube frame).
    Info: goal (4,), goal_steps (int32, steps spent on the current goal), goals_reached (int32), time_out (bool).
    Metrics: goals_reached (CGR so far), dropped (1 on the step the cube dropped), goal_distance (rad).
    """

    metric_names = ("goals_reached", "dropped", "goal_distance")
    random_initial_qpos = True

    def __init__(self, model: mujoco.MjModel, reward: IhomReward = IhomReward(), success_angle: float = 0.4,
                 steps_per_goal: int = 100, max_goals: int = 50, relative_control: bool = True):
        if success_angle <= 0 or steps_per_goal < 1 or max_goals < 1:
            raise ValueError(f"Ihom needs success_angle > 0, steps_per_goal >= 1 and max_goals >= 1, got "
                             f"{success_angle}, {steps_per_goal}, {max_goals}.")
        hand_joints = [j for j in range(model.njnt) if model.joint(j).name.startswith(HAND_JOINT_PREFIX)]
        super().__init__(model, relative_control=relative_control,
                         initial_qpos={model.joint(j).name: 0.0 for j in hand_joints})
        self.reward_config = reward
        self.success_angle = success_angle
        self.steps_per_goal = steps_per_goal
        self.max_goals = max_goals
        cube = model.joint(CUBE_JOINT)
        self.cube_qpos = int(cube.qposadr[0])
        self.cube_dof = int(cube.dofadr[0])
        touch = model.sensor_type == mujoco.mjtSensor.mjSENS_TOUCH
        self.touch_adr = np.asarray(model.sensor_adr[touch])

    def cube_pose(self, snap: Snapshot) -> jax.Array:
        """Cube position (m) and orientation quaternion, shape `(7,)`."""
        return snap.qpos[self.cube_qpos:self.cube_qpos + 7]

    def cube_quat(self, snap: Snapshot) -> jax.Array:
        return snap.qpos[self.cube_qpos + 3:self.cube_qpos + 7]

    def dropped(self, snap: Snapshot) -> jax.Array:
        """True when the cube's centre is below the palm's centre (AngoraPy's drop test)."""
        return snap.qpos[self.cube_qpos + 2] < snap.xpos[self.palm_id, 2]

    def initial_qpos(self, key: jax.Array) -> jax.Array:
        """Flat hand; the cube above the palm (Gym's start), turned by a random rotation, position noise 5 mm."""
        turn_key, shift_key = jax.random.split(key)
        qpos = jnp.asarray(self._qpos0)
        start = self._qpos0[self.cube_qpos:self.cube_qpos + 7]
        quat = quat_mul(jnp.asarray(start[3:]), random_rotation(turn_key))
        pos = start[:3] + INITIAL_POSITION_NOISE * jax.random.normal(shift_key, (3,))
        return qpos.at[self.cube_qpos:self.cube_qpos + 7].set(jnp.concatenate([pos, quat / jnp.linalg.norm(quat)]))

    def initial_info(self, key: jax.Array, snap: Snapshot) -> dict[str, jax.Array]:
        return {"goal": random_rotation(key), "goal_steps": jnp.zeros((), jnp.int32),
                "goals_reached": jnp.zeros((), jnp.int32), "time_out": jnp.zeros((), bool)}

    def observe(self, snap: Snapshot, info: dict[str, jax.Array]) -> Sensation:
        cube_velocity = snap.qvel[self.cube_dof:self.cube_dof + 6]
        asymmetric = jnp.concatenate([self.fingertips(snap).reshape(-1),
                                      rotation_between(self.cube_quat(snap), info["goal"]), cube_velocity])
        return Sensation.make(proprioception=self.proprioception(snap), touch=snap.sensordata[self.touch_adr],
                              vision=self.cube_pose(snap), goal=info["goal"], asymmetric=asymmetric)

    def evaluate(self, key, prev, snap, info):
        c = self.reward_config
        goal = info["goal"]
        before = angular_distance(self.cube_quat(prev), goal)
        distance = angular_distance(self.cube_quat(snap), goal)
        success = distance <= self.success_angle
        dropped = self.dropped(snap)
        force = jnp.sum(snap.actuator_force[2:] ** 2)
        reward = (c.progress * (before - distance) + c.success_bonus * success - c.drop_penalty * dropped
                  - c.step_penalty - c.force_multiplier * force)
        goals_reached = info["goals_reached"] + success.astype(jnp.int32)
        goal_steps = jnp.where(success, 0, info["goal_steps"] + 1)
        out_of_time = jnp.logical_or(goal_steps >= self.steps_per_goal, goals_reached >= self.max_goals)
        next_info = {
            "goal": jnp.where(success, random_rotation(key), goal),
            "goal_steps": goal_steps,
            "goals_reached": goals_reached,
            "time_out": jnp.logical_and(out_of_time, jnp.logical_not(dropped)),
        }
        metrics = {"goals_reached": goals_reached, "dropped": dropped, "goal_distance": distance}
        return reward, dropped, next_info, metrics
