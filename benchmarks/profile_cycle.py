"""Where a training cycle's time goes: a `jax.profiler` trace of a few compiled PPO cycles, its device time split by
phase and by kernel.

    python benchmarks/profile_cycle.py shadow_reach ppo.num_envs=4096 ppo.rollout_length=32 ppo.chunk_length=32 \
        ppo.minibatch_size=32768 ppo.network.width=64 --cycles 3                               # GPU, about 1 minute
    python benchmarks/profile_cycle.py pendulum ppo.num_envs=8 --cycles 2                       # CPU smoke size
    python benchmarks/profile_cycle.py shadow_reach ppo.num_envs=8192 ppo.minibatch_size=8192 \
        distribution.num_devices=2                                                  # the data-parallel cycle, 2 GPUs

The cycle's ops carry named scopes (angora_jax/ppo/cycle.py, rollout.py), so every kernel of the trace is mapped,
through its HLO instruction's `op_name`, to a phase: the environment step (physics and task logic), acting (the policy's
forward pass, sampling, observation normalisation), advantages (GAE, reward scaling), the minibatch updates, or other
(metrics, RNG, copies); collectives (NCCL kernels, CPU all-reduces) count apart, whatever their scope (their time
includes waiting for the other devices). Inside a CUDA graph the trace names kernels for their fusions; those it does
not name (copies) count in the phase of the kernel before them on their stream. Reported per cycle: wall seconds without
the profiler, device-busy seconds (kernel time summed over streams) by phase, their share, the kernel count and the top
kernels, per device (averaged over the devices of `distribution.num_devices`). The device-busy / wall ratio shows how
much of the cycle the device spends idle between kernels (launch and loop overheads).

The raw trace (open `perfetto_trace.json.gz` in https://ui.perfetto.dev) and the compiled HLO (`cycle.hlo.txt`) stay
under --trace-dir. Prints Markdown tables and writes JSON (device, versions, config, numbers) to
benchmarks/results/env_train_throughput/profile_cycle_<task>_<platform>.json or --out.
"""

from __future__ import annotations

import collections
import glob
import gzip
import json
import os
import re
import tempfile
import time

import jax
from common import config_parser, markdown_table, write_results

from angora_jax.experiment.config import load_config, to_dict, validate
from angora_jax.ppo import make_cycle
from angora_jax.ppo.parallel import resolve_num_devices

# (scope in an op_name, phase), the first match wins: env_step lies inside rollout.
PHASES = (("/env_step/", "env step"), ("/rollout/", "acting"), ("/advantages/", "advantages"),
          ("/update/", "updates"))
COMPUTATION = re.compile(r"^(?:ENTRY\s+)?%?([\w.\-]+)\s.*\{\s*$")
INSTRUCTION = re.compile(r"^\s*(?:ROOT\s+)?%?([\w.\-]+)\s*=")
OP_NAME = re.compile(r"op_name=\"([^\"]*)\"")
COLLECTIVE = re.compile(r"(all-reduce|all-gather|reduce-scatter|all-to-all|collective-permute)")
CALLED = re.compile(r"(?:body|condition|calls|to_apply)=%?([\w.\-]+)|branch_computations=\{([^}]*)\}")


def op_names(hlo_text: str) -> dict[str, str | None]:
    """HLO instruction name -> its `op_name` metadata (the JAX scope path), from a compiled module's text.

    Instructions that XLA added without metadata (copies, loop bookkeeping) take the op_name of the instruction
    that calls their computation (a while loop's body belongs to the loop), so they count in the phase they run in.
    """
    own: dict[str, str | None] = {}
    home: dict[str, str] = {}  # instruction -> its computation
    caller: dict[str, str] = {}  # computation -> the instruction that calls it
    computation = ""
    for line in hlo_text.splitlines():
        instruction = INSTRUCTION.match(line)
        if instruction is None:
            header = COMPUTATION.match(line)
            computation = header.group(1) if header else computation
            continue
        name = instruction.group(1)
        op_name = OP_NAME.search(line)
        own[name], home[name] = (op_name.group(1) if op_name else None), computation
        for single, branches in CALLED.findall(line):
            for callee in (single or branches).replace("%", "").split(","):
                caller.setdefault(callee.strip(), name)

    def resolve(name: str, depth: int = 0) -> str | None:
        if own.get(name) is not None or depth > 64:
            return own.get(name)
        parent = caller.get(home.get(name, ""))
        return resolve(parent, depth + 1) if parent else None

    return {name: resolve(name) for name in own}


