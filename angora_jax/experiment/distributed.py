"""Several hosts: join a `jax.distributed` job before anything touches a device.

After `initialize`, `jax.devices()` lists the devices of every process, so `distribution.num_devices: all` trains one
data-parallel cycle over all hosts (see `angora_jax.ppo.parallel`): every process runs the same program on its own
devices and holds identical replicated parameters. Every process must also stop at the same cycle, or the others
wait forever in the next cycle's collectives: `agree_to_stop` turns each process's own reasons (a signal, an error)
into one decision.
"""

from __future__ import annotations

import atexit
import contextlib
import hashlib
import json
import os
import secrets
import selectors
import socket
import sys
import threading
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import jax
import numpy as np
from jax.experimental import multihost_utils

from angora_jax.experiment.config import Config, ConfigError
from angora_jax.experiment.run_dir import RunDirError


def initialize(
    coordinator_address: str | None = None,
    num_processes: int | None = None,
    process_id: int | None = None,
    local_device_ids: list[int] | None = None,
    join_seconds: float = 300.0,
    command: str = "train",
) -> None:
    """Start this process's part of a multi-process job; call it first, before any JAX computation.

    Arguments left None come from the cluster environment that JAX detects (SLURM: SLURM_PROCID, SLURM_NTASKS,
    SLURM_STEP_NODELIST; also Open MPI and Kubernetes). Under such a cluster JAX gives each process one GPU, the one
    whose index on its node is the process's local rank (SLURM: SLURM_LOCALID), so launch one process per GPU
    (examples/slurm_train.sh). On CPU the cross-process collectives go through gloo (JAX has none by default there);
    GPUs use NCCL regardless.

    Args:
        coordinator_address: "host:port" of process 0.
        num_processes: the processes of the job.
        process_id: this process's index among them.
        local_device_ids: this process's GPUs on its host instead (elsewhere than a cluster: process i of one host
            takes `[i]`); JAX_LOCAL_DEVICE_IDS sets it too.
        join_seconds: how long to wait for every process to join. Past it the process exits with code 2 and a
            message naming the settings to check (JAX itself would end it with a C++ abort, exit code 134, after
            its `initialization_timeout`, which is set past this).
        command: the verb named in that message (`angora-jax train`, `resume`).
    """
    jax.config.update("jax_cpu_collectives_implementation", "gloo")
    if process_id == 0 and coordinator_address and (taken := _port_taken(coordinator_address)) is not None:
        # Checked here first: JAX, failing to listen there, at times crashes (SIGSEGV) before it can raise.
        raise ConfigError(_port_taken_message(coordinator_address, taken))
    deadline = threading.Timer(join_seconds, _not_joined, args=(coordinator_address, num_processes, process_id,
                                                                join_seconds, command))
    deadline.daemon = True
    deadline.start()
    try:
        jax.distributed.initialize(coordinator_address, num_processes, process_id, local_device_ids=local_device_ids,
                                   initialization_timeout=int(join_seconds) + 60)
    except jax.errors.JaxRuntimeError as error:
        cause = (str(error).splitlines() or [""])[0]
        if "Failed to start RPC server" in cause:  # process 0 could not listen there
            raise ConfigError(_port_taken_message(coordinator_address, cause)) from error
        raise ConfigError(f"--distributed could not join the job at {coordinator_address} ({cause}): check that "
                          "every process has the same --coordinator and --num-processes and its own --process-id, "
                          "then start them all again.") from error
    finally:
        deadline.cancel()
    watch_the_other_processes()


def _port_taken(address: str) -> str | None:
    """Why process 0 cannot listen on `address`'s port on every interface, as JAX's coordinator does; None if it can."""
    family = socket.AF_INET6 if socket.has_dualstack_ipv6() else socket.AF_INET
    try:
        socket.create_server(("", int(address.rsplit(":", 1)[1])), family=family,
                             dualstack_ipv6=family == socket.AF_INET6).close()
    except OSError as error:
        return os.strerror(error.errno) if error.errno else str(error)
    return None


def _port_taken_message(address: str | None, cause: str) -> str:
    return (f"--distributed: process 0 could not start the job's coordinator at {address} ({cause}): another program "
            "holds that port (a job or a run still going or just ended, or a second process given --process-id 0): "
            "give every process another --coordinator port, one free on process 0's host, and each its own "
            "--process-id.")


