"""Run by test_warp.py in a subprocess with XLA_FLAGS=--xla_force_host_platform_device_count=2 (the device count is
fixed when JAX starts): reach on MuJoCo Warp trained for a few cycles on 1 and on 2 devices with the same totals.
argv[1]: a scratch folder. Prints one JSON object with what the tests assert on."""

import json
import sys
from pathlib import Path

import jax
import numpy as np

import angora_jax as aj
from angora_jax.experiment import resume

WARP_REACH = ["env.options.physics={impl: warp}", "ppo.num_envs=8", "ppo.rollout_length=16", "ppo.chunk_length=8",
              "ppo.minibatch_size=64", "ppo.num_epochs=1", "ppo.num_cycles=3", "logging.progress=none",
              "logging.report=false", "checkpoint.best_metric=null"]


def host(leaf) -> np.ndarray:
    return np.asarray(leaf.addressable_data(0))


def train(root: Path, num_devices: int):
    return aj.train("shadow_reach", [*WARP_REACH, f"distribution.num_devices={num_devices}",
                                     f"logging.run_root={root}", f"logging.run_name=devices{num_devices}"])


if __name__ == "__main__":
    root = Path(sys.argv[1])
    single, double = train(root, 1), train(root, 2)
    counters = double.state.actor.env_state.physics._impl.nacon
    # The same run resumed on one device for a fourth cycle: its 2-device checkpoint holds two contact pools, which one
    # device cannot take, so it goes on from the checkpoint without its environments, with fresh ones.
    config = (root / "devices2" / "config.yaml").read_text()
    (root / "devices2" / "config.yaml").write_text(config.replace("num_devices: 2", "num_devices: 1"))
    continued = resume(root / "devices2", num_cycles=4)
    untimed = ("seconds", "steps_per_second", "compile_seconds", "time", "compile_cache_hits", "compile_cache_misses")
    result = {
        "device_count": jax.device_count(),
        "single": [{k: v for k, v in r.items() if k not in untimed and "memory" not in k} for r in single.history],
        "double": [{k: v for k, v in r.items() if k not in untimed and "memory" not in k} for r in double.history],
        "param_difference": max(float(np.abs(host(a) - host(b)).max()) for a, b in zip(
            jax.tree.leaves(single.state.params), jax.tree.leaves(double.state.params), strict=True)),
        "param_scale": max(float(np.abs(host(a)).max()) for a in jax.tree.leaves(single.state.params)),
        "qpos_difference": float(np.abs(host(single.state.actor.env_state.physics.qpos)
                                        - np.asarray(double.state.actor.env_state.physics.qpos)).max()),
        "contact_counters": {"single": list(single.state.actor.env_state.physics._impl.nacon.shape),
                             "double": list(counters.shape),
                             "double_shards": [list(shard.data.shape) for shard in counters.addressable_shards]},
        "sessions": [json.loads(line) for line in (root / "devices2" / "sessions.jsonl").read_text().splitlines()],
        "continued_cycle": int(continued.state.cycle),
    }
    print(json.dumps(result))
