"""Shared by the benchmark scripts: timing of compiled functions, environment facts, JSON results."""

from __future__ import annotations

import datetime
import importlib.metadata
import json
import os
import platform
import time
from collections.abc import Callable

import jax

RESULTS = os.path.join(os.path.dirname(os.path.abspath(__file__)), "results")


def versions() -> dict[str, str]:
    """Versions of the packages that decide the numbers."""
    names = ("jax", "jaxlib", "mujoco", "mujoco-mjx", "flax", "optax", "angora-jax")
    found = {}
    for name in names:
        try:
            found[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            found[name] = "absent"
    found["python"] = platform.python_version()
    return found


def device() -> dict[str, str | int]:
    """The default JAX device, in words."""
    dev = jax.devices()[0]
    return {"platform": dev.platform, "kind": dev.device_kind, "count": jax.device_count(),
            "host_cpus": os.cpu_count() or 0}


def peak_memory_bytes() -> int | None:
    """Peak bytes in use on the default device since start, where the backend reports it (GPUs do)."""
    stats = jax.devices()[0].memory_stats() or {}
    return stats.get("peak_bytes_in_use")


def time_compiled(fn: Callable, *args, repeats: int = 3, chain: Callable | None = None) -> tuple[float, float, object]:
    """Compile `jit(fn)` for `args`, run it once to warm up, then time `repeats` runs; return (compile s, seconds
    per run, last output). With `chain`, each run takes `chain(previous output)` as its arguments (a training
    cycle continues from the state it returned); otherwise every run takes `args` and the best run counts."""
    start = time.perf_counter()
    compiled = jax.jit(fn).lower(*args).compile()
    compile_s = time.perf_counter() - start
    out = jax.block_until_ready(compiled(*args))
    if chain is not None:
        start = time.perf_counter()
        for _ in range(repeats):
            out = compiled(*chain(out))
        jax.block_until_ready(out)
        return compile_s, (time.perf_counter() - start) / repeats, out
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        out = jax.block_until_ready(compiled(*args))
        best = min(best, time.perf_counter() - start)
    return compile_s, best, out


def write_results(name: str, config: dict, rows: list[dict], out: str | None = None) -> str:
    """Write rows with device, versions and config as JSON to `out` (default: results/<name>_<platform>.json)."""
    os.makedirs(RESULTS, exist_ok=True)
    path = out or os.path.join(RESULTS, f"{name}_{jax.devices()[0].platform}.json")
    record = {"benchmark": name, "date": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
              "device": device(), "versions": versions(), "config": config, "results": rows}
    with open(path, "w") as f:
        json.dump(record, f, indent=2)
    return path


def markdown_table(rows: list[dict], columns: list[tuple[str, str, str]]) -> str:
    """Rows as a Markdown table; `columns` are (key, header, format spec)."""
    lines = ["| " + " | ".join(h for _, h, _ in columns) + " |", "|" + "---|" * len(columns)]
    for row in rows:
        cells = [format(row[k], f) if row.get(k) is not None else "-" for k, _, f in columns]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)
