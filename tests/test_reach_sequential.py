"""The sequential finger-opposition tasks (AngoraPy's ReachSequential and FreeReachSequential): the sequence drawn,
the goal advancing exactly when the current target is reached, the metrics, bad options, MJX/CPU parity, and the rules
that keep a sequence honest: a free target counts only when the other fingertips are away from the thumb, and the
reward does not make reaching a target worse than hovering near it."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from quick_compile import compile_quickly

import angora_jax as aj
from angora_jax.envs.mujoco_task import start_physics
from angora_jax.envs.shadow_hand import REACH_PHYSICS
from angora_jax.envs.shadow_hand.model import load_scene
from angora_jax.envs.shadow_hand.reach import THUMB, Reach

LENGTH = 5
BATCH = 2
# Every step is a success: the goal advances on every step and the episode ends after LENGTH steps.
ALWAYS = {"success_distance": 10.0}


def test_the_sequential_tasks_are_registered():
    assert {"ShadowHandReachSequential", "ShadowHandFreeReachSequential"} <= set(aj.list_tasks())
    env = aj.make("ShadowHandFreeReachSequential", backend="cpu")
    assert env.task.sequence_length == 4 and env.task.free
    assert env.metric_names == ("success", "goal_distance", "sequence_steps", "sequence_success")


def test_a_sequence_is_reproducible_per_key_differs_across_keys_and_never_repeats_a_finger():
    task = Reach(load_scene("reach.xml", physics=REACH_PHYSICS), sequence_length=12)
    keys = jax.random.split(jax.random.key(0), 16)
    drawn = np.asarray(jax.jit(jax.vmap(task.draw_sequence))(keys))
    assert drawn.shape == (16, 12) and drawn.min() >= 0 and drawn.max() <= 3
    np.testing.assert_array_equal(drawn[3], task.draw_sequence(keys[3]))
    assert len({tuple(row) for row in drawn}) == 16, "each key draws its own sequence"
    assert (drawn[:, 1:] != drawn[:, :-1]).all(), "consecutive targets differ, as AngoraPy draws them"
    assert set(drawn.ravel()) == {0, 1, 2, 3}


def test_angorapys_free_sequence_is_the_fixed_order_in_every_episode():
    env = aj.make("ShadowHandFreeReachSequential", backend="cpu", sequence_length=6)
    for k in range(3):
        np.testing.assert_array_equal(env.reset(jax.random.key(k)).info["sequence"], [0, 1, 2, 3, 0, 1])
    drawn = aj.make("ShadowHandFreeReachSequential", backend="cpu", sequence_order="random").reset(jax.random.key(0))
    assert not np.array_equal(drawn.info["sequence"], [0, 1, 2, 3]), "key 0 draws another order"


@pytest.mark.parametrize("task", ["ShadowHandReachSequential", "ShadowHandFreeReachSequential"])
def test_the_goal_advances_exactly_when_the_target_is_reached(task):
    """Under small random actions and a 7 cm success distance, first and middle finger start within reach of the
    thumb and ring and little finger do not (freereach), so some steps advance and some do not."""
    distance = 0.07 if "Free" in task else 0.1
    env = aj.make(task, backend="cpu", sequence_length=LENGTH, max_episode_steps=12,
                  reward={"success_distance": distance})
    rng = np.random.default_rng(0)
    outcomes = set()
    for k in range(4):
        state = env.reset(jax.random.key(k))
        sequence = np.asarray(state.info["sequence"])
        assert int(state.info["target"]) == sequence[0] and int(state.info["sequence_step"]) == 0
        while not float(state.done):
            before = int(state.info["sequence_step"])
            state = env.step(state, jnp.asarray(rng.uniform(-0.1, 0.1, 20), jnp.float32))
            reached = float(state.metrics["goal_distance"]) < distance
            outcomes.add(reached)
            step = int(state.info["sequence_step"])
            assert step == before + reached
            assert float(state.metrics["sequence_steps"]) == step
            assert float(state.metrics["sequence_success"]) == (step == LENGTH)
            assert int(state.info["target"]) == sequence[min(step, LENGTH - 1)]
            np.testing.assert_array_equal(state.obs.goal[-5:], np.eye(5)[sequence[min(step, LENGTH - 1)]])
            assert float(state.done) == (step == LENGTH or float(state.truncated))
    assert outcomes == {True, False}, "the run must show both a step that advances and one that does not"


def test_a_sequence_done_ends_the_episode_with_its_success():
    env = aj.make("ShadowHandReachSequential", backend="cpu", sequence_length=LENGTH, reward=ALWAYS)
    state = env.reset(jax.random.key(1))
    goals = [np.asarray(state.info["goal"])]
    for t in range(1, LENGTH + 1):
        state = env.step(state, jnp.zeros(20))
        goals.append(np.asarray(state.info["goal"]))
        assert float(state.metrics["sequence_steps"]) == t
        assert float(state.done) == (t == LENGTH) and float(state.truncated) == 0.0
    assert float(state.metrics["sequence_success"]) == 1.0
    changes = [np.abs(a - b).max() for a, b in zip(goals[:-2], goals[1:-1], strict=True)]
    assert min(changes) > 1e-3, "each target has its own goal"


def test_bad_sequence_options_are_refused():
    for bad in (0, -2, 2.5, True):
        with pytest.raises(ValueError, match=rf"sequence_length must be an int >= 1.*{bad!r}.*sequence_length=4"):
            aj.make("ShadowHandReach", backend="cpu", sequence_length=bad)
    with pytest.raises(ValueError, match="target_finger='RF'.*sequence_length=4.*target_finger=None"):
        aj.make("ShadowHandFreeReachSequential", backend="cpu", target_finger="RF")
    with pytest.raises(ValueError, match=r"Unknown target_finger 'TH'"):
        aj.make("ShadowHandReachSequential", backend="cpu", target_finger="TH")
    with pytest.raises(ValueError, match=r"Unknown sequence_order 'sorted'.*\('random', 'fixed'\)"):
        aj.make("ShadowHandReachSequential", backend="cpu", sequence_order="sorted")
    with pytest.raises(ValueError, match="sequence_order='fixed'.*give sequence_length too"):
        aj.make("ShadowHandReach", backend="cpu", sequence_order="fixed")


@pytest.mark.slow
def test_mjx_and_cpu_paths_agree_on_the_sequence():
    """Same keys and actions, a success on every step: targets, goals (drawn anew from the step's key on each advance)
    and sequence metrics equal, joint positions and rewards within test_envs' tolerances, until the sequence ends. With
    `touch` the 97 touch readings agree too (no finger touches another in these few steps: test_envs.py presses two
    together, test_warp.py compares readings of contacts)."""
    options = {"sequence_length": LENGTH, "max_episode_steps": 10, "reward": ALWAYS, "touch": True}
    mjx, cpu = aj.make("ShadowHandReachSequential", **options), aj.make("ShadowHandReachSequential", backend="cpu",
                                                                        **options)
    keys = jax.random.split(jax.random.key(0), BATCH)
    reset = compile_quickly(jax.vmap(mjx.reset), keys)
    state = reset(keys)
    step = compile_quickly(jax.vmap(mjx.step), state, jnp.zeros((BATCH, 20), jnp.float32))
    actions = jnp.asarray(np.random.default_rng(0).uniform(-1, 1, (LENGTH, BATCH, 20)), jnp.float32)
    cpu_state = cpu.reset(keys[0])
    np.testing.assert_array_equal(state.info["sequence"][0], cpu_state.info["sequence"])
    assert not (state.info["sequence"][0] == state.info["sequence"][1]).all(), "each environment its own sequence"
    for t in range(LENGTH):
        state, cpu_state = step(state, actions[t]), cpu.step(cpu_state, actions[t, 0])
        np.testing.assert_allclose(state.final_obs.proprioception[0, :24], cpu_state.physics.qpos, atol=2e-3)
        np.testing.assert_allclose(state.reward[0], cpu_state.reward, atol=1e-4)
        assert state.final_obs.touch.shape == (BATCH, 97)
        np.testing.assert_allclose(state.final_obs.touch[0], cpu_state.final_obs.touch, atol=1e-3)
        for name in ("sequence_steps", "sequence_success"):
            assert float(state.metrics[name][0]) == float(cpu_state.metrics[name]), name
        np.testing.assert_array_equal(state.done[0], cpu_state.done)
        if t < LENGTH - 1:
            assert int(state.info["target"][0]) == int(cpu_state.info["target"])
            np.testing.assert_allclose(state.info["goal"][0], cpu_state.info["goal"], atol=2e-3)
    assert float(cpu_state.done) == 1.0 and float(state.metrics["sequence_success"][0]) == 1.0


def start_of(task):
    """The C MuJoCo snapshot of `task`'s initial pose and the episode's info drawn from key 0."""
    start = task.snapshot(start_physics(task, np.asarray(task.initial_qpos(None), np.float64)))
    return start, task.initial_info(jax.random.key(0), start)


def placed(task, snap, tips):
    """`snap` with the five fingertips (FF, MF, RF, LF, thumb) at `tips` (5, 3) m: all that reach's rules read."""
    return snap.replace(site_xpos=snap.site_xpos.at[task.fingertip_ids].set(jnp.asarray(tips, jnp.float32)))


def test_a_free_target_is_reached_only_when_thumb_and_target_meet_alone():
    """All four fingertips 5 mm from the thumb at once reach no target, however often (the old rule, thumb to target
    only, counted FF, MF, RF, LF reached in four steps so); the target 5 mm from the thumb counts when every other
    fingertip is at least `clearance_distance` (4 cm) from it (4.5 cm here), not when one is 3.5 cm from it."""
    task = Reach(load_scene("reach.xml", physics=REACH_PHYSICS), free=True, sequence_length=4,
                 sequence_order="fixed")
    start, info = start_of(task)
    thumb = np.asarray(start.site_xpos[task.fingertip_ids[THUMB]])
    directions = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1], [-1, 0, 0]], np.float32)
    bunched = placed(task, start, np.vstack([thumb + 0.005 * directions, thumb]))
    for _ in range(4):
        _, done, info, metrics = task.evaluate(jax.random.key(1), bunched, bunched, info)
        assert float(metrics["success"]) == 0.0 and int(info["sequence_step"]) == 0 and not bool(done)
    for other, reached in ((0.045, 1.0), (0.035, 0.0)):
        tips = np.vstack([thumb + 0.005 * directions[:1], thumb + other * directions[1:], thumb])
        metrics = task.evaluate(jax.random.key(1), start, placed(task, start, tips), info)[3]
        assert float(metrics["success"]) == reached, other


