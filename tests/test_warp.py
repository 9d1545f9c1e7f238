"""MuJoCo Warp, the physics every GPU user runs (`physics.impl: auto` picks it on a GPU), tested on the CPU through
warp-lang's CPU backend (the `test` extra installs it): its env step agrees with C MuJoCo as MJX's JAX path does, a run
trained on it evaluates on the batched path, 2 devices train what 1 device trains (each device with its own
contact pool), and resuming on another device count goes on with fresh environments. The two-process
`jax.distributed` run on Warp is in test_distributed.py."""

import inspect
import json
import os
import subprocess
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from quick_compile import QUICK_SUBPROCESS_NO_FUSION_EMITTERS, compile_quickly

import angora_jax as aj
from angora_jax.cli import main
from angora_jax.experiment.evaluation import evaluate

TESTS = Path(__file__).resolve().parent
BATCH, STEPS = 3, 50


@pytest.mark.slow
def test_warp_steps_reach_as_c_mujoco_and_mjx_jax_do():
    """The same task logic and physics on Warp as on C MuJoCo, against which reach's MJX JAX path is tested
    (test_envs.py): the same goals, joint angles within 2e-3 rad and rewards within 1e-4 over 50 random-action steps
    (that test's tolerance), the same ends, with fingers touching in some steps, which the touch sensors (`touch`)
    read alike (within 5% or 0.05 N). The solver runs to convergence here:
    at reach's own caps (2 Newton, 4 line-search iterations) each implementation stops its unconverged solve
    differently (Warp and MJX's JAX implementation drift up to 0.046 rad apart over the 50 steps; converged they
    agree within 1e-4 rad, measured on the CPU; compiling the JAX side here would cost 21 s of the suite)."""
    physics = {"impl": "warp", "iterations": 50, "ls_iterations": 50}
    env = aj.make("ShadowHandReach", max_episode_steps=STEPS, physics=physics, touch=True).sized_for(BATCH)
    cpu = aj.make("ShadowHandReach", max_episode_steps=STEPS, physics=physics, touch=True, backend="cpu")
    actions = jnp.asarray(np.random.default_rng(0).uniform(-1, 1, (STEPS, BATCH, 20)), jnp.float32)
    keys = jax.random.split(jax.random.key(0), BATCH)

    def run(keys, actions):
        first = jax.vmap(env.reset)(keys)
        return first, jax.lax.scan(lambda s, a: (jax.vmap(env.step)(s, a),) * 2, first, actions)[1]

    first, warp = compile_quickly(run, keys, actions)(keys, actions)
    for b in range(BATCH):
        twin = cpu.reset(keys[b])
        np.testing.assert_allclose(first.info["goal"][b], twin.info["goal"], atol=1e-5)
        for t in range(STEPS):
            twin = cpu.step(twin, actions[t, b])
            np.testing.assert_allclose(warp.final_obs.proprioception[t, b, :24], twin.physics.qpos, atol=2e-3)
            np.testing.assert_allclose(warp.reward[t, b], twin.reward, atol=1e-4)
            np.testing.assert_allclose(warp.final_obs.touch[t, b], twin.final_obs.touch, rtol=0.05, atol=0.05)
            assert float(warp.done[t, b]) == float(twin.done)
    assert float(jnp.abs(warp.physics.qpos[-1] - warp.physics.qpos[0]).max()) > 0.05, "the hand must move"
    assert int(warp.physics._impl.nacon.max()) > 0, "fingers touch: Warp's contacts are exercised"
    assert float(warp.final_obs.touch.max()) > 0.1, "and the touch sensors (N) read them"


def test_a_warp_environment_sizes_warp_graph_cache_for_its_devices():
    """One process driving 4 GPUs hung after 3 cycles with Warp's default cache of 32 CUDA graphs per call, which
    that process had outgrown; with no bound, runs of one GPU per process ran out of GPU memory (each graph holds
    its allocations). Making a Warp environment sets the bound to 32 graphs per local device for every Warp call
    MJX creates afterwards (`size_warp_graph_cache`)."""
    import warp

    aj.make("ShadowHandReach", physics={"impl": "warp"})
    bound = inspect.signature(warp.jax_callable).parameters["graph_cache_max"].default
    assert bound == 32 * len(jax.local_devices())


