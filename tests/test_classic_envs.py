"""Classic tasks follow gymnasium's dynamics step for step and the Env contract (termination, truncation)."""

import gymnasium as gym
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from angora_jax.envs.classic import Acrobot, CartPole, MountainCar, Pendulum
from angora_jax.envs.registry import make

# Every program here is a step or a few (tests/quick_compile.py).
pytestmark = pytest.mark.usefixtures("quick_file_compiles")


@pytest.fixture(scope="module")
def cartpole():
    env = CartPole()
    return env, jax.jit(env.reset), jax.jit(env.step)


@pytest.fixture(scope="module")
def pendulum():
    env = Pendulum()
    return env, jax.jit(env.reset), jax.jit(env.step)


def test_registered_by_name():
    assert isinstance(make("CartPole"), CartPole)
    assert make("Pendulum", max_episode_steps=50).max_episode_steps == 50


def test_cartpole_matches_gymnasium(cartpole):
    env, reset, step = cartpole
    state = reset(jax.random.key(0))
    reference = gym.make("CartPole-v1").unwrapped
    reference.reset(seed=0)
    reference.state = np.asarray(state.physics, np.float64)
    actions = [1, 1, 0, 1, 0, 0, 0, 1, 1, 1] * 3
    for action in actions:
        obs, reward, terminated, _, _ = reference.step(action)
        state = step(state, jnp.int32(action))
        np.testing.assert_allclose(state.final_obs.proprioception, obs, rtol=1e-4, atol=1e-5)
        assert float(state.reward) == reward
        assert bool(state.done) == terminated
        if terminated:
            break


def test_cartpole_terminates_when_pushed_one_way(cartpole):
    env, reset, step = cartpole
    state = reset(jax.random.key(1))
    steps = 0
    while not state.done and steps < 100:
        state = step(state, jnp.int32(1))
        steps += 1
    assert float(state.done) == 1.0 and float(state.truncated) == 0.0 and steps < 30
    assert abs(float(state.final_obs.proprioception[2])) > env.theta_limit


def test_pendulum_matches_gymnasium_and_truncates(pendulum):
    env, reset, step = pendulum
    state = reset(jax.random.key(0))
    reference = gym.make("Pendulum-v1").unwrapped
    reference.reset(seed=0)
    reference.state = np.asarray(state.physics, np.float64)
    torques = np.linspace(-2.5, 2.5, 20)
    for torque in torques:
        obs, reward, _, _, _ = reference.step(np.array([torque], np.float32))
        state = step(state, jnp.array([torque]))
        np.testing.assert_allclose(state.obs.proprioception, obs, rtol=1e-4, atol=1e-4)
        np.testing.assert_allclose(float(state.reward), reward, rtol=1e-4, atol=1e-4)
    for _ in range(env.max_episode_steps - len(torques)):
        state = step(state, jnp.array([0.0]))
    assert float(state.done) == 1.0 and float(state.truncated) == 1.0 and int(state.steps) == 0


# task -> (gymnasium id, states to start steps from, action sampler). Acrobot's velocities stay within half their
# bounds (4 pi, 9 pi rad/s): near the bounds one float32 Runge-Kutta step of 0.2 s differs from gymnasium's float64
# by up to 1.5e-5 of the value.
PARITY = {
    "Acrobot": ("Acrobot-v1", lambda rng: rng.uniform([-np.pi, -np.pi, -6.3, -14.1], [np.pi, np.pi, 6.3, 14.1]),
                lambda rng: int(rng.integers(3))),
    "MountainCar": ("MountainCar-v0", lambda rng: rng.uniform([-1.2, -0.07], [0.6, 0.07]),
                    lambda rng: int(rng.integers(3))),
    "MountainCarContinuous": ("MountainCarContinuous-v0", lambda rng: rng.uniform([-1.2, -0.07], [0.6, 0.07]),
                              lambda rng: rng.uniform(-1.5, 1.5, (1,))),
}


# Acrobot's RK4 step compiles in 7 s: `make test-fast` checks the other tasks' steps.
@pytest.mark.parametrize("task", [pytest.param(task, marks=pytest.mark.slow) if task == "Acrobot" else task
                                  for task in PARITY])
def test_one_step_from_the_same_state_matches_gymnasium(task):
    """From 200 random states (terminal ones included) and actions, one step of ours and of gymnasium's env agree in
    observation (1e-5), reward and termination; our reset draws from gymnasium's start distribution."""
    name, draw_state, draw_action = PARITY[task]
    env = make(task)
    step = jax.jit(jax.vmap(env.advance))
    reference = gym.make(name).unwrapped
    reference.reset(seed=0)
    rng = np.random.default_rng(0)
    states = np.stack([draw_state(rng) for _ in range(200)]).astype(np.float32)
    actions = [draw_action(rng) for _ in range(200)]
    batch = jax.vmap(env.reset)(jax.random.split(jax.random.key(0), 200)).replace(physics=jnp.asarray(states))
    ended, _ = step(batch, jnp.asarray(np.stack(actions)))
    terminations = 0
    for i, (state, action) in enumerate(zip(states, actions, strict=True)):
        reference.state = np.asarray(state, np.float32 if task.startswith("Mountain") else np.float64)
        obs, reward, terminated, _, _ = reference.step(action)
        np.testing.assert_allclose(ended.obs.proprioception[i], obs, rtol=1e-5, atol=1e-5)
        assert float(ended.reward[i]) == pytest.approx(reward, abs=1e-5)
        assert bool(ended.done[i]) == terminated
        terminations += terminated
    assert terminations > 0, "the states drawn must include some that end the episode"
    starts = np.asarray(jax.vmap(env.reset)(jax.random.split(jax.random.key(1), 500)).obs.proprioception)
    gym_starts = np.stack([reference.reset(seed=seed)[0] for seed in range(500)])
    np.testing.assert_allclose(starts.min(0), gym_starts.min(0), atol=0.02)
    np.testing.assert_allclose(starts.max(0), gym_starts.max(0), atol=0.02)


@pytest.mark.parametrize("task, coast", [("MountainCar", 1), ("MountainCarContinuous", [0.0])])
def test_the_mountain_cars_left_wall_stops_the_car(task, coast):
    """Gymnasium's left wall is inelastic: a car driven past position -1.2 stops there (velocity 0), and the slope
    then rolls it back right. From -1.19 at -0.05 per step without a push, the car would reach
    -1.19 - 0.05 + 0.0025 cos(3.57) = -1.238; random states reach the wall too rarely for the parity test to see it."""
    env = make(task)
    state = env.reset(jax.random.key(0))
    state = state.replace(physics=jnp.array([-1.19, -0.05], jnp.float32))
    state, _ = env.advance(state, jnp.asarray(coast))
    np.testing.assert_allclose(state.obs.proprioception, [-1.2, 0.0], atol=1e-7)
    state, _ = env.advance(state, jnp.asarray(coast))
    assert float(state.obs.proprioception[1]) == pytest.approx(-0.0025 * np.cos(-3.6), rel=1e-5)


def test_new_classic_tasks_are_registered_with_gymnasium_episode_lengths():
    assert isinstance(make("Acrobot"), Acrobot) and make("Acrobot").max_episode_steps == 500
    assert make("MountainCar").max_episode_steps == 200 and make("MountainCar").action_spec.num_actions == 3
    continuous = make("MountainCarContinuous")
    assert isinstance(continuous, MountainCar) and continuous.continuous and continuous.max_episode_steps == 999
