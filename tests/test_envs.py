"""The environment contract on the Shadow-hand reach task: shapes, auto-reset, rewards, errors, MJX/CPU parity.

One environment (max 50 policy steps per episode) is compiled once, batched, for the whole module: MJX compiles of
the hand take tens of seconds on a CPU. The MJX/CPU parity test replays the recorded batched rollout.
"""

import dataclasses
import importlib.util
import os
import subprocess
import sys

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from quick_compile import compile_quickly

import angora_jax as aj
from angora_jax.envs import backends, mjx_env
from angora_jax.envs.classic.cartpole import CartPole
from angora_jax.envs.mjx_env import resolve_impl
from angora_jax.envs.mujoco_task import Snapshot, mjx_impl, start_physics
from angora_jax.envs.shadow_hand import REACH_PHYSICS
from angora_jax.envs.shadow_hand.model import UNTOUCHED_GEOMS, load_scene
from angora_jax.envs.shadow_hand.reach import THUMB, Reach, ReachReward
from angora_jax.ppo import PPOConfig, make_cycle, make_evaluate

BATCH = 3
EPISODE = 50


@pytest.fixture(scope="module")
def env():
    return aj.make("ShadowHandReach", max_episode_steps=EPISODE)


@pytest.fixture(scope="module")
def batched(env):
    """The batched reset and step, compiled quickly (tests/quick_compile.py): the module runs them for 51 steps."""
    keys = jax.random.split(jax.random.key(0), BATCH)
    reset = compile_quickly(jax.vmap(env.reset), keys)
    return reset, compile_quickly(jax.vmap(env.step), reset(keys), jnp.zeros((BATCH, 20), jnp.float32))


@pytest.fixture(scope="module")
def rollout(env, batched):
    """States of a batch over one episode and one more step under random actions, and the actions."""
    reset, step = batched
    state = reset(jax.random.split(jax.random.key(0), BATCH))
    actions = jnp.asarray(np.random.default_rng(0).uniform(-1, 1, (EPISODE + 1, BATCH, 20)), jnp.float32)
    states = [state]
    for action in actions:
        state = step(state, action)
        states.append(state)
    return states, actions


def test_registry_lists_tasks_and_rejects_unknown_names():
    assert {"ShadowHandReach", "ShadowHandFreeReach"} <= set(aj.list_tasks())
    # The config's did-you-mean (`wording.did_you_mean`): make_env's refusal had only the list.
    with pytest.raises(ValueError, match=r"^Unknown task 'ShadowHandRech'\. Did you mean 'ShadowHandReach'\? Known "
                                         r"tasks: .*ShadowHandReach"):
        aj.make_env("ShadowHandRech")
    with pytest.raises(ValueError, match=r"^Unknown task 'Xyzzy'\. Known tasks: "):
        aj.make("Xyzzy")
    with pytest.raises(ValueError, match="Unknown backend"):
        aj.make("ShadowHandReach", backend="gpu")
    with pytest.raises(ValueError, match="Unknown reward coefficients.*success_bonus"):
        aj.make("ShadowHandReach", reward={"sucess_bonus": 1.0})
    with pytest.raises(ValueError, match=r"Unknown reward preset 'punished'.*\['default', 'force_punished'\]"):
        aj.make("ShadowHandReach", backend="cpu", reward_preset="punished")


@pytest.mark.parametrize("task", ["ShadowHandReach", "ShadowHandFreeReach"])
def test_angorapys_force_punished_reach_preset_costs_force(task):
    punished = aj.make(task, backend="cpu", reward_preset="force_punished", reward={"success_bonus": 0.5})
    assert punished.task.reward_config.force_multiplier == 0.05 and punished.task.reward_config.success_bonus == 0.5
    assert aj.make(task, backend="cpu").task.reward_config.force_multiplier == 0.0


