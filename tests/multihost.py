"""One process of the two-process localhost job that test_distributed.py starts: argv is coordinator address, process
id, run root and the run: "cartpole" (each process has 2 CPU devices by XLA_FLAGS, 4 in all) or "warp" (reach on
MuJoCo Warp, one CPU device per process: the cluster layout, one process per GPU). `aj.train` runs 3 cycles over
all devices into one run directory (process 0 logs, both save the checkpoint), but process 1 alone gets a SIGTERM after
cycle 2, so both should stop there; both then resume the run to cycle 3 (the CartPole run; the test's process
resumes the Warp run). Prints one JSON object: how training stopped, a
digest of this process's copy of the final parameters, whether its devices hold the same copy, the
metrics of every cycle and the programs this process compiled (JAX's compile log): every process must compile the
same programs, since a program over all processes' devices that one process runs alone waits for the others (on GPUs
process 0's monitor once did so, the likely cause of a 4-process hang)."""

import collections
import hashlib
import json
import logging
import os
import signal
import sys

from angora_jax.experiment.distributed import initialize

initialize(sys.argv[1], 2, int(sys.argv[2]))

from pathlib import Path  # noqa: E402

import jax  # noqa: E402
import numpy as np  # noqa: E402
from tiny import TINY_PPO  # noqa: E402

import angora_jax as aj  # noqa: E402
from angora_jax.experiment import TrainingInterrupted, resume  # noqa: E402

run_root, process, variant = Path(sys.argv[3]), int(sys.argv[2]), sys.argv[4]
config = {"cartpole": "cartpole", "warp": "shadow_reach"}[variant]
task = ["env.options.physics={impl: warp}", "ppo.minibatch_size=64"] if variant == "warp" else []
overrides = [
    *TINY_PPO,
    *task,
    "ppo.num_envs=8",
    "ppo.num_cycles=3",
    "distribution.num_devices=all",
    "logging.progress=none",
    "logging.report=false",
    f"logging.run_root={run_root}",
    "logging.run_name=two-hosts",
]
records = []
compiled = collections.Counter()


class CompileLog(logging.Handler):
    def emit(self, record):
        message = record.getMessage()
        if message.startswith("Compiling "):
            compiled[message.split()[1]] += 1


logging.getLogger("jax").addHandler(CompileLog())
jax.config.update("jax_log_compiles", True)


def terminate_process_1_after_cycle_2(record):
    records.append(record)
    if process == 1 and record["cycle"] == 2:
        os.kill(os.getpid(), signal.SIGTERM)


try:
    aj.train(config, overrides, on_cycle=terminate_process_1_after_cycle_2)
    stopped = None
except TrainingInterrupted as stop:
    stopped = {"cycle": stop.cycle, "signal": stop.signum}
if variant == "warp":  # the test's own process resumes the Warp run (one recompile instead of one per process)
    print(json.dumps({"stopped": stopped, "compiled": compiled, "metrics": [
        {k: v for k, v in m.items() if k not in ("seconds", "steps_per_second", "compile_seconds",
                                                 "compile_cache_hits", "compile_cache_misses")} for m in records]}))
    sys.exit(0)
run = resume(run_root / "two-hosts", on_cycle=records.append)
digest, local_copies_agree = hashlib.sha256(), True
for leaf in jax.tree.leaves(run.state.params):
    copies = [np.asarray(shard.data) for shard in leaf.addressable_shards]
    local_copies_agree &= all(np.array_equal(copies[0], other) for other in copies[1:])
    digest.update(copies[0].tobytes())
untimed = [
    {k: v for k, v in m.items() if k not in ("seconds", "steps_per_second", "compile_seconds", "compile_cache_hits",
                                          "compile_cache_misses")} for m in records
]
summary = {"stopped": stopped, "params": digest.hexdigest(), "local_copies_agree": bool(local_copies_agree),
           "compiled": compiled}
print(json.dumps(summary | {"metrics": untimed}))
