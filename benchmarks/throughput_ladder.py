"""Throughput ladder: per task and number of environments, bare batched `mjx.step`, our env `step` and our whole
PPO training cycle; the ratios between them, compile times and device memory, in env steps/s and in simulated
seconds per wall second (sim-s/s = env steps/s x control dt, fair across control rates).

"raw" is `vmap(mjx.step)` on the task's model with random controls and nothing else; "env" is our `vmap(env.step)`
(task logic: observation, reward, goals, auto-reset) with random actions; "train" is our compiled cycle (rollout
with the policy, GAE, epochs of minibatch updates), chained from cycle to cycle. All three use `lax.scan`, are
compiled ahead of time (compile time reported apart) and timed after a warm-up run. Tasks without MJX physics
(CartPole, Pendulum) have no raw column.

Each (task, envs) runs in its own process, so that the device's peak memory (`peak_bytes_in_use`, reported by
GPUs) belongs to that size alone; XLA's memory analysis of each compiled program is reported too (on any backend).
`--jobs N` runs N processes at once without GPU preallocation: they compile in parallel on the host's cores and
take turns on the device for the timed runs (an exclusive file lock), so no timed run shares the device.

    python benchmarks/throughput_ladder.py                                    # CPU, tiny: reach at 8 envs
    python benchmarks/throughput_ladder.py --tasks ShadowHandReach,ShadowHandCube --num-envs 1024,4096,16384 \\
        --steps 10 --rollout-length 16 --repeats 2 --jobs 6                   # GPU, about 6-7 minutes on an H100
"""

from __future__ import annotations

import argparse
import fcntl
import json
import os
import subprocess
import sys
import tempfile
import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import IO, Any

from common import env_step_rate, markdown_table, peak_memory_bytes, raw_mjx_rate, train_rate, write_results

from angora_jax.envs.registry import make
from angora_jax.ppo import NetworkConfig, PPOConfig

GIB = 2**30


class DeviceLock:
    """An exclusive `flock` on a file, taken and released each time it is entered: the timed runs of processes
    that share one device happen one process at a time."""

    def __init__(self, path: str):
        self.path = path
        self._file: IO[str] | None = None

    def __enter__(self) -> DeviceLock:
        self._file = open(self.path, "a")  # held open until __exit__
        fcntl.flock(self._file, fcntl.LOCK_EX)
        return self

    def __exit__(self, *exc: object) -> None:
        assert self._file is not None
        fcntl.flock(self._file, fcntl.LOCK_UN)
        self._file.close()
        self._file = None


def measure(spec: dict[str, Any]) -> dict[str, Any]:
    """One rung, in this process: raw MJX, env step and training cycle of `spec["task"]` at `spec["num_envs"]`."""
    env = make(spec["task"], **spec["options"])
    n, steps, repeats = spec["num_envs"], spec["steps"], spec["repeats"]
    lock = DeviceLock(spec["lock"])
    config = PPOConfig(
        num_envs=n, rollout_length=spec["rollout_length"], chunk_length=spec["chunk_length"],
        num_epochs=spec["epochs"], minibatch_size=n * spec["rollout_length"] // spec["minibatches"],
        network=NetworkConfig(name=spec["model"]),
    ).validate_for(env)
    raw = raw_mjx_rate(env, n, steps, repeats, exclusive=lock) if hasattr(env, "mjx_model") else None
    mine = env_step_rate(env, n, steps, repeats, exclusive=lock)
    trained = train_rate(env, config, repeats, exclusive=lock)
    row: dict[str, Any] = {"task": spec["task"], "num_envs": n, "control_dt_s": env.dt}
    for name, rate in (("raw", raw), ("env", mine), ("train", trained)):
        rate = rate or {}
        steps_per_s = rate.get("env_steps_per_s")
        row[f"{name}_env_steps_per_s"] = steps_per_s
        row[f"{name}_sim_s_per_s"] = steps_per_s * env.dt if steps_per_s else None
        row[f"{name}_compile_s"] = rate.get("compile_s")
        row[f"{name}_memory_gib"] = rate["memory_bytes"] / GIB if rate.get("memory_bytes") is not None else None
    row["env_over_raw"] = mine["env_steps_per_s"] / raw["env_steps_per_s"] if raw else None
    row["train_over_env"] = trained["env_steps_per_s"] / mine["env_steps_per_s"]
    row["train_over_raw"] = trained["env_steps_per_s"] / raw["env_steps_per_s"] if raw else None
    peak = peak_memory_bytes()
    row["peak_memory_gib"] = peak / GIB if peak is not None else None
    return row


