"""In-hand cube reorientation (`ShadowHandCube`): episode rules and reward on the task's pure functions, one compiled
batched MJX rollout for shapes and MJX/CPU parity, and one tiny training run.

The rule tests call `evaluate`/`observe` eagerly on snapshots taken from one CPU-twin reset and edited (no MJX
compile). MJX compiles of the cube scene take about a minute on a CPU, so the module compiles reset plus rollout
once, as one program, and the training test compiles one cycle.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import angora_jax as aj
from angora_jax.envs.shadow_hand.ihom import Ihom, IhomReward, angular_distance, quat_mul, random_rotation
from angora_jax.ppo import NetworkConfig, PPOConfig, train

BATCH = 2
STEPS = 25  # 2 s of simulated time
NOISE = 0.2  # share of each actuator's half range
SIZES = {"proprioception": 48, "touch": 97, "vision": 7, "goal": 4, "asymmetric": 25}


def about_x(angle: float) -> jax.Array:
    return jnp.array([np.cos(angle / 2), np.sin(angle / 2), 0.0, 0.0], jnp.float32)


@pytest.fixture(scope="module")
def cpu():
    return aj.make("ShadowHandCube", backend="cpu")


@pytest.fixture(scope="module")
def start(cpu):
    """A snapshot at an episode's start, and its info."""
    state = cpu.reset(jax.random.key(3))
    return state.physics, state.info


def with_cube(task: Ihom, snap, quat=None, height=None):
    """`snap` with the cube turned to `quat` and/or its centre moved to `height` (m)."""
    qpos = snap.qpos
    if quat is not None:
        qpos = qpos.at[task.cube_qpos + 3:task.cube_qpos + 7].set(quat)
    if height is not None:
        qpos = qpos.at[task.cube_qpos + 2].set(height)
    return snap.replace(qpos=qpos)


def test_quaternion_helpers():
    q = random_rotation(jax.random.key(0))
    assert float(angular_distance(q, -q)) == pytest.approx(0.0, abs=1e-6), "q and -q are the same orientation"
    assert float(angular_distance(q, quat_mul(q, about_x(0.3)))) == pytest.approx(0.3, abs=1e-5)
    assert float(angular_distance(about_x(0.0), about_x(np.pi))) == pytest.approx(np.pi, abs=1e-5)
    keys = jax.random.split(jax.random.key(1), 64)
    angles = [float(angular_distance(about_x(0.0), random_rotation(k))) for k in keys]
    assert 0.0 <= min(angles) and max(angles) <= np.pi + 1e-6 and np.std(angles) > 0.3


def test_registry_options_and_errors(cpu):
    assert "ShadowHandCube" in aj.list_tasks()
    assert cpu.dt == pytest.approx(0.08) and cpu.frame_skip == 10 and cpu.task.steps_per_goal == 100
    assert cpu.max_episode_steps == 50 * 100
    with pytest.raises(ValueError, match="whole multiple of the timestep"):
        aj.make("ShadowHandCube", backend="cpu", control_dt=0.07)
    with pytest.raises(ValueError, match="Unknown reward coefficients.*drop_penalty"):
        aj.make("ShadowHandCube", backend="cpu", reward={"dropping_penalty": 1.0})
    with pytest.raises(ValueError, match="iterations"):
        aj.make("ShadowHandCube", backend="cpu", physics={"iterations": 0})
    with pytest.raises(ValueError, match="success_angle > 0"):
        Ihom(cpu.task.model, success_angle=0.0)


def test_initial_state_holds_the_cube_above_the_palm(cpu, start):
    snap, info = start
    task = cpu.task
    assert float(snap.qpos[task.cube_qpos + 2] - snap.xpos[task.palm_id, 2]) > 0.04
    np.testing.assert_allclose(snap.qpos[task.hand_qpos], 0.0, atol=1e-6)  # Gym's flat, open hand
    assert float(jnp.linalg.norm(info["goal"])) == pytest.approx(1.0, abs=1e-5)
    assert int(info["goals_reached"]) == 0 and int(info["goal_steps"]) == 0 and not bool(info["time_out"])
    obs = task.observe(snap, info)
    assert obs.sizes() == SIZES
    np.testing.assert_allclose(obs.goal, info["goal"])
    np.testing.assert_allclose(obs.vision, snap.qpos[task.cube_qpos:task.cube_qpos + 7])


