"""Domain randomization of the hand tasks (`envs.randomization`): ranges are checked before anything compiles, a draw
is per environment and per key, zero-width ranges give the unrandomized task bit for bit, randomized fields change
the physics on both MJX implementations (Warp reading one world's fields per environment), the C MuJoCo twin
simulates the same worlds for the same key, the cube's size scales its geoms, mass and inertia, a delayed action
reaches the physics the drawn number of steps late, and the value function may see the drawn physics.

Warp's CPU kernels compile in seconds, so most tests run on Warp; one runs on MJX's JAX implementation."""

import json
from functools import partial
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from quick_compile import compile_quickly
from tiny import TINY_PPO

import angora_jax as aj
from angora_jax.cli import main
from angora_jax.envs.eager_batch import EagerBatch
from angora_jax.envs.randomization import DELAY_KEY, INFO_KEY
from angora_jax.experiment.evaluation import evaluate

# Every program here runs a few steps or a cycle or three, and none compares itself with an optimised one: the whole
# file compiles quickly (tests/quick_compile.py), its tests sharing JAX's in-process caches (the four `init_from`
# networks compile the task's reset and the eager operations once, not once each).
pytestmark = pytest.mark.usefixtures("quick_file_compiles")

BATCH, STEPS = 3, 6
# Converged solves, so that Warp and C MuJoCo agree within test_warp.py's tolerance (2e-3 rad).
WARP = {"impl": "warp", "iterations": 50, "ls_iterations": 50}
WIDE = {"friction": [0.2, 2.0], "joint_damping": [0.2, 5.0], "armature": [0.5, 2.0], "actuator_gain": [0.3, 3.0],
        "action_delay": [0, 3], "action_noise": 0.1, "observation_noise": 0.01}
FIELDS = {k: v for k, v in WIDE.items() if not k.endswith(("noise", "delay"))}
ZERO_WIDTH = {"friction": [1, 1], "joint_damping": [1, 1], "armature": [1, 1], "actuator_gain": [1, 1],
              "action_delay": [0, 0], "action_noise": 0, "observation_noise": 0}


def rollout(env, keys, actions):
    """`run(keys, actions)`: the batch's first states and its states after each of `STEPS` steps, compiled once
    (quickly, tests/quick_compile.py: these programs run six steps) for arguments shaped as `keys` and `actions`."""
    sized = env.sized_for(BATCH)

    def run(keys, actions):
        first = jax.vmap(sized.reset)(keys)
        return first, jax.lax.scan(lambda s, a: (jax.vmap(sized.step)(s, a),) * 2, first, actions)[1]

    return compile_quickly(run, keys, actions)


@pytest.fixture(scope="module")
def inputs():
    keys = jax.random.split(jax.random.key(3), BATCH)
    actions = jnp.asarray(np.random.default_rng(0).uniform(-1, 1, (STEPS, BATCH, 20)), jnp.float32)
    return keys, actions


@pytest.fixture(scope="module")
def warp_runs(inputs):
    """Reach on Warp unrandomized, with zero-width ranges, with wide ranges and with wide ranges of the model's fields
    only (no noise): (env, first states, states, the compiled `rollout`, which later tests run again on other keys
    instead of compiling the same program anew)."""
    runs = {}
    for name, ranges in {"plain": None, "zero": ZERO_WIDTH, "wide": WIDE, "fields": FIELDS}.items():
        env = aj.make("ShadowHandReach", physics=WARP, randomization=ranges)
        run = rollout(env, *inputs)
        runs[name] = (env, *run(*inputs), run)
    return runs


@pytest.mark.parametrize("ranges, message", [
    ({"friction": [-0.5, 1.0]}, "randomization.friction .* minimum must be >= 0"),
    ({"joint_damping": [2.0, 1.0]}, "randomization.joint_damping's minimum 2.0 is above its maximum 1.0"),
    ({"frction": [0.5, 1.0]}, r"Unknown randomization key 'frction' \(did you mean 'friction'\?\)"),
    ({"cube_mass": [0.5, 1.5]}, "randomization.cube_mass applies to the cube task only"),
    ({"armature": 1.5}, r"randomization.armature is a range of scale factors: give \[lo, hi\]"),
    ({"action_noise": -0.1}, "randomization.action_noise is a standard deviation"),
    ({"cube_size": [0.9, 1.1]}, "randomization.cube_size applies to the cube task only"),
    ({"action_delay": [0, 1.5]}, r"randomization.action_delay is a range of policy steps: give integers \[lo, hi\]"),
    ({"action_delay": [-1, 2]}, "randomization.action_delay is a delay: its minimum must be >= 0, got -1"),
    ({"action_delay": [3, 1]}, "randomization.action_delay's minimum 3 is above its maximum 1"),
])
def test_bad_ranges_are_refused_before_compiling_with_the_key_named(ranges, message):
    with pytest.raises(ValueError, match=message):
        aj.make("ShadowHandReach", randomization=ranges)


