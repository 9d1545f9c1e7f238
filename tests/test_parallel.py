"""Data-parallel training (angora_jax.ppo.parallel): on 4 CPU devices the replicated state stays identical on every
device, normaliser statistics pool exactly, a 4-device run computes the single-device run with the same totals up
to float rounding, and resuming a 4-device run is bit for bit; indivisible totals fail naming the keys."""

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from quick_compile import QUICK_SUBPROCESS

from angora_jax.ppo import PPOConfig
from angora_jax.ppo.parallel import per_device

TESTS = Path(__file__).resolve().parent
BENCHMARKS = TESTS.parent / "benchmarks"


@pytest.fixture(scope="module")
def four_devices(tmp_path_factory):
    """tests/multidevice.py's results; a subprocess because the CPU device count is fixed when JAX starts. Its runs
    are a few cycles of CartPole, so it compiles quickly (tests/quick_compile.py)."""
    env = os.environ | QUICK_SUBPROCESS | {"XLA_FLAGS": "--xla_force_host_platform_device_count=4"}
    done = subprocess.run(
        [sys.executable, str(TESTS / "multidevice.py"), str(tmp_path_factory.mktemp("runs"))],
        cwd=TESTS,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    return json.loads(done.stdout.strip().splitlines()[-1])


@pytest.mark.slow
def test_replicated_state_is_identical_on_every_device(four_devices):
    assert four_devices["device_count"] == 4
    assert all(four_devices["in_sync"]) and len(four_devices["in_sync"]) == 8


@pytest.mark.slow
def test_the_per_device_body_takes_only_the_state_its_constants_stay_inside(four_devices):
    # CartPole's cycle closes over one array; passed in as a shard_map operand instead, constants reach the GPU
    # compiler as loop-carried values it does not fold (angora_jax/ppo/parallel.py, data_parallel).
    operands, state_leaves = four_devices["body_operands"]
    assert operands == state_leaves


@pytest.mark.slow
def test_normaliser_merge_over_devices_equals_one_merge_of_the_whole_batch(four_devices):
    assert four_devices["pooled_stats_error"] < 1e-5


@pytest.mark.slow
def test_four_devices_compute_the_single_device_run_up_to_float_rounding(four_devices):
    # Same random numbers per environment and the same global minibatches on any device count, so the runs differ
    # only in summation order. Observed on CartPole, 8 cycles of 16 envs x 32 steps: parameters (largest |p| 0.59)
    # within 1.8e-7, identical episode returns, every other metric within 1.1e-6.
    single, parallel = four_devices["single"], four_devices["parallel"]
    assert max(four_devices["param_differences"]) < 1e-5 < four_devices["param_scale"]
    assert [m.keys() for m in single] == [m.keys() for m in parallel] and len(single) == 8
    for one, four in zip(single, parallel, strict=True):
        names = sorted(one)
        np.testing.assert_allclose([four[k] for k in names], [one[k] for k in names], rtol=1e-5, atol=1e-5)
    # The runs learn (so agreeing is not agreeing on nothing): returns up about 5x by the last two cycles.
    assert np.nanmean([m["episode_return"] for m in single[-2:]]) > 3 * single[0]["episode_return"]
    assert all(m["finite"] == 1.0 for m in single)


@pytest.mark.slow
def test_resumed_four_device_run_equals_uninterrupted(four_devices):
    assert four_devices["resumed_equals_whole"]


@pytest.mark.slow
def test_four_policy_blocks_lie_one_per_device_and_compute_the_single_device_run(four_devices):
    """ppo.blocks with as many blocks as devices: device d holds block d, and the leader's off-policy term and the
    per-block entropy weights give on 4 devices what they give on one, up to float rounding."""
    assert four_devices["device_blocks"] == [[0] * 4, [1] * 4, [2] * 4, [3] * 4]
    assert all(four_devices["blocks_in_sync"])
    assert max(four_devices["blocks_param_differences"]) < 1e-5
    single, parallel = four_devices["blocks_single"], four_devices["blocks_parallel"]
    assert "leader_off_policy_loss" in single[0] and "block3/episode_return" in single[0]
    for one, four in zip(single, parallel, strict=True):
        names = sorted(one)
        np.testing.assert_allclose([four[k] for k in names], [one[k] for k in names], rtol=1e-5, atol=1e-5)


def test_single_device_config_is_unchanged():
    config = PPOConfig()
    assert per_device(config, 1) is config


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"num_envs": 6}, r"ppo.num_envs=6 is a run total .*num_devices=4 .*multiple of 4; use e.g. ppo.num_envs=8"),
        ({"minibatch_size": 18}, r"ppo.minibatch_size=18 is a run total"),
        (
            {"num_envs": 8, "minibatch_size": 32, "chunk_length": 16},
            r"tiles of n=2 trajectories x m=1 chunk \(.*multiple of 4; use e.g. ppo.minibatch_size=64",
        ),
    ],
)
def test_indivisible_totals_fail_naming_the_keys(changes, message):
    with pytest.raises(ValueError, match=message):
        per_device(PPOConfig().replace(**changes), 4)


def test_a_suggested_fix_fits_the_devices_itself():
    """9 envs with 48-sample minibatches (3 chunks: no tile 4 devices can share) were told ppo.num_envs=12, which
    then failed on the tile rule: the suggestion names both settings, and both together fit."""
    config = PPOConfig().replace(num_envs=9, minibatch_size=48, chunk_length=16)
    with pytest.raises(ValueError, match=r"must be a multiple of 4; use e.g. ppo.num_envs=(\d+) ppo.minibatch_size="
                                         r"(\d+)\.$") as refused:
        per_device(config, 4)
    num_envs, minibatch_size = map(int, re.search(r"num_envs=(\d+) ppo.minibatch_size=(\d+)",
                                                  str(refused.value)).groups())
    assert per_device(config.replace(num_envs=num_envs, minibatch_size=minibatch_size), 4).num_envs == num_envs // 4