def test_goal_reached_gives_bonus_and_a_new_goal(cpu, start):
    snap, info = start
    task = cpu.task
    goal = info["goal"]
    prev = with_cube(task, snap, quat=quat_mul(goal, about_x(1.0)))
    now = with_cube(task, snap, quat=quat_mul(goal, about_x(0.3)))  # within eta = 0.4 rad
    info = dict(info, goal_steps=jnp.int32(57))
    reward, terminated, after, metrics = task.evaluate(jax.random.key(5), prev, now, info)
    assert float(reward) == pytest.approx((1.0 - 0.3) + 5.0 - 0.1, abs=1e-4)
    assert not bool(terminated) and not bool(after["time_out"])
    assert int(after["goals_reached"]) == 1 and int(after["goal_steps"]) == 0, "the goal timer restarts"
    assert float(angular_distance(after["goal"], goal)) > 1e-3, "a new goal is drawn"
    assert float(metrics["goals_reached"]) == 1.0 and float(metrics["goal_distance"]) == pytest.approx(0.3, abs=1e-4)
    # Not yet reached: progress only, the same goal, the timer runs on.
    far = with_cube(task, snap, quat=quat_mul(goal, about_x(0.5)))
    reward, _, after, _ = task.evaluate(jax.random.key(5), prev, far, info)
    assert float(reward) == pytest.approx(0.5 - 0.1, abs=1e-4)
    np.testing.assert_array_equal(after["goal"], goal)
    assert int(after["goal_steps"]) == 58 and int(after["goals_reached"]) == 0


def test_drop_terminates_with_penalty(cpu, start):
    snap, info = start
    task = cpu.task
    below = with_cube(task, snap, height=float(snap.xpos[task.palm_id, 2]) - 0.01)
    reward, terminated, after, metrics = task.evaluate(jax.random.key(0), snap, below, info)
    progress = float(angular_distance(task.cube_quat(snap), info["goal"])
                     - angular_distance(task.cube_quat(below), info["goal"]))
    assert bool(terminated) and float(metrics["dropped"]) == 1.0 and not bool(after["time_out"])
    assert float(reward) == pytest.approx(progress - 20.0 - 0.1, abs=1e-4)


def test_goal_timer_and_goal_cap_truncate(cpu, start):
    snap, info = start
    task = cpu.task
    far = with_cube(task, snap, quat=quat_mul(info["goal"], about_x(2.0)))
    near = with_cube(task, snap, quat=info["goal"])
    key = jax.random.key(0)
    _, terminated, after, _ = task.evaluate(key, far, far, dict(info, goal_steps=jnp.int32(98)))
    assert not bool(after["time_out"]) and int(after["goal_steps"]) == 99
    _, terminated, after, _ = task.evaluate(key, far, far, dict(info, goal_steps=jnp.int32(99)))
    assert bool(after["time_out"]) and not bool(terminated), "8 s without success: truncated, not terminal"
    _, _, after, _ = task.evaluate(key, far, near, dict(info, goal_steps=jnp.int32(99)))
    assert not bool(after["time_out"]), "a success on the last step restarts the timer"
    _, terminated, after, metrics = task.evaluate(key, far, near, dict(info, goals_reached=jnp.int32(49)))
    assert bool(after["time_out"]) and not bool(terminated) and float(metrics["goals_reached"]) == 50.0


def test_consecutive_goals_are_counted_over_an_episode(cpu, start):
    """CGR: successes add up across goals; the count is the metric reported when the episode ends."""
    snap, info = start
    task = cpu.task
    keys = jax.random.split(jax.random.key(9), 5)
    reached = []
    for step, hit in enumerate([True, False, True, True, False]):
        offset = 0.1 if hit else 1.5
        now = with_cube(task, snap, quat=quat_mul(info["goal"], about_x(offset)))
        _, _, info, metrics = task.evaluate(keys[step], now, now, info)
        reached.append(int(metrics["goals_reached"]))
    assert reached == [1, 1, 2, 3, 3]


def test_reward_coefficients_change_the_reward(cpu, start):
    snap, info = start
    goal = info["goal"]
    prev = with_cube(cpu.task, snap, quat=quat_mul(goal, about_x(1.0)))
    now = with_cube(cpu.task, snap, quat=quat_mul(goal, about_x(0.2)))

    def reward(**coefficients):
        task = Ihom(cpu.task.model, IhomReward.from_dict(coefficients))
        return float(task.evaluate(jax.random.key(0), prev, now, info)[0])

    base = reward()
    assert reward(success_bonus=0.0) == pytest.approx(base - 5.0, abs=1e-4)
    assert reward(step_penalty=0.0) == pytest.approx(base + 0.1, abs=1e-4)
    assert reward(progress=2.0) == pytest.approx(base + 0.8, abs=1e-4)


def test_timer_truncates_an_episode_on_the_cpu_twin():
    """Env level: info["time_out"] ends the episode as a truncation (goal timer of 2 policy steps)."""
    env = aj.make("ShadowHandCube", backend="cpu", goal_timeout=0.16)
    state = env.reset(jax.random.key(0))
    state = env.step(state, jnp.zeros(20))
    assert float(state.done) == 0.0
    state = env.step(state, jnp.zeros(20))
    assert float(state.done) == 1.0 and float(state.truncated) == 1.0 and float(state.metrics["dropped"]) == 0.0


def hold_and_jiggle(ctrl0: jax.Array, length: jax.Array, noise: jax.Array, half_range: jax.Array) -> jax.Array:
    """A closed-loop test policy: relative actions that pull the joint targets back to the episode's first targets
    `ctrl0`, plus `noise`; it keeps the cube on the palm (open-loop random actions drop it within ~6 steps)."""
    return jnp.clip((ctrl0 - length) / half_range + noise, -1.0, 1.0)