@pytest.mark.parametrize("key", ["cube_mass", "cube_size"])
def test_the_cube_refuses_a_mass_or_size_that_is_not_positive(key):
    quantity = key.removeprefix("cube_")
    with pytest.raises(ValueError, match=f"randomization.{key} scales the cube's {quantity}: its minimum must be > 0"):
        aj.make("ShadowHandCube", randomization={key: [0.0, 1.0]})


@pytest.mark.slow
def test_a_draw_differs_per_environment_and_is_reproducible_per_key(warp_runs, inputs):
    _, first, _, run = warp_runs["wide"]
    draws = first.info[INFO_KEY]
    assert set(draws) == {"geom_friction", "dof_damping", "dof_armature", "actuator_gainprm", "actuator_biasprm"}
    friction = np.asarray(draws["geom_friction"][:, 0, 0])
    assert len(set(friction.tolist())) == BATCH and (0.2 <= friction).all() and (friction <= 2.0).all()
    # The same keys in reversed slots draw the same worlds, reversed: a draw follows its key, not its slot.
    keys, actions = inputs
    again = run(keys[::-1], actions[:, ::-1])[0].info[INFO_KEY]
    jax.tree.map(lambda a, b: np.testing.assert_array_equal(a[::-1], b), again, draws)
    zero = warp_runs["zero"][1].info[INFO_KEY]
    assert all(bool((factors == 1).all()) for factors in jax.tree.leaves(zero)), "zero width at 1 draws exactly 1"


@pytest.mark.slow
def test_zero_width_ranges_give_the_unrandomized_task_bit_for_bit_on_warp(warp_runs):
    _, plain_first, plain, _ = warp_runs["plain"]
    _, zero_first, zero, _ = warp_runs["zero"]
    for a, b in ((plain_first, zero_first), (plain, zero)):
        np.testing.assert_array_equal(a.physics.qpos, b.physics.qpos)
        np.testing.assert_array_equal(a.physics.qvel, b.physics.qvel)
        jax.tree.map(np.testing.assert_array_equal, a.obs, b.obs)
        np.testing.assert_array_equal(a.reward, b.reward)


@pytest.mark.slow
def test_warp_simulates_each_environment_with_its_own_fields(warp_runs, inputs):
    """Randomized fields change the trajectory, and each environment of a Warp batch reads its own world's fields:
    with the keys' order reversed every environment's trajectory is the same, only in reversed place (had Warp read
    one world's fields for all, the environments would swap worlds)."""
    _, _, fields, run = warp_runs["fields"]
    _, _, plain, _ = warp_runs["plain"]
    assert float(jnp.abs(fields.physics.qpos[-1] - plain.physics.qpos[-1]).max()) > 0.05
    keys, actions = inputs
    _, reversed_run = run(keys[::-1], actions[:, ::-1])
    np.testing.assert_allclose(reversed_run.physics.qpos[:, ::-1], fields.physics.qpos, atol=1e-5)


@pytest.mark.slow
def test_the_cpu_twin_simulates_the_same_worlds_for_the_same_key(warp_runs, inputs):
    _, first, wide, _ = warp_runs["wide"]
    _, _, plain, _ = warp_runs["plain"]
    cpu = aj.make("ShadowHandReach", physics=WARP, randomization=WIDE, backend="cpu")
    keys, actions = inputs
    for b in range(BATCH):
        twin = cpu.reset(keys[b])
        row = jax.tree.map(lambda x, b=b: x[b], first.info)
        jax.tree.map(np.testing.assert_array_equal, row[DELAY_KEY], twin.info[DELAY_KEY])
        # The factors lo + u (hi - lo) from the same u: rounded alike up to a float32 ulp, which an optimised program
        # and the quickly compiled batch's may round differently.
        jax.tree.map(partial(np.testing.assert_allclose, rtol=2e-7), row[INFO_KEY], twin.info[INFO_KEY])
        np.testing.assert_allclose(first.obs.proprioception[b], twin.obs.proprioception, atol=1e-5)
        for t in range(STEPS):
            twin = cpu.step(twin, actions[t, b])
            np.testing.assert_allclose(wide.final_obs.proprioception[t, b], twin.obs.proprioception, atol=2e-3)
        assert float(jnp.abs(plain.physics.qpos[-1, b] - twin.physics.qpos).max()) > 0.02, "the twin is randomized"


