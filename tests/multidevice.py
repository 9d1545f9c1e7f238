"""Run by test_parallel.py in a subprocess with XLA_FLAGS=--xla_force_host_platform_device_count=4 (the device count
is fixed when JAX starts). argv[1]: a scratch folder. Prints one JSON object with what the tests assert on."""

import json
import os
import signal
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh
from jax.sharding import PartitionSpec as P
from tiny import TINY_PPO

import angora_jax as aj
from angora_jax.envs.registry import make
from angora_jax.experiment import TrainingInterrupted, resume
from angora_jax.ppo import PPOConfig, make_cycle
from angora_jax.ppo.blocks import environment_blocks
from angora_jax.ppo.config import BlocksConfig
from angora_jax.ppo.normalization import RunningMeanStd
from angora_jax.ppo.parallel import AXIS

CURVE = PPOConfig(num_envs=16, rollout_length=32, chunk_length=8, minibatch_size=128, num_epochs=2, num_cycles=8)
# Four policy blocks, one per device on 4 devices (ppo.blocks), for 3 cycles.
BLOCKS = CURVE.replace(num_cycles=3, blocks=BlocksConfig(count=4, embedding_size=4,
                                                         entropy_coefs=(0.0, 0.01, 0.02, 0.03)))
REPLICATED = ("params", "opt_state", "obs_stats", "reward_stats", "key", "cycle")


def host(leaf):
    return np.asarray(jax.random.key_data(leaf) if jax.dtypes.issubdtype(leaf.dtype, jax.dtypes.prng_key) else leaf)


def replicas_identical(state) -> bool:
    """Every device's copy of every replicated leaf equals device 0's, bit for bit."""
    for name in REPLICATED:
        for leaf in jax.tree.leaves(getattr(state, name)):
            shards = [host(shard.data) for shard in leaf.addressable_shards]
            if len(shards) != 4 or any(not np.array_equal(shards[0], other) for other in shards[1:]):
                return False
    return True


def curve(num_devices, config=CURVE):
    """Metrics of every cycle, whether the replicas were in sync after it, and the parameters after it (host)."""
    init, cycle = make_cycle(make("CartPole"), None, config, num_devices)
    state, history, in_sync, params = init(jax.random.key(0)), [], [], []
    for _ in range(config.num_cycles):
        state, metrics = cycle(state)
        history.append({name: float(value) for name, value in metrics.items()})
        in_sync.append(num_devices == 1 or replicas_identical(state))
        params.append([host(leaf) for leaf in jax.tree.leaves(state.params)])
    return history, in_sync, params


def largest_difference(single, parallel) -> float:
    """Max abs difference between corresponding leaves of two lists of arrays."""
    return max(float(np.abs(a - b).max()) for a, b in zip(single, parallel, strict=True))


def device_blocks() -> list[list[int]]:
    """The policy blocks of each device's environments, 16 environments in 4 blocks on 4 devices."""
    mesh = Mesh(np.array(jax.devices()), (AXIS,))
    blocks = jax.jit(jax.shard_map(lambda: environment_blocks(16, 4, AXIS), mesh=mesh, in_specs=(), out_specs=P(AXIS)))
    return np.asarray(blocks()).reshape(4, 4).tolist()


def pooled_stats():
    """Max abs difference between stats merged from 4 devices' batches and from the whole batch on one device."""
    batch = jax.random.normal(jax.random.key(1), (64, 3)) * jnp.array([1.0, 5.0, 0.1]) + jnp.array([2.0, -1.0, 0.0])
    start = RunningMeanStd.create((3,)).update(batch[:8] * 3.0)
    mesh = Mesh(np.array(jax.devices()), (AXIS,))
    merged = jax.jit(
        jax.shard_map(lambda b: start.update(b, AXIS), mesh=mesh, in_specs=P(AXIS), out_specs=P(), check_vma=False)
    )(batch)
    whole = start.update(batch)
    return max(
        float(jnp.abs(a - b).max()) for a, b in zip(jax.tree.leaves(merged), jax.tree.leaves(whole), strict=True)
    )


def body_operands() -> tuple[int, int]:
    """The operand count of the data-parallel cycle's shard_map and the TrainState's leaf count: equal when the
    constants the cycle closes over stay inside the per-device body (see `parallel.data_parallel`)."""
    init, cycle = make_cycle(make("CartPole"), None, CURVE, 4)
    state = init(jax.random.key(0))
    (outer,) = jax.make_jaxpr(cycle.compiled)(state).jaxpr.eqns
    (shard_map,) = [eqn for eqn in outer.params["jaxpr"].jaxpr.eqns if eqn.primitive.name == "shard_map"]
    return len(shard_map.invars), len(jax.tree.leaves(state))


def resumed_equals_whole(root: Path) -> bool:
    """A 4-device run stopped by SIGTERM after cycle 2 and resumed ends bit for bit like an uninterrupted one."""
    overrides = [
        *TINY_PPO,
        "ppo.num_cycles=4",
        "distribution.num_devices=4",
        "logging.progress=none",
        "logging.report=false",
        f"logging.run_root={root}",
    ]
    whole = aj.train("cartpole", [*overrides, "logging.run_name=whole"])

    def terminate_after_cycle_2(record):
        if record["cycle"] == 2:
            os.kill(os.getpid(), signal.SIGTERM)

    try:
        aj.train("cartpole", [*overrides, "logging.run_name=split"], on_cycle=terminate_after_cycle_2)
    except TrainingInterrupted:
        pass
    resumed = resume(root / "split")
    leaves = zip(jax.tree.leaves(whole.state), jax.tree.leaves(resumed.state), strict=True)
    return replicas_identical(resumed.state) and all(np.array_equal(host(a), host(b)) for a, b in leaves)


if __name__ == "__main__":
    single, _, single_params = curve(1)
    parallel, in_sync, parallel_params = curve(4)
    result = {
        "device_count": jax.device_count(),
        "single": single,
        "parallel": parallel,
        "in_sync": in_sync,
        "param_differences": [largest_difference(a, b) for a, b in zip(single_params, parallel_params, strict=True)],
        "param_scale": max(float(np.abs(leaf).max()) for leaf in single_params[-1]),
        "pooled_stats_error": pooled_stats(),
        "body_operands": body_operands(),
        "resumed_equals_whole": resumed_equals_whole(Path(sys.argv[1])),
        "device_blocks": device_blocks(),
    }
    blocks_single, _, blocks_single_params = curve(1, BLOCKS)
    blocks_parallel, blocks_in_sync, blocks_parallel_params = curve(4, BLOCKS)
    result |= {
        "blocks_single": blocks_single,
        "blocks_parallel": blocks_parallel,
        "blocks_in_sync": blocks_in_sync,
        "blocks_param_differences": [largest_difference(a, b) for a, b in
                                     zip(blocks_single_params, blocks_parallel_params, strict=True)],
    }
    print(json.dumps(result))
