"""Live progress of a training run: one line rewritten in place on a terminal, plain log lines elsewhere."""

from __future__ import annotations

import errno
import math
import sys
from typing import TextIO


def progress_line(metrics: dict[str, float], total_cycles: int, eta_seconds: float, shown: str | None = None) -> str:
    """`cycle 12/60  env steps 24,576  2,345 steps/s  return 123.4  success 0.120  ETA 0:01:23` for a cycle's
    metrics; the task metric shown is `shown` (a `metric/*` name) when the metrics have it, else the first `metric/*`
    by name; `-` stands for undefined values."""
    parts = [
        f"cycle {int(metrics['cycle'])}/{total_cycles}",
        f"env steps {int(metrics['env_steps']):,}",
        f"{metrics['steps_per_second']:,.0f} steps/s",
        f"return {_show(metrics.get('episode_return', math.nan), '.1f')}",
    ]
    task_metrics = sorted(k for k in metrics if k.startswith("metric/"))
    if shown in task_metrics:
        task_metrics.insert(0, shown)
    if task_metrics:
        parts.append(f"{task_metrics[0].removeprefix('metric/')} {_show(metrics[task_metrics[0]], '.3f')}")
    parts.append(f"ETA {_duration(eta_seconds)}")
    return "  ".join(parts)


class Progress:
    """Shows `progress_line` after each cycle. mode: "bar" (rewrite one line: for terminals), "lines" (one line per
    cycle: for log files), "none", or "auto" ("bar" when `stream` is a terminal, "lines" otherwise). shown: the task
    metric to show (e.g. the run's `checkpoint.best_metric`, `metric/goals_reached` for the cube)."""

    def __init__(self, total_cycles: int, mode: str = "auto", stream: TextIO | None = None, shown: str | None = None):
        self.stream = sys.stdout if stream is None else stream
        self.shown = shown
        if mode == "auto":
            mode = "bar" if self.stream.isatty() else "lines"
        self.mode, self.total = mode, total_cycles
        self._seconds: list[float] = []
        self._width = 0

    def update(self, metrics: dict[str, float]) -> None:
        # The first cycle of a session includes compilation: it would inflate the ETA.
        if "compile_seconds" not in metrics:
            self._seconds.append(metrics["seconds"])
        per_cycle = sum(self._seconds) / len(self._seconds) if self._seconds else metrics["seconds"]
        line = progress_line(metrics, self.total, (self.total - metrics["cycle"]) * per_cycle, self.shown)
        if self.mode == "bar":
            self._write("\r" + line.ljust(self._width))
            self._width = len(line)
        elif self.mode == "lines":
            self._write(line + "\n")

    def announce(self, text: str) -> None:
        """Print `text` on a line of its own (nothing in mode "none"): what the run is doing before its first cycle."""
        if self.mode != "none":
            self._write(text + "\n")

    def close(self) -> None:
        """End the live line, so that later output starts on a fresh line."""
        if self.mode == "bar" and self._width:
            self._write("\n")

    def _write(self, text: str) -> None:
        """Write `text` to the stream; once its reader has gone, show nothing more."""
        try:
            self.stream.write(text)
            self.stream.flush()
        except OSError as error:
            # `train ... | head`, or a pager or `tee` closed (EPIPE), or the terminal (EIO, just before its SIGHUP):
            # the error ended training at the next cycle, before its checkpoint. The run's records are in
            # metrics.jsonl whatever is shown.
            if not isinstance(error, BrokenPipeError) and error.errno != errno.EIO:
                raise
            self.mode = "none"


def _show(value: float, fmt: str) -> str:
    return "-" if math.isnan(value) else format(value, fmt)


def _duration(seconds: float) -> str:
    seconds = max(0, round(seconds))
    return f"{seconds // 3600}:{seconds // 60 % 60:02d}:{seconds % 60:02d}"