@pytest.mark.slow
def test_randomized_fields_change_mjx_jax_physics_and_ones_give_the_unrandomized_task_bit_for_bit(inputs):
    """On MJX's JAX implementation (compiled once for the randomized task, once for the plain one): the drawn factors
    change the trajectory, and factors of exactly 1 (what zero-width ranges draw) give the plain task's states."""
    keys, actions = inputs
    # tests/test_envs.py's episode length and batch: the plain task's programs are its, read from the compilation cache
    # by whichever test compiles them second.
    randomized = aj.make("ShadowHandReach", physics={"impl": "jax"}, randomization=FIELDS, max_episode_steps=50)
    plain = aj.make("ShadowHandReach", physics={"impl": "jax"}, max_episode_steps=50)

    def compiled(env):
        first = compile_quickly(jax.vmap(env.reset), keys)(keys)
        return first, compile_quickly(jax.vmap(env.step), first, actions[0])

    def run(first, step):
        states = []
        for action in actions:
            first = step(first, action)
            states.append(first)
        return jax.tree.map(lambda *s: jnp.stack(s), *states)

    first, step = compiled(randomized)
    drawn = run(first, step)
    ones = run(first.replace(info=first.info | {INFO_KEY: jax.tree.map(jnp.ones_like, first.info[INFO_KEY])}), step)
    unrandomized = run(*compiled(plain))
    assert float(jnp.abs(drawn.physics.qpos[-1] - unrandomized.physics.qpos[-1]).max()) > 0.05
    np.testing.assert_array_equal(ones.physics.qpos, unrandomized.physics.qpos)
    np.testing.assert_array_equal(ones.physics.qvel, unrandomized.physics.qvel)
    np.testing.assert_array_equal(ones.reward, unrandomized.reward)


@pytest.mark.slow
def test_evaluate_runs_a_policy_under_randomization_given_as_an_env_option(tmp_path, capsys):
    """A reach run trains under randomization, its value function seeing the drawn physics; `angora-jax evaluate
    --env-option randomization=...` on the batched path (Warp) plays its policy in other randomized worlds (other
    ranges: the value function's inputs keep their size), recorded as a changed task; the CPU path (C MuJoCo slots,
    each its own world) plays the same episodes: the same lengths, returns within 1% (as test_warp.py's evaluation),
    and returns unlike those of the task it trained in."""
    run = aj.train("shadow_reach", [*TINY_PPO, "ppo.num_cycles=1", "env.options.physics={impl: warp}",
                                    "env.options.randomization={joint_damping: [0.8, 1.2]}",
                                    "env.options.value_sees_physics=true",
                                    "env.options.max_episode_steps=20", "logging.progress=none",
                                    "logging.report=false", "checkpoint.best_metric=null",
                                    f"logging.run_root={tmp_path}", "logging.run_name=reach"]).run_dir
    option = ("randomization={friction: [0.5, 1.5], actuator_gain: [0.2, 0.4], observation_noise: 0.01, "
              "action_delay: [1, 3]}")
    args = ["evaluate", str(run), "--checkpoint", "latest", "--episodes", "2", "--path", "batched"]
    assert main([*args, "--env-option", option]) == 0
    path = Path(capsys.readouterr().out.split("Written: ")[1].split(" and ")[0])
    written = json.loads(path.read_text())
    assert "-changed" in path.name
    assert written["task_options"]["randomization"]["friction"] == [0.5, 1.5], written["task_options"]
    returns = np.asarray(written["per_episode"]["episode_return"])
    cpu = evaluate(run, "latest", episodes=2, save=False, env_overrides=[option])
    np.testing.assert_array_equal(cpu.episodes["episode_length"], written["per_episode"]["episode_length"])
    np.testing.assert_allclose(cpu.episodes["episode_return"], returns, rtol=1e-2)
    plain = evaluate(run, "latest", episodes=2, save=False)
    # The same episodes on the same path in the run's own task: a change well above float rounding.
    changed = np.abs(plain.episodes["episode_return"] - cpu.episodes["episode_return"])
    assert changed.max() > 1e-3 * np.abs(returns).max()