@pytest.mark.slow
def test_a_warp_run_evaluates_on_the_batched_path_as_on_c_mujoco(two_devices, quick_compiles):
    """`angora-jax evaluate --path batched` steps the saved policy's episodes on Warp (the one-device reach run of
    warp_parallel.py), sized for the episodes at once; the C MuJoCo path plays the same episodes (same reset keys,
    mode actions): the same lengths, returns within 1%."""
    run_dir = Path(two_devices["root"]) / "devices1"
    assert main(["evaluate", str(run_dir), "--checkpoint", "latest", "--episodes", "4", "--path", "batched"]) == 0
    (written,) = (run_dir / "evaluation").glob("latest-*-batched.json")
    batched = json.loads(written.read_text())
    cpu = evaluate(run_dir, "latest", episodes=4, save=False)
    assert batched["path"] == "batched" and "MjxEnv (warp)" in batched["physics"]
    np.testing.assert_array_equal(batched["per_episode"]["episode_length"], cpu.episodes["episode_length"])
    np.testing.assert_allclose(batched["per_episode"]["episode_return"], cpu.episodes["episode_return"], rtol=1e-2)
    # One order on both paths (the batched path's came back from JAX sorted by name: episode_length first).
    assert list(batched["per_episode"]) == list(cpu.episodes) == list(cpu.summary)
    assert list(cpu.episodes) == ["episode_return", "episode_length", "metric/goal_distance", "metric/success"]


@pytest.fixture(scope="module")
def two_devices(tmp_path_factory):
    """tests/warp_parallel.py's results; a subprocess because the CPU device count is fixed when JAX starts. Its
    runs are a few cycles long, so it compiles quickly, XLA's CPU fusion emitters off (tests/quick_compile.py)."""
    root = tmp_path_factory.mktemp("runs")
    flags = f"{QUICK_SUBPROCESS_NO_FUSION_EMITTERS['XLA_FLAGS']} --xla_force_host_platform_device_count=2"
    done = subprocess.run(
        [sys.executable, str(TESTS / "warp_parallel.py"), str(root)],
        cwd=TESTS, env=os.environ | QUICK_SUBPROCESS_NO_FUSION_EMITTERS | {"XLA_FLAGS": flags},
        capture_output=True, text=True, timeout=600,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    return json.loads(done.stdout.strip().splitlines()[-1]) | {"stderr": done.stderr, "root": str(root)}


@pytest.mark.slow
def test_two_devices_train_on_warp_what_one_device_trains(two_devices):
    """The same totals on 2 devices as on 1: every metric within 1e-5, parameters within 1e-5 (observed 1.8e-6 of a
    largest parameter of 1.0 after 3 cycles), physics within 1e-4. Each device owns a contact pool with its own
    counters, the run's first line said so, and its buffers were sized for 4 envs, its share."""
    single, double = two_devices["single"], two_devices["double"]
    assert two_devices["device_count"] == 2 and len(single) == len(double) == 3
    for one, two in zip(single, double, strict=True):
        assert one.keys() == two.keys()
        names = sorted(one)
        np.testing.assert_allclose([two[k] for k in names], [one[k] for k in names], rtol=1e-5, atol=1e-5)
    assert two_devices["param_difference"] < 1e-5 < two_devices["param_scale"]
    assert two_devices["qpos_difference"] < 1e-4
    assert two_devices["contact_counters"] == {"single": [1], "double": [2], "double_shards": [[1], [1]]}
    physics = two_devices["sessions"][0]["physics"]
    assert physics["impl"] == "warp" and physics["warp_max_envs"] == 4 and physics["num_devices"] == 2


@pytest.mark.slow
def test_resuming_warp_on_another_device_count_goes_on_with_fresh_environments(two_devices):
    assert two_devices["continued_cycle"] == 4
    assert ("from cycle 3 with fresh environments, not bit for bit: its environments' states do not fit this run "
            "(actor.env_state.physics._impl.nacon: stored (2,) int32, expected (1,) int32") in two_devices["stderr"]


@pytest.mark.slow
def test_checkpoint_size_benchmark_saves_whole_and_lean_at_smoke_size(tmp_path):
    """benchmarks/checkpoint_size.py on Warp reach at 2,048 envs with a 16-wide network, so that the environments are
    most of the state: the lean checkpoint (no environments) takes a fraction of the whole one's disk (measured 0.107:
    0.05 of 0.5 MB, far outside the tens of kB by which Orbax's own files vary), and each part's bytes are reported."""
    out = tmp_path / "sizes.json"
    done = subprocess.run(
        [sys.executable, str(TESTS.parent / "benchmarks" / "checkpoint_size.py"), "shadow_reach", "ppo.num_envs=2048",
         "ppo.minibatch_size=8192", "ppo.network.width=16", "env.options.physics={impl: warp}", "--repeats", "1",
         "--out", str(out)],
        cwd=TESTS.parent / "benchmarks", capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    record = json.loads(out.read_text())
    whole, lean = record["results"]
    assert (whole["checkpoint"], lean["checkpoint"], lean["impl"]) == ("whole", "lean", "warp")
    assert 0 < lean["disk_mb"] and lean["fraction_of_whole"] < 0.4
    assert whole["save_seconds"] > 0 and lean["save_seconds"] > 0 and len(whole["save_seconds_each"]) == 1
    assert 0 < whole["blocking_seconds"] <= whole["save_seconds"] and len(lean["blocking_seconds_each"]) == 1
    assert record["config"]["state_mb"]["environments (actor, discounted_return)"] > 0
    assert "| ShadowHandReach | warp | 2,048 | lean |" in done.stdout
