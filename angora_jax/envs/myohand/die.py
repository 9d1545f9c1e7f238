"""The die of MyoChallenge 2022's die reorientation in the MyoHand's scene, which `reorient.MyoHandReorient` turns
to drawn goals.

The die is MyoSuite's (myosuite 3.0.0, `envs/myo/assets/hand/myohand_die.xml`): a rounded cube 5.7 cm across, 12
capsules of radius 5 mm along its edges and three crossed boxes for its faces, 108 g, placed in MyoSuite's world frame
above the palm, which faces up when the forearm is turned to `PALM_UP` (MyoSuite's die task starts so, every other
joint at 0). Its geoms collide with the hand's collision geoms (24 capsules and 5 ellipsoids). What differs: the die
moves on a free joint, where MyoSuite gives it three slide joints limited to +-25 cm and three hinges (so there it
cannot fall further than 25 cm).

Measured on C MuJoCo (benchmarks/results/myohand/README.md): with no excitation the die slides over the palm as in
MyoSuite's scene (0.027 m at 0.3 s, 0.074 m at 0.75 s; MyoSuite's 0.038 and 0.075 m) and, with no slide limits to hold
it, falls off after 0.88 s; under random excitations it passes MyoSuite's drop threshold (0.2 m) after 0.15-0.23 s
(MyoSuite's scene: 0.26-0.27 s). MuJoCo Warp steps the scene as C MuJoCo does (the die within 0.4 mm after 100
physics steps; tests/test_myohand_reorient.py checks a few policy steps).

MuJoCo Warp and MJX's JAX implementation. MJX's JAX implementation has no collision function for the hand's ellipsoids
against the die's boxes, so it cannot step the scene, nor size Warp's buffers by its worst case (`mjx_env.warp_sizes`).
`load_hand_with_die` therefore asks for Warp under `physics.impl: auto` wherever warp-lang is installed (the CPU
included), and states the scene's budget in MuJoCo's own size fields, which `warp_sizes` reads: `DIE_NCONMAX`
contacts and `DIE_NJMAX` constraint rows per environment. C MuJoCo rollouts gave at most 34 contacts and 145 rows
(150 episodes of up to 150 policy steps of 10 ms from `die_start` under uniform, binary and drifting random
excitations, until the die passed 0.2 m); the budget is about three times that. Warp pools the contacts of all
environments of a batch, so one environment may use more than `DIE_NCONMAX` while others use fewer.
"""

from __future__ import annotations

import itertools

import mujoco
import numpy as np

from angora_jax.envs.mjx_env import choose_impl
from angora_jax.envs.mujoco_task import set_mjx_impl
from angora_jax.envs.myohand.model import MYOHAND_PHYSICS, hand_spec
from angora_jax.envs.shadow_hand.model import PhysicsSettings

DIE = "die"
# MyoSuite's die: where it starts (m, its world frame), its mass (kg) and diagonal inertia (kg m^2), the half-length
# of its edges' capsules (m) and their radius, the half-sizes of its face boxes (m, long and short).
DIE_POS = (-0.240, -0.535, 1.46)
DIE_MASS = 0.108
DIE_INERTIA = 6.48e-05
EDGE_HALF = 0.0235
EDGE_RADIUS = 0.005
FACE_HALF = (0.0284, 0.0236)
# The forearm's rotation (`pro_sup_r`, rad) at the start of MyoSuite's die task: the palm faces up.
PALM_UP = -1.5
# Warp's budget per environment (module docstring): contacts (C MuJoCo rollouts: at most 34), and constraint rows, 4 per
# contact (condim 3 in MuJoCo's pyramidal cone) and 64 for joint and tendon limits (rollouts: at most 145 rows in all).
DIE_NCONMAX = 96
DIE_NJMAX = 4 * DIE_NCONMAX + 64
# What MJX's JAX implementation lacks to step the die's scene (`mjx_env.choose_impl`).
JAX_LACKS = "a collision function for the hand's ellipsoids against the die's boxes"


def add_die(spec: mujoco.MjSpec) -> None:
    """Add MyoSuite's die on a free joint named `DIE` to `spec` (a hand in MyoSuite's frame) at `DIE_POS`."""
    body = spec.worldbody.add_body(name=DIE, pos=DIE_POS, mass=DIE_MASS, inertia=[DIE_INERTIA] * 3,
                                   explicitinertial=True)
    body.add_freejoint(name=DIE)
    corners = np.array(list(itertools.product((-EDGE_HALF, EDGE_HALF), repeat=3)))
    for a, b in itertools.combinations(corners, 2):
        if np.count_nonzero(a != b) == 1:  # two corners one edge apart
            body.add_geom(type=mujoco.mjtGeom.mjGEOM_CAPSULE, fromto=np.concatenate([a, b]), size=[EDGE_RADIUS, 0, 0],
                          contype=1, conaffinity=1)
    long, short = FACE_HALF
    for axis in range(3):
        size = [short] * 3
        size[axis] = long
        body.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, size=size, contype=1, conaffinity=1)


def load_hand_with_die(physics: PhysicsSettings = MYOHAND_PHYSICS) -> mujoco.MjModel:
    """The MyoHand in MyoSuite's frame with MyoSuite's die (`add_die`), compiled with `physics`: under impl "auto" for
    MuJoCo Warp wherever warp-lang is installed (`JAX_LACKS`), with Warp's budget `DIE_NCONMAX` and `DIE_NJMAX`."""
    spec = hand_spec(physics, myosuite_frame=True)
    add_die(spec)
    set_mjx_impl(spec, *choose_impl(physics.impl, jax_lacks=JAX_LACKS))
    spec.nconmax, spec.njmax = DIE_NCONMAX, DIE_NJMAX
    return spec.compile()


def die_start(model: mujoco.MjModel) -> np.ndarray:
    """`qpos` at the start of MyoSuite's die task: the forearm at `PALM_UP`, the other joints at 0 and the die at
    rest at `DIE_POS`, unrotated."""
    qpos = model.qpos0.copy()
    qpos[model.joint("pro_sup_r").qposadr[0]] = PALM_UP
    return qpos
