"""The MyoHand pose task (issue 62): the model, its observations and muscle sense, MyoSuite's success rule, the action
range, and the C MuJoCo twin against MJX.

The C MuJoCo twin runs the task's functions jitted for one environment (a few seconds of compiles), so the fast tests
use it. MJX's JAX implementation compiles the muscle hand in about 30 s of CPU (the batched reset about 10 s and the
step about 19 s at XLA's quick settings, 2 cores); on MuJoCo Warp (on the CPU) the same programs compile in about
4 s, plus about 15 s once per machine to build Warp's kernels. So the MJX comparison runs on Warp, the implementation
that GPUs run, and with the training smoke test it is in the slow tier.
"""

import importlib.util
import json
import math
from types import SimpleNamespace

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from quick_compile import compile_quickly

import angora_jax as aj
from angora_jax.cli import main
from angora_jax.envs import mjx_env
from angora_jax.envs.myohand.model import JOINTS, MUSCLES, load_hand
from angora_jax.envs.myohand.pose import POSE_THRESHOLD, TARGET_RANGES, MyoHandPose, PoseReward
from angora_jax.envs.myohand.reachable import BANK_SIZE, HELD_OUT, load_bank, reachable_posture

BATCH = 2
STEPS = 10


@pytest.fixture(scope="module")
def model() -> mujoco.MjModel:
    return load_hand()


@pytest.fixture(scope="module")
def cpu():
    """The C MuJoCo twin of MyoHandPose and its first state (key 0)."""
    env = aj.make("MyoHandPose", backend="cpu")
    return env, env.reset(jax.random.key(0))


def test_the_hand_has_23_joints_and_39_muscles_on_39_wrapping_tendons(model):
    assert (model.njnt, model.nq, model.nv) == (JOINTS, JOINTS, JOINTS)
    assert model.nu == model.na == model.ntendon == MUSCLES
    assert model.nwrap == 315
    assert np.all(model.actuator_dyntype == mujoco.mjtDyn.mjDYN_MUSCLE)
    np.testing.assert_array_equal(model.actuator_ctrlrange, np.tile([0.0, 1.0], (MUSCLES, 1)))
    assert model.opt.timestep == 0.002


def test_the_muscle_variables_are_labelled_with_the_muscles_names_in_action_order(model):
    labels = MyoHandPose(model).task_variable_labels()
    assert set(labels) == {"muscle_force", "muscle_activation", "muscle_excitation"}
    names = labels["muscle_excitation"]
    assert len(names) == MUSCLES and len(set(names)) == MUSCLES
    assert names[:3] == ("ECRL_r", "ECRB_r", "ECU_r") and names[24] == "FPL_r" and names[-1] == "UI_UB5_r"