@pytest.fixture(scope="module")
def rollout():
    """Initial states and the states after each of STEPS hold-and-jiggle steps of BATCH MJX environments, reset and
    rollout compiled as one program; and the noise."""
    env = aj.make("ShadowHandCube")
    half_range = jnp.asarray(env.task._ctrl_half_range)
    noise = NOISE * jnp.asarray(np.random.default_rng(0).uniform(-1, 1, (STEPS, BATCH, 20)), jnp.float32)

    @jax.jit
    def run(keys, noise):
        first = jax.vmap(env.reset)(keys)

        def one(state, noise):
            action = hold_and_jiggle(first.physics.ctrl, state.physics.actuator_length, noise, half_range)
            state = jax.vmap(env.step)(state, action)
            return state, state

        return first, jax.lax.scan(one, first, noise)[1]

    first, states = run(jax.random.split(jax.random.key(0), BATCH), noise)
    return first, states, noise, half_range


def test_batched_shapes_dtypes_and_finite_values(rollout):
    first, states, _, _ = rollout
    for name, size in SIZES.items():
        for value, lead in ((getattr(first.obs, name), (BATCH,)), (getattr(states.obs, name), (STEPS, BATCH))):
            assert value.shape == lead + (size,) and value.dtype == jnp.float32, name
            assert np.isfinite(np.asarray(value)).all(), name
    assert set(states.metrics) == {"goals_reached", "dropped", "goal_distance"}
    assert np.isfinite(np.asarray(states.reward)).all()
    assert np.asarray(first.info["goal"]).std(axis=0).max() > 0, "each environment draws its own goal"
    assert np.abs(np.asarray(states.obs.touch)).max() > 0, "the cube lands on the hand's touch sensors"


def test_mjx_and_cpu_paths_agree_for_2_seconds(rollout, cpu):
    """Same key and policy: the MJX rollout (float32) and the C MuJoCo twin (float64) agree over 25 policy steps
    (2 s) with the cube in the hand: hand joints within 5e-3 rad, cube position within 5 mm, cube orientation within
    0.05 rad, rewards within 0.03, and episode ends on the same step.

    Looser than reach (2e-3 rad over 50 steps, no contacts) because the cube falls onto the palm and is pushed by
    the fingers: float32 against float64 contact resolution, 4-iteration Newton solves and the closed loop (actions
    are computed from each path's own state) let small differences grow at every impact. Measured worst drift over
    these 25 steps: 1.7e-3 rad, 2.8 mm, 0.022 rad, 9e-3 reward. Touch readings are not compared element-wise: a
    contact point that moves by a fraction of a millimetre can move its force into the neighbouring sensor zone.
    """
    first, states, noise, half_range = rollout
    task = cpu.task
    state = cpu.reset(jax.random.split(jax.random.key(0), BATCH)[0])
    np.testing.assert_allclose(first.info["goal"][0], state.info["goal"], atol=1e-5)
    np.testing.assert_allclose(first.obs.vision[0], state.obs.vision, atol=1e-5)
    ctrl0 = state.physics.ctrl
    for t in range(STEPS):
        state = cpu.step(state, hold_and_jiggle(ctrl0, state.physics.actuator_length, noise[t, 0], half_range))
        mjx_obs = jax.tree.map(lambda x, t=t: x[t, 0], states.final_obs)
        np.testing.assert_allclose(mjx_obs.proprioception[:24], state.obs.proprioception[:24], atol=5e-3)
        np.testing.assert_allclose(mjx_obs.vision[:3], state.obs.vision[:3], atol=5e-3)
        assert float(angular_distance(mjx_obs.vision[3:], state.obs.vision[3:])) < 0.05
        np.testing.assert_allclose(states.reward[t, 0], state.reward, atol=3e-2)
        assert float(states.done[t, 0]) == float(state.done)
        if float(state.done):
            break
    assert t == STEPS - 1, "the test policy should keep the cube in the hand for the whole horizon"
    start = first.physics.qpos[0, task.cube_qpos:task.cube_qpos + 3]
    assert float(jnp.abs(state.physics.qpos[task.cube_qpos:task.cube_qpos + 3] - start).max()) > 0.01, "cube moved"


def test_short_training_run_gives_finite_metrics():
    env = aj.make("ShadowHandCube", touch=False)
    config = PPOConfig(num_cycles=2, num_envs=2, rollout_length=16, chunk_length=16, minibatch_size=32,
                       num_epochs=1, network=NetworkConfig(name="simple"))
    _, history = train(config, env, log=None)
    assert len(history) == 2
    for metrics in history:
        assert metrics["finite"] == 1.0
        for name in ("loss", "entropy", "approx_kl", "explained_variance", "grad_norm"):
            assert np.isfinite(metrics[name]), name
    assert {"metric/goals_reached", "metric/dropped", "metric/goal_distance"} <= set(history[0])
    ended = [m for m in history if m["episodes"] > 0]
    assert ended, "moderate random policies drop the cube within 32 steps"
    assert all(np.isfinite(m["metric/goals_reached"]) and m["metric/goals_reached"] >= 0 for m in ended)