def test_wrong_action_shape_names_the_expected_shape(env):
    # The action is checked before the state is touched, so no state is needed to see the error.
    with pytest.raises(ValueError, match=r"expects one action of shape \(20,\), got \(19,\)"):
        env.step(None, jnp.zeros(19))
    with pytest.raises(ValueError, match=r"got \(4, 20\); for a batch of environments use jax.vmap"):
        env.step(None, jnp.zeros((4, 20)))


@pytest.mark.slow
def test_batched_shapes_dtypes_and_finite_values(rollout):
    rollout, _ = rollout
    sizes = {"proprioception": 48, "touch": 0, "vision": 0, "goal": 20, "asymmetric": 15}
    for state in rollout:
        for name, size in sizes.items():
            value = getattr(state.obs, name)
            assert value.shape == (BATCH, size) and value.dtype == jnp.float32, name
            assert np.isfinite(np.asarray(value)).all(), name
        assert state.reward.shape == state.done.shape == (BATCH,)
        assert state.reward.dtype == jnp.float32 and state.steps.dtype == jnp.int32
        assert set(state.metrics) == {"success", "goal_distance"}
        assert np.isfinite(np.asarray(state.reward)).all()
    rewards = np.stack([np.asarray(s.reward) for s in rollout[1:]])
    assert (rewards < 0.2).all() and (rewards > -1.0).all()
    assert np.ptp(rewards) > 0, "random actions should change the reward"


@pytest.mark.slow
def test_auto_reset_at_time_limit_keeps_final_observation(rollout):
    rollout, _ = rollout
    before, at_limit, after = rollout[EPISODE - 1], rollout[EPISODE], rollout[EPISODE + 1]
    assert np.all(np.asarray(before.done) == 0)
    assert np.all(np.asarray(at_limit.done) == 1) and np.all(np.asarray(at_limit.truncated) == 1)
    assert np.all(np.asarray(at_limit.steps) == 0) and np.all(np.asarray(after.steps) == 1)
    # obs restarted from the initial pose while final_obs holds the ended episode's last observation.
    first = rollout[0].obs.proprioception
    np.testing.assert_allclose(at_limit.obs.proprioception[:, :24], first[:, :24], atol=1e-6)
    assert np.abs(np.asarray(at_limit.final_obs.proprioception - at_limit.obs.proprioception)).max() > 1e-3
    assert not np.array_equal(np.asarray(at_limit.info["goal"]), np.asarray(before.info["goal"]))


@pytest.mark.slow
def test_goal_sampling_puts_thumb_and_target_at_meeting_point(rollout):
    state = rollout[0][0]
    goal = np.asarray(state.info["goal"])
    tips = np.asarray(state.obs.asymmetric).reshape(BATCH, 5, 3)
    for b in range(BATCH):
        if state.info["stay"][b]:
            np.testing.assert_allclose(goal[b], tips[b], atol=1e-6)
            continue
        target = int(state.info["target"][b])
        # Thumb and target goals sit 5 mm short of a common meeting point, far from where the tips start.
        assert 1e-3 < np.linalg.norm(goal[b, 4] - goal[b, target]) <= 0.01 + 1e-6
        assert np.linalg.norm(goal[b, 4] - tips[b, 4]) > 0.02
        others = [i for i in range(4) if i != target]
        np.testing.assert_allclose(goal[b, others], tips[b, others], atol=1e-6)


@pytest.mark.slow
def test_reward_coefficients_change_the_reward(env, rollout):
    prev, state = rollout[0][4], rollout[0][5]
    one = jax.tree.map(lambda x: x[0], (prev, state))
    prev_snap, snap = Snapshot.of(one[0].physics), Snapshot.of(one[1].physics)
    key = jax.random.key(1)
    info = one[0].info

    def reward(free, **coefficients):
        task = Reach(env.task.model, dataclasses.replace(ReachReward(), **coefficients), free=free)
        return float(task.evaluate(key, prev_snap, snap, info)[0])

    base = reward(False)
    np.testing.assert_allclose(base, float(one[1].reward), atol=1e-6)
    assert reward(False, force_multiplier=1e-3) < base
    assert reward(False, success_distance=1.0, success_bonus=5.0) == pytest.approx(base + 5.0, abs=1e-5)
    free_base = reward(True)
    assert reward(True, auxiliary_zone_radius=1.0) < free_base
    assert reward(True, auxiliary_zone_radius=1.0, auxiliary_penalty_multiplier=0.0) == pytest.approx(free_base)


