"""For the tests that run benchmark scripts: where the scripts are (a test puts the folder on `sys.path` before
importing them, as they import `common` as a sibling), and the checks that every results file they write must pass."""

import json
import os
from pathlib import Path

import jax
import mujoco

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"


def results(path: Path, benchmark: str) -> dict:
    """The record a script wrote, after checking that it names this machine's device and package versions."""
    record = json.loads(path.read_text())
    assert record["benchmark"] == benchmark and record["date"]
    assert record["device"]["platform"] == jax.devices()[0].platform == "cpu"
    assert record["device"]["count"] == jax.device_count() and record["device"]["host_cpus"] == os.cpu_count()
    assert record["versions"]["jax"] == jax.__version__ and record["versions"]["mujoco"] == mujoco.__version__
    return record
