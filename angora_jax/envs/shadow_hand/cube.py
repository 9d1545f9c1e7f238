"""The in-hand cube scene: the Gym hand palm-up with a labelled cube on a free joint, pruned and tuned for MJX.

Built from gymnasium-robotics' `manipulate_block_touch_sensors.xml` (the cube's faces carry the Gym block texture:
a letter and colour per face, so every face is distinguishable). Our changes, each for a reason:

- The `target` body is deleted: it is a free body without collisions that only shows the goal in Gym's renderer;
  in MJX it would add 6 DoFs that fall forever.
- Contacts: the hand's collision geoms are capsules and boxes (contype 1, conaffinity 0) and the cube collides with
  all of them (conaffinity 1), plus the Gym model's 19 explicit finger-finger pairs. `load_scene` removes the geoms
  that never touch anything (`model.UNTOUCHED_GEOMS`: the forearm's convex mesh, below the wrist, where a cube has
  already dropped below the palm, which ends the episode; the thumb-base boxes `V_thbase`/`V_thhub` under the palm
  and the thumb's proximal capsule; box-box and box-mesh pairs are the most expensive in MJX). Under random actions
  from the episode start, C MuJoCo saw cube contacts only with palm, little-finger metacarpal and finger/thumb
  phalanges (see `benchmarks/results/physics_throughput/ihom_solver_settings.md`).
- Sensors: only the 97 touch sensors (from Gym's `*_touch_sensors_92` files) are kept, and only with `touch=True`;
  the Gym scene's joint-position sensors duplicate `qpos`, and MJX evaluates every sensor at every physics step.
- Solver and timestep (`PhysicsSettings`): the defaults were chosen from measured dynamics error against the Gym
  scene's settings and measured speed; the evidence is in
  `benchmarks/results/physics_throughput/ihom_solver_settings.md`.
"""

from __future__ import annotations

import mujoco

from angora_jax.envs.shadow_hand.model import TOUCH_SCENE, PhysicsSettings, load_scene

SCENE = TOUCH_SCENE
CUBE_BODY = "object"
CUBE_JOINT = "object:joint"
CUBE_HALF_SIZE = 0.025  # m
# Chosen from the dynamics error against the Gym settings and the speed
# (benchmarks/results/physics_throughput/ihom_solver_settings.md).
CUBE_PHYSICS = PhysicsSettings(timestep=0.008, iterations=4, ls_iterations=8)


def load_cube_scene(touch: bool = True, physics: PhysicsSettings = CUBE_PHYSICS,
                    prune_contacts: bool = True, cameras: tuple[str, ...] = ()) -> mujoco.MjModel:
    """Compile the cube scene; `touch=False` drops the touch sensors (and their per-step cost), `prune_contacts=False`
    keeps the Gym scene's contacts (for comparisons).

    Args:
        cameras: `rendering.CAMERAS` names to add as fixed model cameras `vision_<name>` looking at the palm
            (`model.load_scene`).
    """

    def edit(spec: mujoco.MjSpec) -> None:
        spec.delete(spec.body("target"))

    sensors = (mujoco.mjtSensor.mjSENS_TOUCH,) if touch else ()
    return load_scene(SCENE, edit, physics, prune_contacts, sensors, cameras)
