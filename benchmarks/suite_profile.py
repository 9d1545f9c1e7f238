"""Where the test suite's time goes, test by test: each phase's (setup, call, teardown) wall time beside its own CPU
time, the CPU time of the subprocesses it waited for (the command, notebooks, docs pages, benchmark scripts), XLA's
compiling, JAX's tracing and lowering, and the programs read from the persistent compilation cache. On 2 CPU cores
the suite cannot end sooner than its CPU time over 2, so that total is the number to cut.

    python benchmarks/suite_profile.py                       # the whole suite, as `make test` runs it
    python benchmarks/suite_profile.py tests/test_gae.py -n 0

Runs pytest with this module as a plugin (every pytest-xdist worker records its own phases; loaded without
ANGORA_SUITE_PROFILE_DIR set, the plugin records nothing), prints the totals and the files and tests that take
longest, and writes JSON (device, versions, pytest's arguments, one row for the suite, each file and each test) to
benchmarks/results/suite_profile/suite_profile_<platform>.json or --out. Exits with pytest's status.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

import pytest

# `make test`'s arguments (Makefile).
MAKE_TEST = ["-q", "-rs", "-n", "auto", "--dist", "loadfile", "--no-loadscope-reorder"]
FOLDER = "ANGORA_SUITE_PROFILE_DIR"
MEASURES = ("wall_s", "cpu_s", "subprocess_cpu_s", "compile_s", "compiles", "trace_lower_s", "cache_reads")

# JAX's monitoring events, summed since the worker started (this module imports JAX only once a test runs: loaded
# by `-p`, it comes before conftest.py, which sets JAX's environment first). JAX times a program read from the
# persistent cache as a backend compile too, and reports the read inside it: a read is taken back out of the compiles.
_totals = dict.fromkeys(("compile_s", "compiles", "trace_lower_s", "cache_reads"), 0.0)
_listening = False


def _on_event(event: str, duration: float, **_) -> None:
    if event.endswith("backend_compile_duration"):
        _totals["compile_s"] += duration
        _totals["compiles"] += 1
    elif event.endswith(("jaxpr_trace_duration", "jaxpr_to_mlir_module_duration")):
        _totals["trace_lower_s"] += duration
    elif event.endswith("cache_retrieval_time_sec"):
        _totals["cache_reads"] += 1
        _totals["compiles"] -= 1
        _totals["compile_s"] -= duration


def _now() -> dict[str, float]:
    own, children = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return {"wall_s": time.perf_counter(), "cpu_s": own.ru_utime + own.ru_stime,
            "subprocess_cpu_s": children.ru_utime + children.ru_stime, **_totals}


def _record(item, phase: str):
    folder = os.environ.get(FOLDER)
    if not folder:
        yield
        return
    global _listening
    if not _listening:
        import jax

        jax.monitoring.register_event_duration_secs_listener(_on_event)
        _listening = True
    before = _now()
    yield
    after = _now()
    row = {"test": item.nodeid, "phase": phase, **{k: round(after[k] - before[k], 3) for k in MEASURES}}
    with open(Path(folder) / f"{os.environ.get('PYTEST_XDIST_WORKER', 'main')}.jsonl", "a") as f:
        f.write(json.dumps(row) + "\n")


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_setup(item):
    yield from _record(item, "setup")


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_call(item):
    yield from _record(item, "call")


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_teardown(item, nextitem):
    yield from _record(item, "teardown")


def summarize(phases: list[dict], wall_s: float, cpu_s: float) -> list[dict]:
    """Rows: the suite (pytest's wall clock and the CPU time of all its processes beside the sums over phases),
    then each file and each test (its phases summed), longest first."""
    rows = []
    for scope, name_of in (("file", lambda t: t.split("::")[0]), ("test", lambda t: t)):
        sums: dict[str, dict[str, float]] = defaultdict(lambda: dict.fromkeys(MEASURES, 0.0))
        for phase in phases:
            for k in MEASURES:
                sums[name_of(phase["test"])][k] += phase[k]
        rows += sorted(({"scope": scope, "name": name, **{k: round(v, 2) for k, v in s.items()}}
                        for name, s in sums.items()), key=lambda r: -r["wall_s"])
    tests = {phase["test"] for phase in phases}
    suite = {"scope": "suite", "name": "all", "tests": len(tests), "pytest_wall_s": round(wall_s, 1),
             "pytest_cpu_s": round(cpu_s, 1),
             **{k: round(sum(phase[k] for phase in phases), 2) for k in MEASURES}}
    return [suite, *rows]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", default=None,
                        help="JSON path (default: results/suite_profile/suite_profile_<platform>.json)")
    parser.add_argument("--top", type=int, default=15, help="files and tests to print (default 15)")
    args, pytest_args = parser.parse_known_args()
    pytest_args = pytest_args or MAKE_TEST
    root = Path(__file__).resolve().parents[1]
    with tempfile.TemporaryDirectory(prefix="suite_profile_") as folder:
        env = os.environ | {FOLDER: folder,
                            "PYTHONPATH": os.pathsep.join(filter(None, [str(Path(__file__).parent),
                                                                       os.environ.get("PYTHONPATH")]))}
        before, start = resource.getrusage(resource.RUSAGE_CHILDREN), time.perf_counter()
        status = subprocess.run([sys.executable, "-m", "pytest", "-p", "suite_profile", *pytest_args], cwd=root,
                                env=env).returncode
        wall_s, after = time.perf_counter() - start, resource.getrusage(resource.RUSAGE_CHILDREN)
        cpu_s = after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime
        phases = [json.loads(line) for path in sorted(Path(folder).glob("*.jsonl")) for line in open(path)]
    if not phases:
        raise SystemExit(f"pytest (status {status}) ran no test: nothing to profile. Its arguments: {pytest_args}")

    from common import markdown_table, write_results

    rows = summarize(phases, wall_s, cpu_s)
    suite = rows[0]
    columns = [("name", "name", ""), ("wall_s", "wall s", ".1f"), ("cpu_s", "own CPU s", ".1f"),
               ("subprocess_cpu_s", "subprocess CPU s", ".1f"), ("compile_s", "XLA compile s", ".1f"),
               ("compiles", "compiles", ".0f"), ("trace_lower_s", "trace+lower s", ".1f"),
               ("cache_reads", "cache reads", ".0f")]
    print(f"\n{suite['tests']} tests in {suite['pytest_wall_s']:.0f} s of wall clock on {os.cpu_count()} CPUs; all "
          f"pytest's processes used {suite['pytest_cpu_s']:.0f} s of CPU (the suite's floor on N cores: that / N)\n")
    print(markdown_table([suite], columns))
    for scope in ("file", "test"):
        print(f"\nLongest {scope}s:\n")
        print(markdown_table([r for r in rows if r["scope"] == scope][:args.top], columns))
    path = write_results("suite_profile", {"pytest_args": pytest_args, "host_cpus": os.cpu_count()}, rows, args.out,
                         study="suite_profile")
    print(f"\nwrote {path}")
    sys.exit(status)


if __name__ == "__main__":
    main()