@pytest.mark.slow
def test_the_value_function_sees_the_drawn_physics_in_one_layout_whichever_ranges_are_set(inputs):
    """`value_sees_physics`: `asymmetric` ends with the log of each drawn factor and the delay, held through the
    episode, in a layout that does not depend on the ranges (a run evaluated under other ranges, or none, keeps its
    value function's input size); zeros for the nominal physics. On the C MuJoCo twin (the batched path adds it in the
    same `MujocoEnv` code: test_evaluate_runs_a_policy_under_randomization_given_as_an_env_option)."""
    keys, actions = inputs
    plain = aj.make("ShadowHandReach", physics=WARP, backend="cpu").reset(keys[0]).obs.asymmetric
    env = aj.make("ShadowHandReach", physics=WARP, randomization=WIDE, value_sees_physics=True, backend="cpu")
    state = env.reset(keys[0])
    hand = env.task.randomizer.hand_dofs
    factors = state.info[INFO_KEY]
    expected = np.concatenate([np.log(factors["geom_friction"][0, :1]), np.log(factors["dof_damping"][hand]),
                               np.log(factors["dof_armature"][hand]), np.log(factors["actuator_gainprm"][:, 0]),
                               [state.info[DELAY_KEY]["delay"]]])
    assert len(hand) == 24 and expected.shape == (1 + 24 + 24 + 20 + 1,)
    np.testing.assert_array_equal(state.obs.asymmetric[: plain.shape[0]], plain)
    np.testing.assert_allclose(state.obs.asymmetric[plain.shape[0]:], expected, rtol=1e-6)
    for t in range(2):
        state = env.step(state, actions[t, 0])
        np.testing.assert_allclose(state.obs.asymmetric[plain.shape[0]:], expected, rtol=1e-6)
    # What the policy sees is as without the option.
    without = aj.make("ShadowHandReach", physics=WARP, randomization=WIDE, backend="cpu").reset(keys[0]).obs
    jax.tree.map(np.testing.assert_array_equal, without, env.reset(keys[0]).obs.replace(asymmetric=plain))
    friction = aj.make("ShadowHandReach", physics=WARP, randomization={"friction": [0.5, 1.5]},
                       value_sees_physics=True, backend="cpu").reset(keys[0]).obs.asymmetric[plain.shape[0]:]
    assert friction.shape == expected.shape and friction[0] != 0 and not np.any(friction[1:])
    nominal = aj.make("ShadowHandReach", physics=WARP, value_sees_physics=True, backend="cpu").reset(keys[0])
    np.testing.assert_array_equal(nominal.obs.asymmetric, np.concatenate([plain, np.zeros(expected.shape)]))


def cube_pose(env, inputs):
    """The cube's pose (position and quaternion, (BATCH, 7)) after `STEPS` steps of `rollout` on `env`."""
    cube = slice(env.task.cube_qpos, env.task.cube_qpos + 7)
    return rollout(env, *inputs)(*inputs)[1].physics.qpos[-1, :, cube]


@pytest.fixture(scope="module")
def plain_cube_pose(inputs):
    """`cube_pose` of the unrandomized cube on Warp (compiled once: Warp's programs are never read from JAX's
    persistent cache)."""
    return cube_pose(aj.make("ShadowHandCube", physics={"impl": "warp"}), inputs)


@pytest.mark.slow
def test_the_cube_ranges_scale_only_the_cube_and_change_its_motion_on_warp(inputs, plain_cube_pose):
    """On the cube, `cube_mass` scales the cube's mass and inertia only, `cube_damping` its free joint's 6 dofs only and
    `joint_damping` the hand's joints only; a heavier, more damped cube moves otherwise on Warp."""
    ranges = {"cube_mass": [4.0, 5.0], "cube_damping": [50.0, 60.0], "joint_damping": [2.0, 3.0]}
    env = aj.make("ShadowHandCube", physics={"impl": "warp"}, randomization=ranges)
    randomizer = env.task.randomizer
    factors = randomizer.draw(jax.random.key(0))
    mass, damping = np.asarray(factors["body_mass"]), np.asarray(factors["dof_damping"])
    assert np.flatnonzero(mass != 1).tolist() == [randomizer.cube_body] and 4 <= mass[randomizer.cube_body] <= 5
    np.testing.assert_array_equal(np.asarray(factors["body_inertia"])[randomizer.cube_body], mass[randomizer.cube_body])
    assert len(randomizer.cube_dofs) == 6 and (damping[randomizer.cube_dofs] >= 50).all()
    assert ((2 <= damping[randomizer.hand_dofs]) & (damping[randomizer.hand_dofs] <= 3)).all()
    assert float(jnp.abs(cube_pose(env, inputs) - plain_cube_pose).max()) > 1e-3