@pytest.mark.slow
def test_freereach_goal_is_the_target_finger_one_hot(env, rollout):
    task = Reach(env.task.model, free=True)
    snap = Snapshot.of(jax.tree.map(lambda x: x[0], rollout[0][0].physics))
    info = task.initial_info(jax.random.key(7), snap)
    goal = np.asarray(task.observe(snap, info).goal)
    assert goal.shape == (5,) and goal.sum() == 1.0 and goal[int(info["target"])] == 1.0 and goal[4] == 0.0


def test_freereach_penalises_the_other_fingertips_near_the_thumb_not_the_target():
    """Freereach: each non-target fingertip inside `auxiliary_zone_radius` (6.015 cm) of the thumb tip costs
    `auxiliary_penalty_multiplier` per metre it intrudes; the target, which has to come to the thumb, costs nothing.
    Fingertips on a line from the thumb: FF 3 cm, MF 5 mm, RF 5 cm, LF 10 cm; a near non-target also bars success."""
    task = aj.make("ShadowHandFreeReach", backend="cpu").task
    c = task.reward_config
    start = task.snapshot(start_physics(task, np.asarray(task.initial_qpos(None), np.float64)))
    thumb = np.asarray(start.site_xpos[task.fingertip_ids[THUMB]])
    away = np.array([0.03, 0.005, 0.05, 0.10])
    tips = np.vstack([thumb + away[:, None] * np.array([1.0, 0.0, 0.0]), thumb])
    placed = start.replace(site_xpos=start.site_xpos.at[task.fingertip_ids].set(jnp.asarray(tips, jnp.float32)))
    for target in (1, 0):  # MF, then FF
        info = dict(task.initial_info(jax.random.key(0), start), target=jnp.int32(target))
        reward, _, _, metrics = task.evaluate(jax.random.key(1), start, placed, info)
        others = np.delete(away, target)
        intrusion = np.maximum(c.auxiliary_zone_radius - others, 0.0).sum()
        assert float(metrics["goal_distance"]) == pytest.approx(away[target], abs=1e-6)
        assert float(reward) == pytest.approx(-away[target] - c.auxiliary_penalty_multiplier * intrusion, abs=1e-6)
        assert float(metrics["success"]) == 0.0


@pytest.mark.slow
def test_mjx_and_cpu_paths_agree_for_50_steps(rollout):
    """Same key and actions: joint positions within 2e-3 rad and rewards within 1e-4 over 50 policy steps.

    The CPU twin is float64 C MuJoCo and MJX runs float32, so the trajectories drift apart slowly; the hand has no
    contacts here, so the drift stays far below the tolerance (measured about 2e-4 rad over 60 steps).
    """
    states, actions = rollout
    cpu = aj.make("ShadowHandReach", max_episode_steps=EPISODE, backend="cpu")
    cpu_state = cpu.reset(jax.random.split(jax.random.key(0), BATCH)[0])
    np.testing.assert_allclose(states[0].info["goal"][0], cpu_state.info["goal"], atol=1e-5)
    for t in range(EPISODE):
        cpu_state = cpu.step(cpu_state, actions[t, 0])
        mjx_qpos = states[t + 1].final_obs.proprioception[0, :24]
        np.testing.assert_allclose(mjx_qpos, cpu_state.physics.qpos, atol=2e-3)
        np.testing.assert_allclose(states[t + 1].reward[0], cpu_state.reward, atol=1e-4)
    assert float(cpu_state.done) == 1.0
    assert float(jnp.abs(cpu_state.physics.qpos - cpu.task.initial_qpos(None)).max()) > 0.05, "the hand must move"


