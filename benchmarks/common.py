"""Shared by the benchmark scripts: timing of compiled functions, the throughput measurements (raw MJX, our env
step, our training cycle), environment facts, JSON results and Markdown tables."""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import datetime
import importlib.metadata
import json
import os
import platform
import time
from collections.abc import Callable
from contextlib import AbstractContextManager

import jax
import jax.numpy as jnp
import numpy as np

from angora_jax.envs.core import Env
from angora_jax.envs.mjx_env import mjx_module  # ours drops mujoco-mjx's notice that optional Warp is absent
from angora_jax.envs.random_rollout import batched_reset, make_random_rollout
from angora_jax.experiment.doctor import versions as doctor_versions
from angora_jax.ppo import PPOConfig, make_cycle

# One folder per study (the question a set of results answers), each with a README.md that names its files and says
# which are current; tests/test_results_layout.py holds every file to that.
RESULTS = os.path.join(os.path.dirname(os.path.abspath(__file__)), "results")
# Returns to reach (issue 18's bars): PPO's after 1M env steps in Schulman et al. 2017 (Fig. 3) for Hopper, Walker2d
# and HalfCheetah, of the order of the paper's Fig. 9; for Ant, which Schulman et al. did not run, PPO's best average
# return within 1M steps in Fujimoto et al. 2018 (the TD3 paper's table of results, Gym's Ant-v1: 1,083); and 5,000
# for Humanoid (it walks).
TARGETS = {"Hopper": 2300.0, "Walker2d": 3400.0, "HalfCheetah": 1700.0, "Ant": 1083.0, "Humanoid": 5000.0}


def versions() -> dict[str, str | None]:
    """Versions of the packages that decide the numbers (None: not installed): those a run records
    (`experiment.doctor.versions`, warp-lang included), Brax (the peer some benchmarks run) and Python."""
    found = doctor_versions()
    try:
        found["brax"] = importlib.metadata.version("brax")
    except importlib.metadata.PackageNotFoundError:
        found["brax"] = None
    found["python"] = platform.python_version()
    return found


def device() -> dict[str, str | int]:
    """The default JAX device, in words."""
    dev = jax.devices()[0]
    return {"platform": dev.platform, "kind": dev.device_kind, "count": jax.device_count(),
            "host_cpus": os.cpu_count() or 0}


def peak_memory_bytes() -> int | None:
    """Peak bytes in use on the default device since the process started, where the backend reports it (GPUs
    do, CPUs do not)."""
    stats = jax.devices()[0].memory_stats() or {}
    return stats.get("peak_bytes_in_use")


@dataclasses.dataclass
class Measurement:
    """One compiled program, timed.

    compile_s: ahead-of-time lowering and compilation. seconds: wall seconds per run (the best run, or the mean
    of chained runs). out: the last run's output. memory_bytes: XLA's own account of the device memory the program
    needs (arguments + outputs + temporaries - aliased buffers), or None where the backend gives none; unlike
    `peak_memory_bytes` it belongs to this program alone.
    """

    compile_s: float
    seconds: float
    out: object
    memory_bytes: int | None


def compiled_memory_bytes(compiled: jax.stages.Compiled) -> int | None:
    """Device bytes a compiled program needs by XLA's memory analysis, or None where it is not available."""
    stats = compiled.memory_analysis()
    if stats is None:
        return None
    return (stats.argument_size_in_bytes + stats.output_size_in_bytes + stats.temp_size_in_bytes
            - stats.alias_size_in_bytes)


def measure_compiled(fn: Callable, *args, repeats: int = 3, chain: Callable | None = None,
                     exclusive: AbstractContextManager | None = None) -> Measurement:
    """Compile `jit(fn)` for `args`, run it once to warm up, then time `repeats` runs.

    With `chain`, each run takes `chain(previous output)` as its arguments (a training cycle continues from the
    state it returned) and the mean counts; otherwise every run takes `args` and the best run counts.
    `exclusive` is held around the warm-up and the timed runs but not the compilation, so that processes sharing
    one device can compile at the same time and still time alone (see `throughput_ladder.py`).
    """
    start = time.perf_counter()
    compiled = jax.jit(fn).lower(*args).compile()
    compile_s = time.perf_counter() - start
    memory = compiled_memory_bytes(compiled)
    with exclusive or contextlib.nullcontext():
        out = jax.block_until_ready(compiled(*args))
        if chain is not None:
            start = time.perf_counter()
            for _ in range(repeats):
                out = compiled(*chain(out))
            jax.block_until_ready(out)
            return Measurement(compile_s, (time.perf_counter() - start) / repeats, out, memory)
        best = float("inf")
        for _ in range(repeats):
            start = time.perf_counter()
            out = jax.block_until_ready(compiled(*args))
            best = min(best, time.perf_counter() - start)
    return Measurement(compile_s, best, out, memory)