@pytest.mark.slow
def test_an_action_delay_is_drawn_per_environment_and_reaches_the_physics_that_many_steps_late(warp_runs, inputs):
    """The delay is an integer drawn per environment at reset, the same for the same key; with a delay of 2 the
    physics of step t receive the control of step t - 2's action (chosen in that step's state) and the first two
    steps hold the reset's control."""
    env = warp_runs["wide"][0]
    many = jax.random.split(jax.random.key(5), 16)
    reset = compile_quickly(jax.vmap(env.sized_for(16).reset), many)
    delays = np.asarray(reset(many).info[DELAY_KEY]["delay"])
    assert delays.dtype == np.int32 and set(delays.tolist()) == {0, 1, 2, 3}
    np.testing.assert_array_equal(np.asarray(reset(many).info[DELAY_KEY]["delay"]), delays)
    late = aj.make("ShadowHandReach", physics=WARP, randomization={"action_delay": [2, 2]})
    keys, actions = inputs
    first, states = rollout(late, keys, actions)(keys, actions)
    assert first.info[DELAY_KEY]["pending"].shape == (BATCH, 2, 20)

    def late_controls(first, states, actions):
        """The control of step t - 2's action in step t - 2's state, for steps t = 2 ... `STEPS` - 1: one program
        (eagerly, each slice and operation would compile its own)."""
        before = [first] + [jax.tree.map(lambda x, t=t: x[t], states) for t in range(STEPS - 3)]
        control = jax.vmap(late.task.control)
        return jnp.stack([control(actions[t - 2], late.task.snapshot(before[t - 2])) for t in range(2, STEPS)])

    late_ctrl = compile_quickly(late_controls, first.physics, states.physics, actions)(first.physics, states.physics,
                                                                                      actions)
    for t in range(STEPS):
        expected = first.physics.ctrl if t < 2 else late_ctrl[t - 2]
        # Computed outside the step's program: the same up to float32 rounding of a fused operation.
        np.testing.assert_allclose(states.physics.ctrl[t], expected, rtol=1e-6, atol=1e-7)


@pytest.mark.slow
def test_the_cube_size_scales_its_geoms_mass_and_inertia_on_every_path(inputs, plain_cube_pose):
    """`cube_size` scales the cube's geoms (sizes, bounding radii and boxes) by s, its mass by s^3 and inertia by s^5
    (times `cube_mass`'s factor); a larger cube moves otherwise on Warp, and the C MuJoCo twin and an `EagerBatch`
    slot write the same factors into their models."""
    ranges = {"cube_size": [1.3, 1.4], "cube_mass": [2.0, 2.0]}
    env = aj.make("ShadowHandCube", physics={"impl": "warp"}, randomization=ranges)
    randomizer, model = env.task.randomizer, env.task.model
    factors = randomizer.draw(jax.random.key(0))
    size = float(factors["geom_size"][randomizer.cube_geoms[0], 0])
    assert 1.3 <= size <= 1.4 and len(randomizer.cube_geoms) == 2
    for field in ("geom_size", "geom_rbound", "geom_aabb"):
        scaled = np.flatnonzero((np.asarray(factors[field]) != 1).reshape(model.ngeom, -1).any(axis=1))
        assert scaled.tolist() == randomizer.cube_geoms.tolist(), field
        assert (np.asarray(factors[field])[randomizer.cube_geoms] == np.float32(size)).all(), field
    np.testing.assert_allclose(factors["body_mass"][randomizer.cube_body], 2 * size**3, rtol=1e-6)
    np.testing.assert_allclose(factors["body_inertia"][randomizer.cube_body], 2 * size**5, rtol=1e-6)
    assert float(jnp.abs(cube_pose(env, inputs) - plain_cube_pose).max()) > 1e-3
    cpu = aj.make("ShadowHandCube", physics={"impl": "warp"}, randomization=ranges, backend="cpu")
    key = inputs[0][0]
    drawn = cpu.reset(key).info[INFO_KEY]
    geoms = randomizer.cube_geoms
    np.testing.assert_array_equal(cpu.model.geom_size[geoms], model.geom_size[geoms] * np.float64(
        drawn["geom_size"][geoms]))
    assert cpu.model.body_mass[randomizer.cube_body] == model.body_mass[randomizer.cube_body] * np.float64(
        drawn["body_mass"][randomizer.cube_body])
    # MuJoCo Warp lays the bounding boxes out as (ngeom, 2, 3) (the Warp rollout above scaled them); MJX's JAX
    # implementation as C MuJoCo does, and builds a box's collision vertices from the scaled geom_size.
    jax_env = aj.make("ShadowHandCube", physics={"impl": "jax"}, randomization=ranges)
    applied = jax_env.task.randomizer.apply(jax_env.mjx_model, factors)
    np.testing.assert_allclose(np.asarray(applied.geom_aabb)[geoms], np.float32(model.geom_aabb[geoms]) * size,
                               rtol=1e-6)
    np.testing.assert_array_equal(np.asarray(applied.geom_size)[0], np.float32(model.geom_size[0]))
    with EagerBatch(env, 1) as batch:
        batch.reset(0, key)
        np.testing.assert_array_equal(batch.models[0].geom_rbound, cpu.model.geom_rbound)
        np.testing.assert_array_equal(batch.models[0].geom_aabb, cpu.model.geom_aabb)


