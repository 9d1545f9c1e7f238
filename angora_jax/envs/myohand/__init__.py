"""MyoHand tasks (MyoSuite's muscle-driven hand, from the optional `myo-sim` package), registered as `MyoHandPose`,
`MyoHandReach` and `MyoHandReorient`.

The hand is built only when a task is made, so that `import angora_jax` needs no `myo-sim`; making a task without it
raises a ModuleNotFoundError naming the install command.
"""

from __future__ import annotations

from collections.abc import Callable

import mujoco

from angora_jax.envs.backends import on_backend
from angora_jax.envs.core import Env
from angora_jax.envs.myohand.die import load_hand_with_die
from angora_jax.envs.myohand.model import MYOHAND_PHYSICS, load_hand
from angora_jax.envs.myohand.muscle_task import SUCCESS_STEPS, MuscleHandTask
from angora_jax.envs.myohand.pose import POSE_THRESHOLD, START_SPREAD, MyoHandPose, PoseReward
from angora_jax.envs.myohand.reach import NEAR_PER_TIP, TIPS, MyoHandReach, ReachReward
from angora_jax.envs.myohand.reorient import (
    DROP_DISTANCE,
    GOAL_POSITION,
    GOAL_ROTATION,
    POSITION_THRESHOLD,
    ROTATION_THRESHOLD,
    STEPS_PER_GOAL,
    MyoHandReorient,
    ReorientReward,
)
from angora_jax.envs.registry import register


def _on_backend(task: Callable[[mujoco.MjModel], MuscleHandTask], control_dt: float, max_episode_steps: int,
                physics: dict[str, float | str] | None, backend: str) -> Env:
    """The task that `task` makes of the hand compiled with `physics`, on `backend` (the arguments of `make_pose`).
    The hand stands where MyoSuite puts it, so gravity pulls on it as in MyoSuite's tasks and their targets apply."""
    settings = MYOHAND_PHYSICS.with_options(physics)
    frame_skip = settings.frame_skip(control_dt)
    return on_backend(backend, task(load_hand(settings, myosuite_frame=True)), frame_skip, max_episode_steps,
                      settings.warp_max_envs)


def make_pose(reward: dict[str, float] | None = None, pose_threshold: float = POSE_THRESHOLD,
              success_steps: int = SUCCESS_STEPS, start_spread: float = START_SPREAD, targets: str = "asl",
              control_dt: float = 0.02, max_episode_steps: int = 100, physics: dict[str, float | str] | None = None,
              backend: str = "mjx") -> Env:
    """Build `MyoHandPose` (`pose.MyoHandPose`; MyoSuite's myoHandPoseRandom-v0 defaults). Times in s, angles in rad.

    Args:
        reward: `pose.PoseReward` coefficients overriding MyoSuite's weights (e.g. `{effort: 0}`).
        pose_threshold: a step is solved below this pose error.
        success_steps: an episode is a success when solved on more than this many steps.
        start_spread: in (0, 1]: each start's pose error as a fraction of MyoSuite's uniform start's (the start is
            target + start_spread x (uniform start - target)); 1 is MyoSuite's task, below 1 an easier one whose
            `success` is not MyoSuite's (a curriculum's first stage; 0.4 starts about 1 rad from the target).
        targets: "asl" (MyoSuite's: each joint uniform within the ASL digits' ranges), "reachable" (postures the
            hand makes itself, `reachable.py`'s bank less its held-out rows) or "reachable_held_out" (those rows).
        control_dt: simulated time per policy step, a whole multiple of the timestep (the frame skip is control_dt /
            timestep: 0.02 / 0.002 = 10).
        max_episode_steps: policy steps per episode.
        physics: `PhysicsSettings` fields overriding the model's own settings (`model.MYOHAND_PHYSICS`: 2 ms, Newton,
            100 iterations, 50 line-search steps).
        backend: "mjx" (batched, training) or "cpu" (the C MuJoCo twin).
    """
    coefficients = PoseReward.from_dict(reward)
    return _on_backend(lambda model: MyoHandPose(model, coefficients, pose_threshold=pose_threshold,
                                                 success_steps=success_steps, start_spread=start_spread,
                                                 targets=targets),
                       control_dt, max_episode_steps, physics, backend)


