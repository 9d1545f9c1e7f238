"""One process of the two-process localhost job that test_parallel.py starts: argv is coordinator address, process
id and run root; each process has 2 CPU devices (XLA_FLAGS), 4 in all. `aj.train` runs 3 cycles over all 4 devices
into one run directory (process 0 logs, both save the checkpoint); prints one JSON object: a digest of this
process's copy of the parameters, whether its two devices hold the same copy, and the cycles' metrics."""

import hashlib
import json
import sys

from angora_jax.experiment.distributed import initialize

initialize(sys.argv[1], 2, int(sys.argv[2]))

import jax  # noqa: E402
import numpy as np  # noqa: E402
from tiny import TINY_PPO  # noqa: E402

import angora_jax as aj  # noqa: E402

overrides = [
    *TINY_PPO,
    "ppo.num_envs=8",
    "ppo.num_cycles=3",
    "distribution.num_devices=all",
    "logging.progress=none",
    "logging.report=false",
    f"logging.run_root={sys.argv[3]}",
    "logging.run_name=two-hosts",
]
run = aj.train("cartpole", overrides)
digest, local_copies_agree = hashlib.sha256(), True
for leaf in jax.tree.leaves(run.state.params):
    copies = [np.asarray(shard.data) for shard in leaf.addressable_shards]
    local_copies_agree &= all(np.array_equal(copies[0], other) for other in copies[1:])
    digest.update(copies[0].tobytes())
untimed = [
    {k: v for k, v in m.items() if k not in ("seconds", "steps_per_second", "compile_seconds")} for m in run.history
]
print(json.dumps({"params": digest.hexdigest(), "local_copies_agree": bool(local_copies_agree), "metrics": untimed}))