def phase_of(op_name: str | None) -> str:
    """The cycle phase of an op, from its scope path; "other" outside the named phases and without a path."""
    path = f"/{op_name}/"
    return next((phase for scope, phase in PHASES if scope in path), "other")


def kernel_events(trace: dict) -> list[dict]:
    """The device's kernel events of a Perfetto trace: those on GPU/TPU device processes where the trace has any,
    else (CPU) the host events that ran an HLO op."""
    events = trace["traceEvents"] if isinstance(trace, dict) else trace
    device_pids = {e["pid"] for e in events if e.get("ph") == "M" and e.get("name") == "process_name"
                   and "/device:" in e.get("args", {}).get("name", "")}
    spans = [e for e in events if e.get("ph") == "X" and "dur" in e]
    if device_pids:
        return self_time([e for e in spans if e["pid"] in device_pids])
    return self_time([e for e in spans if "hlo_op" in e.get("args", {})])


def self_time(events: list[dict]) -> list[dict]:
    """The events with `dur` reduced to their own time: a span that encloses others on its thread (a while loop
    on the CPU runs its body's ops inside it) keeps only the time none of them covers."""
    events = sorted(({**e, "dur": float(e["dur"])} for e in events), key=lambda e: (e["pid"], e.get("tid"),
                                                                                  e["ts"], -e["dur"]))
    open_spans: list[dict] = []
    for event in events:
        while open_spans and (open_spans[-1]["pid"], open_spans[-1].get("tid")) != (event["pid"], event.get("tid")):
            open_spans.pop()
        while open_spans and open_spans[-1]["ts"] + open_spans[-1]["length"] <= event["ts"]:
            open_spans.pop()
        if open_spans:
            open_spans[-1]["dur"] -= event["dur"]
        event["length"] = event["dur"]
        open_spans.append(event)
    return events


def summarize(events: list[dict], names: dict[str, str], cycles: int, top: int) -> tuple[dict, list[dict]]:
    """Device seconds per cycle by phase (and kernel counts), and the `top` kernels by time; `cycles` is the number
    of cycles traced times the devices, so that the numbers are per device."""
    by_phase: dict[str, float] = collections.defaultdict(float)
    count: dict[str, int] = collections.defaultdict(int)
    by_kernel: dict[str, dict] = {}
    previous: dict[tuple, str] = {}  # stream -> the phase of its last attributed kernel
    for e in events:
        hlo_op = e.get("args", {}).get("hlo_op")
        stream = (e["pid"], e.get("tid"))
        if hlo_op not in names and e["name"] in names:
            hlo_op = e["name"]  # inside a CUDA graph the trace names the graph; the kernel is named for its fusion
        if "nccl" in e["name"].lower() or COLLECTIVE.match(hlo_op or e["name"]):
            phase = "collectives"
        elif hlo_op in names:
            phase = previous[stream] = phase_of(names[hlo_op])
        else:  # e.g. a copy inside a CUDA graph: it runs in the phase of the kernels around it
            phase = previous.get(stream, "unattributed")
        seconds = e["dur"] * 1e-6 / cycles
        by_phase[phase] += seconds
        count[phase] += 1
        kernel = by_kernel.setdefault(e["name"], {"kernel": e["name"], "hlo_op": hlo_op, "phase": phase,
                                                   "op_name": names.get(hlo_op), "seconds": 0.0, "calls": 0})
        kernel["seconds"] += seconds
        kernel["calls"] += 1
    phases = {phase: {"device_s": by_phase[phase], "kernels": count[phase] / cycles} for phase in by_phase}
    kernels = sorted(by_kernel.values(), key=lambda k: -k["seconds"])[:top]
    for kernel in kernels:
        kernel["calls"] /= cycles
    return phases, kernels