def _not_joined(coordinator_address: str | None, num_processes: int | None, process_id: int | None,
                join_seconds: float, command: str) -> None:
    """End this process, still inside `jax.distributed.initialize`, with exit code 2 and what to check: from a timer
    thread, since JAX's own end of the wait is a C++ abort that no Python code can intercept."""
    where = coordinator_address or "the coordinator that the cluster names"
    this = f"process {process_id} of {num_processes}" if num_processes is not None else "this process"
    print(f"angora-jax {command}: the jax.distributed job did not come together within {join_seconds / 60:g} "
          f"minutes: {this} waited at {where} for the others. Start every process with the same --coordinator "
          "HOST:PORT (process 0's host, a port free there) and --num-processes N, each with its own --process-id "
          "from 0 to N-1; hosts must reach that port through any firewall; and a slow start (a busy cluster queue) "
          "takes a larger --join-minutes. Nothing was written.", file=sys.stderr, flush=True)
    os._exit(2)  # the main thread is blocked in JAX's C++ client: no exception can reach it


# The key under which process 0 tells the others the port that it watches them on, and the job's token: a connection
# that does not open with the token (a port scanner, a stray client) is no process of the job and is not watched,
# so its close cannot end the run.
_WATCH_KEY = "angora_jax/process_watch_port"
_TOKEN_BYTES = 16
# A process that ends normally says so on its connection first (atexit), so that its end is not taken for a loss.
_BYE = b"bye"


def watch_the_other_processes() -> None:
    """End this process with the lost-process message (`lost_process_exit`) as soon as another process of the job is
    gone, from a background thread, wherever this one is: JAX learns of a killed process only at its heartbeat timeout
    (100 s) unless a Gloo or NCCL collective meets the closed connection first, and then ends every process itself
    with a C++ abort (exit 134) that no Python code can intercept (`get_distributed_runtime_client`'s
    `missed_heartbeat_callback` aborts with std::bad_cast in jaxlib 0.10 before calling Python). Process 0 waiting at
    Orbax's checkpoint barriers when process 1 was killed mid-save aborted so after 80 to 100 s.

    Each process keeps one TCP connection to process 0 open (its port in the job's key-value store), on which nothing
    is sent until the process exits normally and says goodbye: the system closes it when a process dies (kill -9, out
    of memory), which the other end sees at once. When process 0 itself is killed the others see it at the same moment
    as JAX's coordination client, which then often aborts first. Best effort: nothing is watched where the connection
    cannot be made (a firewall between hosts), and a host that vanishes without closing its connections is left to
    JAX's heartbeat timeout."""
    if jax.process_count() == 1:
        return
    try:
        state = jax._src.distributed.global_state  # Orbax uses its client likewise: the job's key-value store
        if jax.process_index() == 0:
            family = socket.AF_INET6 if socket.has_dualstack_ipv6() else socket.AF_INET
            server = socket.create_server(("", 0), family=family, dualstack_ipv6=family == socket.AF_INET6)
            token = secrets.token_bytes(_TOKEN_BYTES)
            state.client.key_value_set(_WATCH_KEY, f"{server.getsockname()[1]} {token.hex()}")
            watched = {}
        else:
            port, token_hex = state.client.blocking_key_value_get(_WATCH_KEY, 60_000).split()
            token = bytes.fromhex(token_hex)
            connection = socket.create_connection((state.coordinator_address.rsplit(":", 1)[0].strip("[]"),
                                                   int(port)), timeout=30)
            connection.sendall(token + jax.process_index().to_bytes(4, "little"))
            connection.settimeout(None)
            server, watched = None, {connection: 0}
    except Exception:  # noqa: BLE001 (unwatched: JAX's own detection, as before)
        return
    atexit.register(_say_goodbye, watched)
    threading.Thread(target=_watch, args=(server, watched, token), daemon=True,
                     name="angora-jax process watch").start()


