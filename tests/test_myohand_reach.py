"""The MyoHand reach task (issue 62): where its targets are drawn, MyoSuite's success rule and reward terms on
hand-made states, and its observations, on the C MuJoCo twin (a few seconds). Its Warp-against-twin check is
test_myohand's, parametrized over both tasks (slow)."""

import math

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

import angora_jax as aj
from angora_jax.envs.myohand.model import JOINTS, MUSCLES
from angora_jax.envs.myohand.reach import TARGET_BOXES, TIPS, MyoHandReach, ReachReward

FLAT = 3 * len(TIPS)


@pytest.fixture(scope="module")
def model() -> mujoco.MjModel:
    """The hand as `MyoHandReach` builds it."""
    return aj.make("MyoHandReach", backend="cpu").task.model


@pytest.fixture(scope="module")
def task(model) -> MyoHandReach:
    return MyoHandReach(model)


def test_observations_hold_joints_fingertips_the_muscle_sense_and_the_goal():
    env = aj.make("MyoHandReach", backend="cpu")
    state = env.step(env.reset(jax.random.key(0)), jnp.full(MUSCLES, 0.3))
    sizes = {name: int(value.shape[-1]) for name, value in state.obs.__dict__.items()}
    assert sizes == {"proprioception": 2 * JOINTS + FLAT, "touch": 0, "muscle": 4 * MUSCLES, "vision": 0,
                     "goal": 2 * FLAT, "asymmetric": 0}
    data = env.data
    tips = np.concatenate([data.site(tip).xpos for tip in TIPS])
    np.testing.assert_allclose(state.obs.proprioception, np.concatenate([data.qpos, data.qvel, tips]), rtol=1e-6,
                               atol=1e-5)
    np.testing.assert_allclose(state.obs.muscle, np.concatenate(
        [data.actuator_length, data.actuator_velocity, data.actuator_force, data.act]), rtol=1e-6, atol=1e-6)
    target = np.asarray(state.info["target"])
    np.testing.assert_allclose(state.obs.goal, np.concatenate([target, target - tips]), atol=1e-5)
    variables = env.task_variables(state)
    assert variables["target"].shape == variables["tip_positions"].shape == (FLAT,)
    assert variables["muscle_excitation"].shape == (MUSCLES,)


def test_targets_are_drawn_in_myosuites_boxes_which_the_fingertips_reach(model, task):
    """Targets fill MyoSuite's boxes (its world frame); with the hand where MyoSuite puts it, each box's centre lies
    within 1 cm of where its fingertip gets over 4,000 random joint configurations (in myo-sim's own frame, about
    1.5 m away)."""
    low, high = np.asarray(TARGET_BOXES).transpose(1, 0, 2)
    targets = np.asarray(jax.vmap(task.draw_target)(jax.random.split(jax.random.key(1), 500)))
    assert targets.shape == (500, len(TIPS), 3)
    assert np.all(targets >= low - 1e-6) and np.all(targets <= high + 1e-6)
    assert np.all(np.ptp(targets, axis=0) > 0.8 * (high - low)), "targets spread over their boxes"
    data = mujoco.MjData(model)
    ids = [model.site(tip).id for tip in TIPS]
    rng = np.random.default_rng(0)
    reached = []
    for qpos in rng.uniform(model.jnt_range[:, 0], model.jnt_range[:, 1], (4000, JOINTS)):
        data.qpos[:] = qpos
        mujoco.mj_kinematics(model, data)
        reached.append(data.site_xpos[ids].copy())
    nearest = np.linalg.norm(np.asarray(reached) - (low + high) / 2, axis=-1).min(axis=0)
    assert np.all(nearest < 0.01), dict(zip(TIPS, nearest, strict=True))


def open_hand(model: mujoco.MjModel, act: float = 0.0):
    """A C MuJoCo snapshot of the open hand at rest (every joint at 0), every muscle at activation `act`, and its
    fingertips `(5, 3)`."""
    data = mujoco.MjData(model)
    data.act[:] = act
    mujoco.mj_forward(model, data)
    return MyoHandReach(model).snapshot(data), np.array([data.site(tip).xpos for tip in TIPS])


