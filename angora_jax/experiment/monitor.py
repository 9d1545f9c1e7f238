"""The experiment monitor: one JSON line per cycle in `RUN_DIR/metrics.jsonl`, optionally TensorBoard events and
Weights & Biases (`experiment.wandb_logging`).

A line holds the cycle's training metrics (episode_return, episode_length, `metric/<task metric>`, the losses,
entropy, approx_kl, clip_fraction, explained_variance, learning_rate, seconds, steps_per_second and, on the first
cycle of a session, compile_seconds and the programs read from the persistent compilation cache or compiled,
compile_cache_hits and compile_cache_misses), normaliser statistics (`norm/...`), memory (`memory/...`, bytes) and
`time` (Unix seconds). Undefined values (no episode finished) are written as null.
"""

from __future__ import annotations

import contextlib
import errno
import json
import math
import os
import resource
import sys
import time
from pathlib import Path
from typing import Any

import jax
import numpy as np

from angora_jax.experiment.run_dir import (
    CONFIG_FILE,
    METRICS_FILE,
    START_RUNS,
    DiskFullError,
    RunDirError,
    no_room,
    not_a_run_dir,
    run_dir_path,
)
from angora_jax.experiment.wandb_logging import WandbConfig, WandbLog
from angora_jax.ppo.config import StopAt
from angora_jax.ppo.cycle import TrainState
from angora_jax.ppo.episode_pool import Pool
from angora_jax.ppo.parallel import host_copy
from angora_jax.whole_files import written_whole
from angora_jax.wording import agreeing, counted


def normalizer_summary(state: TrainState) -> dict[str, float]:
    """Scalars that show what the running normalisation has learned: the reward scale (std of the discounted
    return) and, per observation modality that has features, the mean |mean| and mean std over features."""
    # NumPy on this process's copy: only process 0 of a multi-process run records, and a jnp operation there, a
    # program the others never run, is the likely cause of 4 processes on 4 H100s hanging before their first record
    # (with it gone, the same launch trained).
    reward, observations = host_copy((state.reward_stats, state.obs_stats))
    stats = {"norm/reward_std": float(np.sqrt(reward.var)), "norm/count": float(reward.count)}
    for name, modality in observations.__dict__.items():
        if modality.mean.size:
            stats[f"norm/{name}_abs_mean"] = float(np.abs(modality.mean).mean())
            stats[f"norm/{name}_std"] = float(np.sqrt(modality.var).mean())
    return stats


def memory_summary() -> dict[str, float]:
    """Device memory in use and its peak (bytes) where the backend reports it (GPUs), and the process's peak
    resident host memory."""
    scale = 1 if sys.platform == "darwin" else 1024  # ru_maxrss is bytes on macOS, KiB on Linux
    stats = {"memory/host_peak_bytes": float(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * scale)}
    device = jax.local_devices()[0].memory_stats() or {}
    for key in ("bytes_in_use", "peak_bytes_in_use"):
        if key in device:
            stats[f"memory/device_{key}"] = float(device[key])
    return stats


class Monitor:
    """Appends one record per cycle to `metrics.jsonl` (and to TensorBoard and W&B when asked). `config`, the run's
    resolved config, is what W&B shows as the run's config."""

    def __init__(self, run_dir: Path, tensorboard: bool = False, wandb: WandbConfig | None = None,
                 config: dict[str, Any] | None = None):
        self.path = Path(run_dir) / METRICS_FILE
        # Unbuffered: a record is written whole or, when the disk is full, cut back to the previous one (`record`).
        self._file = self.path.open("ab", buffering=0)
        self._writer = None
        if tensorboard:
            from tensorboardX import SummaryWriter  # optional dependency, checked by config.validate

            self._writer = SummaryWriter(str(Path(run_dir) / "tensorboard"))
        self._wandb = WandbLog(run_dir, wandb, config or {}) if wandb is not None else None

    def record(self, metrics: dict[str, float], state: TrainState) -> dict[str, Any]:
        """Write the cycle's record (metrics plus normaliser and memory statistics) and return it."""
        record = {**metrics, **normalizer_summary(state), **memory_summary(), "time": time.time()}
        line = (json.dumps({k: _json_value(v) for k, v in record.items()}) + "\n").encode()
        end = os.fstat(self._file.fileno()).st_size
        try:
            if self._file.write(line) != len(line):
                raise OSError(errno.ENOSPC, "the record was written in part")
        except OSError as error:
            with contextlib.suppress(OSError):
                os.ftruncate(self._file.fileno(), end)  # no half line for the next write to follow
            room = no_room(error)
            raise (DiskFullError if room else RunDirError)(
                f"Cannot write the record of cycle {record.get('cycle')} to {self.path}: "
                f"{room[0] if room else error.strerror or error} ({error.strerror or error}). The records and "
                f"checkpoints written before are intact; {room[1] if room else 'fix the cause'}, then `angora-jax "
                f"check {self.path.parent}` says how to continue.") from None
        if self._writer is not None:
            step = int(metrics["env_steps"])
            for key, value in record.items():
                if isinstance(value, float) and math.isfinite(value) and key != "time":
                    self._writer.add_scalar(key, value, step)
            self._writer.flush()
        if self._wandb is not None:
            self._wandb.log(record)
        return record

    def close(self) -> None:
        self._file.close()
        if self._writer is not None:
            self._writer.close()
        if self._wandb is not None:
            self._wandb.close()


