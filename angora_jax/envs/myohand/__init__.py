"""MyoHand tasks (MyoSuite's muscle-driven hand, from the optional `myo-sim` package), registered as `MyoHandPose` and
`MyoHandReach`.

The hand is built only when a task is made, so that `import angora_jax` needs no `myo-sim`; making a task without it
raises a ModuleNotFoundError naming the install command.
"""

from __future__ import annotations

from collections.abc import Callable

import mujoco

from angora_jax.envs.backends import on_backend
from angora_jax.envs.core import Env
from angora_jax.envs.myohand.model import MYOHAND_PHYSICS, load_hand
from angora_jax.envs.myohand.muscle_task import SUCCESS_STEPS, MuscleHandTask
from angora_jax.envs.myohand.pose import POSE_THRESHOLD, MyoHandPose, PoseReward
from angora_jax.envs.myohand.reach import NEAR_PER_TIP, TIPS, MyoHandReach, ReachReward
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
              success_steps: int = SUCCESS_STEPS, control_dt: float = 0.02, max_episode_steps: int = 100,
              physics: dict[str, float | str] | None = None, backend: str = "mjx") -> Env:
    """Build `MyoHandPose` (`pose.MyoHandPose`; MyoSuite's myoHandPoseRandom-v0 defaults). Times in s, angles in rad.

    Args:
        reward: `pose.PoseReward` coefficients overriding MyoSuite's weights (e.g. `{effort: 0}`).
        pose_threshold: a step is solved below this pose error.
        success_steps: an episode is a success when solved on more than this many steps.
        control_dt: simulated time per policy step, a whole multiple of the timestep (the frame skip is control_dt /
            timestep: 0.02 / 0.002 = 10).
        max_episode_steps: policy steps per episode.
        physics: `PhysicsSettings` fields overriding the model's own settings (`model.MYOHAND_PHYSICS`: 2 ms, Newton,
            100 iterations, 50 line-search steps).
        backend: "mjx" (batched, training) or "cpu" (the C MuJoCo twin).
    """
    coefficients = PoseReward.from_dict(reward)
    return _on_backend(lambda model: MyoHandPose(model, coefficients, pose_threshold=pose_threshold,
                                                 success_steps=success_steps),
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


register("MyoHandPose", make_pose)
register("MyoHandReach", make_reach)