def info_at(tips: np.ndarray, distance: float) -> dict[str, jax.Array]:
    """A new episode's info whose targets lie `distance` (m, norm over the five tips) from `tips`."""
    offset = np.ones_like(tips) * distance / math.sqrt(tips.size)
    return {"target": jnp.asarray((tips + offset).ravel(), jnp.float32), "solved_steps": jnp.zeros((), jnp.int32),
            "steps": jnp.zeros((), jnp.int32)}


def test_a_step_is_solved_below_0_0625_m_and_an_episode_succeeds_after_more_than_5_solved_steps(model, task):
    """MyoSuite's definitions: the distance over the five tips below 0.0125 m x 5 is solved; an episode solved on more
    than 5 steps is a success. Reward: minus the distance, 4 x the bonus (1 below 0.125 m, 1 more below 0.0625 m),
    minus the mean squared activation."""
    snap, tips = open_hand(model)
    for distance, bonus in ((0.06, 2), (0.065, 1), (0.13, 0)):
        reward, terminated, _, metrics = task.evaluate(None, snap, snap, info_at(tips, distance))
        assert float(metrics["solved"]) == (distance < 0.0625) and not bool(terminated)
        np.testing.assert_allclose(metrics["tip_distance"], distance, atol=1e-5)
        np.testing.assert_allclose(metrics["mean_tip_distance"], distance / math.sqrt(len(TIPS)), atol=1e-5)
        np.testing.assert_allclose(reward, -distance + 4 * bonus, atol=1e-5)
    info, far = info_at(tips, 0.06), info_at(tips, 0.07)
    successes = []
    for _ in range(7):
        _, _, info, metrics = task.evaluate(None, snap, snap, info)
        successes.append(float(metrics["success"]))
    assert successes == [0, 0, 0, 0, 0, 1, 1], "a success after the sixth solved step"
    _, _, info, metrics = task.evaluate(None, snap, snap, {**info, "target": far["target"]})
    assert float(metrics["success"]) == 1.0 and int(info["solved_steps"]) == 7, "an unsolved step keeps the success"


def test_beyond_0_375_m_an_episode_fails_from_its_second_step(model, task):
    snap, tips = open_hand(model)
    info = info_at(tips, 0.4)
    reward, terminated, info, _ = task.evaluate(None, snap, snap, info)
    assert not bool(terminated), "MyoSuite does not check the first step"
    np.testing.assert_allclose(reward, -0.4, atol=1e-5)
    reward, terminated, _, _ = task.evaluate(None, snap, snap, info)
    assert bool(terminated)
    np.testing.assert_allclose(reward, -0.4 - 50, atol=1e-5)


def test_the_effort_cost_is_the_mean_squared_activation(model, task):
    (rest, tips), (excited, _) = open_hand(model, 0.0), open_hand(model, 0.5)
    info = info_at(tips, 0.1)
    reward, _, _, metrics = task.evaluate(None, excited, excited, info)
    np.testing.assert_allclose(metrics["effort"], 0.25, atol=1e-6)
    np.testing.assert_allclose(task.evaluate(None, rest, rest, info)[0] - reward, 0.25, atol=1e-5)
    free = MyoHandReach(model, ReachReward(effort=0.0))
    np.testing.assert_allclose(free.evaluate(None, excited, excited, info)[0], reward + 0.25, atol=1e-5)


def test_episodes_start_open_and_at_rest_and_options_are_checked():
    env = aj.make("MyoHandReach", backend="cpu")
    state = env.reset(jax.random.key(3))
    np.testing.assert_array_equal(state.obs.proprioception[:2 * JOINTS], np.zeros(2 * JOINTS))
    np.testing.assert_array_equal(env.task_variables(state)["muscle_activation"], np.zeros(MUSCLES))
    with pytest.raises(ValueError, match="Unknown reward coefficients"):
        aj.make("MyoHandReach", reward={"reac": 1.0}, backend="cpu")
    with pytest.raises(ValueError, match="reach_threshold must be > 0"):
        aj.make("MyoHandReach", reach_threshold=0.0, backend="cpu")
    with pytest.raises(ValueError, match="lacks the fingertip sites"):
        MyoHandReach(mujoco.MjModel.from_xml_string(
            '<mujoco><worldbody><body><joint name="j" range="-1 1"/><geom size="0.1"/></body></worldbody>'
            '<actuator><muscle joint="j" lengthrange="-1 1"/></actuator></mujoco>'))