def test_cpu_twin_refuses_misuse():
    cpu = aj.make("ShadowHandReach", max_episode_steps=2, backend="cpu")
    with pytest.raises(RuntimeError, match="before reset"):
        cpu.step(None, jnp.zeros(20))
    first = cpu.reset(jax.random.key(0))
    second = cpu.step(first, jnp.zeros(20))
    with pytest.raises(ValueError, match="stateful"):
        cpu.step(first, jnp.zeros(20))
    last = cpu.step(second, jnp.zeros(20))
    assert float(last.done) == 1.0 and float(last.truncated) == 1.0
    with pytest.raises(RuntimeError, match="episode has ended"):
        cpu.step(last, jnp.zeros(20))


def test_physics_impl_and_contact_caps_are_checked():
    with pytest.raises(ValueError, match=r"impl='wrap'.*\('jax', 'warp', 'auto'\)"):
        aj.make("ShadowHandReach", physics={"impl": "wrap"})
    with pytest.raises(ValueError, match="contact_caps must be >= 0"):
        aj.make("ShadowHandReach", physics={"contact_caps": -1})
    with pytest.raises(ValueError, match="warp_max_envs must be >= 1"):
        aj.make("ShadowHandReach", physics={"warp_max_envs": 0})


def test_warp_buffer_size_is_a_physics_setting(monkeypatch):
    built = []
    monkeypatch.setattr(backends, "MjxEnv", lambda task, skip, steps, warp_max_envs: built.append(warp_max_envs))
    aj.make("ShadowHandCube", physics={"warp_max_envs": 4096})
    aj.make("ShadowHandReach")
    assert built == [4096, None]  # None: sized for the batch that runs it (Env.sized_for)


def test_warp_buffers_are_sized_for_the_batch_that_runs(monkeypatch):
    env = aj.make("ShadowHandReach", physics={"impl": "jax"})
    assert env.sized_for(64) is env, "MJX's JAX implementation has no shared buffers"
    env.impl = "warp"  # what sized_for decides on; building a Warp env needs warp-lang, absent here
    made = []
    monkeypatch.setattr(mjx_env.MjxEnv, "__init__", lambda self, task, skip, steps, warp_max_envs=None:
                        made.append((task, skip, steps, warp_max_envs)))
    env.sized_for(64)
    assert made == [(env.task, env.frame_skip, env.max_episode_steps, 64)]
    env.warp_max_envs = 128
    assert env.sized_for(64) is env, "a size the user set is kept"


def test_training_and_evaluation_size_the_env_for_their_batch():
    sizes = []

    class Recording(CartPole):
        def sized_for(self, num_envs):
            sizes.append(num_envs)
            return self

    config = PPOConfig(num_envs=8, rollout_length=16, minibatch_size=32)
    make_cycle(Recording(), None, config)
    make_evaluate(Recording(), None, config, 5)
    assert sizes == [8, 5]


def test_auto_physics_is_warp_on_a_gpu_with_warp_lang_else_jax(monkeypatch):
    assert resolve_impl("auto") == "jax" and resolve_impl("warp") == "warp"  # this CPU machine
    gpu = type("Device", (), {"platform": "gpu"})()
    monkeypatch.setattr(mjx_env.jax, "local_devices", lambda: [gpu])
    find_spec = importlib.util.find_spec

    def warp_installed(installed):
        def find(name, *args):
            return (object() if installed else None) if name == "warp" else find_spec(name, *args)

        monkeypatch.setattr(importlib.util, "find_spec", find)

    warp_installed(True)
    assert resolve_impl("auto") == "warp"
    warp_installed(False)
    assert resolve_impl("auto") == "jax", "the fallback without warp-lang"
    monkeypatch.undo()
    assert mjx_impl(aj.make("ShadowHandReach").task.model) == "jax", "the default, 'auto', on this CPU machine"


