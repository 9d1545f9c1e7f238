"""Data-parallel scaling: a task config trained for a few cycles on 1 device and on D devices (several D at once).

Strong scaling (default): the same totals on D devices (`ppo.num_envs`, `ppo.minibatch_size` are run totals, see
angora_jax/ppo/parallel.py), so each device gets 1/D of the work. Weak scaling (`--weak`): the D-device run has D
times the environments and the minibatch size, so each device does the 1-device run's work and the number of updates
per cycle stays the same (the usual way to use more GPUs: a larger batch in the same time).

    # 2 GPUs (about 1.5 minutes for reach, 3 for the cube: one compile per run, ~30 s reach, ~75 s cube):
    python benchmarks/scaling.py shadow_reach --cycles 40
    python benchmarks/scaling.py shadow_reach --cycles 40 --weak
    python benchmarks/scaling.py shadow_ihom --cycles 4 ppo.rollout_length=32 ppo.minibatch_size=32768
    # CPU smoke size, 2 forced host devices:
    XLA_FLAGS=--xla_force_host_platform_device_count=2 python benchmarks/scaling.py shadow_reach --cycles 2 \
        ppo.num_envs=4 ppo.rollout_length=16 ppo.minibatch_size=32 ppo.num_epochs=1

`--layouts` picks how D devices are driven: `one` process for all of them (the default), and/or `processes`, D
processes with one device each, joined by `jax.distributed` on this host: the layout of a cluster job, one process
per GPU. Every layout is compared with the same 1-device run (one process).

    python benchmarks/scaling.py shadow_reach --cycles 30 --weak --layouts processes   # 2 GPUs, one process each
    # the cube on MuJoCo Warp, 16,384 envs per GPU, 2 and 4 GPUs, both layouts (about 12 minutes on 4 H100s):
    python benchmarks/scaling.py shadow_ihom --cycles 6 --weak --devices 2 4 --layouts one processes

Training steps/s exclude compilation: they count the cycles after the first (the first compiles the cycle); compile
seconds are the first cycle's wall time less the median of the others. "scaling" is a run's steps/s over the
1-device run's (targets under weak scaling: at least 1.9x on 2 GPUs, 3.6x on 4), "efficiency" that over D. Under
strong scaling the runs compute the same training up to float rounding, so their final metrics and parameters are
printed side by side: on CPU they agree to about 1e-6; on GPUs contact-rich physics can amplify rounding over many
steps. Prints a
Markdown table and writes JSON (device, versions, config, rows) to
benchmarks/results/scaling/scaling_<task>[_weak][_processes]_<platform>.json or --out (`_processes` when that is
the only layout).
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import statistics
import subprocess
import sys
import tempfile

import jax
import numpy as np
from common import config_parser, markdown_table, write_results

from angora_jax.experiment.config import load_config, to_dict, validate
from angora_jax.experiment.distributed import initialize
from angora_jax.ppo.parallel import host_copy
from angora_jax.ppo.train import training_cycles

FINAL = ("episode_return", "episode_length", "entropy", "loss", "approx_kl", "explained_variance")
LAYOUTS = ("one", "processes")


def run(resolved: dict, cycles: int, num_devices: int, scale: int = 1) -> tuple[dict, list[np.ndarray]]:
    """Train the config `resolved` (a dict, every key) for `cycles` cycles on `num_devices` devices, with `scale`
    times its environments and minibatch size; return a result row and the final parameters (on the host)."""
    ppo = resolved["ppo"]
    config = load_config(resolved, [f"ppo.num_cycles={cycles}", f"distribution.num_devices={num_devices}",
                                    f"ppo.num_envs={ppo['num_envs'] * scale}",
                                    f"ppo.minibatch_size={ppo['minibatch_size'] * scale}"])
    env = validate(config)
    seconds, metrics, params = [], {}, None
    for state, metrics in training_cycles(config.ppo, env, None, None, num_devices):
        seconds.append(metrics["seconds"])
        params = state.params
        print(f"  {num_devices} device(s), cycle {metrics['cycle']}: {metrics['seconds']:.2f} s", flush=True)
    steady = seconds[1:]
    steps_per_cycle = config.ppo.num_envs * config.ppo.rollout_length
    row = {
        "task": config.env.task,
        "devices": num_devices,
        "num_envs": config.ppo.num_envs,
        "envs_per_device": config.ppo.num_envs // num_devices,
        "steps_per_cycle": steps_per_cycle,
        "cycles": cycles,
        "compile_s": seconds[0] - statistics.median(steady),
        "steps_per_s": steps_per_cycle * len(steady) / sum(steady),
        "cycle_seconds": seconds,
        "final": {name: value for name, value in metrics.items() if name in FINAL or name.startswith("metric/")},
    }
    row["sim_s_per_s"] = row["steps_per_s"] * env.dt
    # Parameters are replicated: this process's copy is all of them (also when other processes hold the rest).
    return row, jax.tree.leaves(host_copy(params))


def run_in_processes(resolved: dict, cycles: int, processes: int, scale: int = 1) -> tuple[dict, list[np.ndarray]]:
    """`run` as `processes` processes of one device each (device i for process i), joined by `jax.distributed` on
    localhost; returns process 0's row and final parameters. Raises RuntimeError with a process's error output."""
    with socket.socket() as probe:  # a free port for the coordinator
        probe.bind(("localhost", 0))
        address = f"localhost:{probe.getsockname()[1]}"
    with tempfile.TemporaryDirectory() as folder:
        config_path, params_path = os.path.join(folder, "config.json"), os.path.join(folder, "params.npz")
        with open(config_path, "w") as f:
            json.dump(resolved, f)
        children = [
            subprocess.Popen(
                [sys.executable, __file__, config_path, "--cycles", str(cycles), "--scale", str(scale),
                 "--child", f"{rank},{processes},{address},{params_path}"],
                env=os.environ | {"JAX_LOCAL_DEVICE_IDS": str(rank)},  # read by jax.distributed.initialize
                stdout=subprocess.PIPE,
                stderr=subprocess.PIPE,
                text=True,
            )
            for rank in range(processes)
        ]
        outputs = [child.communicate() for child in children]
        for rank, (child, (_, err)) in enumerate(zip(children, outputs, strict=True)):
            if child.returncode != 0:
                raise RuntimeError(f"process {rank} of {processes} failed (exit {child.returncode}):\n{err[-3000:]}")
        print(outputs[0][0].rsplit("\n", 2)[0], flush=True)  # process 0's progress lines
        with np.load(params_path) as saved:
            params = [saved[f"arr_{i}"] for i in range(len(saved.files))]
        return json.loads(outputs[0][0].strip().splitlines()[-1]), params


def child(args: argparse.Namespace) -> None:
    """One process of `run_in_processes`: join the job, train, and (process 0) print the row and save parameters."""
    rank, processes, address, params_path = args.child.split(",")
    initialize(address, int(processes), int(rank))
    row, params = run(to_dict(load_config(args.config)), args.cycles, jax.device_count(), args.scale)
    row["processes"] = int(processes)
    if jax.process_index() == 0:
        np.savez(params_path, *params)
        print(json.dumps(row))


def main() -> None:
    parser = config_parser(__doc__)
    parser.add_argument("--cycles", type=int, default=10, help="cycles per run, at least 2 (the first compiles)")
    parser.add_argument("--devices", type=int, nargs="+", default=[2], help="the device counts compared with 1")
    parser.add_argument("--weak", action="store_true", help="weak scaling: D times the envs and minibatch on D devices")
    parser.add_argument("--layouts", nargs="+", choices=LAYOUTS, default=["one"],
                        help="one process for all devices, and/or one process per device (jax.distributed here)")
    parser.add_argument("--child", help=argparse.SUPPRESS)  # rank,processes,coordinator,params path
    parser.add_argument("--scale", type=int, default=1, help=argparse.SUPPRESS)
    parser.add_argument("--out", default=None,
                        help="JSON path (default: results/scaling/scaling_<task>[_weak][_processes]_<platform>.json)")
    args = parser.parse_intermixed_args()
    if args.child:
        return child(args)
    if args.cycles < 2:
        parser.error(f"--cycles must be at least 2 (the first cycle compiles and is not timed), got {args.cycles}")
    # One process per device needs no devices in this process (its children take them); one process for all does.
    if "one" in args.layouts and max(args.devices) > jax.device_count():
        parser.error(
            f"--devices {max(args.devices)} but JAX sees {jax.device_count()} device(s); on CPU set "
            f"XLA_FLAGS=--xla_force_host_platform_device_count={max(args.devices)}"
        )

    # Read the config once, so that all runs train the same one even if the file changes meanwhile.
    resolved = to_dict(load_config(args.config, args.overrides))
    measure = {"one": run, "processes": run_in_processes}
    single, single_params = measure[args.layouts[0]](resolved, args.cycles, 1)
    single |= {"layout": args.layouts[0], "scaling": 1.0, "efficiency": 1.0}
    rows = [single]
    for layout in args.layouts:
        for devices in args.devices:
            row, params = measure[layout](resolved, args.cycles, devices, devices if args.weak else 1)
            row |= {"layout": layout, "scaling": row["steps_per_s"] / single["steps_per_s"]}
            row["efficiency"] = row["scaling"] / devices
            if not args.weak:
                row["max_param_difference"] = max(
                    float(np.abs(a - b).max()) for a, b in zip(single_params, params, strict=True))
            rows.append(row)
    metric_columns = [(f"final_{name}", name, ".4g") for name in single["final"]]
    for row in rows:
        row |= {f"final_{name}": value for name, value in row["final"].items()}

    print(markdown_table(rows, [
        ("task", "task", "s"), ("layout", "layout", "s"), ("devices", "devices", "d"),
        ("envs_per_device", "envs/device", "d"), ("steps_per_s", "train env steps/s", ",.0f"),
        ("sim_s_per_s", "sim-s/s", ",.1f"), ("num_envs", "envs", "d"), ("scaling", "scaling vs 1 device", ".2f"),
        ("efficiency", "efficiency", ".2f"), ("compile_s", "compile s", ".1f"), *metric_columns,
    ]))
    if not args.weak:
        for row in rows[1:]:
            print(f"largest parameter difference after {args.cycles} cycles, {row['devices']} devices "
                  f"({row['layout']}) vs 1: {row['max_param_difference']:.3g}")
    only_processes = args.layouts == ["processes"]
    name = f"scaling_{single['task']}{'_weak' if args.weak else ''}{'_processes' if only_processes else ''}"
    path = write_results(name, {"args": vars(args), "config": resolved}, rows, args.out, study="scaling")
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