def run_rung(spec: dict[str, Any], folder: str) -> dict[str, Any]:
    """`measure(spec)` in a fresh Python process; a failure (e.g. out of memory) becomes a row with its error."""
    result = os.path.join(folder, f"{spec['task']}_{spec['num_envs']}.json")
    env = dict(os.environ, XLA_PYTHON_CLIENT_PREALLOCATE="false")
    done = subprocess.run([sys.executable, os.path.abspath(__file__), "--rung", json.dumps(spec), "--result", result],
                          env=env, capture_output=True, text=True)
    if done.returncode != 0:
        tail = (done.stderr or done.stdout).strip().splitlines()[-5:]
        print(f"{spec['task']} @ {spec['num_envs']} failed (exit {done.returncode}): " + " / ".join(tail), flush=True)
        return {"task": spec["task"], "num_envs": spec["num_envs"], "error": "\n".join(tail)}
    with open(result) as f:
        row = json.load(f)
    print(f"{row['task']} @ {row['num_envs']}: env {row['env_env_steps_per_s']:,.0f}, train "
          f"{row['train_env_steps_per_s']:,.0f} env steps/s", flush=True)
    return row


def ladder(tasks: list[str], sizes: list[int], settings: dict[str, Any], jobs: int,
           on_row: Callable[[list[dict[str, Any]]], None] | None = None) -> list[dict[str, Any]]:
    """All rungs, `jobs` processes at a time sharing one device lock; rows in (task, size) order. `on_row` gets
    the rows finished so far after each rung (e.g. to save them before a time limit cuts the run short)."""
    finished: list[dict[str, Any]] = []
    guard = threading.Lock()

    def rung(spec: dict[str, Any]) -> dict[str, Any]:
        row = run_rung(spec, folder)
        with guard:
            finished.append(row)
            if on_row is not None:
                on_row(list(finished))
        return row

    with tempfile.TemporaryDirectory() as folder, ThreadPoolExecutor(jobs) as pool:
        lock = os.path.join(folder, "device.lock")
        specs = [dict(settings, task=task, num_envs=n, lock=lock) for task in tasks for n in sizes]
        return list(pool.map(rung, specs))


COLUMNS = [
    ("task", "task", "s"), ("num_envs", "envs", ",d"),
    ("raw_env_steps_per_s", "raw MJX env steps/s", ",.0f"), ("env_env_steps_per_s", "env steps/s", ",.0f"),
    ("train_env_steps_per_s", "train env steps/s", ",.0f"), ("train_sim_s_per_s", "train sim-s/s", ",.0f"),
    ("env_over_raw", "env / raw", ".2f"), ("train_over_env", "train / env", ".2f"),
    ("train_over_raw", "train / raw", ".2f"),
    ("raw_compile_s", "compile raw s", ".0f"), ("env_compile_s", "compile env s", ".0f"),
    ("train_compile_s", "compile train s", ".0f"),
    ("train_memory_gib", "train program GiB", ".2f"), ("peak_memory_gib", "peak GiB", ".2f"),
]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--tasks", default="ShadowHandReach", help="comma-separated task names")
    parser.add_argument("--options", default="{}", help="task options as JSON, for every task")
    parser.add_argument("--num-envs", default="8", help="comma-separated numbers of environments")
    parser.add_argument("--steps", type=int, default=4, help="policy steps per timed run of raw and env")
    parser.add_argument("--rollout-length", type=int, default=8)
    parser.add_argument("--chunk-length", type=int, default=8, help="truncated-BPTT chunk; must divide the rollout")
    parser.add_argument("--minibatches", type=int, default=2, help="minibatches per epoch")
    parser.add_argument("--epochs", type=int, default=2)
    parser.add_argument("--model", default="simple")
    parser.add_argument("--repeats", type=int, default=1, help="timed runs after the warm-up")
    parser.add_argument("--jobs", type=int, default=1, help="processes at once (compile in parallel, time alone)")
    parser.add_argument("--out", default=None,
                        help="JSON path (default: results/env_train_throughput/throughput_ladder_<platform>.json)")
    parser.add_argument("--rung", help=argparse.SUPPRESS)  # internal: run one measurement (a JSON spec)
    parser.add_argument("--result", help=argparse.SUPPRESS)  # internal: where that measurement goes
    args = parser.parse_args()

    if args.rung:
        row = measure(json.loads(args.rung))
        with open(args.result, "w") as f:
            json.dump(row, f)
        return
    if args.jobs < 1:
        parser.error(f"--jobs must be >= 1, got {args.jobs}.")
    settings = {"options": json.loads(args.options), "steps": args.steps, "rollout_length": args.rollout_length,
                "chunk_length": args.chunk_length, "minibatches": args.minibatches, "epochs": args.epochs,
                "model": args.model, "repeats": args.repeats}
    tasks = args.tasks.split(",")
    sizes = [int(n) for n in args.num_envs.split(",")]
    config = {**settings, "tasks": tasks, "num_envs": sizes, "jobs": args.jobs}
    # This process touches the device only to name it in the results: without preallocation, it leaves the
    # device's memory to the measuring processes.
    os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")
    rows = ladder(tasks, sizes, settings, args.jobs, on_row=lambda done: write_results(
        "throughput_ladder", config, done, args.out, study="env_train_throughput"))
    path = write_results("throughput_ladder", config, rows, args.out, study="env_train_throughput")
    print(markdown_table(rows, COLUMNS))
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