def main() -> None:
    parser = config_parser(__doc__)
    parser.add_argument("--cycles", type=int, default=3, help="cycles timed and then traced, after two warm-ups")
    parser.add_argument("--top", type=int, default=15, help="kernels listed")
    parser.add_argument("--trace-dir", default=None, help="where the raw trace goes (default: a temporary folder)")
    parser.add_argument("--out", default=None,
                        help="JSON path (default: results/env_train_throughput/profile_cycle_<task>_<platform>.json)")
    args = parser.parse_intermixed_args()
    if args.cycles < 1:
        parser.error(f"--cycles must be at least 1, got {args.cycles}")

    config = load_config(args.config, args.overrides)
    env = validate(config)
    num_devices = resolve_num_devices(config.distribution.num_devices)
    init, cycle = make_cycle(env, None, config.ppo, num_devices)
    state = init(jax.random.key(config.ppo.seed))
    executable = cycle.lower(state).compile()
    # The executable takes its inputs' exact layout; the data-parallel cycle restores it for every call (XLA returns
    # empty arrays, e.g. absent modalities, replicated rather than split over the devices).
    place = cycle.place if num_devices > 1 else (lambda state: state)

    def compiled(state):
        return executable(place(state))

    hlo_text = executable.as_text()
    names = op_names(hlo_text)
    for _ in range(2):
        state, _ = compiled(state)
    jax.block_until_ready(state)
    start = time.perf_counter()
    for _ in range(args.cycles):
        state, _ = compiled(state)
    jax.block_until_ready(state)
    wall = (time.perf_counter() - start) / args.cycles

    trace_dir = args.trace_dir or tempfile.mkdtemp(prefix="profile_cycle_")
    os.makedirs(trace_dir, exist_ok=True)
    with open(os.path.join(trace_dir, "cycle.hlo.txt"), "w") as f:
        f.write(hlo_text)  # kernels name their HLO instructions: this resolves them to code
    with jax.profiler.trace(trace_dir, create_perfetto_trace=True):
        start = time.perf_counter()
        for _ in range(args.cycles):
            state, _ = compiled(state)
        jax.block_until_ready(state)
        traced_wall = (time.perf_counter() - start) / args.cycles
    trace_path = max(glob.glob(os.path.join(trace_dir, "**", "perfetto_trace.json.gz"), recursive=True),
                     key=os.path.getmtime)
    with gzip.open(trace_path) as f:
        events = kernel_events(json.load(f))
    phases, kernels = summarize(events, names, args.cycles * num_devices, args.top)

    busy = sum(p["device_s"] for p in phases.values())
    busy_by_device = collections.defaultdict(float)
    for e in events:
        busy_by_device[e["pid"]] += e["dur"] * 1e-6 / args.cycles
    steps = config.ppo.num_envs * config.ppo.rollout_length
    rows = [{"phase": phase, **values, "share": values["device_s"] / busy if busy else None}
            for phase, values in sorted(phases.items(), key=lambda item: -item[1]["device_s"])]
    print(f"{config.env.task}: {steps:,} env steps per cycle, {wall:.4f} s per cycle without the profiler "
          f"({steps / wall:,.0f} env steps/s), {traced_wall:.4f} s with it; device busy {busy:.4f} s per cycle "
          f"({busy / traced_wall:.0%} of the traced wall time)"
          + (f"; {num_devices} devices, busy s each: {', '.join(f'{b:.4f}' for b in busy_by_device.values())}"
             if num_devices > 1 else ""))
    print(markdown_table(rows, [("phase", "phase", "s"), ("device_s", "device s / cycle", ".4f"),
                                ("share", "share of busy", ".1%"), ("kernels", "kernels / cycle", ",.0f")]))
    print(markdown_table(kernels, [("kernel", "kernel", "s"), ("phase", "phase", "s"),
                                   ("seconds", "s / cycle", ".4f"), ("calls", "calls / cycle", ",.0f")]))
    summary = {"devices": num_devices, "wall_s_per_cycle": wall, "traced_wall_s_per_cycle": traced_wall,
               "device_busy_s_per_cycle": busy, "device_busy_s_per_cycle_each": list(busy_by_device.values()),
               "env_steps_per_cycle": steps, "env_steps_per_s": steps / wall, "top_kernels": kernels,
               "trace": trace_path}
    path = write_results(f"profile_cycle_{config.env.task}", {"args": vars(args), "config": to_dict(config),
                                                              "summary": summary}, rows, args.out,
                         study="env_train_throughput")
    print(f"trace: {trace_path}\nwrote {path}")


if __name__ == "__main__":
    main()
