"""Shadow Dexterous Hand tasks, registered as `ShadowHandReach`, `ShadowHandFreeReach` and `ShadowHandCube`."""

from __future__ import annotations

from angora_jax.envs.core import Env
from angora_jax.envs.cpu_env import CpuEnv
from angora_jax.envs.mjx_env import MjxEnv
from angora_jax.envs.mujoco_task import MujocoTask
from angora_jax.envs.registry import register
from angora_jax.envs.shadow_hand.cube import CUBE_PHYSICS, load_cube_scene
from angora_jax.envs.shadow_hand.ihom import Ihom, IhomReward
from angora_jax.envs.shadow_hand.model import PhysicsSettings, load_scene
from angora_jax.envs.shadow_hand.reach import Reach, ReachReward

BACKENDS = ("mjx", "cpu")


def build(backend: str, task: MujocoTask, frame_skip: int, max_episode_steps: int, settings: PhysicsSettings) -> Env:
    """The task on a backend: "mjx" (batched, jit-able) or "cpu" (the eager C MuJoCo twin)."""
    if backend not in BACKENDS:
        raise ValueError(f"Unknown backend {backend!r}; choose one of {BACKENDS}.")
    if backend == "cpu":
        return CpuEnv(task, frame_skip=frame_skip, max_episode_steps=max_episode_steps)
    return MjxEnv(task, frame_skip, max_episode_steps, warp_max_envs=settings.warp_max_envs)


# Newton 2 / line search 4 at 5 ms: 7.2x the Gym settings' sim-s/s on an H100 with fingertips within 2.5 mm of them
# over 50 open-loop policy steps (benchmarks/results/physics_throughput_gpu.json).
REACH_PHYSICS = PhysicsSettings(timestep=0.005, iterations=2, ls_iterations=4)


def make_reach(free: bool = False, reward: dict[str, float] | None = None, control_dt: float = 0.02,
               max_episode_steps: int = 100, relative_control: bool = True,
               physics: dict[str, float] | None = None, backend: str = "mjx") -> Env:
    """Build a reach task. Defaults follow AngoraPy: 0.02 s per policy step, 100 policy steps per episode,
    relative joint-target control. physics: `PhysicsSettings` fields overriding `REACH_PHYSICS` (the Gym scene's own
    settings are timestep 0.002, iterations 20, ls_iterations 50). `backend="cpu"` gives the eager MuJoCo twin."""
    settings = REACH_PHYSICS.with_options(physics)
    frame_skip = settings.frame_skip(control_dt)
    task = Reach(load_scene("reach.xml", physics=settings), ReachReward.from_dict(reward), free=free,
                 relative_control=relative_control)
    return build(backend, task, frame_skip, max_episode_steps, settings)


def make_free_reach(**options) -> Env:
    """`make_reach(free=True, ...)`: only the thumb and the target finger need to meet."""
    return make_reach(free=True, **options)


def make_ihom(reward: dict[str, float] | None = None, touch: bool = True, success_angle: float = 0.4,
              goal_timeout: float = 8.0, max_goals: int = 50, control_dt: float = 0.08,
              physics: dict[str, float] | None = None, relative_control: bool = True, backend: str = "mjx") -> Env:
    """Build in-hand cube reorientation (see `ihom.Ihom`). Times in s, angles in rad.

    control_dt: simulated time per policy step, 0.08 s as in OpenAI's Dactyl (12.5 Hz) so that the 8 s goal timer
    is 100 policy steps (AngoraPy's code runs 10 x 2 ms = 0.02 s per step with 100 steps per goal, i.e. 2 s).
    physics: `PhysicsSettings` fields (timestep, iterations, ls_iterations); the frame skip is control_dt / timestep
    (default 0.08 / 0.008 = 10). max_episode_steps is max_goals * goal steps, never reached before the goal timer or
    the cap ends an episode.
    """
    settings = CUBE_PHYSICS.with_options(physics)
    frame_skip = settings.frame_skip(control_dt)
    steps_per_goal = round(goal_timeout / control_dt)
    if steps_per_goal < 1:
        raise ValueError(f"goal_timeout ({goal_timeout} s) must last at least one policy step ({control_dt} s).")
    task = Ihom(load_cube_scene(touch, settings), IhomReward.from_dict(reward), success_angle=success_angle,
                steps_per_goal=steps_per_goal, max_goals=max_goals, relative_control=relative_control)
    return build(backend, task, frame_skip, max_goals * steps_per_goal, settings)


register("ShadowHandReach", make_reach)
register("ShadowHandFreeReach", make_free_reach)
register("ShadowHandCube", make_ihom)
