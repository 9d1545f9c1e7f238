"""`MyoHandReach`: bring the five fingertips of the muscle-driven MyoHand to drawn targets, after MyoSuite's
`myoHandReachRandom-v0`.

What is MyoSuite's (myosuite 3.0.0, `envs/myo/tasks/basic/arm/reach.py`, `terms/base_reward.py`'s
`multi_site_reach_reward` and the registration in `envs/myo/tasks/basic/__init__.py`): the hand stands where MyoSuite
puts it (`model.load_hand(myosuite_frame=True)`) and each episode starts open and at rest (every joint at 0, the
model's `qpos0`). Each fingertip site (`TIPS`: thumb, index, middle, ring, little) gets a target drawn uniformly in its
box (`TARGET_BOXES`, m, MyoSuite's world frame; its default `"box"` sampling). The reach distance is the Euclidean norm
over all five tips at once (of the 15 coordinates of target minus tip, m). A step is `solved` when the distance is
below 0.0625 m (`near`: 0.0125 m per tip, times 5); an episode is a `success` when it is solved on more than 5 of its
steps (MyoSuite's `evaluate_success`, `successful_steps=5`). Episodes last 100 steps of 20 ms (10 physics steps of
2 ms). The reward's terms and weights are MyoSuite's: reach (minus the distance, weight 1), bonus (1 below twice
`near`, 1 more below `near`, weight 4) and penalty (-1 when the distance exceeds 0.375 m, `far_th` 0.075 m per tip
times 5, weight 50; it also ends the episode; checked from the second step on, as MyoSuite checks it once the
simulated time exceeds two control steps, which its floating-point clock does at the second step).

What differs: the effort cost, the mean squared activation over the 39 muscles (MyoSuite's generic `act_reg` term),
is charged with weight 1 as in `MyoHandPose`, where MyoSuite's reach weights it 0. Actions are the muscles'
excitations in [0, 1] (`ctrl`), where MyoSuite maps actions in [-1, 1] through a sigmoid. The observation holds the
muscle sense besides MyoSuite's activations, and velocities in rad/s instead of MyoSuite's rad per control step.
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
from angora_jax.envs.myohand.muscle_task import SUCCESS_STEPS, MuscleHandTask

TIPS = ("THtip_r", "IFtip_r", "MFtip_r", "RFtip_r", "LFtip_r")
# Per tip (in `TIPS`' order), the lowest and highest corner of its target box (m, MyoSuite's world frame):
# myoHandReachRandom-v0's `target_reach_range`.
TARGET_BOXES = (
    ((-0.185, -0.577, 1.455), (-0.125, -0.517, 1.535)),
    ((-0.191, -0.567, 1.445), (-0.111, -0.527, 1.465)),
    ((-0.186, -0.567, 1.437), (-0.106, -0.527, 1.457)),
    ((-0.188, -0.563, 1.435), (-0.108, -0.523, 1.455)),
    ((-0.188, -0.548, 1.424), (-0.108, -0.508, 1.444)),
)
# MyoSuite's per-tip thresholds (m): solved below `NEAR_PER_TIP` times the tips, failed beyond `FAR_PER_TIP` times them.
NEAR_PER_TIP = 0.0125
FAR_PER_TIP = 0.075
# The first step on which the far penalty applies (MyoSuite: simulated time beyond two control steps).
PENALTY_FROM_STEP = 2


@dataclasses.dataclass(frozen=True)
class ReachReward(Coefficients):
    """Weights of the reward's terms (MyoSuite's `DEFAULT_RWD_KEYS_AND_WEIGHTS` for reach, plus the effort), in m.

    Attributes:
        reach: weight of minus the reach distance (m).
        bonus: weight of the bonus, 1 while the distance is below twice the threshold and 1 more below it.
        effort: weight of minus the mean squared muscle activation.
        penalty: weight of minus 1 when the distance exceeds `far_distance`, which also ends the episode.
        far_distance: the distance (m) beyond which an episode fails, from its second step on.
    """

    reach: float = 1.0
    bonus: float = 4.0
    effort: float = 1.0
    penalty: float = 50.0
    far_distance: float = FAR_PER_TIP * len(TIPS)


class MyoHandReach(MuscleHandTask):
    """Bring the five fingertips to drawn targets with 39 muscles (the module docstring gives MyoSuite's definitions).

    Observation: proprioception (23 joint angles in rad, 23 velocities in rad/s, the 5 fingertips' positions, 15 in m),
    muscle (`MuscleHandTask.muscles`: 39 lengths, 39 lengthening velocities, 39 forces, 39 activations), goal (the
    15 target coordinates and the 15 errors target minus tip, m). Positions are in MyoSuite's world frame. Actions: 39
    excitations in [0, 1] (`MuscleHandTask`).
    Metrics: `success` (solved on more than `success_steps` steps of the episode so far; its value at an episode's
    end is MyoSuite's success), `solved` (this step's distance below `reach_threshold`), `tip_distance` (m, the norm
    over the five tips that the rule thresholds), `mean_tip_distance` (m, the mean of the five tips' own distances)
    and `effort` (mean squared activation).

    Attributes:
        reward_config: the reward's weights.
        reach_threshold: a step is solved below this reach distance (m).
    """

    metric_names = ("success", "solved", "tip_distance", "mean_tip_distance", "effort")

    def __init__(self, model: mujoco.MjModel, reward: ReachReward = ReachReward(),
                 reach_threshold: float = NEAR_PER_TIP * len(TIPS), success_steps: int = SUCCESS_STEPS):
        super().__init__(model, success_steps)
        missing = [tip for tip in TIPS if mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, tip) < 0]
        if missing:
            raise ValueError(f"The model lacks the fingertip sites {missing}: build it with "
                             "envs.myohand.model.load_hand(myosuite_frame=True) (myo-sim 0.2.3).")
        if reach_threshold <= 0:
            raise ValueError(f"reach_threshold must be > 0 (m), got {reach_threshold}.")
        self.reward_config = reward
        self.reach_threshold = float(reach_threshold)
        self._tips = np.array([model.site(tip).id for tip in TIPS])
        self._box_low, self._box_high = np.asarray(TARGET_BOXES, np.float32).transpose(1, 0, 2)

    def initial_qpos(self, key: jax.Array) -> jax.Array:
        """The open hand, every joint at 0 (`qpos0`), as MyoSuite's reach starts."""
        return jnp.asarray(self.model.qpos0, jnp.float32)

    def draw_target(self, key: jax.Array) -> jax.Array:
        """Targets `(5, 3)` in m, each tip's uniform within its box of `TARGET_BOXES`."""
        return jax.random.uniform(key, self._box_low.shape, minval=self._box_low, maxval=self._box_high)

    def initial_info(self, key: jax.Array, snap: Snapshot) -> dict[str, jax.Array]:
        return {"target": self.draw_target(key).ravel(), "solved_steps": jnp.zeros((), jnp.int32),
                "steps": jnp.zeros((), jnp.int32)}

    def tip_positions(self, snap: Snapshot) -> jax.Array:
        """The five fingertips' positions, flat `(15,)` in `TIPS`' order (m)."""
        return snap.site_xpos[self._tips].ravel()

    def observe(self, snap: Snapshot, info: dict[str, jax.Array]) -> Sensation:
        tips = self.tip_positions(snap)
        return Sensation.make(proprioception=jnp.concatenate([snap.qpos, snap.qvel, tips]), muscle=self.muscles(snap),
                              goal=jnp.concatenate([info["target"], info["target"] - tips]))

    def evaluate(self, key: jax.Array, prev: Snapshot, snap: Snapshot, info: dict[str, jax.Array]
                 ) -> tuple[jax.Array, jax.Array, dict[str, jax.Array], dict[str, jax.Array]]:
        """Reward, termination and metrics of a step, as the class docstring and `ReachReward` say."""
        c = self.reward_config
        error = (info["target"] - self.tip_positions(snap)).reshape(len(TIPS), 3)
        distance = jnp.linalg.norm(error)
        solved = distance < self.reach_threshold
        bonus = solved.astype(jnp.float32) + (distance < 2 * self.reach_threshold)
        steps = info["steps"] + 1
        far = (distance > c.far_distance) & (steps >= PENALTY_FROM_STEP)
        effort = self.effort(snap)
        reward = -c.reach * distance + c.bonus * bonus - c.effort * effort - c.penalty * far
        solved_steps, success = self.count_success(info["solved_steps"], solved)
        metrics = {"success": success, "solved": solved.astype(jnp.float32), "tip_distance": distance,
                   "mean_tip_distance": jnp.mean(jnp.linalg.norm(error, axis=1)), "effort": effort}
        return reward, far, {**info, "solved_steps": solved_steps, "steps": steps}, metrics

    def task_variables(self, snap: Snapshot, info: dict[str, jax.Array]) -> dict[str, jax.Array]:
        """`MuscleHandTask.task_variables` (its target: the 15 target coordinates, m) and tip_positions (15, m)."""
        return super().task_variables(snap, info) | {"tip_positions": self.tip_positions(snap)}
