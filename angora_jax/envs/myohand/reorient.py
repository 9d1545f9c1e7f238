"""`MyoHandReorient`: turn MyoChallenge 2022's die on the palm-up, muscle-driven MyoHand to a sequence of drawn goals,
counted as consecutive goals reached (CGR) as on the Shadow cube (`shadow_hand.ihom`).

What is MyoSuite's (myosuite `envs/myo/myochallenge/reorient_v0.py`, `ReorientEnvV0`, registered as
myoChallengeDieReorientP1-v0): the scene (`die.load_hand_with_die`: MyoSuite's die above the palm, the forearm turned
palm up, every other joint at 0, the die at rest, the same start every episode), policy steps of 10 ms (5 physics
steps of 2 ms), and phase 1's goals: a goal position drawn uniformly within +-1 cm per axis of the die's start
(`goal_position`) and a goal orientation whose three Euler angles are drawn uniformly within +-1.57 rad
(`goal_rotation`, +-90 degrees; MyoSuite's `euler2quat`, rotations about the world's x, then y, then z axes, applied
to the die's start orientation). Phase 2 (myoChallengeDieReorientP2-v0) draws +-2 cm and +-3.14 rad (set
`goal_position: 0.02, goal_rotation: 3.14`) and also the die's size, mass and friction, which this task does not. A
step is `solved` when the die's centre is within 0.025 m of the goal position and its orientation within 0.262 rad of
the goal's, and it has not dropped; it has `dropped` when its centre is more than 0.2 m from the goal position, which
ends the episode. MyoSuite's reward terms (minus the position distance, weight 100, minus the rotation distance,
weight 1, minus the effort) are here, but the defaults reward progress instead (see Reward below).

The rotation error. MyoSuite's is the norm of the difference of the two orientations' Euler angles (`mat2euler`). We
use the rotation angle between them (the geodesic distance, `ihom.angular_distance`, in [0, pi]): it is a distance
between orientations, the same for every attitude, where the Euler difference depends on the attitude (near a pitch
of +-90 degrees small turns change the Euler angles by much more than their angle) and jumps by 2 pi where an angle
wraps. For a turn about one world axis from the die's start orientation the two agree (both give the turn's angle);
near the start orientation the Euler difference of a small turn is the norm of its rotation vector to first order,
so both thresholds of 0.262 rad (15 degrees) mean the same there.

Goals in a row, as on the Shadow cube. A goal is `reached` when it has been solved on more than `success_steps` (5)
steps since it was drawn: MyoSuite's success rule, applied per goal. Then a new goal is drawn (from the pose where the
old one was reached) and CGR (`cgr`) counts up. Each goal gets `steps_per_goal` policy steps (150, MyoSuite's whole
episode of 1.5 s): a goal not reached in time ends the episode (terminal, as the Shadow cube's goal timer and for the
same reason: the task's score is then final). `max_goals` reached cuts the episode (a truncation, to bound it). The
metric `success` is MyoSuite's score of an episode: 1 when the first goal was reached, i.e. solved on more than 5 of
its (at most) 150 steps; its value at an episode's end is the episode's.

Reward (`ReorientReward`), with p the position distance (m) and d the rotation angle (rad) to the goal active during
the step, and p', d' the same before the step: r = position_progress * (p' - p) + rotation_progress * (d' - d) -
position * p - rotation * d + orientation * (1 - d / pi) + goal_bonus * reached - drop_penalty * dropped - effort *
effort. The defaults (100, 1, 0, 0, 0, 5, 50, 1) reward the decrease of MyoSuite's two distances with MyoSuite's
weights, as the Shadow cube rewards the decrease of its angle (`ihom.IhomReward.progress`), not the distances
themselves. MyoSuite's terms charge every
step the die is away from its goal, so every episode is a sum of costs; under that reward, with a drop ending the
episode, dropping the die at once is the best policy unless the drop costs more than all of them. Measured: the
first GPU run, with MyoSuite's terms (100, 1) and a drop penalty of 100, learned to drop the die sooner (its episodes
fell from 18 to 6 steps of 10 ms in 164 cycles; benchmarks/results/myohand/README.md). Progress sums over an
episode to the distance closed, whatever the path (a potential-based shaping), so holding the die costs only effort
(at most about 0.33 a step, about 11 under gamma 0.97), against 50 and the distance lost on a drop; set `position:
100, rotation: 1, position_progress: 0, rotation_progress: 0` for MyoSuite's terms. The goal bonus (5, the Shadow
cube's +5 per goal) pays for a reached goal; MyoSuite's die task has no bonus and a drop penalty of 0 (its `penalty`
weight; 10 in its comment). The effort is the mean squared activation over the 39 muscles, weight 1, as `MyoHandPose`
and `MyoHandReach` charge it (MyoSuite's die task weights its `act_reg`, the norm of the activations over their
number, 0).
Scale, read from the measured cortical run (7 minutes: drops fell to a quarter, the rotation error did not fall):
turning the die at 3 rad/s earns 0.03 a step under the default `rotation_progress`, against an effort of about 0.26
every step, so the turn's signal is a tenth of the effort's. Measured since (one H200, one seed each;
benchmarks/results/myohand): `rotation_progress` 10, the dense `orientation` term at 0.05 (7.5 over a goal's 150
steps, as the Shadow cube's 5 per second does over 1.5 s), `effort` 0.1 and gamma 0.99 (about 1 s ahead at 10 ms
steps, where 0.97 looks 0.33 s ahead, less than a turn takes) turned the die: in 16 minutes the rotation error fell
from 2.3 to 0.8 rad and the first goals were reached (training-mean CGR 0.025). `myohand_reorient_cortical` uses
them; the task's defaults stay as above. Goals nearer the start (`goal_rotation`) are a curriculum's first stage.
Actions are the 39 muscles' excitations in [0, 1] (`ctrl`), where MyoSuite maps actions in [-1, 1] through a sigmoid;
the die moves on a free joint (`die.py` says what that changes).

Observations. proprioception (61): the hand's 23 joint angles (rad) and velocities (rad/s; MyoSuite: rad per control
step), the five fingertips' positions (15, m); muscle (156, `MuscleHandTask.muscles`); goal (36): the die's position
(3, m) and orientation (9, its rotation matrix row by row), the goal's (3 and 9), and their difference: goal minus die
position (3, m) and the rotation from the die to the goal (9, a matrix, world frame); asymmetric (23, the value
function's): the die's linear (3, m/s, world frame) and angular velocity (3, rad/s, its own frame), the fingertips
(15), the share of `max_goals` reached and the share of `steps_per_goal` used. Touch: none. The Shadow tasks' touch is
the Gym hand's 92 sensor zones (`shadow_hand.model.add_touch_sensors` copies their sites by the Gym hand's body names);
the MyoHand has no such zones, and drawing them onto its bones is work of its own, not a cheap reuse.

MyoChallenge 2022's published results, metric for metric: benchmarks/results/myohand/README.md ("Die reorientation:
the MyoChallenge 2022 anchor").
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
from angora_jax.envs.myohand.die import DIE, die_start
from angora_jax.envs.myohand.model import JOINTS
from angora_jax.envs.myohand.muscle_task import SUCCESS_STEPS, MuscleHandTask
from angora_jax.envs.myohand.reach import TIPS
from angora_jax.envs.shadow_hand.ihom import about_axis, angular_distance, quat_mul, rotation_between, rotation_matrix

# MyoSuite's tolerances (`pos_th`, `rot_th`, `drop_th`): m, rad, m.
POSITION_THRESHOLD = 0.025
ROTATION_THRESHOLD = 0.262
DROP_DISTANCE = 0.2
# Phase 1's goal ranges (myoChallengeDieReorientP1-v0): +- m per axis of the die's start, +- rad per Euler angle.
GOAL_POSITION = 0.010
GOAL_ROTATION = 1.57
# MyoSuite's episode (150 policy steps of 10 ms): the steps each goal gets.
STEPS_PER_GOAL = 150


@dataclasses.dataclass(frozen=True)
class ReorientReward(Coefficients):
    """Weights of the reward's terms (the module docstring says which are MyoSuite's and why the defaults differ), in m
    and rad.

    Attributes:
        position_progress: weight of the decrease of the distance (m) from the die's centre to the goal position over
            the step.
        rotation_progress: weight of the decrease of the rotation angle (rad) from the die's orientation to the goal's
            over the step.
        position: weight of minus the distance (m) to the goal position (MyoSuite's term, weight 100 there).
        rotation: weight of minus the rotation angle (rad) to the goal (MyoSuite's term, weight 1 there).
        orientation: paid every policy step times (1 - d / pi), d the rotation angle to the goal: the weight at the
            goal, 0 facing away. The Shadow cube's dense term (`ihom.IhomReward.orientation`, MuJoCo Playground's),
            per step instead of per second; unlike `rotation` it is never negative, so it pays for holding the die
            near its goal where `rotation` charges for every step held away from it.
        goal_bonus: added on the step a goal is reached.
        drop_penalty: subtracted on the step the die drops (which ends the episode).
        effort: weight of minus the mean squared muscle activation.
    """

    position_progress: float = 100.0
    rotation_progress: float = 1.0
    position: float = 0.0
    rotation: float = 0.0
    orientation: float = 0.0
    goal_bonus: float = 5.0
    drop_penalty: float = 50.0
    effort: float = 1.0


def euler_to_quat(angles: jax.Array) -> jax.Array:
    """The orientation of MyoSuite's `euler2quat`: turns by `angles` (3, rad) about the world's x, then y, then z axes,
    as a unit quaternion (w, x, y, z)."""
    return quat_mul(quat_mul(about_axis(2, angles[2]), about_axis(1, angles[1])), about_axis(0, angles[0]))


class MyoHandReorient(MuscleHandTask):
    """Turn the die to drawn goals with 39 muscles (the module docstring gives every definition).

    Info: target (7: goal position in m, goal quaternion), goals_reached (int32, CGR so far), goal_solved (int32,
    solved steps on the current goal), goal_steps (int32, steps on the current goal), success (float32), time_out
    (bool, the goal cap was reached). Metrics: `cgr` (goals reached so far), `success` (the first goal reached),
    `solved` (this step), `dropped` (1 on the step the die dropped; its mean at episodes' ends is the drop rate),
    `timed_out` (1 on the step a goal's time ran out), `position_error` (m), `rotation_error` (rad) and `effort`.

    Attributes:
        reward_config: the reward's weights.
        goal_position: goal positions are drawn within this many m per axis of the die's start.
        goal_rotation: goal orientations' Euler angles are drawn within this many rad.
        position_threshold: a step is solved within this distance (m) of the goal position ...
        rotation_threshold: ... and this rotation angle (rad) of the goal orientation.
        drop_distance: the die has dropped beyond this distance (m) from the goal position.
        steps_per_goal: policy steps each goal gets.
        max_goals: goals reached that end (truncate) an episode.
    """

    metric_names = ("cgr", "success", "solved", "dropped", "timed_out", "position_error", "rotation_error", "effort")

    def __init__(self, model: mujoco.MjModel, reward: ReorientReward = ReorientReward(),
                 goal_position: float = GOAL_POSITION, goal_rotation: float = GOAL_ROTATION,
                 position_threshold: float = POSITION_THRESHOLD, rotation_threshold: float = ROTATION_THRESHOLD,
                 drop_distance: float = DROP_DISTANCE, success_steps: int = SUCCESS_STEPS,
                 steps_per_goal: int = STEPS_PER_GOAL, max_goals: int = 50):
        super().__init__(model, success_steps)
        if mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, DIE) < 0:
            raise ValueError("MyoHandReorient needs the die: build the scene with envs.myohand.die.load_hand_with_die.")
        if goal_position < 0 or goal_rotation < 0:
            raise ValueError(f"goal_position (m) and goal_rotation (rad) must be >= 0, got {goal_position}, "
                             f"{goal_rotation}.")
        if position_threshold <= 0 or rotation_threshold <= 0 or drop_distance <= 0:
            raise ValueError(f"position_threshold, rotation_threshold and drop_distance must be > 0, got "
                             f"{position_threshold}, {rotation_threshold}, {drop_distance}.")
        if steps_per_goal < 1 or max_goals < 1:
            raise ValueError(f"steps_per_goal and max_goals must be >= 1, got {steps_per_goal}, {max_goals}.")
        self.reward_config = reward
        self.goal_position = float(goal_position)
        self.goal_rotation = float(goal_rotation)
        self.position_threshold = float(position_threshold)
        self.rotation_threshold = float(rotation_threshold)
        self.drop_distance = float(drop_distance)
        self.steps_per_goal = int(steps_per_goal)
        self.max_goals = int(max_goals)
        die = model.joint(DIE)
        self._die_qpos = int(die.qposadr[0])
        self._die_dof = int(die.dofadr[0])
        self._tips = np.array([model.site(tip).id for tip in TIPS])
        self._start = die_start(model).astype(np.float32)

    def initial_qpos(self, key: jax.Array) -> jax.Array:
        """MyoSuite's start (`die.die_start`): palm up, the die at rest above the palm."""
        return jnp.asarray(self._start)

    def die_pose(self, snap: Snapshot) -> tuple[jax.Array, jax.Array]:
        """The die's centre (3, m, world frame) and orientation (4, quaternion w x y z)."""
        pose = snap.qpos[self._die_qpos:self._die_qpos + 7]
        return pose[:3], pose[3:]

    def sample_goal(self, key: jax.Array) -> jax.Array:
        """A goal `(7,)`: position (m) uniform within `goal_position` per axis of the die's start, and the orientation
        of Euler angles uniform within `goal_rotation` (`euler_to_quat`, from the die's start orientation)."""
        position_key, rotation_key = jax.random.split(key)
        offset = jax.random.uniform(position_key, (3,), minval=-self.goal_position, maxval=self.goal_position)
        angles = jax.random.uniform(rotation_key, (3,), minval=-self.goal_rotation, maxval=self.goal_rotation)
        start = jnp.asarray(self._start[self._die_qpos:self._die_qpos + 7])
        return jnp.concatenate([start[:3] + offset, quat_mul(euler_to_quat(angles), start[3:])])

    def initial_info(self, key: jax.Array, snap: Snapshot) -> dict[str, jax.Array]:
        zero = jnp.zeros((), jnp.int32)
        return {"target": self.sample_goal(key), "goals_reached": zero, "goal_solved": zero, "goal_steps": zero,
                "success": jnp.zeros((), jnp.float32), "time_out": jnp.zeros((), bool)}

    def errors(self, snap: Snapshot, target: jax.Array) -> tuple[jax.Array, jax.Array]:
        """The die's position distance (m) and rotation angle (rad) to `target` (a goal, `(7,)`)."""
        position, quat = self.die_pose(snap)
        return jnp.linalg.norm(target[:3] - position), angular_distance(quat, target[3:])

    def observe(self, snap: Snapshot, info: dict[str, jax.Array]) -> Sensation:
        position, quat = self.die_pose(snap)
        target = info["target"]
        tips = snap.site_xpos[self._tips].ravel()
        velocity = snap.qvel[self._die_dof:self._die_dof + 6]
        clocks = jnp.stack([info["goals_reached"] / self.max_goals, info["goal_steps"] / self.steps_per_goal])
        goal = jnp.concatenate([position, rotation_matrix(quat), target[:3], rotation_matrix(target[3:]),
                                target[:3] - position, rotation_matrix(rotation_between(quat, target[3:]))])
        return Sensation.make(proprioception=jnp.concatenate([snap.qpos[:JOINTS], snap.qvel[:JOINTS], tips]),
                              muscle=self.muscles(snap), goal=goal,
                              asymmetric=jnp.concatenate([velocity, tips, clocks.astype(jnp.float32)]))

    def evaluate(self, key: jax.Array, prev: Snapshot, snap: Snapshot, info: dict[str, jax.Array]
                 ) -> tuple[jax.Array, jax.Array, dict[str, jax.Array], dict[str, jax.Array]]:
        """Reward, termination and metrics of a step, as the module docstring and `ReorientReward` say."""
        c = self.reward_config
        target = info["target"]
        position_error, rotation_error = self.errors(snap, target)
        dropped = position_error > self.drop_distance
        solved = (position_error < self.position_threshold) & (rotation_error < self.rotation_threshold) & ~dropped
        goal_solved = info["goal_solved"] + solved.astype(jnp.int32)
        reached = goal_solved > self.success_steps
        goals_reached = info["goals_reached"] + reached.astype(jnp.int32)
        goal_steps = jnp.where(reached, 0, info["goal_steps"] + 1)
        timed_out = (goal_steps >= self.steps_per_goal) & ~dropped
        success = jnp.maximum(info["success"], (reached & (info["goals_reached"] == 0)).astype(jnp.float32))
        effort = self.effort(snap)
        position_before, rotation_before = self.errors(prev, target)
        reward = (c.position_progress * (position_before - position_error)
                  + c.rotation_progress * (rotation_before - rotation_error)
                  - c.position * position_error - c.rotation * rotation_error
                  + c.orientation * (1.0 - rotation_error / jnp.pi) + c.goal_bonus * reached
                  - c.drop_penalty * dropped - c.effort * effort)
        terminated = dropped | timed_out
        next_info = {"target": jnp.where(reached, self.sample_goal(key), target), "goals_reached": goals_reached,
                     "goal_solved": jnp.where(reached, 0, goal_solved), "goal_steps": goal_steps, "success": success,
                     "time_out": (goals_reached >= self.max_goals) & ~terminated}
        metrics = {"cgr": goals_reached.astype(jnp.float32), "success": success, "solved": solved.astype(jnp.float32),
                   "dropped": dropped.astype(jnp.float32), "timed_out": timed_out.astype(jnp.float32),
                   "position_error": position_error, "rotation_error": rotation_error, "effort": effort}
        return reward, terminated, next_info, metrics

    def task_variables(self, snap: Snapshot, info: dict[str, jax.Array]) -> dict[str, jax.Array]:
        """`MuscleHandTask.task_variables` (its target: the goal, 7; joint angles and velocities: the hand's 23) and the
        die's: die_position (3, m), die_rotation (9, its rotation matrix row by row), rotation_to_goal (9, the matrix
        from the die's orientation to the goal's)."""
        position, quat = self.die_pose(snap)
        return super().task_variables(snap, info) | {
            "joint_angles": snap.qpos[:JOINTS], "joint_velocities": snap.qvel[:JOINTS],  # the hand's, not the die's
            "die_position": position, "die_rotation": rotation_matrix(quat),
            "rotation_to_goal": rotation_matrix(rotation_between(quat, info["target"][3:]))}
