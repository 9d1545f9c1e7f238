"""docs/muscle-model.md states the MyoHand's muscle values as the compiled model has them: each muscle's peak force,
optimal length and length range, the time constants and curve parameters every muscle shares, the curves' values
that the page quotes, the tendons' wrap objects and the activation's rise and fall times. A model that changes
(another myo-sim, another MuJoCo) fails here until the page is updated. The hand compiles on C MuJoCo in about 2 s.
"""

from pathlib import Path

import mujoco
import numpy as np
import pytest

from angora_jax.envs.myohand.model import load_hand

PAGE = Path(__file__).resolve().parent.parent / "docs" / "muscle-model.md"


@pytest.fixture(scope="module")
def model() -> mujoco.MjModel:
    return load_hand()


@pytest.fixture(scope="module")
def page() -> str:
    return PAGE.read_text()


@pytest.fixture(scope="module")
def prose(page) -> str:
    """The page with every run of whitespace one space, so that a sentence is found across its line breaks."""
    return " ".join(page.split())


def test_each_muscles_peak_force_optimal_length_and_length_range_are_the_models(model, page):
    gain, lengths = model.actuator_gainprm, model.actuator_lengthrange
    optimal = (lengths[:, 1] - lengths[:, 0]) / (gain[:, 1] - gain[:, 0])
    rows = [f"| `{model.actuator(i).name}` | {gain[i, 2]:.1f} | {100 * optimal[i]:.2f} | "
            f"{100 * lengths[i, 0]:.1f} - {100 * lengths[i, 1]:.1f} |" for i in range(model.nu)]
    assert [row for row in rows if row not in page] == []
    assert page.count("\n| `") == model.nu, "one table row per muscle, no other rows naming a muscle first"


def test_the_shared_time_constants_and_curve_parameters_are_the_models(model, page):
    dynamics = np.unique(model.actuator_dynprm[:, :3], axis=0)
    curves = np.unique(model.actuator_gainprm[:, [0, 1, 4, 5, 6, 7, 8]], axis=0)
    assert len(dynamics) == 1 and len(curves) == 1, "every muscle shares them"
    (tau_act, tau_deact, smoothing), (low, high, lmin, lmax, vmax, fpmax, fvmax) = dynamics[0], curves[0]
    assert smoothing == 0 and np.allclose(model.actuator_biasprm, model.actuator_gainprm)
    assert np.all(model.actuator_gainprm[:, 2] > 0), "peak forces given per muscle, so scale is unused"
    for row in [f"| tau_act | {tau_act:g} s |", f"| tau_deact | {tau_deact:g} s |", f"| range | {low:g} - {high:g} |",
                f"| lmin, lmax | {lmin:g}, {lmax:g} |", f"| vmax | {vmax:g} L0/s |", f"| fvmax | {fvmax:g} |",
                f"| fpmax | {fpmax:g} |"]:
        assert row in page


def test_the_curve_values_the_page_quotes_are_mujocos(model, prose):
    """FL 0.5 at 0.75 and 1.3, FV 0.25 at half the shortening vmax and fvmax from 0.3 L0/s on, FP 0.65 at 1.3 and 1.95
    at 1.6: MuJoCo's curves for the hand's parameters, evaluated with a unit L0 and F0."""
    prm = model.actuator_gainprm[0, :9].copy()
    prm[2] = 1.0
    low, high = prm[0], prm[1]
    lengthrange = np.array([0.0, high - low])  # L0 = 1, so a length is its normalised length minus `low`

    def gain(length: float, velocity: float = 0.0) -> float:
        return -mujoco.mju_muscleGain(length - low, velocity, lengthrange, 1.0, prm)

    def passive(length: float) -> float:
        return -mujoco.mju_muscleBias(length - low, lengthrange, 1.0, prm)

    assert gain(0.75) == pytest.approx(0.5) and gain(1.3) == pytest.approx(0.5) and gain(1.0) == pytest.approx(1)
    assert gain(0.5) == pytest.approx(0, abs=1e-9) and gain(1.6) == pytest.approx(0, abs=1e-9)
    assert gain(1.0, -0.75) == pytest.approx(0.25) and gain(1.0, -1.5) == pytest.approx(0, abs=1e-9)
    assert gain(1.0, 0.2) < 1.19 and gain(1.0, 0.3) == pytest.approx(1.2) and gain(1.0, 3.0) == pytest.approx(1.2)
    assert passive(1.0) == 0 and passive(1.3) == pytest.approx(0.65) and passive(1.6) == pytest.approx(1.95)
    assert "0 up to L = 1, 0.65 at 1.3, 1.95 at 1.6" in prose and "reached from 0.3 L0/s (0.2 vmax) on" in prose


def test_the_tendons_wrap_objects_and_the_activations_rise_and_fall_are_as_stated(model, prose):
    kinds = {kind: int(np.sum(model.wrap_type == kind)) for kind in
             (mujoco.mjtWrap.mjWRAP_SITE, mujoco.mjtWrap.mjWRAP_SPHERE, mujoco.mjtWrap.mjWRAP_CYLINDER)}
    assert (f"through {kinds[mujoco.mjtWrap.mjWRAP_SITE]} sites, wrapping over {kinds[mujoco.mjtWrap.mjWRAP_SPHERE]} "
            f"spheres and {kinds[mujoco.mjtWrap.mjWRAP_CYLINDER]} cylinders ({model.nwrap} wrap points") in prose
    assert not model.tendon_stiffness.any() and not model.tendon_damping.any() and not model.tendon_limited.any()
    data = mujoco.MjData(model)
    data.ctrl[:] = 1
    rise = 0
    while data.act[0] < 0.9:
        mujoco.mj_step(model, data)
        rise += 1
    data.ctrl[:] = 0
    fall = 0
    while data.act[0] > 0.1:
        mujoco.mj_step(model, data)
        fall += 1
    step_ms = 1000 * model.opt.timestep
    assert f"a = 0.9 in {rise * step_ms:.0f} ms" in prose and f"back to 0.1 in {fall * step_ms:.0f} ms" in prose


def test_the_muscle_modality_is_as_the_page_states_it(model, prose):
    """Its size and the order of its four parts, each a table row, are what `MuscleHandTask.muscles` returns."""
    from angora_jax.envs.myohand.pose import MyoHandPose

    data = mujoco.MjData(model)
    data.ctrl[:] = 0.5
    mujoco.mj_step(model, data)
    task = MyoHandPose(model)
    modality = np.asarray(task.muscles(task.snapshot(data)))
    parts = {"length": data.actuator_length, "velocity": data.actuator_velocity, "force": data.actuator_force,
             "activation": data.act}
    np.testing.assert_allclose(modality, np.concatenate(list(parts.values())), rtol=1e-6, atol=1e-6)
    assert (f"(`MuscleHandTask.muscles`), {modality.size} numbers: the {model.nu} muscles' lengths, then their "
            "velocities, then their forces, then their activations, each in actuator order") in prose
    assert all(f"| {part} | " in prose for part in parts)