def read_metrics(run_dir: str | Path) -> list[dict[str, Any]]:
    """The records of `run_dir/metrics.jsonl` in order, nulls read back as NaN. A damaged line (an edit, a copy cut
    short) is skipped with a warning naming it (`angora-jax check` lists them). A run that has not finished a cycle
    yet has none, as has a directory being made into one (`train` makes it, then writes its config); RunDirError for
    a path that does not exist (mistyped), a file or a folder of runs, each of which read as a run without records."""
    path = run_dir_path(run_dir)
    metrics = path / METRICS_FILE
    if not metrics.is_file() and not (path / CONFIG_FILE).is_file() and (
            not path.is_dir() or any((child / CONFIG_FILE).is_file() for child in path.iterdir())):
        raise RunDirError(not_a_run_dir(run_dir, START_RUNS))
    rows, damaged = _parse_metrics(metrics)
    if damaged:
        count = len(damaged)
        print(f"Warning: {metrics}: {agreeing(count, 'line')} {', '.join(map(str, damaged[:5]))} "
              f"{agreeing(count, 'is not a record', 'are not records')} of a cycle and {agreeing(count, 'is', 'are')} "
              "skipped (angora-jax check RUN_DIR).", file=sys.stderr)
    return [_with_nans(row) for _, row in rows]


def ended_by_stop_at(run_dir: str | Path, stop_at: StopAt | None, cycle: int | None) -> str | None:
    """What ended `run_dir` under its `ppo.stop_at` at `cycle` ("metric/goals_reached 30.4 >= 30"), read from the
    records up to that cycle; None when it has no target, no such record, or the record does not reach it."""
    if stop_at is None or cycle is None:
        return None
    return stop_at.ended(stop_at_pool(run_dir, stop_at, cycle)[0])


def stop_at_pool(run_dir: str | Path, stop_at: StopAt, cycle: int) -> tuple[float, Pool]:
    """The value that `stop_at` compared at `cycle` (NaN without that cycle's record) and the pool the next cycle
    continues (`StopAt.compared`), from `run_dir`'s records of the cycles up to `cycle`: a resumed run compares as if
    it had not stopped."""
    value, pool = math.nan, []
    for _, row in _parse_metrics(Path(run_dir) / METRICS_FILE)[0]:
        if row["cycle"] <= cycle:
            compared, pool = stop_at.compared(pool, _with_nans(row))
            value = compared if row["cycle"] == cycle else math.nan
    return value, pool


def _with_nans(record: dict[str, Any]) -> dict[str, Any]:
    """A record as read from metrics.jsonl, its nulls (non-finite values when written) read back as NaN."""
    return {k: math.nan if v is None else v for k, v in record.items()}


def logged_cycles(run_dir: str | Path) -> list[int]:
    """The cycle numbers of the records in `run_dir/metrics.jsonl`, in file order (damaged lines left out)."""
    return [row["cycle"] for _, row in _parse_metrics(Path(run_dir) / METRICS_FILE)[0]]


def damaged_metric_lines(run_dir: str | Path) -> list[int]:
    """The line numbers (from 1) of metrics.jsonl that hold no cycle's record."""
    return _parse_metrics(Path(run_dir) / METRICS_FILE)[1]


