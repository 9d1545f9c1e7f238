"""The die of MyoChallenge 2022's die reorientation in the MyoHand's scene: groundwork for a `MyoHandReorient` task,
which does not exist yet (no goal, reward or success rule here).

The die is MyoSuite's (myosuite 3.0.0, `envs/myo/assets/hand/myohand_die.xml`): a rounded cube 5.7 cm across, 12
capsules of radius 5 mm along its edges and three crossed boxes for its faces, 108 g, placed in MyoSuite's world frame
above the palm, which faces up when the forearm is turned to `PALM_UP` (MyoSuite's die task starts so, every other
joint at 0). Its geoms collide with the hand's collision geoms (24 capsules and 5 ellipsoids). What differs: the die
moves on a free joint, where MyoSuite gives it three slide joints limited to +-25 cm and three hinges (so there it
cannot fall further than 25 cm).

Measured on C MuJoCo (benchmarks/results/myohand/README.md): with no excitation the die slides over the palm as in
MyoSuite's scene (0.027 m at 0.3 s, 0.074 m at 0.75 s; MyoSuite's 0.038 and 0.075 m) and, with no slide limits to hold
it, falls off after 0.88 s; under random excitations it passes MyoSuite's drop threshold (0.2 m) after 0.15-0.23 s
(MyoSuite's scene: 0.26-0.27 s). MuJoCo Warp accepts the scene and steps it as C MuJoCo does (the die within 0.4 mm
after 100 physics steps), but `mjx_env.warp_sizes` cannot size Warp's buffers for it: it asks MJX's JAX
implementation, which has no collision function for the hand's ellipsoids against the die's boxes.

Missing for `MyoHandReorient` (MyoSuite's `ReorientEnv`, myoChallengeDieReorientP1/P2-v0): the goal (orientation
drawn per axis within +-90 degrees for phase 1, +-180 for phase 2, position within +-1 / +-2 cm; phase 2 also draws the
die's size +-7 mm, mass 50-250 g and friction), the tolerance (solved within 0.025 m and 0.262 rad of Euler-angle
error, success on more than 5 of 150 steps of 10 ms, failed beyond 0.2 m), CGR (goals reached in a row with a step
cap, as on the Shadow cube), Warp's buffer sizes without MJX's JAX implementation, and the speed of contacts at 16k+
environments.
"""

from __future__ import annotations

import itertools

import mujoco
import numpy as np

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
    """The MyoHand in MyoSuite's frame with MyoSuite's die (`add_die`), compiled with `physics`."""
    spec = hand_spec(physics, myosuite_frame=True)
    add_die(spec)
    return spec.compile()


def die_start(model: mujoco.MjModel) -> np.ndarray:
    """`qpos` at the start of MyoSuite's die task: the forearm at `PALM_UP`, the other joints at 0 and the die at
    rest at `DIE_POS`, unrotated."""
    qpos = model.qpos0.copy()
    qpos[model.joint("pro_sup_r").qposadr[0]] = PALM_UP
    return qpos
