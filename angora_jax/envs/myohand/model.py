"""The MyoHand model: MyoSuite's muscle-driven right hand as `myo-sim` builds it, compiled for MJX.

`myo-sim` (0.2.3, Apache-2.0, the `myo` extra) holds MyoSuite's musculoskeletal models. Its MyoHand has 23 joints
(forearm rotation, wrist, thumb and fingers), 39 muscle actuators (MuJoCo's muscle activation dynamics, gain and
bias) pulling on 39 tendons that wrap over 315 spheres, cylinders and sites, and collision geoms that collide with
nothing (contype 1, conaffinity 0): the hand alone makes no contacts. MJX accepts it as built, with both
implementations; we change only the settings of `PhysicsSettings`.
"""

from __future__ import annotations

import importlib.util

import mujoco

from angora_jax.envs.shadow_hand.model import PhysicsSettings

# The model's own solver settings (myo-sim 0.2.3): 2 ms, Newton with up to 100 iterations and 50 line-search steps.
MYOHAND_PHYSICS = PhysicsSettings(timestep=0.002, iterations=100, ls_iterations=50)
MUSCLES = 39
JOINTS = 23
INSTALL_HINT = 'pip install -c constraints.txt -e ".[myo]" (or pip install myo-sim==0.2.3)'
# Where MyoSuite (3.0.0, `core/model_recipes.py`, `_calibrate_compose_hand_root`) puts the composed hand's root body:
# position (m) and quaternion (w, x, y, z) in its legacy world frame, where its tasks' targets and objects are given.
# myo-sim leaves the root at the origin, unrotated, so gravity pulls on the hand from another direction there.
MYOSUITE_ROOT_POS = (-0.02525155, 0.07146933, 1.39249298)
MYOSUITE_ROOT_QUAT = (0.52167746, 0.46981366, -0.47875126, -0.52718591)


def require_myo_sim() -> None:
    """Raise a ModuleNotFoundError naming the fix when the `myo-sim` package (the MyoHand's files) is missing."""
    if importlib.util.find_spec("myo_sim") is None:
        raise ModuleNotFoundError(f"The MyoHand tasks build the hand from the 'myo-sim' package: {INSTALL_HINT}.")


def hand_spec(physics: PhysicsSettings = MYOHAND_PHYSICS, myosuite_frame: bool = False) -> mujoco.MjSpec:
    """The MyoHand's spec with `physics` (timestep, solver iterations, MJX implementation), for a scene to add to
    before compiling (`load_hand` compiles it as it is).

    Args:
        physics: the solver settings.
        myosuite_frame: place the hand where MyoSuite does (`MYOSUITE_ROOT_POS`, `MYOSUITE_ROOT_QUAT`), so that
            positions given in MyoSuite's world frame (reach targets, the die) apply as they are, and gravity pulls
            as there; otherwise the root stays where myo-sim puts it.
    """
    require_myo_sim()
    from myo_sim.build.compose import build_right_hand_from_arm_spec

    spec = build_right_hand_from_arm_spec()
    if myosuite_frame:
        root = spec.body("myoarm_r_root")
        root.pos, root.quat = MYOSUITE_ROOT_POS, MYOSUITE_ROOT_QUAT
    physics.apply(spec)
    return spec


def load_hand(physics: PhysicsSettings = MYOHAND_PHYSICS, myosuite_frame: bool = False) -> mujoco.MjModel:
    """Compile the MyoHand (`hand_spec`'s arguments). Its joints are `JOINTS` hinges (rad), its actuators `MUSCLES`
    muscles whose `ctrl` is the excitation in [0, 1] (`actuator_ctrlrange`) and whose `act` is the activation, one
    state per muscle (`na` = `nu`)."""
    return hand_spec(physics, myosuite_frame).compile()