def test_observations_hold_joints_the_muscle_sense_and_the_goal(cpu):
    env, state = cpu
    sizes = {name: int(value.shape[-1]) for name, value in state.obs.__dict__.items()}
    assert sizes == {"proprioception": 2 * JOINTS, "touch": 0, "muscle": 4 * MUSCLES, "vision": 0,
                     "goal": 2 * JOINTS, "asymmetric": 0}
    state = env.step(state, jnp.full(MUSCLES, 0.3))
    data = env.data
    # The muscle modality reads the C MuJoCo data: lengths, lengthening velocities, forces and activations, each in
    # actuator order; the activations rise towards the excitation, so they are neither 0 nor 0.3 yet.
    np.testing.assert_allclose(state.obs.muscle, np.concatenate(
        [data.actuator_length, data.actuator_velocity, data.actuator_force, data.act]), rtol=1e-6, atol=1e-6)
    assert np.all((data.act > 0.01) & (data.act < 0.3))
    assert np.all(data.actuator_force <= 0) and np.any(data.actuator_force < -1.0), "excited muscles pull"
    np.testing.assert_allclose(state.obs.proprioception, np.concatenate([data.qpos, data.qvel]), rtol=1e-6,
                               atol=1e-6)
    target = state.info["target"]
    np.testing.assert_allclose(state.obs.goal, np.concatenate([target, target - data.qpos]), atol=1e-6)
    task = env.task_variables(state)
    assert task["muscle_force"].shape == (MUSCLES,)
    np.testing.assert_allclose(task["joint_velocities"], data.qvel, rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(task["muscle_excitation"], 0.3, rtol=1e-6)  # the ctrl the action set


def test_files_written_before_the_muscle_modality_still_load():
    """An exported policy stores its observation statistics per modality (flax serialization); one written before
    `muscle` existed lacks it, which a task without muscles restores as empty. A task that observes muscles refuses
    it, naming why."""
    from flax import serialization

    from angora_jax.envs.core import Sensation
    from angora_jax.ppo.normalization import observation_stats

    stats = observation_stats(Sensation.make(proprioception=jnp.ones(3), goal=jnp.ones(2)))
    old = serialization.to_state_dict(stats)
    del old["muscle"]
    restored = serialization.from_state_dict(stats, serialization.msgpack_restore(serialization.msgpack_serialize(old)))
    assert jax.tree.structure(restored) == jax.tree.structure(stats) and restored.muscle.mean.shape == (0,)
    muscled = observation_stats(Sensation.make(proprioception=jnp.ones(3), muscle=jnp.ones(4 * MUSCLES)))
    with pytest.raises(ValueError, match=r"no \['muscle'\], which this task observes"):
        serialization.from_state_dict(muscled, old)


def test_the_gymnasium_view_shows_the_muscle_sense_and_passes_check_env():
    import gymnasium
    from gymnasium.utils.env_checker import check_env

    env = gymnasium.make("AngoraJax/MyoHandPose-v0")
    spaces = {name: space.shape for name, space in env.observation_space.spaces.items()}
    assert spaces == {"proprioception": (2 * JOINTS,), "muscle": (4 * MUSCLES,), "goal": (2 * JOINTS,)}
    assert (env.action_space.low.min(), env.action_space.high.max(), env.action_space.shape) == (0.0, 1.0, (MUSCLES,))
    check_env(env.unwrapped, skip_render_check=True)


def test_starts_and_targets_are_drawn_within_their_ranges(model):
    task = MyoHandPose(model)
    keys = jax.random.split(jax.random.key(1), 200)
    starts = jax.vmap(task.initial_qpos)(keys)
    targets = jax.vmap(task.draw_target)(keys)
    low, high = np.asarray(TARGET_RANGES).T
    assert np.all(starts >= model.jnt_range[:, 0] - 1e-6) and np.all(starts <= model.jnt_range[:, 1] + 1e-6)
    assert np.all(targets >= low - 1e-6) and np.all(targets <= high + 1e-6)
    wide = high - low > 0.1
    assert np.all(np.ptp(targets, axis=0)[wide] > 0.5 * (high - low)[wide]), "targets spread over their ranges"


def test_start_spread_scales_the_starts_pose_error_towards_the_episodes_target(model):
    """start = target + s (uniform start - target), the target the one `initial_info` draws: over 400 resets the
    median start error at s = 0.4 is 0.4 (within 0.39 - 0.41) times MyoSuite's (2.6 rad here; about 1.04 rad at
    0.4), starts stay within the joints' ranges, and s = 1 is MyoSuite's start bit for bit."""
    pose_keys, task_keys = jnp.moveaxis(jax.vmap(jax.random.split)(jax.random.split(jax.random.key(3), 400)), 1, 0)
    targets = jax.vmap(MyoHandPose(model).draw_target)(task_keys)
    errors = {}
    for spread in (1.0, 0.4):
        task = MyoHandPose(model, start_spread=spread)
        starts = np.asarray(jax.vmap(task.start_qpos)(pose_keys, task_keys))
        assert np.all(starts >= model.jnt_range[:, 0] - 1e-6) and np.all(starts <= model.jnt_range[:, 1] + 1e-6)
        errors[spread] = np.median(np.linalg.norm(starts - targets, axis=1))
    np.testing.assert_array_equal(jax.vmap(MyoHandPose(model).start_qpos)(pose_keys, task_keys),
                                  jax.vmap(MyoHandPose(model).initial_qpos)(pose_keys))
    assert 2.3 < errors[1.0] < 2.9 and 0.39 < errors[0.4] / errors[1.0] < 0.41, errors


def test_the_c_mujoco_twin_starts_at_start_spread_of_myosuites_distance_from_the_same_target(cpu):
    """The twin's reset places the hand at the start `start_qpos` gives with the target its episode then holds: per
    episode, start minus target at 0.4 is 0.4 x that of MyoSuite's start from the same key."""
    near = aj.make("MyoHandPose", backend="cpu", start_spread=0.4)
    far = cpu[0]
    for seed in range(3):
        wide, close = far.reset(jax.random.key(seed)), near.reset(jax.random.key(seed))
        target = np.asarray(wide.info["target"])
        np.testing.assert_array_equal(close.info["target"], target)
        np.testing.assert_allclose(near.data.qpos - target, 0.4 * (far.data.qpos - target), atol=1e-5)


@pytest.mark.parametrize("forward", ["identity", pytest.param("warp", marks=pytest.mark.slow)])
def test_mjx_starts_at_start_spread_where_the_c_mujoco_twin_does(forward, monkeypatch):
    """MJX's batched reset at start_spread 0.4 (on MuJoCo Warp) puts the hand where the C MuJoCo twin's does for the
    same keys, aiming at the same target (float32 against float64). The reset's forward pass changes neither (the
    drawn qpos is written back after it), so the fast case runs the reset with the identity for it: Warp's own forward
    costs about 15 s of CPU once per machine to build its kernels for the hand, which the slow case pays."""
    env = aj.make("MyoHandPose", physics={"impl": "warp"}, start_spread=0.4).sized_for(BATCH)
    if forward == "identity":  # after the model and data are put on the device, which the module does too
        monkeypatch.setattr(mjx_env, "mjx_module", lambda: SimpleNamespace(forward=lambda model, data: data))
    keys = jax.random.split(jax.random.key(5), BATCH)
    states = compile_quickly(jax.vmap(env.reset), keys)(keys)
    twin = aj.make("MyoHandPose", backend="cpu", start_spread=0.4)
    for b in range(BATCH):
        state = twin.reset(keys[b])
        np.testing.assert_allclose(states.info["target"][b], state.info["target"], atol=1e-6)
        np.testing.assert_allclose(states.physics.qpos[b], twin.data.qpos, atol=1e-6)
        assert np.linalg.norm(twin.data.qpos - state.info["target"]) < 2.0, "a start nearer than MyoSuite's 2.6 rad"


def test_the_reachable_bank_holds_the_postures_its_seeds_make_within_the_joints_ranges():
    """Rows 0, 1 and the last (a held-out one) are `reachable_posture` of their seeds on the pose task's hand (in
    MyoSuite's frame: gravity shapes where the hand rests), so the shipped file is what its generator makes. The joint
    limits are soft constraints, so a hand pressed against one rests a little past it (up to 0.09 rad in the bank)."""
    bank = load_bank()
    hand = load_hand(myosuite_frame=True)
    assert bank.shape == (BANK_SIZE, JOINTS) and bank.dtype == np.float32
    for row in (0, 1, BANK_SIZE - 1):
        np.testing.assert_allclose(bank[row], reachable_posture(hand, row), atol=1e-5)
    assert np.all(bank >= hand.jnt_range[:, 0] - 0.1) and np.all(bank <= hand.jnt_range[:, 1] + 0.1)


def test_reachable_targets_are_bank_rows_and_held_out_targets_only_the_held_out_rows(model):
    """targets=reachable draws rows of the bank less its last HELD_OUT, reachable_held_out only those; both spread over
    their part (hundreds of distinct rows in 600 draws), and start_spread still moves the start towards them."""
    bank = load_bank()
    keys = jax.random.split(jax.random.key(7), 600)
    rows = {}
    for targets, part in (("reachable", bank[:-HELD_OUT]), ("reachable_held_out", bank[-HELD_OUT:])):
        task = MyoHandPose(model, targets=targets, start_spread=0.5)
        drawn = np.asarray(jax.vmap(task.draw_target)(keys))
        match = np.all(drawn[:, None, :] == part[None, :, :], axis=-1)
        assert np.all(match.sum(axis=1) >= 1), f"{targets}: every target is a row of its part of the bank"
        rows[targets] = {tuple(row) for row in drawn}
        assert len(rows[targets]) > 300
        pose_keys = jax.random.split(jax.random.key(8), 600)
        starts = np.asarray(jax.vmap(task.start_qpos)(pose_keys, keys))
        uniform = np.asarray(jax.vmap(task.initial_qpos)(pose_keys))
        np.testing.assert_allclose(starts - drawn, 0.5 * (uniform - drawn), atol=1e-5)
    assert not rows["reachable"] & rows["reachable_held_out"]


def test_an_unknown_targets_value_is_refused_naming_the_choices(model):
    with pytest.raises(ValueError, match="targets must be one of asl, reachable, reachable_held_out"):
        MyoHandPose(model, targets="random")


@pytest.mark.parametrize("spread", [0, -0.4, 1.5, float("nan"), True, "0.4"])
def test_start_spread_outside_0_to_1_is_refused_naming_the_range(model, spread):
    with pytest.raises(ValueError, match=r"start_spread must be a number in \(0, 1\]"):
        MyoHandPose(model, start_spread=spread)


def test_a_config_with_start_spread_beyond_1_exits_2_naming_the_fix(capsys):
    assert main(["config", "show", "myohand_pose", "env.options.start_spread=1.5"]) == 2
    assert "env.options.start_spread=0.4" in capsys.readouterr().err


def snapshot(model: mujoco.MjModel, qpos: np.ndarray, act: float = 0.0):
    """A C MuJoCo snapshot of the hand at rest at `qpos`, every muscle at activation `act`."""
    data = mujoco.MjData(model)
    data.qpos[:] = qpos
    data.act[:] = act
    mujoco.mj_forward(model, data)
    return MyoHandPose(model).snapshot(data)


def test_a_step_is_solved_below_0_7_rad_and_an_episode_succeeds_after_more_than_5_solved_steps(model):
    """MyoSuite's definitions: the Euclidean joint error over the 23 joints below `pose_thd` 0.7 rad is solved; an
    episode solved on more than 5 steps is a success. Reward: minus the error, 4 x the bonus (1 below 0.7 rad, 1 more
    below 1.05), minus the mean squared activation."""
    task = MyoHandPose(model)
    target = np.asarray(TARGET_RANGES).mean(axis=1)
    info = {"target": jnp.asarray(target, jnp.float32), "solved_steps": jnp.zeros((), jnp.int32)}
    direction = np.ones(JOINTS) / math.sqrt(JOINTS)
    near, far = (snapshot(model, target + error * direction) for error in (0.69, 0.71))
    reward, terminated, after, metrics = task.evaluate(None, near, near, info)
    assert float(metrics["solved"]) == 1.0 and not bool(terminated)
    np.testing.assert_allclose(metrics["pose_error"], 0.69, atol=1e-5)
    np.testing.assert_allclose(reward, -0.69 + 4 * 2, atol=1e-5)
    reward, _, _, metrics = task.evaluate(None, far, far, info)
    assert float(metrics["solved"]) == 0.0
    np.testing.assert_allclose(reward, -0.71 + 4 * 1, atol=1e-5)
    successes = []
    for _ in range(7):
        _, _, info, metrics = task.evaluate(None, near, near, info)
        successes.append(float(metrics["success"]))
    assert successes == [0, 0, 0, 0, 0, 1, 1], "a success after the sixth solved step"
    _, _, info, metrics = task.evaluate(None, far, far, info)
    assert float(metrics["success"]) == 1.0 and int(info["solved_steps"]) == 7, "an unsolved step keeps the success"
    assert POSE_THRESHOLD == 0.7


def test_the_effort_cost_is_the_mean_squared_activation(model):
    task = MyoHandPose(model)
    target = np.asarray(TARGET_RANGES).mean(axis=1)
    info = {"target": jnp.asarray(target, jnp.float32), "solved_steps": jnp.zeros((), jnp.int32)}
    rest, excited = snapshot(model, target, 0.0), snapshot(model, target, 0.5)
    rest_reward, _, _, _ = task.evaluate(None, rest, rest, info)
    reward, _, _, metrics = task.evaluate(None, excited, excited, info)
    np.testing.assert_allclose(metrics["effort"], 0.25, atol=1e-6)
    np.testing.assert_allclose(rest_reward - reward, 0.25, atol=1e-5)
    free = MyoHandPose(model, PoseReward(effort=0.0))
    np.testing.assert_allclose(free.evaluate(None, excited, excited, info)[0], rest_reward, atol=1e-5)


def test_excitations_outside_0_1_are_clipped_as_muscles_clamp_them(model):
    task = MyoHandPose(model)
    lows, highs = task.action_bounds()
    np.testing.assert_array_equal(lows, np.zeros(MUSCLES))
    np.testing.assert_array_equal(highs, np.ones(MUSCLES))
    action = jnp.linspace(-0.5, 1.5, MUSCLES)
    np.testing.assert_allclose(task.control(action, None), np.clip(np.asarray(action), 0.0, 1.0))
    twins = []
    for excitation in (1.0, 3.0):
        env = aj.make("MyoHandPose", backend="cpu")
        state = env.reset(jax.random.key(2))
        twins.append(env.step(state, jnp.full(MUSCLES, excitation)).obs.proprioception)
    np.testing.assert_array_equal(twins[0], twins[1])


def test_options_are_checked_and_a_missing_myo_sim_names_the_install(monkeypatch):
    with pytest.raises(ValueError, match="Unknown reward coefficients"):
        aj.make("MyoHandPose", reward={"efort": 1.0}, backend="cpu")
    with pytest.raises(ValueError, match="whole multiple of the timestep"):
        aj.make("MyoHandPose", control_dt=0.003, backend="cpu")
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "myo_sim" else real(name, *a))
    with pytest.raises(ModuleNotFoundError, match=r'pip install -c constraints.txt -e "\.\[myo\]"'):
        aj.make("MyoHandPose", backend="cpu")


