"""Shadow Dexterous Hand tasks, registered as `ShadowHandReach`, `ShadowHandFreeReach`, their sequential variants
`ShadowHandReachSequential` and `ShadowHandFreeReachSequential`, and `ShadowHandCube`."""

from __future__ import annotations

from collections.abc import Callable

import mujoco

from angora_jax.envs.backends import on_backend
from angora_jax.envs.cameras import CameraVision
from angora_jax.envs.core import Env
from angora_jax.envs.mujoco_task import MujocoTask
from angora_jax.envs.randomization import ModelRandomizer, Randomization
from angora_jax.envs.registry import register
from angora_jax.envs.shadow_hand.cube import CUBE_BODY, CUBE_PHYSICS, load_cube_scene
from angora_jax.envs.shadow_hand.ihom import REWARD_PRESETS as IHOM_REWARDS
from angora_jax.envs.shadow_hand.ihom import Ihom, IhomReward, PoseNoise, PoseReader
from angora_jax.envs.shadow_hand.model import PhysicsSettings, add_touch_sensors, load_scene
from angora_jax.envs.shadow_hand.reach import REWARD_PRESETS as REACH_REWARDS
from angora_jax.envs.shadow_hand.reach import Reach, ReachReward
from angora_jax.registry import import_registrar


def build(backend: str, task: MujocoTask, frame_skip: int, max_episode_steps: int, settings: PhysicsSettings,
          randomization: Randomization | None = None, cube_body: str | None = None,
          value_sees_physics: bool = False) -> Env:
    """The task on a backend (`angora_jax.envs.backends.on_backend`), Warp sized by `settings`, domain-randomized by
    `randomization` (`cube_body` names the cube's body for its ranges), the drawn physics among the value function's
    inputs if `value_sees_physics` (the nominal physics without `randomization`)."""
    if randomization is not None or value_sees_physics:
        task.randomizer = ModelRandomizer(randomization or Randomization(), task.model, cube_body, value_sees_physics)
    return on_backend(backend, task, frame_skip, max_episode_steps, settings.warp_max_envs)


# Newton 2 / line search 4 at 5 ms: 7.2x the Gym settings' sim-s/s on an H100 with fingertips within 2.5 mm of them
# over 50 open-loop policy steps (benchmarks/results/physics_throughput/physics_throughput_gpu.json).
REACH_PHYSICS = PhysicsSettings(timestep=0.005, iterations=2, ls_iterations=4)


def make_reach(free: bool = False, reward_preset: str = "default", reward: dict[str, float] | None = None,
               control_dt: float = 0.02, max_episode_steps: int = 100, control: str = "position",
               physics: dict[str, float] | None = None, vision: dict | None = None, target_finger: str | None = None,
               freeze_wrist: bool = False, sequence_length: int | None = None, sequence_order: str = "random",
               randomization: dict | None = None, value_sees_physics: bool = False, touch: bool = False,
               backend: str = "mjx") -> Env:
    """Build a reach task. Defaults follow AngoraPy: 0.02 s per policy step, 100 policy steps per episode,
    joint targets set relative to the joints' positions (`control`: see `HandTask`).

    Args:
        physics: `PhysicsSettings` fields overriding `REACH_PHYSICS` (the Gym scene's own settings are timestep 0.002,
            iterations 20, ls_iterations 50).
        vision: camera images of the hand in `Sensation.vision` (`envs.cameras.CameraVision` fields, as for the cube),
            besides the usual inputs.
        reward_preset: a key of `reach.REWARD_PRESETS`, AngoraPy's "default" or "force_punished"; `reward` overrides
            single coefficients of it.
        target_finger: "FF", "MF", "RF" or "LF" for every episode (AngoraPy's `force_finger`), None to draw one per
            episode.
        freeze_wrist: the wrist holds its initial pose (`HandTask`).
        sequence_length: None for one target per episode, or the number of target fingers an episode asks for in turn
            (AngoraPy's sequential tasks; `reach.Reach`), with metrics `sequence_steps` and `sequence_success`.
        sequence_order: "random" (each target drawn among the three fingers other than the previous) or "fixed" (FF, MF,
            RF, LF, FF, ...).
        randomization: domain randomization ranges, `randomization.Randomization` fields without the cube's.
        value_sees_physics: the value function's `asymmetric` inputs also hold the episode's drawn physics (the log
            of each factor and the action delay: `randomization.ModelRandomizer.physics_inputs`), the policy's do not.
        touch: the hand carries Gym's 97 touch sensors (the cube's, `model.add_touch_sensors`) and `Sensation.touch`
            holds their readings (N); off by default, as in Gym's HandReach, so that MJX evaluates no sensor.
        backend: "mjx" (batched, for training) or "cpu" (the eager C MuJoCo twin).
    """
    ranges = Randomization.from_options(randomization, cube=False)
    cameras = CameraVision.from_options(vision)
    settings = REACH_PHYSICS.with_options(physics)
    frame_skip = settings.frame_skip(control_dt)
    sensors = (mujoco.mjtSensor.mjSENS_TOUCH,) if touch else ()
    scene = load_scene("reach.xml", add_touch_sensors if touch else None, settings, sensors=sensors,
                       cameras=cameras.cameras if cameras else ())
    task = Reach(scene, ReachReward.preset(REACH_REWARDS, reward_preset, reward), free=free, control=control,
                 vision=cameras, target_finger=target_finger, freeze_wrist=freeze_wrist,
                 sequence_length=sequence_length, sequence_order=sequence_order)
    return build(backend, task, frame_skip, max_episode_steps, settings, ranges, value_sees_physics=value_sees_physics)