def test_reaching_a_sequential_reach_target_pays_more_than_hovering_outside_it():
    """A sequence's reward is the progress towards the current goal, so reaching a target and then holding still
    (the goal has moved on: 0.10-0.11 m away) pays more over 10 steps than hovering 5 mm outside the success distance.
    Under minus the goal distance, reaching paid the 0.1 bonus and then about -0.1 per step against -0.025 hovering:
    the likely reason why ShadowHandReachSequential learned to reach no target."""
    task = Reach(load_scene("reach.xml", physics=REACH_PHYSICS), sequence_length=4)
    start, info = start_of(task)
    goal = np.asarray(info["goal"])
    outside = goal + (task.reward_config.success_distance + 0.005) / np.sqrt(15)
    returns = {}
    for name, tips in (("reached", goal), ("hovering", outside)):
        at = placed(task, start, tips)
        reward, _, after, metrics = task.evaluate(jax.random.key(1), start, at, info)
        assert float(metrics["sequence_steps"]) == (name == "reached")
        held = [task.evaluate(jax.random.key(2), at, at, after)[0] for _ in range(10)]
        np.testing.assert_allclose(held, 0.0, atol=1e-6, err_msg="holding still makes no progress")
        returns[name] = float(reward) + float(np.sum(held))
    assert returns["reached"] > returns["hovering"] + 0.05, returns