@pytest.fixture(scope="module", params=["MyoHandPose", "MyoHandReach"])
def warp_rollout(request):
    """A batch of MJX environments of a MyoHand task on MuJoCo Warp (on the CPU here) stepped `STEPS` times with random
    excitations, from the keys the C MuJoCo twin is reset with: the task's name, the keys, states and excitations."""
    env = aj.make(request.param, physics={"impl": "warp"}).sized_for(BATCH)
    keys = jax.random.split(jax.random.key(3), BATCH)
    reset = compile_quickly(jax.vmap(env.reset), keys)
    state = reset(keys)
    actions = jnp.asarray(np.random.default_rng(0).uniform(0, 1, (STEPS, BATCH, MUSCLES)), jnp.float32)
    step = compile_quickly(jax.vmap(env.step), state, actions[0])
    states = [state]
    for action in actions:
        states.append(step(states[-1], action))
    return request.param, keys, states, actions


@pytest.mark.slow
def test_mjx_on_warp_and_the_c_mujoco_twin_agree_for_10_steps(warp_rollout):
    """Same keys and excitations: joint angles within 1e-4 rad, muscle forces within 1e-3 of the largest force and
    rewards within 1e-4 over 10 policy steps (100 physics steps; float32 Warp against float64 C MuJoCo). Warp is the
    implementation GPUs run; MJX's JAX implementation wraps some tendons differently from C MuJoCo (its differences,
    and Warp's over 500 physics steps, are in benchmarks/results/myohand/). Both tasks: the pose's hand and the
    reach's, which stands where MyoSuite puts it (gravity from another direction)."""
    task, keys, states, actions = warp_rollout
    cpu = aj.make(task, backend="cpu")
    for b in range(BATCH):
        state = cpu.reset(keys[b])
        np.testing.assert_allclose(states[0].info["target"][b], state.info["target"], atol=1e-6)
        for t in range(STEPS):
            state = cpu.step(state, actions[t, b])
            mjx = states[t + 1]
            np.testing.assert_allclose(mjx.obs.proprioception[b, :JOINTS], state.obs.proprioception[:JOINTS],
                                       atol=1e-4)
            forces = state.obs.muscle[2 * MUSCLES:3 * MUSCLES]
            np.testing.assert_allclose(mjx.obs.muscle[b, 2 * MUSCLES:3 * MUSCLES], forces,
                                       atol=1e-3 * float(jnp.abs(forces).max()))
            np.testing.assert_allclose(mjx.obs.muscle[b, 3 * MUSCLES:], state.obs.muscle[3 * MUSCLES:], atol=1e-4)
            np.testing.assert_allclose(mjx.reward[b], state.reward, atol=1e-4)
        moved = jnp.abs(state.obs.proprioception[:JOINTS] - states[0].obs.proprioception[b, :JOINTS]).max()
        assert float(moved) > 0.05, "the hand must move"