def time_compiled(fn: Callable, *args, repeats: int = 3, chain: Callable | None = None) -> tuple[float, float, object]:
    """`measure_compiled` as (compile s, seconds per run, last output)."""
    m = measure_compiled(fn, *args, repeats=repeats, chain=chain)
    return m.compile_s, m.seconds, m.out


def _rate(m: Measurement, env_steps: int) -> dict[str, float | int | None]:
    return {"compile_s": m.compile_s, "env_steps_per_s": env_steps / m.seconds, "memory_bytes": m.memory_bytes}


def env_step_rate(env: Env, num_envs: int, steps: int, repeats: int = 3, seed: int = 0,
                  exclusive: AbstractContextManager | None = None) -> dict[str, float | int | None]:
    """Our batched `env.step` (task logic, auto-reset) with uniform random actions: a jitted `lax.scan` of `steps`
    policy steps of `num_envs` environments. Returns compile_s, env_steps_per_s (policy steps) and memory_bytes."""
    state = jax.jit(batched_reset, static_argnums=(0, 2))(env, jax.random.key(seed), num_envs)
    rollout = make_random_rollout(env, num_envs, steps)
    m = measure_compiled(rollout, state, jax.random.key(seed + 1), repeats=repeats, exclusive=exclusive)
    return _rate(m, num_envs * steps)


def raw_mjx_rate(env: Env, num_envs: int, steps: int, repeats: int = 3, seed: int = 0,
                 exclusive: AbstractContextManager | None = None) -> dict[str, float | int | None]:
    """Bare `vmap(mjx.step)` on the task's model, nothing else: fresh uniform controls every `frame_skip` physics
    steps, from episode starts as our reset makes them. Same keys as `env_step_rate`, rates in policy steps
    (`frame_skip` physics steps each), so the two divide."""
    model, task = env.mjx_model, env.task
    low, high = (jnp.asarray(x, jnp.float32) for x in task.model.actuator_ctrlrange.T)
    data = jax.jit(batched_reset, static_argnums=(0, 2))(env, jax.random.key(seed), num_envs).physics

    def policy_step(data, key):
        ctrl = jax.random.uniform(key, (num_envs, task.model.nu), minval=low, maxval=high)
        data = data.replace(ctrl=ctrl)
        data = jax.lax.fori_loop(0, env.frame_skip, lambda _, d: jax.vmap(mjx_module().step, (None, 0))(model, d), data)
        return data, None

    def rollout(data, key):
        return jax.lax.scan(policy_step, data, jax.random.split(key, steps))[0]

    m = measure_compiled(rollout, data, jax.random.key(seed + 1), repeats=repeats, exclusive=exclusive)
    return _rate(m, num_envs * steps)


def train_rate(env: Env, config: PPOConfig, repeats: int = 3,
               exclusive: AbstractContextManager | None = None) -> dict[str, float | int | None]:
    """Env steps consumed per second by our whole compiled PPO cycle (rollout, GAE, all minibatch updates),
    chained from cycle to cycle. Returns compile_s, env_steps_per_s and memory_bytes."""
    init, cycle = make_cycle(env, None, config)
    state = init(jax.random.key(config.seed))
    m = measure_compiled(cycle, state, repeats=repeats, chain=lambda out: (out[0],), exclusive=exclusive)
    return _rate(m, config.num_envs * config.rollout_length)


def timed(seconds: dict[str, float], name: str, function: Callable, *args, **kwargs):
    """`function(*args, **kwargs)`, its wall time (s) stored as `seconds[name]`: one timed part of a benchmark that
    calls the analyses as a user does (compile included unless the program is already compiled). Printed as it ends,
    so the log of a long run shows how far it got."""
    start = time.perf_counter()
    out = function(*args, **kwargs)
    seconds[name] = time.perf_counter() - start
    print(f"{name}: {seconds[name]:.1f} s", flush=True)
    return out


def lagged_decoding_rows(decoding, control, lags: list[int], layers: list[str],
                         variables: list[str]) -> tuple[list[dict], list[tuple[str, str, str]]]:
    """Rows (lag x layer x variable) of a lagged `analysis.decode` of the trained network (`decoding`) beside the same
    network with random weights on the same inputs (`control`), and the Markdown columns to print them. A row is
    `above_random_weights` when the trained layer's 95% interval lies wholly above the random-weights layer's and
    above 0 (an R^2 below 0 decodes nothing, however it compares)."""
    rows = [{"lag": int(k), "lag_s": float(decoding["lag_s"].sel(lag=k)), "layer": layer, "variable": variable,
             **{column: float(result[field].sel(lag=k, layer=layer, variable=variable))
                for column, result, field in (("r2", decoding, "r2"), ("r2_low", decoding, "r2_low"),
                                              ("random_weights_r2", control, "r2"),
                                              ("random_weights_r2_high", control, "r2_high"),
                                              ("noise_baseline", decoding, "baseline"))}}
            for k in lags for layer in layers for variable in variables]
    for row in rows:
        row["above_random_weights"] = row["r2_low"] > max(row["random_weights_r2_high"], 0.0)
    columns = [("lag", "lag", "d"), ("layer", "layer", "s"), ("variable", "variable", "s"), ("r2", "R^2", ".3f"),
               ("random_weights_r2", "random weights", ".3f"), ("noise_baseline", "noise", ".3f"),
               ("above_random_weights", "above", "")]
    return rows, columns


