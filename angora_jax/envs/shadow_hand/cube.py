"""The in-hand cube scene: the Gym hand palm-up with a labelled cube on a free joint, pruned and tuned for MJX.

Built from gymnasium-robotics' `manipulate_block_touch_sensors.xml` (the cube's faces carry the Gym block texture:
a letter and colour per face, so every face is distinguishable). Our changes, each for a reason:

- The `target` body is deleted: it is a free body without collisions that only shows the goal in Gym's renderer;
  in MJX it would add 6 DoFs that fall forever.
- Contacts: the hand's collision geoms are capsules and boxes (contype 1, conaffinity 0) and the cube collides with
  all of them (conaffinity 1), plus the Gym model's 19 explicit finger-finger pairs. We remove the geoms that can
  never touch a cube that is still in the hand: the forearm's convex mesh (below the wrist: a cube there has
  already dropped below the palm, which ends the episode) and the thumb base boxes `V_thbase`/`V_thhub` (they
  collide with everything, but lie under the palm and the thumb's proximal capsule; box-box pairs are the most
  expensive in MJX). Under random actions from the episode start, C MuJoCo saw cube contacts only with palm,
  little-finger metacarpal and finger/thumb phalanges (see `benchmarks/results/ihom_solver_settings.md`).
- Sensors: only the 97 touch sensors (from Gym's `*_touch_sensors_92` files) are kept, and only with `touch=True`;
  the Gym scene's joint-position sensors duplicate `qpos`, and MJX evaluates every sensor at every physics step.
- Solver and timestep (`PhysicsSettings`): the defaults were chosen from measured dynamics error against the Gym
  scene's settings and measured speed; the evidence is in `benchmarks/results/ihom_solver_settings.md`.
"""

from __future__ import annotations

import dataclasses

import mujoco

from angora_jax.envs.shadow_hand.model import load_scene

SCENE = "manipulate_block_touch_sensors.xml"
CUBE_BODY = "object"
CUBE_JOINT = "object:joint"
CUBE_HALF_SIZE = 0.025  # m
# Hand geoms that can never touch a cube that is still above the palm (see the module docstring).
UNREACHABLE_GEOMS = ("robot0:C_forearm", "robot0:V_thbase", "robot0:V_thhub")


@dataclasses.dataclass(frozen=True)
class PhysicsSettings:
    """Simulation settings of the cube scene.

    timestep: physics step in s. iterations / ls_iterations: Newton solver and line-search iteration caps.
    The Gym scene itself runs timestep 0.002, iterations 20 and MuJoCo's default ls_iterations 50 (`GYM`).
    """

    timestep: float = 0.008
    iterations: int = 4
    ls_iterations: int = 8

    def __post_init__(self):
        if self.timestep <= 0 or self.iterations < 1 or self.ls_iterations < 1:
            raise ValueError(f"PhysicsSettings need timestep > 0 and iterations, ls_iterations >= 1, got {self}.")


GYM = PhysicsSettings(timestep=0.002, iterations=20, ls_iterations=50)


def load_cube_scene(touch: bool = True, physics: PhysicsSettings = PhysicsSettings()) -> mujoco.MjModel:
    """Compile the cube scene; `touch=False` drops the touch sensors (and their per-step cost)."""

    def edit(spec: mujoco.MjSpec) -> None:
        spec.delete(spec.body("target"))
        for name in UNREACHABLE_GEOMS:
            geom = spec.geom(name)
            geom.contype = 0
            geom.conaffinity = 0
        for sensor in list(spec.sensors):
            if not (touch and sensor.type == mujoco.mjtSensor.mjSENS_TOUCH):
                spec.delete(sensor)
        spec.option.timestep = physics.timestep
        spec.option.iterations = physics.iterations
        spec.option.ls_iterations = physics.ls_iterations

    return load_scene(SCENE, edit)