def make_reach(reward: dict[str, float] | None = None, reach_threshold: float = NEAR_PER_TIP * len(TIPS),
               success_steps: int = SUCCESS_STEPS, control_dt: float = 0.02, max_episode_steps: int = 100,
               physics: dict[str, float | str] | None = None, backend: str = "mjx") -> Env:
    """Build `MyoHandReach` (`reach.MyoHandReach`; MyoSuite's myoHandReachRandom-v0 defaults). Times in s, lengths
    in m; the hand stands where MyoSuite puts it.

    Args:
        reward: `reach.ReachReward` coefficients overriding MyoSuite's weights (e.g. `{effort: 0}`).
        reach_threshold: a step is solved below this distance over the five tips (0.0625 m).
        success_steps: an episode is a success when solved on more than this many steps.
        control_dt: simulated time per policy step, a whole multiple of the timestep.
        max_episode_steps: policy steps per episode.
        physics: `PhysicsSettings` fields overriding the model's own settings (as `make_pose`).
        backend: "mjx" (batched, training) or "cpu" (the C MuJoCo twin).
    """
    coefficients = ReachReward.from_dict(reward)
    return _on_backend(lambda model: MyoHandReach(model, coefficients, reach_threshold=reach_threshold,
                                                  success_steps=success_steps),
                       control_dt, max_episode_steps, physics, backend)


def make_reorient(reward: dict[str, float] | None = None, goal_position: float = GOAL_POSITION,
                  goal_rotation: float = GOAL_ROTATION, position_threshold: float = POSITION_THRESHOLD,
                  rotation_threshold: float = ROTATION_THRESHOLD, drop_distance: float = DROP_DISTANCE,
                  success_steps: int = SUCCESS_STEPS, steps_per_goal: int = STEPS_PER_GOAL, max_goals: int = 50,
                  control_dt: float = 0.01, physics: dict[str, float | str] | None = None,
                  backend: str = "mjx") -> Env:
    """Build `MyoHandReorient` (`reorient.MyoHandReorient`; MyoSuite's myoChallengeDieReorientP1-v0 defaults, goals
    in a row as on the Shadow cube). Times in s, lengths in m, angles in rad. Episodes end by a drop, a goal's time
    running out or `max_goals`, never by the step limit (max_goals * steps_per_goal).

    Args:
        reward: `reorient.ReorientReward` coefficients overriding the defaults (e.g. `{effort: 0}`).
        goal_position: goal positions within this many m per axis of the die's start (phase 2: 0.02).
        goal_rotation: goal Euler angles within this many rad (phase 2: 3.14).
        position_threshold: a step is solved within this distance of the goal position ...
        rotation_threshold: ... and this rotation angle of the goal orientation.
        drop_distance: the die has dropped beyond this distance from the goal position.
        success_steps: a goal is reached when solved on more than this many steps.
        steps_per_goal: policy steps each goal gets (MyoSuite's episode: 150).
        max_goals: goals reached that cut an episode.
        control_dt: simulated time per policy step, a whole multiple of the timestep (MyoSuite's 0.01: 5 x 2 ms).
        physics: `PhysicsSettings` fields overriding the model's own settings (as `make_pose`); impl "auto" runs
            MuJoCo Warp wherever warp-lang is installed (`die.load_hand_with_die`).
        backend: "mjx" (batched, training) or "cpu" (the C MuJoCo twin).
    """
    coefficients = ReorientReward.from_dict(reward)
    settings = MYOHAND_PHYSICS.with_options(physics)
    task = MyoHandReorient(load_hand_with_die(settings), coefficients, goal_position=goal_position,
                           goal_rotation=goal_rotation, position_threshold=position_threshold,
                           rotation_threshold=rotation_threshold, drop_distance=drop_distance,
                           success_steps=success_steps, steps_per_goal=steps_per_goal, max_goals=max_goals)
    return on_backend(backend, task, settings.frame_skip(control_dt), max_goals * steps_per_goal,
                      settings.warp_max_envs)


register("MyoHandPose", make_pose)
register("MyoHandReach", make_reach)
register("MyoHandReorient", make_reorient)