def study_folder(study: str) -> str:
    """benchmarks/results/<study>/, made if missing: where a script of that study writes unless told otherwise."""
    path = os.path.join(RESULTS, study)
    os.makedirs(path, exist_ok=True)
    return path


# Result path (or stem) asked for -> the one this process chose for it: its later saves (a script that saves as it
# goes, so that a run cut short keeps its rows) rewrite that file, never another.
_CHOSEN: dict[str, str] = {}


def fresh_stem(stem: str, suffixes: tuple[str, ...]) -> tuple[str, bool]:
    """The stem this process writes `stem + suffix` for each of `suffixes` under, and whether it chose it before. A
    result that this process did not write is never replaced (a committed measurement, a user's earlier run): the
    first free one of STEM, STEM-2, STEM-3, ... with none of `suffixes` taken, so that a result's JSON and figure keep
    one name; later calls in this process return the same stem."""
    key = stem + "|".join(suffixes)
    if key in _CHOSEN:
        return _CHOSEN[key], True
    chosen, taken = stem, 1
    while any(os.path.exists(chosen + suffix) for suffix in suffixes):
        taken += 1
        chosen = f"{stem}-{taken}"
    _CHOSEN[key] = chosen
    return chosen, False


def write_json(stem: str, record: dict, suffixes: tuple[str, ...] = (".json",), indent: int | None = 2) -> str:
    """Write `record` to `fresh_stem(stem, suffixes)` + `suffixes[0]` (the JSON's suffix, as asked) and return that
    stem (the caller writes its other files, e.g. the figure, under it). The first write in a process refuses a file
    made meanwhile by another run."""
    chosen, before = fresh_stem(stem, suffixes)
    with open(chosen + suffixes[0], "w" if before else "x") as file:
        json.dump(record, file, indent=indent)
    return chosen


def write_results(name: str, config: dict, rows: list[dict], out: str | None = None, *, study: str,
                  extra: dict | None = None) -> str:
    """Write rows with device, versions and config as JSON to `out` (default:
    results/<study>/<name>_<platform>.json), with `extra`'s keys beside them (e.g. statistics over rows). A file that
    this process did not write is never replaced (`fresh_stem`): the rows go to the next free name, NAME-2.json,
    NAME-3.json, ..., which this process's later saves rewrite; the path written is returned."""
    asked = out or os.path.join(study_folder(study), f"{name}_{jax.devices()[0].platform}.json")
    stem, suffix = os.path.splitext(asked)
    record = {"benchmark": name, "date": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
              "device": device(), "versions": versions(), "config": config, "results": rows, **(extra or {})}
    return write_json(stem, record, (suffix,)) + suffix


def rolling_peak(values, window: int) -> tuple[int, float, float]:
    """Of the means of `values` over `window` consecutive entries (NaN skipped): the index of the entry that ends the
    highest window, that window's mean, and the last window's mean. A training metric's peak and where it ended,
    judged on a few cycles rather than one noisy cycle."""
    values = np.asarray(values, dtype=float)
    rolling = np.array([np.nanmean(values[i:i + window]) for i in range(len(values) - window + 1)])
    top = int(np.nanargmax(rolling))
    return top + window - 1, float(rolling[top]), float(rolling[-1])


def markdown_table(rows: list[dict], columns: list[tuple[str, str, str]]) -> str:
    """Rows as a Markdown table; `columns` are (key, header, format spec)."""
    lines = ["| " + " | ".join(h for _, h, _ in columns) + " |", "|" + "---|" * len(columns)]
    for row in rows:
        cells = [format(row[k], f) if row.get(k) is not None else "-" for k, _, f in columns]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def config_parser(doc: str) -> argparse.ArgumentParser:
    """A benchmark's command line that starts like `angora-jax train`: a config (a configs/ name or YAML path) and
    key.sub=value overrides."""
    parser = argparse.ArgumentParser(description=doc, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("config", help="a configs/ name or YAML path, e.g. shadow_reach, shadow_ihom")
    parser.add_argument("overrides", nargs="*", help="key.sub=value overrides, as for angora-jax train")
    return parser
