"""Finger reaching on the Shadow hand, after AngoraPy's `Reach` and `FreeReach` tasks.

Both bring the thumb tip to a target finger's tip (first, middle, ring or little finger, drawn per episode, or one
fixed finger with `target_finger`, AngoraPy's `force_finger`).
`reach` asks for all five fingertips at sampled positions (the non-target fingers where they started, thumb and
target at a meeting point above the palm); `freereach` only asks thumb and target to meet, with the other fingertips
away from the thumb (`ReachReward.clearance_distance`), and penalises other fingertips that enter a zone around the
thumb. With `sequence_length` both become AngoraPy's `ReachSequential` and
`FreeReachSequential`: a sequence of target fingers is drawn per episode and the goal moves to the next finger as
soon as the current one is reached. Rewards are a prototype function plus `ReachReward` coefficients,
so ablations change a config, not code.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import mujoco

from angora_jax.envs.cameras import CameraVision
from angora_jax.envs.coefficients import Coefficients
from angora_jax.envs.core import Sensation
from angora_jax.envs.mujoco_task import Snapshot
from angora_jax.envs.shadow_hand.hand import HandTask

THUMB = 4
NUM_TARGET_FINGERS = 4
# The target fingers in `HandTask.fingertips` order, by AngoraPy's names (its `force_finger`).
TARGET_FINGERS = ("FF", "MF", "RF", "LF")
# Gym HandReach's meeting point relative to the palm (m), for the hand's pose in reach.xml; fingers point to -y.
MEETING_OFFSET = (0.0, -0.09, 0.05)
# How a sequential task orders its targets (`Reach`'s sequence_order).
SEQUENCE_ORDERS = ("random", "fixed")


@dataclasses.dataclass(frozen=True)
class ReachReward(Coefficients):
    """Reward coefficients (AngoraPy's REACH_BASE). Distances in m.

    Attributes:
        success_distance: a reach succeeds when the goal distance is below this.
        success_bonus: reward added on every step that is a success.
        clearance_distance: freereach only; a target counts as reached (`success`) only while every other fingertip is
            at least this far from the thumb tip, so that thumb and target meet alone, not all fingertips at once (0: no
            such check). 0.04 m is twice `success_distance`: the other tips stay about one fingertip spacing (2.2-3.0 cm
            between neighbours in the initial pose) from the target's.
        force_multiplier: weight of the squared actuator forces (wrist excluded), a metabolic cost.
        auxiliary_zone_radius: freereach only; non-target fingertips closer than this to the thumb are penalised.
        auxiliary_penalty_multiplier: freereach only; penalty per metre of intrusion into that zone.
        stay_probability: reach without a sequence only; share of episodes whose goal is to hold the initial pose.
    """

    success_distance: float = 0.02
    success_bonus: float = 0.1
    clearance_distance: float = 0.04
    force_multiplier: float = 0.0
    auxiliary_zone_radius: float = 0.06015
    auxiliary_penalty_multiplier: float = 0.01
    stay_probability: float = 0.1


# AngoraPy's reach presets (its reward_configs.py `reach` and `free_reach`, chosen with `--rcon`).
REWARD_PRESETS = {"default": ReachReward(), "force_punished": ReachReward(force_multiplier=0.05)}


class Reach(HandTask):
    """Bring all fingertips to goal positions: thumb and target finger meet, the others stay.

    Observation: proprioception (24 joint positions and 24 velocities), touch (the model's touch sensor readings in N:
    97 in a scene with `model.add_touch_sensors`, else none), goal (15 goal coordinates in m and a
    one-hot target finger over 5, all zero for a hold-still goal), asymmetric (15 fingertip coordinates in m).

    sequence_length: None for one target per episode; an int >= 1 draws that many target fingers per episode, each
    differing from the one before (as AngoraPy's sequential tasks draw the next finger), has no hold-still goals, and
    advances to the next finger on the step the current one is reached (`success`); its reward counts the progress
    towards the current goal (`evaluate`). The episode terminates when the last one is reached. Extra metrics:
    `sequence_steps` (targets reached so far this episode) and `sequence_success` (1 once all `sequence_length`
    targets are reached).
    sequence_order: "random" (the fingers drawn as above, AngoraPy's ReachSequential) or "fixed" (FF, MF, RF, LF,
    FF, ... in every episode, AngoraPy's FreeReachSequential with its default exemplary sequence).
    """

    metric_names = ("success", "goal_distance")
    sequence_metric_names = ("sequence_steps", "sequence_success")

    def __init__(self, model: mujoco.MjModel, reward: ReachReward = ReachReward(), free: bool = False,
                 control: str = "position", vision: CameraVision | None = None, target_finger: str | None = None,
                 freeze_wrist: bool = False, sequence_length: int | None = None, sequence_order: str = "random"):
        super().__init__(model, control=control, vision=vision, freeze_wrist=freeze_wrist)
        if target_finger is not None and target_finger not in TARGET_FINGERS:
            raise ValueError(f"Unknown target_finger {target_finger!r}; choose one of {TARGET_FINGERS} (first, "
                             "middle, ring, little) or None to draw one per episode.")
        if sequence_length is not None:
            if isinstance(sequence_length, bool) or not isinstance(sequence_length, int) or sequence_length < 1:
                raise ValueError(f"sequence_length must be an int >= 1 (target fingers per episode), got "
                                 f"{sequence_length!r}; give e.g. sequence_length=4, or None for one target per "
                                 "episode.")
            if target_finger is not None:
                # Consecutive targets of a sequence differ (AngoraPy), so one fixed finger cannot make a sequence.
                raise ValueError(f"target_finger={target_finger!r} fixes one finger, but sequence_length="
                                 f"{sequence_length} draws a sequence of different fingers; give target_finger=None "
                                 "or sequence_length=None.")
            self.metric_names = self.metric_names + self.sequence_metric_names
        if sequence_order not in SEQUENCE_ORDERS:
            raise ValueError(f"Unknown sequence_order {sequence_order!r}; choose one of {SEQUENCE_ORDERS}.")
        if sequence_order == "fixed" and sequence_length is None:
            raise ValueError("sequence_order='fixed' orders a sequence of targets; give sequence_length too, e.g. "
                             "sequence_length=4.")
        self.reward_config = reward
        self.free = free
        self.target_finger = target_finger
        self.sequence_length = sequence_length
        self.sequence_order = sequence_order

    def draw_sequence(self, key: jax.Array) -> jax.Array:
        """`sequence_length` target finger indices (int32, in 0..3): with `sequence_order` "random" uniform, each
        differing from the one before; with "fixed" 0, 1, 2, 3, 0, ... whatever the key."""
        if self.sequence_order == "fixed":
            return jnp.arange(self.sequence_length, dtype=jnp.int32) % NUM_TARGET_FINGERS
        first_key, shift_key = jax.random.split(key)
        first = jax.random.randint(first_key, (1,), 0, NUM_TARGET_FINGERS)
        # A shift of 1-3 fingers (mod 4) gives each of the three other fingers with equal chance.
        shifts = jax.random.randint(shift_key, (self.sequence_length - 1,), 1, NUM_TARGET_FINGERS)
        return jnp.cumsum(jnp.concatenate([first, shifts])) % NUM_TARGET_FINGERS

    def goal_positions(self, key: jax.Array, home: jax.Array, palm: jax.Array, target: jax.Array) -> jax.Array:
        """Goal coordinates (5, 3) in m: `home` (5, 3) fingertips, with thumb and `target` at a meeting point
        drawn above `palm` (3,)."""
        meeting = palm + jnp.asarray(MEETING_OFFSET) + 0.005 * jax.random.normal(key, (3,))
        goal = home
        for idx in (THUMB, target):
            # Stop 5 mm short of the meeting point along the approach so the two goals do not coincide.
            direction = meeting - home[idx]
            goal = goal.at[idx].set(meeting - 0.005 * direction / jnp.linalg.norm(direction))
        return goal

    def initial_info(self, key: jax.Array, snap: Snapshot) -> dict[str, jax.Array]:
        finger_key, meet_key, stay_key = jax.random.split(key, 3)
        tips = self.fingertips(snap)
        if self.sequence_length is not None:
            sequence = self.draw_sequence(finger_key)
            goal = self.goal_positions(meet_key, tips, snap.xpos[self.palm_id], sequence[0])
            return {"goal": goal, "target": sequence[0], "stay": jnp.zeros(()), "sequence": sequence,
                    "sequence_step": jnp.zeros((), jnp.int32), "home": tips}
        target = (jax.random.randint(finger_key, (), 0, NUM_TARGET_FINGERS) if self.target_finger is None
                  else jnp.asarray(TARGET_FINGERS.index(self.target_finger), jnp.int32))
        goal = self.goal_positions(meet_key, tips, snap.xpos[self.palm_id], target)
        stay = jnp.logical_and(jnp.logical_not(self.free),
                               jax.random.uniform(stay_key) < self.reward_config.stay_probability)
        return {"goal": jnp.where(stay, tips, goal), "target": target, "stay": stay.astype(jnp.float32)}

    def next_target(self, key: jax.Array, snap: Snapshot, info: dict[str, jax.Array], success: jax.Array):
        """The sequential task's info after a step with `success` (float, 0 or 1): on success the next target and its
        goal (AngoraPy draws the new goal as soon as the old one is reached), else unchanged. Also returns whether the
        sequence is done (bool) and its metrics."""
        reached = info["sequence_step"] + success.astype(jnp.int32)
        done = reached >= self.sequence_length
        # After the last target the episode terminates; clamping keeps the index valid until the reset.
        target = info["sequence"][jnp.minimum(reached, self.sequence_length - 1)]
        goal = self.goal_positions(key, info["home"], snap.xpos[self.palm_id], target)
        moved = success > 0
        info = {**info, "sequence_step": reached, "target": jnp.where(moved, target, info["target"]),
                "goal": jnp.where(moved, goal, info["goal"])}
        metrics = {"sequence_steps": reached.astype(jnp.float32), "sequence_success": done.astype(jnp.float32)}
        return info, done, metrics

    def goal_distance(self, snap: Snapshot, info: dict[str, jax.Array]) -> jax.Array:
        """reach: distance (m) of all 15 fingertip coordinates to the goal; freereach: thumb to target tip."""
        tips = self.fingertips(snap)
        if self.free:
            return jnp.linalg.norm(tips[THUMB] - tips[info["target"]])
        return jnp.linalg.norm(tips - info["goal"])

    def observe(self, snap: Snapshot, info: dict[str, jax.Array]) -> Sensation:
        target = jax.nn.one_hot(info["target"], 5) * (1.0 - info["stay"])
        goal = target if self.free else jnp.concatenate([info["goal"].reshape(-1), target])
        return Sensation.make(proprioception=self.proprioception(snap), touch=self.touch(snap), goal=goal,
                              asymmetric=self.fingertips(snap).reshape(-1))

    def evaluate(self, key, prev, snap, info):
        """Reward: the approach to the goal, plus `success_bonus` on a success, minus the force cost and (freereach)
        the other fingertips' intrusion near the thumb. The approach is minus the goal distance (m); in a sequence
        it is the progress towards the current goal over the step (m, the goal distance before minus after), as
        AngoraPy's sequential freereach rewards: the goal jumps when a target is reached, and minus the new goal's
        distance would pay less after reaching a target than hovering just outside `success_distance`, so a policy
        learned to hover. Progress measured against one goal is not changed by the jump."""
        c = self.reward_config
        distance = self.goal_distance(snap, info)
        approach = -distance if self.sequence_length is None else self.goal_distance(prev, info) - distance
        success = distance < c.success_distance
        force = jnp.sum(snap.actuator_force[2:] ** 2)
        reward = approach - c.force_multiplier * force
        if self.free:
            tips = self.fingertips(snap)
            to_thumb = jnp.linalg.norm(tips[:THUMB] - tips[THUMB], axis=-1)
            others = jnp.arange(THUMB) != info["target"]
            intrusion = jnp.maximum(c.auxiliary_zone_radius - to_thumb, 0.0) * others
            reward = reward - c.auxiliary_penalty_multiplier * jnp.sum(intrusion)
            success = success & jnp.all((to_thumb >= c.clearance_distance) | ~others)
        success = success.astype(jnp.float32)
        reward = reward + c.success_bonus * success
        metrics = {"success": success, "goal_distance": distance}
        if self.sequence_length is None:
            return reward, jnp.zeros((), bool), info, metrics
        info, done, sequence_metrics = self.next_target(key, snap, info, success)
        return reward, done, info, {**metrics, **sequence_metrics}