@pytest.mark.slow
def test_myohand_pose_trains_two_cycles_with_the_beta_head(tmp_path, quick_compiles):
    """The shipped config, shrunk (4 envs, 8 steps per cycle, 4-step episodes, a 16-unit MLP) on MuJoCo Warp: two
    cycles run and log the task's metrics at the episodes' ends."""
    run = aj.train("myohand_pose", [
        "env.options.physics={impl: warp}", "env.options.max_episode_steps=4", "ppo.num_cycles=2", "ppo.num_envs=4",
        "ppo.rollout_length=8", "ppo.chunk_length=8", "ppo.minibatch_size=16", "ppo.num_epochs=1",
        "ppo.network.width=16", "checkpoint.every=2", "checkpoint.snapshot_every=0", "logging.progress=none",
        "logging.report=false", f"logging.run_root={tmp_path}", "logging.run_name=pose"])
    history = [json.loads(line) for line in (run.run_dir / "metrics.jsonl").read_text().splitlines()]
    assert len(history) == len(run.history) == 2
    assert {"metric/success", "metric/pose_error", "metric/effort"} <= set(history[-1])
    assert all(np.isfinite(record["episode_return"]) for record in history)
    agent = aj.load_agent(run.run_dir, "latest")
    assert agent.config.ppo.head == "beta" and float(agent.env.action_spec.low.min()) == 0.0


def test_a_config_of_the_myohand_without_myo_sim_exits_2_naming_the_install(monkeypatch, capsys):
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "myo_sim" else real(name, *a))
    assert main(["config", "show", "myohand_pose"]) == 2
    assert 'pip install -c constraints.txt -e ".[myo]"' in capsys.readouterr().err


def test_a_config_with_unknown_targets_exits_2_naming_the_choices(capsys):
    assert main(["config", "show", "myohand_pose", "env.options.targets=random"]) == 2
    assert "targets must be one of asl, reachable, reachable_held_out" in capsys.readouterr().err