@pytest.mark.slow
def test_a_run_trained_under_randomization_resumes_exactly(tmp_path):
    """Reach under randomization (every kind: fields, delay, noise), 12-step episodes so that auto-resets draw new
    worlds and delays mid-run: stopped after its first cycle (`minutes`) and resumed, it ends as the run that was not
    stopped, metrics and the whole state (drawn factors and delay queues in the environments' info included) bit for
    bit."""
    ranges = "{friction: [0.5, 1.5], actuator_gain: [0.5, 1.5], action_delay: [0, 2], action_noise: 0.05, " \
             "observation_noise: 0.01}"
    overrides = [*TINY_PPO, "ppo.num_cycles=3", "ppo.network.width=16", "env.options.physics={impl: warp}",
                 f"env.options.randomization={ranges}", "env.options.max_episode_steps=12", "logging.progress=none",
                 "logging.report=false", "checkpoint.every=100", "checkpoint.snapshot_every=0",
                 f"logging.run_root={tmp_path}"]
    whole = aj.train("shadow_reach", [*overrides, "logging.run_name=whole"])
    first = aj.train("shadow_reach", [*overrides, "logging.run_name=pieces"], minutes=1e-9)
    assert not first.finished and [r["cycle"] for r in first.history] == [1]
    rest = aj.resume(first.run_dir)
    assert rest.finished and [r["cycle"] for r in rest.history] == [2, 3]
    untimed = {"seconds", "steps_per_second", "compile_seconds", "time", "memory/host_peak_bytes",
               "compile_cache_hits", "compile_cache_misses"}
    for a, b in zip(whole.history[1:], rest.history, strict=True):
        assert {k: v for k, v in a.items() if k not in untimed} == {k: v for k, v in b.items() if k not in untimed}
    info = whole.state.actor.env_state.info
    assert len(set(np.asarray(info[INFO_KEY]["geom_friction"][:, 0, 0]).tolist())) == 4, "one world per env"
    assert info[DELAY_KEY]["pending"].shape == (4, 2, 20)
    # Except MuJoCo Warp's contact pool field `contact__geomcollisionid` (shared by the batch): its unused entries hold
    # whatever memory Warp allocated (values like 1912240451), in unrandomized Warp runs too; no step reads them, as
    # the equal metrics and physics show.
    differ = []
    for (path, a), b in zip(jax.tree_util.tree_leaves_with_path(whole.state), jax.tree.leaves(rest.state), strict=True):
        if jax.dtypes.issubdtype(a.dtype, jax.dtypes.prng_key):
            a, b = jax.random.key_data(a), jax.random.key_data(b)
        if not np.array_equal(a, b):
            differ.append(jax.tree_util.keystr(path))
    assert differ in ([], [".actor.env_state.physics._impl.contact__geomcollisionid"]), differ


