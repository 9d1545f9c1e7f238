"""One writer per run: `RUN_DIR/writer.lock` names the process that trains the run (host, process id, its start).

`train` and `resume` hold the lock while they write the run's training files (metrics.jsonl, checkpoints/,
sessions.jsonl); in a multi-process job, process 0 holds it for all. Readers (`evaluate`, `report`, `monitor`,
`record`, `check`) take no lock. A second writer is refused with `RunLockedError`, which names the holder. A lock
whose holder is gone (same host, process ended: killed, or the machine rebooted) is taken over with a message; a
lock held on another host is never broken without `force`, since this host cannot see whether that process lives,
and a lock whose process runs on this host is never broken, `force` or not.
"""

from __future__ import annotations

import contextlib
import json
import os
import socket
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from angora_jax.experiment.run_dir import LOCK_FILE, RunDirError


class RunLockedError(RunDirError):
    """Another process holds (or may hold) the run's writer lock."""


@dataclass(frozen=True)
class LockHolder:
    """Who holds a run's lock: host name, process id, the process's start on that host (clock ticks since boot, from
    /proc; None elsewhere), when it took the lock (Unix seconds) and the run directory it took it for (absolute; None
    in locks written before it was recorded)."""

    host: str
    pid: int
    process_start: int | None
    since: float
    run_dir: str | None = None

    def describe(self) -> str:
        since = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(self.since))
        if self.pid < 0:
            return f"an unknown process (the lock file is unreadable: edited or damaged; written {since})"
        return f"process {self.pid} on host {self.host}, since {since}"

    def runs_here(self) -> bool:
        """True when the holder is a process of this host that this host sees alive: no `force` takes its lock."""
        return self.pid >= 0 and self.host == socket.gethostname() and not self.is_gone()

    def is_gone(self) -> bool:
        """True when this host can tell the holder has ended (it runs here, and no such process lives, or only as a
        zombie: killed, not yet reaped)."""
        if self.host != socket.gethostname():
            return False
        try:
            os.kill(self.pid, 0)
        except ProcessLookupError:
            return True
        except PermissionError:  # a process of another user: alive
            return False
        # A killed process whose parent never reaps it stays a zombie, forever in a container without an init.
        if _process_state(self.pid) in ("Z", "X"):
            return True
        # The id may have been given to another process since (after a reboot, or a long time): compare starts.
        return self.process_start is not None and _process_start(self.pid) != self.process_start


def _written_holder(data: dict) -> LockHolder:
    """The holder that a lock file's JSON names; ValueError (KeyError, TypeError, OverflowError) for values that no
    writer of a lock writes (an edited or damaged file): a process id no process has (0 or below, past the system's
    range, not a whole number), which `os.kill` refuses or takes for a process group; a start that is no whole number,
    which no process's start equals, so that a live holder would be taken for one that ended; a time no clock shows."""
    pid, start, since, run_dir = data["pid"], data.get("process_start"), float(data["since"]), data.get("run_dir")
    if type(pid) is not int or not 0 < pid < 2 ** 31 or not (start is None or type(start) is int) or not (
            run_dir is None or isinstance(run_dir, str)):
        raise ValueError(f"not a lock's holder: pid {pid!r}, process_start {start!r}, run_dir {run_dir!r}")
    time.localtime(since)  # OverflowError, ValueError or OSError for a time out of the clock's range (1e300, NaN)
    return LockHolder(str(data["host"]), pid, start, since, run_dir)


def _stat_fields(pid: int) -> list[str] | None:
    """The fields of /proc/PID/stat after the process name (Linux), from field 3 (the state) on; None where /proc
    does not say."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    return stat.rpartition(")")[2].split()  # the name before ')' may hold spaces


def _process_state(pid: int) -> str | None:
    """The process's state letter (R, S, D, Z for a zombie, ...), None where /proc does not say."""
    fields = _stat_fields(pid)
    return fields[0] if fields else None


def _process_start(pid: int) -> int | None:
    """The process's start time in clock ticks since boot (Linux), which tells a process from a later one that got
    the same id; None where /proc does not say."""
    fields = _stat_fields(pid)
    return int(fields[19]) if fields else None  # field 22


