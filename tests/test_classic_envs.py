"""Classic tasks follow gymnasium's dynamics step for step and the Env contract (termination, truncation)."""

import gymnasium as gym
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from angora_jax.envs.classic import CartPole, Pendulum
from angora_jax.envs.registry import make


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