@pytest.mark.parametrize("network", [
    pytest.param({"name": "simple", "width": 8}, id="mlp", marks=pytest.mark.slow),
    pytest.param({"name": "simple", "width": 8, "shared_trunk": True}, id="shared", marks=pytest.mark.slow),
    pytest.param({"name": "gru", "width": 8, "cell_size": 8}, id="gru", marks=pytest.mark.slow),
    pytest.param({"name": "cortical"}, id="cortical", marks=pytest.mark.slow)])
def test_init_from_a_run_without_value_sees_physics_carries_its_value_function_over(network, monkeypatch):
    """`ppo.init_from` a reach run trained without `value_sees_physics`, fine-tuned with it: the value function's
    inputs gain 70 entries at the end of `asymmetric`. Everything carries over; the weights that read the new entries
    start at zero, so the new model's policy and value are the source's whatever physics it is given. The source's
    `asymmetric` statistics carry over for the entries it had (the new ones mean 0, variance 1, the count afresh so
    the first batch sets them all), the other modalities' as they were. A source that misfits otherwise is refused."""
    from types import SimpleNamespace

    from angora_jax.nets import make_network
    from angora_jax.ppo import NetworkConfig, PPOConfig, make_cycle
    from angora_jax.ppo import cycle as cycle_module
    from angora_jax.ppo.cycle import SavedRunMisfit, build_head, build_model, check_saved_values

    plain = aj.make("ShadowHandReach", max_episode_steps=10)
    sees = aj.make("ShadowHandReach", max_episode_steps=10, randomization={"joint_damping": [0.8, 1.2]},
                   value_sees_physics=True)
    config = PPOConfig(num_envs=2, rollout_length=8, chunk_length=8, minibatch_size=16, num_epochs=1,
                       network=NetworkConfig(**network))
    source = make_cycle(plain, None, config)[0](jax.random.key(1))
    old = source.obs_stats.asymmetric
    stats = source.obs_stats.replace(asymmetric=old.replace(mean=old.mean + 0.5, var=old.var * 2, count=old.count + 9))
    monkeypatch.setattr(cycle_module, "read_saved_run", lambda _: SimpleNamespace(params=source.params,
                                                                                 obs_stats=stats))
    fine_tune = config.replace(init_from="runs/source")
    check_saved_values(sees, fine_tune)
    state = make_cycle(sees, None, fine_tune)[0](jax.random.key(2))

    model = build_model(make_network(config.network), build_head(plain, config), config)
    leaves, treedef = jax.tree.flatten(plain.observation_shapes())
    keys = jax.random.split(jax.random.key(3), len(leaves) + 1)
    obs = jax.tree.unflatten(treedef, [jax.random.normal(k, (BATCH, *leaf.shape))
                                      for leaf, k in zip(leaves, keys[:-1], strict=True)])
    physics = jax.random.normal(keys[-1], (BATCH, 70))
    carry = model.initial_carry(BATCH)
    _, policy, value = model.apply({"params": source.params}, carry, obs)
    grown = obs.replace(asymmetric=jnp.concatenate([obs.asymmetric, physics], axis=-1))
    _, policy_now, value_now = model.apply({"params": state.params}, carry, grown)
    np.testing.assert_allclose(policy_now, policy, rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(value_now, value, rtol=1e-5, atol=1e-5)

    size = old.mean.shape[0]
    asymmetric = state.obs_stats.asymmetric
    assert asymmetric.mean.shape == (size + 70,)
    np.testing.assert_array_equal(asymmetric.mean[:size], stats.asymmetric.mean)
    np.testing.assert_array_equal(asymmetric.var[:size], stats.asymmetric.var)
    np.testing.assert_array_equal(asymmetric.mean[size:], 0.0)
    np.testing.assert_array_equal(asymmetric.var[size:], 1.0)
    assert float(asymmetric.count) < 1e-3
    np.testing.assert_array_equal(state.obs_stats.proprioception.mean, stats.proprioception.mean)
    assert float(state.obs_stats.proprioception.count) == float(stats.proprioception.count)

    first = jax.tree_util.tree_leaves_with_path(source.params)[0][0]
    misfit = jax.tree_util.tree_map_with_path(lambda path, x: jnp.zeros((3, 3)) if path == first else x, source.params)
    monkeypatch.setattr(cycle_module, "read_saved_run", lambda _: SimpleNamespace(params=misfit, obs_stats=stats))
    with pytest.raises(SavedRunMisfit, match="do not fit this run's"):
        check_saved_values(sees, fine_tune)