def test_warp_without_warp_lang_names_the_package(monkeypatch):
    find_spec = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "warp" else find_spec(name, *a))
    with pytest.raises(ModuleNotFoundError, match=r"pip install warp-lang==1\.18\.0"):
        aj.make("ShadowHandReach", physics={"impl": "warp"})


@pytest.mark.skipif(importlib.util.find_spec("warp") is not None, reason="warp-lang is installed here")
def test_making_an_mjx_env_without_warp_prints_nothing():
    """mujoco-mjx prints "Failed to import warp" on import when the optional warp-lang is absent; ours swallows it."""
    done = subprocess.run([sys.executable, "-c", "import angora_jax as aj; aj.make('ShadowHandReach')"],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "Failed to import" not in done.stdout + done.stderr


LOCAL_DEVICE_CHECK = """
import jax
everywhere = jax.devices()
jax.devices = lambda *backend: everywhere[::-1]  # as under jax.distributed: the first device is another process's
import angora_jax as aj
env = aj.make("ShadowHandReach")
arrays = [leaf for leaf in jax.tree.leaves((env.mjx_model, env._data0)) if isinstance(leaf, jax.Array)]
placed = {device for leaf in arrays for device in leaf.devices()}
print(sorted(str(d) for d in placed), jax.local_devices()[0])
assert placed == {jax.local_devices()[0]}, placed
"""


@pytest.mark.slow
def test_mjx_model_and_data_live_on_this_processs_device():
    """MJX places models on `jax.devices()[0]` by default, which under jax.distributed belongs to process 0; on any
    other process jit then refuses the model ("Closing over jax.Array that spans non-addressable devices")."""
    env = {"XLA_FLAGS": "--xla_force_host_platform_device_count=2", "JAX_PLATFORMS": "cpu"}
    done = subprocess.run([sys.executable, "-c", LOCAL_DEVICE_CHECK], capture_output=True, text=True, timeout=300,
                          env={**os.environ, **env})
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]


def test_pruned_geoms_never_touch_so_pruning_leaves_the_dynamics_unchanged():
    """The untouched geoms are out of collision in our scenes (and unread sensors gone), and C MuJoCo follows the Gym
    scene exactly."""
    pruned = load_scene("reach.xml", physics=REACH_PHYSICS)
    gym = load_scene("reach.xml", physics=REACH_PHYSICS, prune_contacts=False, sensors=None)
    assert pruned.nsensor == 0 and gym.nsensor == 29, "reach reads no sensor; the Gym scene has 29"
    assert mjx_impl(pruned) == "jax"
    assert mjx_impl(load_scene("reach.xml", physics=dataclasses.replace(REACH_PHYSICS, impl="warp"))) == "warp"
    for name in UNTOUCHED_GEOMS:
        assert pruned.geom(name).contype == pruned.geom(name).conaffinity == 0
        assert gym.geom(name).contype == 1
    task = Reach(pruned)
    datas = [start_physics(task, np.asarray(task.initial_qpos(None), np.float64), mujoco.MjData(m))
             for m in (pruned, gym)]
    low, high = pruned.actuator_ctrlrange.T
    contacts = 0
    for target in np.random.default_rng(0).uniform(low, high, (30, pruned.nu)):
        for model, data in zip((pruned, gym), datas, strict=True):
            data.ctrl[:] = target
            mujoco.mj_step(model, data, nstep=4)
        contacts += datas[0].ncon
        np.testing.assert_array_equal(datas[0].qpos, datas[1].qpos)
    assert contacts > 0, "the fingers must touch each other, or the comparison shows nothing"