def _watch(server: socket.socket | None, watched: dict[socket.socket, int], token: bytes) -> None:
    """Process 0: accept the others' connections on `server` into `watched` (connection: process index), each only
    once it has sent the job's `token`; every process: end with the lost-process message when a watched connection
    closes without a goodbye."""
    selector = selectors.DefaultSelector()
    for connection in [server, *watched]:
        if connection is not None:
            selector.register(connection, selectors.EVENT_READ)
    while True:
        for key, _ in selector.select():
            if key.fileobj is server:
                try:
                    accepted, _ = server.accept()
                except OSError:
                    continue
                try:
                    # A stray client cannot hold the watch up for long: 5 s to send the token and the index.
                    accepted.settimeout(5)
                    opening = accepted.recv(len(token) + 4, socket.MSG_WAITALL)
                    accepted.settimeout(None)
                except OSError:
                    opening = b""
                if len(opening) != len(token) + 4 or not secrets.compare_digest(opening[:len(token)], token):
                    accepted.close()
                    continue
                watched[accepted] = int.from_bytes(opening[len(token):], "little")
                selector.register(accepted, selectors.EVENT_READ)
                continue
            try:
                received = key.fileobj.recv(len(_BYE), socket.MSG_WAITALL)
            except OSError:
                received = b""
            selector.unregister(key.fileobj)
            if received != _BYE:
                lost_process_exit(f"process {watched[key.fileobj]}{' (the coordinator)' * (server is None)} closed "
                                  "its connection to this one without ending normally")


def _say_goodbye(watched: dict[socket.socket, int]) -> None:
    """At a normal exit: tell the processes watching this one that its connection closes because it ended."""
    for connection in list(watched):
        with contextlib.suppress(OSError):
            connection.sendall(_BYE)


def is_main_process() -> bool:
    """Whether this process is process 0, the one that should write logs and checkpoints."""
    return jax.process_index() == 0


def shared_run_dir(config: Config, create: Callable[[Config], Path]) -> Path:
    """The run directory of a new run, the same on every process: `create(config)` on a single process; with several,
    process 0 creates `logging.run_root/logging.run_name` and the others wait for it (a dated name could differ
    between hosts, so a multi-process run needs `logging.run_name`, e.g. the SLURM job id)."""
    if jax.process_count() == 1:
        return create(config)
    if config.logging.run_name is None:
        raise ConfigError(
            f"A run over {jax.process_count()} processes needs logging.run_name (all processes write one run "
            "directory), e.g. logging.run_name=$SLURM_JOB_ID."
        )
    path, failure = config.logging.root / config.logging.run_name, None
    if is_main_process():
        try:
            path = create(config)
        except Exception as error:  # raised below on every process: the others would wait for it in the first cycle
            failure = error
    if agree_to_stop(None, failure is not None).failed:
        raise failure or RunDirError(f"Process 0 could not create the run directory {path}; its output says why.")
    return path


def agree_on_settings(settings: dict[str, Any], fix: str) -> None:
    """ConfigError on every process unless every process of the job was given the same `settings` (the same keys on
    all; values that JSON writes, or their str). Nothing checks this otherwise: processes started with other overrides
    would train one run with, e.g., two discount factors while config.yaml records process 0's, and processes given
    other run names wait for each other's checkpoint folders (orbax gives up after 10 minutes, and then the job still
    hangs). One tiny all-gather of a 32-bit digest per key; `fix` ends the message. Every process must call it at the
    same point."""
    if jax.process_count() == 1:
        return
    keys = sorted(settings)
    digests = np.array([int.from_bytes(hashlib.sha256(json.dumps(settings[key], sort_keys=True, default=str)
                                                      .encode()).digest()[:4], "little", signed=True) for key in keys],
                       np.int32)
    gathered = multihost_utils.process_allgather(digests)
    differ = [i for i in range(len(gathered)) if not np.array_equal(gathered[i], gathered[0])]
    if differ:
        which = sorted({keys[k] for i in differ for k in np.flatnonzero(gathered[i] != gathered[0])})
        raise ConfigError(
            f"The {jax.process_count()} processes of this jax.distributed job were not given the same settings: "
            f"process(es) {', '.join(map(str, differ))} differ from process 0 in {', '.join(which)} (this process "
            f"is process {jax.process_index()}). {fix}"
        )


