"""The gymnasium view: registered ids, spaces, check_env, determinism and rendering."""


import gymnasium
import jax.numpy as jnp
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import angora_jax  # noqa: F401  (registers the gymnasium ids)
from angora_jax.envs.gym_view import GymEnv


@pytest.fixture(scope="module")
def reach():
    env = gymnasium.make("AngoraJax/ShadowHandReach-v0", render_mode="rgb_array", max_episode_steps=5)
    yield env
    env.close()


def test_every_shipped_task_has_a_gymnasium_id():
    """Shipped tasks, not every registered one: a test file's own task (test_analysis_methods' ThreeTorques, registered
    when pytest collects it in every worker) has an id only once `register_gymnasium_envs()` is called again."""
    from angora_jax.envs.registry import SHIPPED_TASKS

    assert set(SHIPPED_TASKS) <= set(angora_jax.list_tasks())
    for task in SHIPPED_TASKS:
        assert f"AngoraJax/{task}-v0" in gymnasium.registry


def test_reach_spaces(reach):
    space = reach.observation_space
    assert set(space.spaces) == {"proprioception", "goal", "asymmetric"}
    assert space["proprioception"].shape == (48,) and space["goal"].shape == (20,)
    assert reach.action_space.shape == (20,) and np.all(reach.action_space.low == -1)


def test_reach_passes_check_env(reach):
    check_env(reach.unwrapped, skip_render_check=True)


def test_reach_episode_is_seeded_and_truncates(reach):
    first, _ = reach.reset(seed=3)
    again, _ = reach.reset(seed=3)
    np.testing.assert_array_equal(first["goal"], again["goal"])
    for t in range(5):
        obs, reward, terminated, truncated, info = reach.step(reach.action_space.sample())
        assert reach.observation_space.contains(obs) and np.isfinite(reward) and not terminated
        assert set(info) == {"success", "goal_distance"}
        assert truncated == (t == 4)


def test_reach_renders_frames_that_change(reach, opengl):
    reach.reset(seed=0)
    before = reach.render()
    for _ in range(3):
        reach.step(np.ones(20, np.float32))
    after = reach.render()
    assert before.shape == (240, 320, 3) and before.dtype == np.uint8
    assert before.std() > 5, "a frame of one colour shows nothing"
    assert np.abs(before.astype(int) - after.astype(int)).mean() > 0.5, "the hand moved, the frame must change"


def test_pure_jax_task_through_gymnasium_and_errors():
    cartpole = gymnasium.make("AngoraJax/CartPole-v0")
    check_env(cartpole.unwrapped, skip_render_check=True)
    with pytest.raises(ValueError, match="no MuJoCo scene to render"):
        GymEnv("CartPole", render_mode="rgb_array")
    with pytest.raises(ValueError, match="render_mode must be"):
        GymEnv("ShadowHandReach", render_mode="human")


def test_an_action_outside_a_discrete_space_and_a_frame_of_no_pixels_are_refused():
    """CartPole through gymnasium took action 5 (or 0.5) of its Discrete(2) without a word, stepping as some valid
    action; a frame size of 0 or -5 pixels (or "320") was taken, to fail or draw an empty frame at the first render."""
    env = GymEnv("CartPole")
    env.reset(seed=0)
    for action in (5, -1, 0.5):
        with pytest.raises(ValueError, match=rf"^CartPole takes one of the actions 0 to 1 \(its action_space is "
                                             rf"Discrete\(2\)\), got {action!r}\.$"):
            env.step(action)
    for action in (1, np.int64(0), np.array(1), jnp.int32(1)):
        env.step(action)
    for size, given in (({"width": 0}, "0 x 240"), ({"height": -5}, "320 x -5"), ({"width": "320"}, "'320' x 240")):
        with pytest.raises(ValueError, match=rf"^Frames are whole numbers of pixels, at least 1 x 1: width and "
                                             rf"height, got {given}\.$"):
            GymEnv("CartPole", **size)


def test_a_non_finite_action_in_a_box_space_is_refused():
    """Pendulum through gymnasium took a NaN torque without a word and carried on with a NaN state: every later
    observation and reward was NaN."""
    env = GymEnv("Pendulum")
    env.reset(seed=0)
    for action in (np.array([np.nan], np.float32), np.array([np.inf]), [-np.inf]):
        with pytest.raises(ValueError, match=r"^Pendulum takes actions of finite numbers within its action_space "
                                             r"Box\(-2\.0, 2\.0, \(1,\), float32\), got .*(nan|inf)"):
            env.step(action)
    obs, reward, *_ = env.step(np.array([1.0], np.float32))
    assert np.isfinite(obs["proprioception"]).all() and np.isfinite(reward)