class RunLock:
    """The writer lock of one run directory; use as a context manager, or `acquire` and `release`."""

    def __init__(self, run_dir: str | Path):
        self.path = Path(run_dir) / LOCK_FILE
        self._held = False

    def holder(self) -> LockHolder | None:
        """The lock's holder, or None when nobody holds it; an unreadable lock file reads as a holder unknown."""
        try:
            return _written_holder(json.loads(self.path.read_text()))
        except FileNotFoundError:
            return None
        except (OSError, ValueError, KeyError, TypeError, OverflowError):
            return LockHolder("", -1, None, self.path.stat().st_mtime)

    def copied_from(self, holder: LockHolder) -> Path | None:
        """The run directory this lock file was copied from with the run (`cp -r` of a run while it trained), when
        the holder took it for that other directory, which still holds the same lock: the holder writes there, and
        nobody writes this copy. None otherwise (a run moved while it trains is still written by its holder)."""
        if holder.run_dir is None or Path(holder.run_dir) == self.path.parent.resolve():
            return None
        return Path(holder.run_dir) if RunLock(holder.run_dir).holder() == holder else None

    def acquire(self, force: bool = False) -> None:
        """Take the lock, or raise RunLockedError naming its holder and the fix. A holder that is gone (see module
        docstring) is replaced with a message on stderr; `force` also replaces a holder this host cannot check (on
        another host, or an unreadable lock file), never one alive on this host."""
        me = {"host": socket.gethostname(), "pid": os.getpid(), "process_start": _process_start(os.getpid()),
              "since": time.time(), "run_dir": str(self.path.parent.resolve())}
        # Written whole beside the lock, then linked into place: the link fails if the lock exists, so two processes
        # cannot both take it, and nobody reads a half-written lock.
        draft = self.path.with_name(f"{LOCK_FILE}.{me['pid']}.{me['host']}.tmp")
        try:
            draft.write_text(json.dumps(me) + "\n")
            for _ in range(2):
                with contextlib.suppress(FileExistsError):
                    os.link(draft, self.path)
                    self._held = True
                    return
                holder = self.holder()
                if holder is None:
                    continue  # released in between
                if (original := self.copied_from(holder)) is not None:
                    print(f"Taking over the writer lock of {self.path.parent}: it was copied with the run from "
                          f"{original}, which {holder.describe()} trains; nobody writes this copy.",
                          file=sys.stderr, flush=True)
                    self.path.unlink(missing_ok=True)
                    continue
                if holder.pid == os.getpid() and holder.host == me["host"]:
                    raise RunLockedError(f"{self.path.parent} is already being written by this process (a second "
                                         "train or resume of the same run in one notebook?).")
                gone = holder.is_gone()
                if not (gone or force) or holder.runs_here():
                    raise RunLockedError(self._refusal(holder))
                reason = "its process has ended" if gone else "forced (--force)"
                print(f"Taking over the writer lock of {self.path.parent} from {holder.describe()}: {reason}.",
                      file=sys.stderr, flush=True)
                self.path.unlink(missing_ok=True)
            raise RunLockedError(f"{self.path.parent}: another process took the writer lock at the same moment. Try "
                                 "again, or see who holds it in its lock file " f"{self.path}.")
        finally:
            draft.unlink(missing_ok=True)

    def _refusal(self, holder: LockHolder) -> str:
        if holder.pid < 0:
            fix = "if no process trains it now, resume with --force to take the lock over"
        elif holder.host == socket.gethostname():
            fix = (f"wait for it to finish or stop it (Ctrl-C or kill {holder.pid}; it saves a checkpoint), then "
                   "resume (--force takes over only a lock this host cannot check: this process runs here)")
        else:
            fix = ("if that process is certainly gone (its job ended, the machine is down), resume with --force to "
                   "take the lock over")
        return (f"{self.path.parent} is being trained by {holder.describe()} (lock file {self.path}). Two writers "
                f"would mix their checkpoints and metrics. To continue it, {fix}. Evaluating, recording and reports "
                "need no lock: they can run now.")

    def release(self) -> None:
        """Give the lock up if this object holds it (and the file is still ours)."""
        if not self._held:
            return
        self._held = False
        release_own_lock(self.path.parent)

    def __enter__(self) -> RunLock:
        self.acquire()
        return self

    def __exit__(self, *exc) -> None:
        self.release()


def release_own_lock(run_dir: str | Path) -> None:
    """Remove the run's lock if this process holds it: for a process about to end without unwinding (`os._exit`)."""
    holder = RunLock(run_dir).holder()
    if holder is not None and holder.pid == os.getpid() and holder.host == socket.gethostname():
        (Path(run_dir) / LOCK_FILE).unlink(missing_ok=True)
