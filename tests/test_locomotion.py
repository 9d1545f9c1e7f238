"""Gymnasium's MuJoCo tasks (v5) on our stack: step for step the same observations, rewards and terminations as
Gymnasium's own environments from the same states, and the batched MJX path close to the C MuJoCo twin."""

import gymnasium as gym
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import angora_jax as aj
from angora_jax.envs.locomotion import EPISODE_STEPS
from angora_jax.envs.locomotion.tasks import GAITS

GYMNASIUM_IDS = {name: f"{name}-v5" for name in [*GAITS, "InvertedPendulum", "InvertedDoublePendulum", "Reacher"]}


@pytest.mark.parametrize("name", GYMNASIUM_IDS)
def test_steps_match_gymnasium_v5_from_the_same_state(name):
    """40 random actions (or until Gymnasium terminates) from our start, copied into Gymnasium's env: observation and
    reward within 1e-5 at every step (float32 task logic against Gymnasium's float64), the same termination."""
    env = aj.make(name, backend="cpu")
    reference = gym.make(GYMNASIUM_IDS[name])
    assert env.max_episode_steps == reference.spec.max_episode_steps == EPISODE_STEPS.get(name, 1000)
    assert env.dt == pytest.approx(reference.unwrapped.dt)
    reference = reference.unwrapped
    reference.reset(seed=0)
    state = env.reset(jax.random.key(0))
    reference.set_state(env.data.qpos.copy(), env.data.qvel.copy())
    np.testing.assert_allclose(state.obs.proprioception, reference._get_obs(), atol=1e-5)
    np.testing.assert_array_equal(env.action_spec.low, reference.action_space.low)
    np.testing.assert_array_equal(env.action_spec.high, reference.action_space.high)
    rng = np.random.default_rng(1)
    for _ in range(40):
        action = rng.uniform(reference.action_space.low, reference.action_space.high).astype(np.float32)
        obs, reward, terminated, _, _ = reference.step(action)
        state = env.step(state, jnp.asarray(action))
        np.testing.assert_allclose(state.final_obs.proprioception, obs, atol=1e-5)
        assert float(state.reward) == pytest.approx(reward, abs=1e-5)
        assert bool(state.done) == terminated
        if terminated:
            break


@pytest.mark.parametrize("name", ["Hopper", "Reacher"])
def test_starts_follow_gymnasium_distribution(name):
    """Our starts (JAX PRNG) lie where Gymnasium's do: qpos0 plus noise of the task's scale; Reacher's target in
    the 0.2 m disk, at rest."""
    env = aj.make(name, backend="cpu")
    task = env.task
    keys = jax.random.split(jax.random.key(0), 200)
    qpos = np.stack([task.initial_qpos(k) for k in keys])
    qvel = np.stack([task.initial_qvel(jax.random.fold_in(k, 1)) for k in keys])
    reference = gym.make(GYMNASIUM_IDS[name]).unwrapped
    theirs = []
    for seed in range(200):
        reference.reset(seed=seed)
        theirs.append(np.concatenate([reference.data.qpos, reference.data.qvel]))
    theirs, ours = np.stack(theirs), np.concatenate([qpos, qvel], axis=1)
    np.testing.assert_allclose(ours.min(0), theirs.min(0), atol=0.02)
    np.testing.assert_allclose(ours.max(0), theirs.max(0), atol=0.02)
    if name == "Reacher":
        assert np.all(np.linalg.norm(qpos[:, -2:], axis=1) < 0.2) and np.all(qvel[:, -2:] == 0)


def test_mjx_path_tracks_the_c_mujoco_twin():
    """Swimmer (no termination, no contacts: the quickest to compile) batched on MJX's JAX implementation against C
    MuJoCo from the same key and actions: MJX computes in float32, so the states drift apart slowly; within 1e-2
    after 20 steps."""
    mjx_env, cpu_env = aj.make("Swimmer", impl="jax"), aj.make("Swimmer", backend="cpu")
    actions = np.random.default_rng(0).uniform(-1, 1, (20, 2)).astype(np.float32)
    step = jax.jit(mjx_env.step)
    state, twin = jax.jit(mjx_env.reset)(jax.random.key(3)), cpu_env.reset(jax.random.key(3))
    np.testing.assert_allclose(state.obs.proprioception, twin.obs.proprioception, atol=1e-5)
    for action in actions:
        state, twin = step(state, jnp.asarray(action)), cpu_env.step(twin, jnp.asarray(action))
        np.testing.assert_allclose(state.reward, twin.reward, atol=1e-2)
    np.testing.assert_allclose(state.obs.proprioception, twin.obs.proprioception, atol=1e-2)
