"""Gymnasium's MuJoCo tasks (v5) on our stack: step for step the same observations, rewards and terminations as
Gymnasium's own environments from the same states, and the batched MJX path close to the C MuJoCo twin."""

import importlib.util

import gymnasium as gym
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from quick_compile import compile_quickly

import angora_jax as aj
from angora_jax.envs.locomotion import EPISODE_STEPS
from angora_jax.envs.locomotion.tasks import GAITS

GYMNASIUM_IDS = {name: f"{name}-v5" for name in [*GAITS, "InvertedPendulum", "InvertedDoublePendulum", "Reacher"]}
# What makes a task Gymnasium's own: Humanoid runs Newton unless asked for humanoid.xml's PGS (the C twin only).
GYMNASIUM_OPTIONS = {"Humanoid": {"solver": "pgs"}}
HUMANOID_BATCH = 2


@pytest.mark.parametrize("name", GYMNASIUM_IDS)
def test_steps_match_gymnasium_v5_from_the_same_state(name):
    """40 random actions (or until Gymnasium terminates) from our start, copied into Gymnasium's env: observation
    within 1e-5 + 1e-6 x |value| and reward within 1e-5 at every step (float32 task logic against Gymnasium's
    float64: Humanoid's contact forces reach 10^3 N, which float32 rounds by up to 3e-5), the same termination. Ant's
    and Humanoid's contact forces (cfrc_ext) are not all zero on the way."""
    env = aj.make(name, backend="cpu", **GYMNASIUM_OPTIONS.get(name, {}))
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
    touched = False
    for _ in range(40):
        action = rng.uniform(reference.action_space.low, reference.action_space.high).astype(np.float32)
        obs, reward, terminated, _, _ = reference.step(action)
        state = env.step(state, jnp.asarray(action))
        np.testing.assert_allclose(state.final_obs.proprioception, obs, rtol=1e-6, atol=1e-5)
        assert float(state.reward) == pytest.approx(reward, abs=1e-5)
        assert bool(state.done) == terminated
        touched |= bool(np.any(reference.data.cfrc_ext))
        if terminated:
            break
    assert touched or not env.task.body_dynamics


# Gymnasium's start noise: uniform in +-scale around qpos0 / qvel0, on (qpos, qvel) coordinates; Reacher draws its
# arm's joints and velocities so and places the target (the last two qpos, at rest) in a 0.2 m disk.
START_NOISE = {"Hopper": (5e-3, 5e-3, slice(None)), "Humanoid": (1e-2, 1e-2, slice(None)),
               "Reacher": (0.1, 5e-3, slice(0, 2))}


@pytest.mark.parametrize("name", START_NOISE)
def test_starts_follow_gymnasium_distribution(name):
    """Our starts (JAX PRNG) and Gymnasium's, 200 each, depart from qpos0 / qvel0 as uniform noise of the task's scale
    s does: every |offset| within s, the largest above 0.9 s (missed by a true uniform with probability 0.9^200) and
    each coordinate's standard deviation within 15% of s / sqrt(3) (about 4.5 sampling standard errors). Starts
    without noise, or with twice or half of it, fail. Reacher's target lies in the 0.2 m disk, at rest."""
    env = aj.make(name, backend="cpu")
    task = env.task
    keys = jax.random.split(jax.random.key(0), 200)
    qpos = np.stack([task.initial_qpos(k) for k in keys])
    qvel = np.stack([task.initial_qvel(jax.random.fold_in(k, 1)) for k in keys])
    reference = gym.make(GYMNASIUM_IDS[name]).unwrapped
    theirs = {"qpos": [], "qvel": []}
    for seed in range(200):
        reference.reset(seed=seed)
        theirs["qpos"].append(reference.data.qpos.copy())
        theirs["qvel"].append(reference.data.qvel.copy())
    qpos_scale, qvel_scale, noisy = START_NOISE[name]
    for who, (positions, velocities) in {"ours": (qpos, qvel), "Gymnasium's": (np.stack(theirs["qpos"]),
                                                                                np.stack(theirs["qvel"]))}.items():
        for field, values, origin, scale in [("qpos", positions, reference.init_qpos, qpos_scale),
                                             ("qvel", velocities, reference.init_qvel, qvel_scale)]:
            offsets = (values - origin)[:, noisy]
            where = f"{who} {field} of {name}"
            assert np.abs(offsets).max() <= scale * (1 + 1e-5), where
            assert np.abs(offsets).max(0).min() > 0.9 * scale, where
            np.testing.assert_allclose(offsets.std(0), scale / np.sqrt(3), rtol=0.15, err_msg=where)
    if name == "Reacher":
        assert np.all(np.linalg.norm(qpos[:, -2:], axis=1) < 0.2) and np.all(qvel[:, -2:] == 0)