def test_a_fixed_target_finger_and_a_frozen_wrist():
    """`target_finger` fixes the finger every episode draws (AngoraPy's force_finger); `freeze_wrist` makes the wrist's
    actuators hold its initial pose: under 20 steps of random actions the wrist turned 0.28 rad free, 0.08 held."""
    turned = {}
    for frozen in (False, True):
        env = aj.make("ShadowHandReach", backend="cpu", target_finger="RF", freeze_wrist=frozen)
        state = env.reset(jax.random.key(1))
        start = np.asarray(state.physics.qpos[:2]).copy()
        rng = np.random.default_rng(0)
        for _ in range(20):
            state = env.step(state, jnp.asarray(rng.uniform(-1, 1, 20), jnp.float32))
        turned[frozen] = float(np.abs(np.asarray(state.physics.qpos[:2]) - start).max())
    assert turned[False] > 0.2 and turned[True] < 0.1, turned
    targets = {int(env.reset(jax.random.key(k)).info["target"]) for k in range(8)}
    assert targets == {2}, "RF, the ring finger, in every episode"
    np.testing.assert_array_equal(env.reset(jax.random.key(0)).obs.goal[-5:], [0, 0, 1, 0, 0])
    with pytest.raises(ValueError, match=r"Unknown target_finger 'TH'.*\('FF', 'MF', 'RF', 'LF'\)"):
        aj.make("ShadowHandFreeReach", backend="cpu", target_finger="TH")


@pytest.mark.parametrize("control", ["absolute", "position", "target"])
def test_each_control_mode_maps_actions_onto_the_actuators_ranges(control):
    """Under "absolute" (the cube presets' control) -1, 0 and 1 are each actuator's low end, the middle of its range
    and its high end; "position" centres the step on where each actuator is (its length) and "target" on the last
    targets, a step of 1 moving half the range from there, within the range."""
    env = aj.make("ShadowHandReach", backend="cpu", control=control)
    snap = env.reset(jax.random.key(0)).physics
    low, high = (np.asarray(bound, np.float64) for bound in env.task.model.actuator_ctrlrange.T)
    centre = {"absolute": (low + high) / 2, "position": np.asarray(snap.actuator_length, np.float64),
              "target": np.asarray(snap.ctrl, np.float64)}[control]
    for action in (-1.0, 0.0, 1.0):
        targets = np.asarray(env.task.control(jnp.full(20, action, jnp.float32), snap))
        np.testing.assert_allclose(targets, np.clip(centre + action * (high - low) / 2, low, high), atol=1e-6)
    if control == "absolute":
        np.testing.assert_allclose(env.task.control(-jnp.ones(20), snap), low, atol=1e-6)
        np.testing.assert_allclose(env.task.control(jnp.ones(20), snap), high, atol=1e-6)


# Thumb and first finger pressed together: the joint angles (rad) at which their fingertip pads (the touch sites
# `Tch_fftip`, `Tch_thtip`) coincide, found by least squares on C MuJoCo's kinematics from the initial pose; the distal
# capsules then overlap by 15 mm. (Where the tip sites `S_*tip` coincide instead, the contact lies outside every
# touch zone and all sensors read 0.)
PRESSED_QPOS = {"robot0:FFJ3": 0.2081, "robot0:FFJ2": 0.9017, "robot0:FFJ1": 1.119, "robot0:FFJ0": 0.9021,
                "robot0:THJ4": 0.3782, "robot0:THJ3": 0.922, "robot0:THJ2": 0.0539, "robot0:THJ1": -0.1919,
                "robot0:THJ0": -0.7577}


