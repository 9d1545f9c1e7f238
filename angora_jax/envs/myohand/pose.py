"""`MyoHandPose`: bring the muscle-driven MyoHand to a drawn posture, after MyoSuite's `myoHandPoseRandom-v0`.

What is MyoSuite's (myosuite 3.0.0, `envs/myo/tasks/basic/arm/pose.py` and its registration): each episode starts
from joint angles drawn uniformly within the joints' ranges and draws a target posture uniformly per joint between
the smallest and the largest angle that joint takes in MyoSuite's ten American Sign Language digit postures
(`TARGET_RANGES`; the forearm rotation, the wrist and two abductions are 0 in all ten, so their targets are 0). The
pose error is the Euclidean norm of target minus joint angles over all 23 joints (rad). A step is `solved` when the
error is below 0.7 rad (MyoSuite's `pose_thd` for the hand); an episode is a `success` when it is solved on more than
5 of its steps (MyoSuite's `evaluate_success`, `successful_steps=5`). Episodes last 100 steps of 20 ms (10 physics
steps of 2 ms), and the reward's terms and weights are MyoSuite's: pose (minus the error), bonus (1 below the
threshold, 1 more below 1.5 times it) and penalty (-1 beyond 2 pi rad, which ends the episode). The hand stands
where MyoSuite puts it (`model.load_hand(myosuite_frame=True)`), so gravity pulls on it as there.

What differs: the effort cost is the mean squared activation over the 39 muscles (MyoSuite's generic `act_reg` term
in `terms/base_reward.py`); MyoSuite's pose task itself charges the norm of the activations divided by their number.
Actions are the muscles' excitations in [0, 1] (`ctrl`), where MyoSuite maps actions in [-1, 1] through a sigmoid.

An option that is not MyoSuite's, for a curriculum's first stage: `start_spread` s in (0, 1] draws each episode's start
as target + s x (uniform start - target), the uniform start being MyoSuite's; the start's pose error is then s times
that of MyoSuite's start, in the same direction (s = 0.4: a median of about 1 rad, where the oracle controller of
`benchmarks/myohand_pose_oracle.py` succeeds on 83% of episodes). With s < 1 the `success` and every other metric are
of that easier task, not of MyoSuite's; s = 1 (the default) is MyoSuite's task, bit for bit.

A second option that is not MyoSuite's: `targets`. "asl" (the default) is MyoSuite's draw above; "reachable" draws
the target from a bank of postures the hand makes itself (`reachable.py`: where a constant random excitation brings
it), rows the held-out part excludes, and "reachable_held_out" from that held-out part only, for evaluation on targets
that training never saw. Starts, success and reward are the same; the targets are anywhere in the joints' ranges, not
within the ASL digits' ranges, and a controller that knows the model succeeds on 85% of them (15% of MyoSuite's).
"""

from __future__ import annotations

import dataclasses
import math
import numbers

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from angora_jax.envs.coefficients import Coefficients
from angora_jax.envs.core import Sensation
from angora_jax.envs.mujoco_task import Snapshot
from angora_jax.envs.myohand.muscle_task import SUCCESS_STEPS, MuscleHandTask
from angora_jax.envs.myohand.reachable import bank_part

