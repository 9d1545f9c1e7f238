"""The die of MyoChallenge 2022 in the MyoHand's scene (issue 62's reorientation groundwork; no task yet), on C
MuJoCo (under a second): it is MyoSuite's die, it touches the palm-up hand at the start, and it falls off under
random excitations as it does in MyoSuite's own scene (benchmarks/results/myohand/README.md)."""

import mujoco
import numpy as np
import pytest

from angora_jax.envs.myohand.die import DIE, DIE_MASS, DIE_POS, die_start, load_hand_with_die
from angora_jax.envs.myohand.model import JOINTS, MUSCLES


@pytest.fixture(scope="module")
def model() -> mujoco.MjModel:
    return load_hand_with_die()


def test_the_die_is_myosuites_on_a_free_joint(model):
    die = model.body(DIE)
    assert model.njnt == JOINTS + 1 and model.nq == JOINTS + 7 and model.nu == MUSCLES
    assert model.jnt_type[model.joint(DIE).id] == mujoco.mjtJoint.mjJNT_FREE
    np.testing.assert_allclose(die.mass, DIE_MASS)
    geoms = model.geom_bodyid == die.id
    types = model.geom_type[geoms]
    assert np.count_nonzero(types == mujoco.mjtGeom.mjGEOM_CAPSULE) == 12
    assert np.count_nonzero(types == mujoco.mjtGeom.mjGEOM_BOX) == 3
    data = mujoco.MjData(model)
    data.qpos[:] = die_start(model)
    mujoco.mj_forward(model, data)
    np.testing.assert_allclose(data.xpos[die.id], DIE_POS)
    corners = data.geom_xpos[geoms]
    np.testing.assert_allclose(np.ptp(corners, axis=0), [0.047] * 3, atol=1e-9)  # capsule centres over the edges


def test_the_die_touches_the_palm_up_hand_and_falls_off_under_random_excitations(model):
    data = mujoco.MjData(model)
    data.qpos[:] = die_start(model)
    mujoco.mj_forward(model, data)
    die = model.body(DIE).id
    touching = {frozenset(model.geom_bodyid[[c.geom1, c.geom2]]) for c in data.contact[:data.ncon]}
    assert touching and all(die in pair and len(pair) == 2 for pair in touching), "the die rests on the hand"
    rng = np.random.default_rng(0)
    for _ in range(40):  # 0.4 s of 10 ms policy steps (MyoSuite's die task: 5 physics steps of 2 ms)
        data.ctrl[:] = rng.uniform(0, 1, MUSCLES)
        mujoco.mj_step(model, data, nstep=5)
    assert np.linalg.norm(data.xpos[die] - DIE_POS) > 0.2, "MyoSuite's drop threshold, passed at 0.15-0.27 s"