# Reads a pose estimator file for the cube's `pose_estimator` option. Estimators are made and trained in
# angora_jax.vision, which builds on envs, so it registers its reader here (`PoseEstimator.load`) when imported.
_pose_estimator_reader: Callable[[str], PoseReader] | None = None


def register_pose_estimator_reader(reader: Callable[[str], PoseReader]) -> None:
    """Make `reader(file) -> pose estimator` the way `make_ihom` reads its `pose_estimator` file; angora_jax.vision
    registers `PoseEstimator.load` when it is imported (the first read imports it after `import angora_jax`)."""
    global _pose_estimator_reader
    _pose_estimator_reader = reader


def read_pose_estimator(file: str) -> PoseReader:
    """The pose estimator saved in `file`, read by the registered reader; RuntimeError naming the fix without one."""
    if _pose_estimator_reader is None:  # `import angora_jax` names the module that registers it, without importing it
        import_registrar(__name__)
    if _pose_estimator_reader is None:
        raise RuntimeError(f"Reading the pose estimator {file!r} needs angora_jax.vision, which registers the reader: "
                           "import angora_jax (or angora_jax.vision) first.")
    return _pose_estimator_reader(file)


def make_free_reach(**options) -> Env:
    """`make_reach(free=True, ...)`: only the thumb and the target finger need to meet."""
    return make_reach(free=True, **options)


def make_reach_sequential(sequence_length: int = 4, **options) -> Env:
    """AngoraPy's `ReachSequential`: `make_reach(sequence_length=4, ...)`, four target fingers per episode in turn."""
    return make_reach(sequence_length=sequence_length, **options)


def make_free_reach_sequential(sequence_length: int = 4, sequence_order: str = "fixed", **options) -> Env:
    """AngoraPy's `FreeReachSequential`: `make_reach(free=True, sequence_length=4, sequence_order="fixed", ...)`,
    FF, MF, RF, LF in every episode as AngoraPy's default exemplary sequence; "random" draws them."""
    return make_reach(free=True, sequence_length=sequence_length, sequence_order=sequence_order, **options)