# Per joint (in the model's joint order), the lowest and highest angle (rad) over MyoSuite's ten ASL digit postures
# (`ASL_qpos` in myosuite 3.0.0 `envs/myo/tasks/basic/__init__.py`, for the hand that myo-sim composes).
TARGET_RANGES = (
    (0.0, 0.0), (0.0, 0.0), (0.0, 0.0),  # pro_sup, deviation, flexion (forearm and wrist)
    (-0.147495, 0.28272), (0.0248, 0.6392), (-0.7854, 0.01569), (-1.309, -0.0262045),  # thumb: cmc, mp, ip
    (0.366605, 1.30045), (-0.006982, 0.010473), (0.128305, 1.45492), (0.111722, 0.998897),  # index
    (0.39275, 1.48459), (0.0, 0.0), (0.18852, 1.45318), (0.117825, 1.44532),  # middle
    (0.306345, 1.571), (-0.204204, -0.010472), (0.0, 1.52387), (0.06284, 1.45318),  # ring
    (0.21994, 1.48459), (-0.2618, -0.068068), (0.18852, 1.571), (0.01571, 1.571),  # little
)
# MyoSuite's hand pose threshold (`pose_thd`, rad).
POSE_THRESHOLD = 0.7
# The start's pose error over MyoSuite's (`MyoHandPose.start_spread`): 1 is MyoSuite's uniform start.
START_SPREAD = 1.0
# Where targets come from (`MyoHandPose.targets`): MyoSuite's ASL ranges, or the reachable bank's training or held-out
# rows.
TARGETS = ("asl", "reachable", "reachable_held_out")


@dataclasses.dataclass(frozen=True)
class PoseReward(Coefficients):
    """Weights of the reward's terms (MyoSuite's `DEFAULT_RWD_KEYS_AND_WEIGHTS` for pose), errors in rad.

    Attributes:
        pose: weight of minus the pose error.
        bonus: weight of the bonus, 1 while the error is below the threshold and 1 more below 1.5 times it.
        effort: weight of minus the mean squared muscle activation.
        penalty: weight of minus 1 when the error exceeds `far_error`, which also ends the episode.
    """

    pose: float = 1.0
    bonus: float = 4.0
    effort: float = 1.0
    penalty: float = 50.0
    far_error: float = 2 * math.pi