@dataclass(frozen=True)
class StopDecision:
    """What all processes do after a cycle: stop for `signum` (a signal some process received, else None), whether
    processes `failed` (their indices) with an error of their own, whether some process ran `out_of_time` (its
    wall-clock limit for this session, `angora-jax train --minutes`), and whether every failure was in `on_cycle`
    (the user's code, after the cycle's state was whole: all processes can save it together)."""

    signum: int | None
    failed: tuple[int, ...]
    out_of_time: bool = False
    in_on_cycle: bool = False


def agree_to_stop(signum: int | None, failed: bool, out_of_time: bool = False,
                  in_on_cycle: bool = False) -> StopDecision:
    """The stop decision of all processes from this process's reasons: a signal it received (or None), whether it
    failed (`in_on_cycle`: in the user's `on_cycle`) and whether its time limit has passed. Any process's signal
    stops all (the highest signal number wins if several differ); any failure is reported to all; one process out of
    time stops all (their clocks differ). Every process must call it once per cycle, at the same point. On a single
    process it returns the reasons as they are, without communication; with several it is one tiny all-gather of
    three int32 each."""
    failure = (2 if in_on_cycle else 1) if failed else 0
    if jax.process_count() == 1:
        return StopDecision(signum, (jax.process_index(),) if failed else (), out_of_time, failure == 2)
    flags = multihost_utils.process_allgather(np.array([signum or 0, failure, int(out_of_time)], np.int32))
    failed_ones = np.flatnonzero(flags[:, 1])
    return StopDecision(int(flags[:, 0].max()) or None, tuple(int(i) for i in failed_ones), bool(flags[:, 2].max()),
                        failed_ones.size > 0 and bool((flags[failed_ones, 1] == 2).all()))


class ProcessFailed(RuntimeError):
    """Another process of a multi-process run stopped with an error; this one stops after the same cycle."""

    def __init__(self, processes: tuple[int, ...], cycle: int, run_dir: Path, saved: bool = False):
        self.processes, self.cycle = processes, cycle
        kept = ("in on_cycle (their output has the error), so this process stops too, with the checkpoint of that "
                "cycle saved by all" if saved else
                "(their output has the error), so this process stops too, without a checkpoint of that cycle")
        super().__init__(
            f"Process(es) {', '.join(map(str, processes))} of this run failed after cycle {cycle} {kept}; after "
            f"fixing the cause, continue with: angora-jax resume {run_dir} --distributed"
        )


# Exit code 1, the CLI's EXIT_FAILED (another process of the run failed); not imported: the CLI imports this module.
EXIT_FAILED = 1

# How a collective fails, on CPU (gloo) and GPUs (NCCL's ncclRemoteError, as XLA reports it: "NCCL operation ...
# failed: remote process exited or there was a network error"), when another process of the job is gone. Not any
# NCCL error: "unhandled cuda error" or a failed ncclCommInitRank is this process's own failure, which the user must
# see as it is rather than as a lost process.
LOST_PEER = ("Gloo", "Connection closed by peer", "Connection reset by peer",
             "remote process exited or there was a network error", "ncclRemoteError", "heartbeat")


def lost_process_cause(error: BaseException) -> str | None:
    """The first line of `error` when it says that a collective of a multi-process job lost a process (else None)."""
    text = str(error)
    if jax.process_count() == 1 or not any(marker in text for marker in LOST_PEER):
        return None
    return text.splitlines()[0][:300]


def lost_process_exit(cause: str) -> None:
    """Say that another process of the job is gone and end this one with exit code 1 at once. os._exit, because an
    ordinary exit runs jax.distributed's shutdown, which waits for the gone process until the heartbeat timeout and
    then aborts with a C++ stack trace (exit 134); nothing is left to save, as no collective can finish without it."""
    print(f"angora-jax: Another process of this jax.distributed job is gone ({cause}): it was killed (kill -9, out of "
          "memory, a lost node; its output or the scheduler's log says which) or cannot reach this one. This process "
          "cannot go on without it and stops too, without a checkpoint of the cycle in progress; the checkpoints "
          "saved before are intact. Continue with every process: angora-jax resume RUN_DIR --distributed",
          file=sys.stderr, flush=True)
    sys.stdout.flush()
    os._exit(EXIT_FAILED)