@pytest.mark.slow
def test_mjx_path_tracks_the_c_mujoco_twin():
    """Swimmer (no termination, no contacts: the quickest to compile) batched on MJX's JAX implementation against C
    MuJoCo from the same key and actions: MJX computes in float32, so the states drift apart slowly; within 1e-2
    after 20 steps."""
    mjx_env, cpu_env = aj.make("Swimmer", impl="jax"), aj.make("Swimmer", backend="cpu")
    actions = np.random.default_rng(0).uniform(-1, 1, (20, 2)).astype(np.float32)
    state = compile_quickly(mjx_env.reset, jax.random.key(3))(jax.random.key(3))
    step = compile_quickly(mjx_env.step, state, jnp.asarray(actions[0]))
    twin = cpu_env.reset(jax.random.key(3))
    np.testing.assert_allclose(state.obs.proprioception, twin.obs.proprioception, atol=1e-5)
    for action in actions:
        state, twin = step(state, jnp.asarray(action)), cpu_env.step(twin, jnp.asarray(action))
        np.testing.assert_allclose(state.reward, twin.reward, atol=1e-2)
    np.testing.assert_allclose(state.obs.proprioception, twin.obs.proprioception, atol=1e-2)


WARP = pytest.param("warp", marks=pytest.mark.skipif(importlib.util.find_spec("warp") is None,
                                                    reason="MuJoCo Warp needs warp-lang (pip install warp-lang)"))


@pytest.fixture(scope="module", params=["jax", WARP])
def humanoid_on_mjx(request):
    """Humanoid on one of MJX's implementations and its C MuJoCo twin (Newton on both), with the MJX path's batched
    reset and step compiled once, quickly (tests/quick_compile.py; JAX: about 60 s on 2 CPU cores instead of 90;
    Warp, which computes the contact forces inside its step, runs where warp-lang is installed, on a GPU or the
    CPU)."""
    env = aj.make("Humanoid", impl=request.param).sized_for(HUMANOID_BATCH)
    keys = jax.random.split(jax.random.key(3), HUMANOID_BATCH)
    reset = compile_quickly(jax.vmap(env.reset), keys)
    actions = jnp.zeros((HUMANOID_BATCH, env.task.model.nu), jnp.float32)
    return env, aj.make("Humanoid", backend="cpu"), reset, compile_quickly(jax.vmap(env.step), reset(keys), actions)


@pytest.mark.slow
def test_mjx_path_computes_humanoids_body_dynamics_as_the_c_mujoco_twin(humanoid_on_mjx):
    """Humanoid batched on MJX (float32) against C MuJoCo (float64) from the same keys and random actions until each
    episode ends (29 and 24 steps: it falls): the start within 1e-5 + 1e-5 x |value| (its drawn quaternion is not
    normalised, as in C MuJoCo), then joints, cinert, cvel and actuator forces within 1e-3 + 1e-4 x |value|,
    the contact forces that rne_postconstraint computes after the step within 1e-2 + 1e-3 x |value| (float32
    constraint solves; measured: at most 1.6e-2), rewards within 1e-3 (measured 1.4e-4),
    the same terminations, and contacts in at least a third of the steps."""
    env, cpu, reset, step = humanoid_on_mjx
    keys = jax.random.split(jax.random.key(3), HUMANOID_BATCH)
    actions = np.random.default_rng(0).uniform(-0.4, 0.4, (32, HUMANOID_BATCH, env.task.model.nu)).astype(np.float32)
    states = [reset(keys)]
    for action in actions:
        states.append(step(states[-1], jnp.asarray(action)))
    forces = slice(-(env.task.model.nbody - 1) * 6, None)  # cfrc_ext, the observation's last part
    for b, key in enumerate(keys):
        twin, touched = cpu.reset(key), []  # the stateful twin runs one episode at a time
        np.testing.assert_allclose(states[0].obs.proprioception[b], twin.obs.proprioception, rtol=1e-5, atol=1e-5)
        for t, action in enumerate(actions[:, b]):
            twin, ours = cpu.step(twin, jnp.asarray(action)), states[t + 1]
            obs, expected = np.asarray(ours.final_obs.proprioception[b]), np.asarray(twin.final_obs.proprioception)
            np.testing.assert_allclose(obs[:forces.start], expected[:forces.start], rtol=1e-4, atol=1e-3)
            np.testing.assert_allclose(obs[forces], expected[forces], rtol=1e-3, atol=1e-2)
            assert float(ours.reward[b]) == pytest.approx(float(twin.reward), abs=1e-3)
            assert bool(ours.done[b]) == bool(twin.done)
            touched.append(bool(np.any(expected[forces])))
            if twin.done:
                break
        assert twin.done and sum(touched) >= len(touched) / 3


def test_humanoid_refuses_pgs_on_mjx():
    """MJX has no PGS solver (Humanoid's model asks for it): the batched path refuses it and says so."""
    with pytest.raises(ValueError, match="MJX has no PGS solver"):
        aj.make("Humanoid", solver="pgs")
