"""`angora-jax monitor`: the HTML report of runs that are training, regenerated on a timer and served over HTTP.

AngoraPy follows a running experiment in a web app; here the static report (`report`) is rewritten every `every`
seconds from the runs' files (metrics.jsonl, sessions.jsonl, config.yaml), with each run's status, and reloads itself
in the browser. Nothing in the run directories is written: the monitor can watch runs of other processes and hosts
that share a file system, and stopping it never touches a run.
"""

from __future__ import annotations

import functools
import http.server
import sys
import threading
from collections.abc import Sequence
from pathlib import Path

from angora_jax.experiment.report import load_run, write_report


class LiveReport:
    """Regenerates the report of `run_dirs` into `out_dir` every `every` seconds in a background thread and, when
    `port` is not None, serves `out_dir` on http://host:port/ (port 0 picks a free one: see `url`).

    Use as a context manager, or call `start()` and `stop()`. RunDirError (from `load_run`) at construction when a
    path is not a run directory, so a typo fails at once rather than in the thread.
    """

    def __init__(self, run_dirs: Sequence[str | Path], out_dir: str | Path, every: float = 30.0,
                 port: int | None = 8000, host: str = "127.0.0.1"):
        if every <= 0:
            raise ValueError(f"every (seconds between updates) must be > 0, got {every}.")
        for run_dir in run_dirs:
            load_run(run_dir)
        self.run_dirs, self.out_dir, self.every = list(run_dirs), Path(out_dir), every
        self.updates = 0
        self._stopping = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="angora_jax live report", daemon=True)
        self._server = None
        if port is not None:
            handler = functools.partial(_QuietHandler, directory=str(self.out_dir))
            self._server = http.server.ThreadingHTTPServer((host, port), handler)

    @property
    def url(self) -> str | None:
        """The page's address (None when not serving)."""
        if self._server is None:
            return None
        host, port = self._server.server_address[:2]
        return f"http://{host}:{port}/index.html"

    def update(self) -> Path:
        """Regenerate the report now; return index.html."""
        page = write_report(self.run_dirs, self.out_dir, refresh_seconds=max(1, round(self.every)))
        self.updates += 1
        return page

    def start(self) -> LiveReport:
        self.update()
        self._thread.start()
        if self._server is not None:
            threading.Thread(target=self._server.serve_forever, name="angora_jax report server", daemon=True).start()
        return self

    def stop(self) -> None:
        self._stopping.set()
        if self._server is not None:
            self._server.shutdown()
            self._server.server_close()
        if self._thread.is_alive():
            self._thread.join()

    def wait(self) -> None:
        """Block until `stop()` (or Ctrl-C in the caller)."""
        self._stopping.wait()

    def __enter__(self) -> LiveReport:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    def _loop(self) -> None:
        while not self._stopping.wait(self.every):
            try:
                self.update()
            except Exception as error:  # a run directory being moved or rewritten: keep the last page, try again
                print(f"angora-jax monitor: report not updated ({error}); retrying in {self.every:g} s",
                      file=sys.stderr)


class _QuietHandler(http.server.SimpleHTTPRequestHandler):
    """Serves the report folder without a log line per request (the page reloads itself all the time)."""

    def log_message(self, format, *args):  # noqa: A002 (the base class's signature)
        pass

    def end_headers(self):
        self.send_header("Cache-Control", "no-store")  # curves are rewritten under the same names
        super().end_headers()