@pytest.mark.slow
def test_reach_touch_reads_thumb_and_finger_pressed_together_and_nothing_in_the_open_hand(quick_compiles):
    """With `touch`, reach observes the cube's 97 touch sensors (N): all zero in the open initial pose; with thumb and
    first finger pressed together, only sensors on those two fingers read, in C MuJoCo and MJX's JAX implementation
    alike (the same state, `mjx.forward`); without `touch` there are none."""
    from mujoco import mjx

    assert aj.make("ShadowHandReach", backend="cpu").reset(jax.random.key(0)).obs.touch.shape == (0,)
    # The solver runs to convergence: at reach's own caps (2 Newton iterations) MJX stops its unconverged solve of this
    # deep contact far from C MuJoCo's (12.0 N against 5.0 N on the first sensor).
    task = aj.make("ShadowHandReach", backend="cpu", touch=True, physics={"iterations": 50, "ls_iterations": 50}).task
    model = task.model
    names = [model.sensor(int(i)).name for i in range(model.nsensor)]
    open_hand = start_physics(task, np.asarray(task.initial_qpos(None), np.float64))
    info = task.initial_info(jax.random.key(0), task.snapshot(open_hand))
    np.testing.assert_array_equal(task.observe(task.snapshot(open_hand), info).touch, np.zeros(97))
    qpos = np.asarray(task.initial_qpos(None), np.float64)
    for name, angle in PRESSED_QPOS.items():
        qpos[model.joint(name).qposadr[0]] = angle
    pressed = start_physics(task, qpos)
    touch = np.asarray(task.observe(task.snapshot(pressed), info).touch)
    reading = {names[i] for i in np.flatnonzero(touch)}
    assert touch.sum() > 1.0 and reading, "pressed together, the fingers push on each other (N)"
    assert all(("ff" in name or "th" in name) and ("tip" in name or "distal" in name) for name in reading), reading
    on_mjx = jax.jit(mjx.forward)(mjx.put_model(model), mjx.put_data(model, pressed))
    mjx_touch = np.asarray(task.observe(task.snapshot(on_mjx), info).touch)
    # The same sensors read, with forces of one size: the 15 mm overlap is far deeper than any contact in a step, and
    # its forces differ between the implementations' contact models (measured: 5.0 N in C MuJoCo, 6.8 N in MJX).
    np.testing.assert_array_equal(np.flatnonzero(mjx_touch), np.flatnonzero(touch))
    np.testing.assert_allclose(mjx_touch, touch, rtol=0.5)


def test_a_quoted_no_for_a_true_or_false_task_option_is_refused_not_taken_as_true():
    """`touch: "no"` (a non-empty string) switched ShadowHandReach's 97 touch sensors on without a word."""
    from angora_jax.envs.registry import make

    for value in ("no", "false", 0):
        with pytest.raises(ValueError, match=f"ShadowHandReach's option touch must be true or false, got {value!r}"):
            make("ShadowHandReach", touch=value)


def test_a_task_given_as_no_name_is_refused_saying_what_to_give():
    """`aj.make(config)` (a Config where the task's name goes), `aj.make(agent)` or `aj.make(None)` failed with
    "'Config' object has no attribute 'startswith'" from inside the registry."""
    config = aj.load_config("cartpole")
    with pytest.raises(TypeError, match=r"^make takes a task's name \(e\.g\. 'CartPole'; aj\.list_tasks\(\) lists "
                                        r"them\), got a Config: aj\.make\(config\.env\.task, "
                                        r"\*\*config\.env\.options\) makes its task\.$"):
        aj.make(config)
    for given, said in ((None, "None"), (3, "3 \\(int\\)"), (config.env, "an EnvConfig")):
        with pytest.raises(TypeError, match=rf"^make takes a task's name .*, got {said}"):
            aj.make_env(given)
    assert aj.make(config.env.task, **config.env.options).max_episode_steps == 500


def test_an_option_the_task_does_not_take_is_named_with_the_options_it_takes():
    """`aj.make("CartPole", max_episode_step=3)` (and the same keyword to gymnasium.make) said only Python's
    "CartPole.__init__() got an unexpected keyword argument 'max_episode_step'"; a config's env.options said more."""
    with pytest.raises(TypeError, match=r"^Task 'CartPole' has no option 'max_episode_step' \(did you mean "
                                        r"'max_episode_steps'\?\); its options: max_episode_steps\.$"):
        aj.make("CartPole", max_episode_step=3)
    with pytest.raises(TypeError, match=r"^Task 'CartPole' has no option 'colour'; its options: max_episode_steps\."):
        aj.make_env("CartPole", colour="red")
    assert aj.make("CartPole", max_episode_steps=3).max_episode_steps == 3