class MyoHandPose(MuscleHandTask):
    """Reach a drawn posture of the 23 joints with 39 muscles (the module docstring gives MyoSuite's definitions).

    Observation: proprioception (23 joint angles in rad, 23 velocities in rad/s), muscle (per muscle, in actuator
    order: 39 lengths in m, 39 lengthening velocities in m/s and 39 forces in N, negative when pulling: what muscle
    spindles and Golgi tendon organs sense; then 39 activations in [0, 1], an efference copy, which MyoSuite's pose
    task observes too; `MuscleHandTask.muscles`), goal (the 23 target angles and the 23 errors target minus angle, rad).
    Actions: 39 excitations in [0, 1] (`MuscleHandTask`).
    Metrics: `success` (solved on more than `success_steps` steps of the episode so far; its value at an episode's
    end is MyoSuite's success when `start_spread` is 1), `solved` (this step's error below `pose_threshold`),
    `pose_error` (rad) and `effort` (mean squared activation).

    Attributes:
        reward_config: the reward's weights.
        pose_threshold: a step is solved below this pose error (rad).
        start_spread: the start's pose error as a fraction of MyoSuite's uniform start's, in (0, 1] (the module
            docstring); below 1 the metrics are of an easier task than MyoSuite's.
        targets: one of `TARGETS` (the module docstring): "asl" is MyoSuite's.
    """

    metric_names = ("success", "solved", "pose_error", "effort")
    random_initial_qpos = True

    def __init__(self, model: mujoco.MjModel, reward: PoseReward = PoseReward(),
                 pose_threshold: float = POSE_THRESHOLD, success_steps: int = SUCCESS_STEPS,
                 start_spread: float = START_SPREAD, targets: str = "asl"):
        super().__init__(model, success_steps)
        if len(TARGET_RANGES) != model.njnt:
            raise ValueError(f"TARGET_RANGES holds {len(TARGET_RANGES)} joints, the model {model.njnt}: build the "
                             "model with envs.myohand.model.load_hand (myo-sim 0.2.3).")
        if pose_threshold <= 0:
            raise ValueError(f"pose_threshold must be > 0 (rad), got {pose_threshold}.")
        if isinstance(start_spread, bool) or not isinstance(start_spread, numbers.Real) or not 0 < start_spread <= 1:
            raise ValueError(f"start_spread must be a number in (0, 1], got {start_spread!r}: 1 starts where MyoSuite "
                             "does (uniform within the joints' ranges), 0.4 about 1 rad from the target; set e.g. "
                             "env.options.start_spread=0.4.")
        if targets not in TARGETS:
            raise ValueError(f"targets must be one of {', '.join(TARGETS)}, got {targets!r}: asl is MyoSuite's draw, "
                             "reachable postures the hand makes itself (env.options.targets=reachable).")
        self.start_spread = float(start_spread)
        self.targets = targets
        if targets != "asl":
            self._bank = bank_part(held_out=targets == "reachable_held_out")
        self.reward_config = reward
        self.pose_threshold = float(pose_threshold)
        self._joint_low, self._joint_high = model.jnt_range.T.astype(np.float32)
        self._target_low, self._target_high = np.asarray(TARGET_RANGES, np.float32).T

    def initial_qpos(self, key: jax.Array) -> jax.Array:
        """Angles drawn uniformly within the joints' ranges (MyoSuite's `reset_type="random"`)."""
        return jax.random.uniform(key, (self.model.nq,), minval=self._joint_low, maxval=self._joint_high)

    def start_qpos(self, pose_key: jax.Array, task_key: jax.Array) -> jax.Array:
        """The start `(23,)` in rad: `initial_qpos(pose_key)` (MyoSuite's) moved towards the episode's target, which
        `initial_info` draws from `task_key`, to `start_spread` of its distance. Within the joints' ranges, as both
        ends are."""
        uniform = self.initial_qpos(pose_key)
        if self.start_spread == 1:  # MyoSuite's start exactly, not target + (uniform - target) rounded
            return uniform
        target = self.draw_target(task_key)
        return target + self.start_spread * (uniform - target)

    def draw_target(self, key: jax.Array) -> jax.Array:
        """A target posture `(23,)` in rad: uniform per joint within `TARGET_RANGES` ("asl"), or a uniformly drawn
        row of the reachable bank's part that `targets` names."""
        if self.targets == "asl":
            return jax.random.uniform(key, self._target_low.shape, minval=self._target_low, maxval=self._target_high)
        return jnp.asarray(self._bank)[jax.random.randint(key, (), 0, len(self._bank))]

    def initial_info(self, key: jax.Array, snap: Snapshot) -> dict[str, jax.Array]:
        return {"target": self.draw_target(key), "solved_steps": jnp.zeros((), jnp.int32)}

    def observe(self, snap: Snapshot, info: dict[str, jax.Array]) -> Sensation:
        goal = jnp.concatenate([info["target"], info["target"] - snap.qpos])
        return Sensation.make(proprioception=jnp.concatenate([snap.qpos, snap.qvel]), muscle=self.muscles(snap),
                              goal=goal)

    def pose_error(self, snap: Snapshot, info: dict[str, jax.Array]) -> jax.Array:
        """Euclidean norm of target minus joint angles over all joints (rad), MyoSuite's pose distance."""
        return jnp.linalg.norm(info["target"] - snap.qpos)

    def evaluate(self, key: jax.Array, prev: Snapshot, snap: Snapshot, info: dict[str, jax.Array]
                 ) -> tuple[jax.Array, jax.Array, dict[str, jax.Array], dict[str, jax.Array]]:
        """Reward, termination and metrics of a step, as the class docstring and `PoseReward` say."""
        c = self.reward_config
        error = self.pose_error(snap, info)
        solved = error < self.pose_threshold
        bonus = solved.astype(jnp.float32) + (error < 1.5 * self.pose_threshold)
        far = error > c.far_error
        effort = self.effort(snap)
        reward = -c.pose * error + c.bonus * bonus - c.effort * effort - c.penalty * far
        solved_steps, success = self.count_success(info["solved_steps"], solved)
        metrics = {"success": success, "solved": solved.astype(jnp.float32), "pose_error": error, "effort": effort}
        return reward, far, {**info, "solved_steps": solved_steps}, metrics