def make_ihom(reward_preset: str = "dense", reward: dict[str, float] | None = None, touch: bool = True,
              success_angle: float = 0.4, goal_timeout: float = 8.0, timer: str = "terminal", max_goals: int = 50,
              control_dt: float = 0.08, relative_goal: bool = True, control: str = "absolute",
              action_scale: float = 0.2, start_pool: int = 512, physics: dict[str, float] | None = None,
              vision: dict | None = None, pose_estimator: str | None = None, freeze_wrist: bool = False,
              pose_noise: dict[str, float] | None = None, goals: str = "random", randomization: dict | None = None,
              value_sees_physics: bool = False, backend: str = "mjx") -> Env:
    """Build in-hand cube reorientation (see `ihom.Ihom`). Times in s, angles in rad.

    The defaults are the recipe of `configs/shadow_ihom.yaml`; `configs/shadow_ihom_paper.yaml` sets AngoraPy's.

    Args:
        reward_preset: a key of `ihom.REWARD_PRESETS`: "dense", "paper" (AngoraPy's eq. 1-2, its "default"),
            "penalized_force" or "penalized_anatomy" (AngoraPy's); `reward` overrides single coefficients of it.
        timer: "terminal" (a goal that times out ends the episode, as in AngoraPy) or "truncation".
        relative_goal: the goal modality also holds the rotation from the cube to the goal (AngoraPy: False).
        control: how actions move the joint targets (`HandTask`; AngoraPy: "position").
        action_scale: the scale of that move (`HandTask`; AngoraPy: 1.0).
        control_dt: simulated time per policy step, 0.08 s as in OpenAI's Dactyl (12.5 Hz) so that the 8 s goal timer is
            100 policy steps (AngoraPy's code runs 10 x 2 ms = 0.02 s per step with 100 steps per goal, i.e. 2 s).
        physics: `PhysicsSettings` fields (timestep, iterations, ls_iterations, impl); the frame skip is control_dt /
            timestep (default 0.08 / 0.008 = 10). max_episode_steps is max_goals * goal steps, never reached before the
            goal timer or the cap ends an episode.
        vision: camera images in place of the cube's pose (`envs.cameras.CameraVision` fields, e.g. `{cameras: [front],
            width: 64, height: 64}`), rendered by MuJoCo Warp inside the step on a GPU and by OpenGL otherwise.
        pose_estimator: a `vision.PoseEstimator` file (`angora-jax pretrain-vision` writes `<out>.pose.msgpack`): the
            policy sees the pose it estimates from its cameras' RGB frames (which set `vision`; give no other) where it
            saw the true pose, with inputs of the same shapes. Train the estimator on the renderer these frames come
            from (Warp's on a GPU).
        freeze_wrist: the wrist holds its initial pose whatever the policy's first two actions say (`HandTask`).
        pose_noise: noise on the pose the policy sees, `ihom.PoseNoise` fields (position in m, rotation in rad); `{}`
            gives AngoraPy's NoisyManipulateBlock (3.71 mm, pi / 36).
        goals: "random" (any rotation) or "test_set", the 24 axis-aligned orientations (AngoraPy's
            TestCaseManipulateBlock), to evaluate runs on the same fixed set: `evaluate --env-option goals=test_set`.
        randomization: domain randomization ranges, `randomization.Randomization` fields (docs/tasks.md).
        value_sees_physics: as for `make_reach`, with the cube's mass, damping and size.
    """
    ranges = Randomization.from_options(randomization, cube=True)
    estimator = None
    if pose_estimator is not None:
        if vision is not None:
            raise ValueError("pose_estimator sees through the cameras it was trained on; give no vision option "
                             "with it.")
        estimator = read_pose_estimator(pose_estimator)
        vision = {"cameras": list(estimator.cameras), "width": estimator.size, "height": estimator.size,
                  "renderer": estimator.renderer}
    cameras = CameraVision.from_options(vision)
    settings = CUBE_PHYSICS.with_options(physics)
    frame_skip = settings.frame_skip(control_dt)
    steps_per_goal = round(goal_timeout / control_dt)
    if steps_per_goal < 1:
        raise ValueError(f"goal_timeout ({goal_timeout} s) must last at least one policy step ({control_dt} s).")
    scene = load_cube_scene(touch, settings, cameras=cameras.cameras if cameras else ())
    task = Ihom(scene, IhomReward.preset(IHOM_REWARDS, reward_preset, reward),
                success_angle=success_angle, steps_per_goal=steps_per_goal, max_goals=max_goals, dt=control_dt,
                timer=timer, relative_goal=relative_goal, control=control, action_scale=action_scale,
                start_pool=start_pool, vision=cameras, pose_estimator=estimator, freeze_wrist=freeze_wrist,
                pose_noise=None if pose_noise is None else PoseNoise.from_options(pose_noise), goals=goals)
    return build(backend, task, frame_skip, max_goals * steps_per_goal, settings, ranges, CUBE_BODY, value_sees_physics)


register("ShadowHandReach", make_reach)
register("ShadowHandFreeReach", make_free_reach)
register("ShadowHandReachSequential", make_reach_sequential)
register("ShadowHandFreeReachSequential", make_free_reach_sequential)
register("ShadowHandCube", make_ihom)