def bare_metric_records(run_dir: str | Path) -> list[tuple[int, int]]:
    """(line number from 1, cycle) of each record of metrics.jsonl without env_steps, such as `{"cycle": 7}`: a
    cycle's number without the values that every record `Monitor.record` writes carries (env_steps, time, the
    normaliser's and memory's statistics). It writes each record as one whole line, and one cut short does not parse,
    so such a line was edited or written by another program. It reads as a record (`report` counts its cycle, with no
    point on the curves), which is why `angora-jax check` names it."""
    return [(number, row["cycle"]) for number, _, row in _numbered_metrics(Path(run_dir) / METRICS_FILE)
            if row is not None and "env_steps" not in row]


def _parse_metrics(path: Path) -> tuple[list[tuple[str, dict[str, Any]]], list[int]]:
    """(line text, record) of each whole record line, and the numbers of the damaged lines. A last line without its
    newline is being written right now (a live report reads while the run trains) and is neither."""
    numbered = _numbered_metrics(path)
    return ([(line, row) for _, line, row in numbered if row is not None],
            [number for number, line, row in numbered if row is None and line.strip()])


def _numbered_metrics(path: Path) -> list[tuple[int, str, dict[str, Any] | None]]:
    """(line number from 1, text, record or None) of each whole line of `path` (none where it is missing)."""
    try:
        text = path.read_text(errors="replace")
    except FileNotFoundError:
        return []
    lines = text.splitlines()
    if lines and not text.endswith("\n"):
        lines.pop()
    return [(number, line, _record(line)) for number, line in enumerate(lines, 1)]


def _record(line: str) -> dict[str, Any] | None:
    """The cycle's record a line of metrics.jsonl holds, or None when it holds none: a record's values are numbers
    (or null, for a non-finite one), as `Monitor.record` writes them. A line edited to hold text where a number goes
    ended `report` in a TypeError traceback, while `check` called the file intact."""
    try:
        row = json.loads(line)
    except ValueError:
        return None
    numbers = isinstance(row, dict) and all(value is None or isinstance(value, int | float) for value in row.values())
    return row if numbers and isinstance(row.get("cycle"), int) else None


def set_aside_after(run_dir: str | Path, cycle: int) -> Path | None:
    """Before resuming from `cycle`: move the records of later cycles (written after the checkpoint, before the
    run was killed) from metrics.jsonl into a new side file, so the log holds each cycle once. Returns the side
    file, or None when there was nothing to move."""
    path = Path(run_dir) / METRICS_FILE
    if not path.exists():
        return None
    kept_lines, later = [], []
    for line in path.read_text(errors="replace").splitlines():
        row = _record(line)
        if row is not None and row["cycle"] <= cycle:
            kept_lines.append(line)
        elif line.strip():  # a later record, or a damaged line (which the log keeps no more than a later one)
            later.append(line)
    if not later:
        return None
    side = path.with_name(f"metrics.after-cycle-{cycle}.jsonl")
    index = 1
    while side.exists():
        index += 1
        side = path.with_name(f"metrics.after-cycle-{cycle}-{index}.jsonl")
    # Each file whole or not at all, and the side file only beside a log that no longer holds its records: a resume
    # that fails here (a full disk) and is run again must not pile up copies of the same records.
    with written_whole(side, replace=False) as draft:
        draft.write_text("\n".join(later) + "\n")
    try:
        with written_whole(path) as draft:
            draft.write_text("".join(line + "\n" for line in kept_lines))
    except BaseException:
        side.unlink()
        raise
    return side


def set_aside_message(side: Path, cycle: int) -> str:
    """The sentence naming what `set_aside_after(run_dir, cycle)` moved into `side`: later cycles' records, damaged
    lines (a record cut mid-write is no record of a later cycle), or both."""
    lines = side.read_text(errors="replace").splitlines()
    damaged = sum(_record(line) is None for line in lines)
    what = counted(damaged, "damaged line") + " of metrics.jsonl"
    if damaged < len(lines):
        what = f"Records after cycle {cycle}" + f" and {what}" * bool(damaged)
    return f"{what} {'is' if what.startswith('1 ') else 'are'} kept in {side}."


def _json_value(value: Any) -> Any:
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value
