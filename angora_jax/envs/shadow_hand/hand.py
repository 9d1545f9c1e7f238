"""What all Shadow-hand tasks share: fingertips, proprioception and the mapping from actions to joint targets."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from angora_jax.envs.cameras import CameraVision
from angora_jax.envs.mujoco_task import MujocoTask, Snapshot
from angora_jax.envs.shadow_hand.model import FINGERTIP_SITES, HAND_JOINT_PREFIX, PALM_BODY

# OpenAI Gym HandReach's initial pose (joint name -> rad): a relaxed, slightly flexed hand.
REACH_INITIAL_QPOS = {
    "robot0:WRJ1": -0.16514339750464327, "robot0:WRJ0": -0.31973286565062153,
    "robot0:FFJ3": 0.14340512546557435, "robot0:FFJ2": 0.32028208333591573,
    "robot0:FFJ1": 0.7126053607727917, "robot0:FFJ0": 0.6705281001412586,
    "robot0:MFJ3": 0.000246444303701037, "robot0:MFJ2": 0.3152655251085491,
    "robot0:MFJ1": 0.7659800313729842, "robot0:MFJ0": 0.7323156897425923,
    "robot0:RFJ3": 0.00038520700007378114, "robot0:RFJ2": 0.36743546201985233,
    "robot0:RFJ1": 0.7119514095008576, "robot0:RFJ0": 0.6699446327514138,
    "robot0:LFJ4": 0.0525442258033891, "robot0:LFJ3": -0.13615534724474673,
    "robot0:LFJ2": 0.39872030433433003, "robot0:LFJ1": 0.7415570009679252,
    "robot0:LFJ0": 0.704096378652974, "robot0:THJ4": 0.003673823825070126,
    "robot0:THJ3": 0.5506291436028695, "robot0:THJ2": -0.014515151997119306,
    "robot0:THJ1": -0.0015229223564485414, "robot0:THJ0": -0.7894883021600622,
}


# The wrist's actuators (`HandTask`'s freeze_wrist holds them).
WRIST_ACTUATOR_PREFIX = "robot0:A_WRJ"

# How an action becomes joint targets (`HandTask.control`).
CONTROL_MODES = ("position", "target", "absolute")


class HandTask(MujocoTask):
    """Base of Shadow-hand tasks on one compiled model.

    Actions are 20 values in [-1, 1], one per actuator; `control` says what they move, by up to `action_scale` x half
    the actuator's control range per policy step:

    - "position" (AngoraPy's and Gym's relative control): targets are set from the joints' current positions. A zero
      action then sets each target where the joint already is, so nothing resists gravity: the palm-up hand sags.
    - "target": targets move from the previous step's targets (MuJoCo Playground's LEAP hand). A zero action holds
      the hand still, so a policy that does nothing keeps an object it holds.
    - "absolute": [-1, 1] maps onto the control range (`action_scale` unused).
    freeze_wrist: the two wrist actuators hold the wrist at its initial pose whatever the policy's first two action
    values say (AngoraPy's option), so only the fingers move.
    """

    camera_body = PALM_BODY

    def __init__(self, model: mujoco.MjModel, control: str = "position", action_scale: float = 1.0,
                 initial_qpos: dict[str, float] | None = None, vision: CameraVision | None = None,
                 freeze_wrist: bool = False):
        if control not in CONTROL_MODES:
            raise ValueError(f"Unknown control {control!r}; choose one of {CONTROL_MODES}.")
        if action_scale <= 0:
            raise ValueError(f"action_scale must be > 0 (share of half the control range per step), got "
                             f"{action_scale}.")
        if vision is not None:
            vision.camera_ids(model)
        self.vision = vision
        self.model = model
        self.control_mode = control
        self.action_scale = action_scale
        self.fingertip_ids = np.array([model.site(n).id for n in FINGERTIP_SITES])
        self.palm_id = model.body(PALM_BODY).id
        hand_joints = [j for j in range(model.njnt) if model.joint(j).name.startswith(HAND_JOINT_PREFIX)]
        self.hand_qpos = np.array([model.jnt_qposadr[j] for j in hand_joints])
        self.hand_dofs = np.array([model.jnt_dofadr[j] for j in hand_joints])
        qpos = model.qpos0.astype(np.float32).copy()
        for name, value in (initial_qpos or REACH_INITIAL_QPOS).items():
            qpos[model.joint(name).qposadr[0]] = value
        self._qpos0 = qpos
        low, high = model.actuator_ctrlrange.T.astype(np.float32)
        self._ctrl_low, self._ctrl_high = low, high
        self._ctrl_half_range = (high - low) / 2
        self.freeze_wrist = freeze_wrist
        wrist = [a for a in range(model.nu) if model.actuator(a).name.startswith(WRIST_ACTUATOR_PREFIX)]
        self._wrist_actuators = np.array(wrist)
        # Each wrist actuator drives one joint (joint transmission): its target is that joint's initial position.
        self._wrist_hold = np.clip(qpos[model.jnt_qposadr[model.actuator_trnid[wrist, 0]]], low[wrist], high[wrist])
        self.touch_adr = np.asarray(model.sensor_adr[model.sensor_type == mujoco.mjtSensor.mjSENS_TOUCH])

    def initial_qpos(self, key: jax.Array) -> jax.Array:
        return jnp.asarray(self._qpos0)

    def control(self, action: jax.Array, snap: Snapshot) -> jax.Array:
        if self.control_mode == "absolute":
            center, scale = (self._ctrl_low + self._ctrl_high) / 2, 1.0
        else:
            center = snap.actuator_length if self.control_mode == "position" else snap.ctrl
            scale = self.action_scale
        ctrl = jnp.clip(center + action * scale * self._ctrl_half_range, self._ctrl_low, self._ctrl_high)
        return ctrl.at[self._wrist_actuators].set(self._wrist_hold) if self.freeze_wrist else ctrl

    def fingertips(self, snap: Snapshot) -> jax.Array:
        """Fingertip positions (m, world frame), shape `(5, 3)` in the order FF, MF, RF, LF, thumb."""
        return snap.site_xpos[self.fingertip_ids]

    def touch(self, snap: Snapshot) -> jax.Array:
        """The model's touch sensor readings (N, the contact normal forces inside each sensor's zone), in sensor
        order, shape `(n,)`: 97 with Gym's touch sensors (`model.add_touch_sensors`), 0 without any."""
        return snap.sensordata[self.touch_adr]

    def task_variables(self, snap: Snapshot, info: dict[str, jax.Array]) -> dict[str, jax.Array]:
        """fingertips (15, m, world frame: FF, MF, RF, LF, thumb x xyz) and joint_angles (24, rad)."""
        return {"fingertips": self.fingertips(snap).reshape(-1), "joint_angles": snap.qpos[self.hand_qpos]}

    def proprioception(self, snap: Snapshot) -> jax.Array:
        """Hand joint positions (rad) and velocities (rad/s), shape `(48,)`; objects' joints are not the hand's."""
        return jnp.concatenate([snap.qpos[self.hand_qpos], snap.qvel[self.hand_dofs]])
