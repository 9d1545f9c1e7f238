"""Several processes joined by `jax.distributed` on this host (gloo CPU collectives): they stop together, train in
sync and resume; a failure in one stops the others; and the scaling benchmark's one-process and one-process-per-device
layouts at smoke size. Separate from test_parallel.py (devices of one process) so that the test runner can give these
subprocess-heavy tests to another worker."""

import hashlib
import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import jax
import numpy as np
import pytest
from quick_compile import QUICK_SUBPROCESS
from tiny import TINY_PPO

import angora_jax as aj
from angora_jax.experiment import Checkpoints, ConfigError, distributed, read_metrics, resume, runner
from angora_jax.experiment.distributed import ProcessFailed, StopDecision
from angora_jax.experiment.run_dir import CHECKPOINTS
from angora_jax.ppo import parallel

TESTS = Path(__file__).resolve().parent
BENCHMARKS = TESTS.parent / "benchmarks"

# The runs in this process are a cycle or two of a tiny CartPole (tests/quick_compile.py).
pytestmark = pytest.mark.usefixtures("quick_file_compiles")


@pytest.mark.slow
@pytest.mark.parametrize("variant, devices_per_process", [("cartpole", 2), ("warp", 1)])
def test_two_processes_with_jax_distributed_stop_together_train_in_sync_and_resume_in_one(tmp_path, variant,
                                                                                         devices_per_process,
                                                                                         quick_compiles):
    """CartPole on 2 devices per process, and reach on MuJoCo Warp on one device per process (the cluster layout)."""
    with socket.socket() as probe:  # a free port for the coordinator
        probe.bind(("localhost", 0))
        address = f"localhost:{probe.getsockname()[1]}"
    # Three cycles per process: compiling is most of their time (tests/quick_compile.py).
    env = os.environ | QUICK_SUBPROCESS | {"XLA_FLAGS": f"{os.environ.get('XLA_FLAGS', '')} "
                                                        f"--xla_force_host_platform_device_count={devices_per_process}"}
    processes = [
        subprocess.Popen(
            [sys.executable, str(TESTS / "multihost.py"), address, str(index), str(tmp_path), variant],
            cwd=TESTS,
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for index in range(2)
    ]
    outputs = [process.communicate(timeout=300) for process in processes]
    assert all(process.returncode == 0 for process in processes), [err[-3000:] for _, err in outputs]
    first, second = (json.loads(out.strip().splitlines()[-1]) for out, _ in outputs)
    # Process 1 alone got SIGTERM after cycle 2; both stopped there (agree_to_stop) and saved.
    assert first["stopped"] == second["stopped"] == {"cycle": 2, "signal": signal.SIGTERM}
    # Process 0 also logs; it must not compile (and run alone) a program over both processes' devices.
    assert first["compiled"] == second["compiled"] and "jit(cycle)" in first["compiled"]
    if variant == "warp":
        # One checkpoint of the two processes: this one-device process resumes it (the two contact pools do not fit
        # one device, so with fresh environments) and trains cycle 3.
        for main, other in zip(first["metrics"], second["metrics"], strict=True):
            assert {key: main[key] for key in other} == other
        resumed = resume(tmp_path / "two-hosts")
        assert [record["cycle"] for record in read_metrics(tmp_path / "two-hosts")] == [1, 2, 3]
        assert int(resumed.state.cycle) == 3 and resumed.history[0]["finite"] == 1.0
        return
    # Both resumed together.
    assert first["local_copies_agree"] and second["local_copies_agree"]
    assert first["params"] == second["params"]
    # Process 0's records add the monitor's normaliser, memory and time fields to the cycle metrics both have.
    assert len(first["metrics"]) == len(second["metrics"]) == 3
    for main, other in zip(first["metrics"], second["metrics"], strict=True):
        assert {key: main[key] for key in other} == other and "norm/count" in main
    # Process 0 alone logged; the checkpoint both wrote restores in this single-device process.
    assert [record["cycle"] for record in read_metrics(tmp_path / "two-hosts")] == [1, 2, 3]
    restored = resume(tmp_path / "two-hosts")
    digest = hashlib.sha256()
    for leaf in jax.tree.leaves(restored.state.params):
        digest.update(np.asarray(leaf).tobytes())
    assert int(restored.state.cycle) == 3 and digest.hexdigest() == first["params"]


def test_a_failure_in_another_process_stops_this_one_after_the_same_cycle(tmp_path, monkeypatch):
    # What agree_to_stop reports when process 1 of two failed after this cycle (the real all-gather is exercised by
    # the two-process test above): this process stops too, naming it, and saves no checkpoint of that cycle.
    monkeypatch.setattr(runner, "agree_to_stop", lambda signum, failed, out_of_time, in_on_cycle: StopDecision(
        signum, (1,)))
    overrides = [*TINY_PPO, "logging.progress=none", "logging.report=false", f"logging.run_root={tmp_path}"]
    with pytest.raises(ProcessFailed, match=r"Process\(es\) 1 of this run failed after cycle 1 .*angora-jax resume"):
        aj.train("cartpole", [*overrides, "logging.run_name=peer"])
    assert [record["cycle"] for record in read_metrics(tmp_path / "peer")] == [1]
    checkpoints = Checkpoints(tmp_path / "peer" / CHECKPOINTS, aj.load_config("cartpole").checkpoint, create=False)
    assert checkpoints.steps("latest") == []
    checkpoints.close()


def test_an_on_cycle_failing_in_another_process_saves_the_cycle_in_every_process(tmp_path, monkeypatch):
    """The user's on_cycle failed on one process of several: the cycle's state was whole, yet no process saved it,
    so up to checkpoint.every cycles were lost (one process alone kept it). Now every process saves that cycle
    together, then stops, and the message says the checkpoint is there."""
    calls = []

    def agree(signum, failed, out_of_time=False, in_on_cycle=False):  # after the cycle, then after the save
        calls.append(failed)
        return StopDecision(signum, (1,), in_on_cycle=True) if len(calls) == 1 else StopDecision(signum, ())

    monkeypatch.setattr(runner, "agree_to_stop", agree)
    overrides = [*TINY_PPO, "logging.progress=none", "logging.report=false", f"logging.run_root={tmp_path}",
                 "checkpoint.every=50"]
    with pytest.raises(ProcessFailed, match=r"Process\(es\) 1 of this run failed after cycle 1 in on_cycle .*with "
                                            r"the checkpoint of that cycle saved by all.*angora-jax resume"):
        aj.train("cartpole", [*overrides, "logging.run_name=peer"])
    checkpoints = Checkpoints(tmp_path / "peer" / CHECKPOINTS, aj.load_config("cartpole").checkpoint, create=False)
    assert checkpoints.steps("latest") == [1] and calls == [False, False]
    checkpoints.close()


@pytest.mark.parametrize("flags, failed, in_on_cycle", [
    ([[0, 0, 0], [0, 2, 0]], (1,), True),  # the other process's on_cycle failed
    ([[0, 2, 0], [0, 2, 0]], (0, 1), True),  # both processes' on_cycle
    ([[0, 2, 0], [0, 1, 0]], (0, 1), False),  # one failed elsewhere (a disk filled): a save could wait forever
    ([[0, 0, 0], [0, 0, 1]], (), False),
])
def test_processes_agree_that_every_failure_was_in_on_cycle_only_when_each_was(monkeypatch, flags, failed,
                                                                              in_on_cycle):
    monkeypatch.setattr(jax, "process_count", lambda: 2)
    monkeypatch.setattr(distributed.multihost_utils, "process_allgather", lambda _: np.array(flags, np.int32))
    decision = distributed.agree_to_stop(None, False)
    assert (decision.failed, decision.in_on_cycle) == (failed, in_on_cycle)


# Weak scaling in one process and strong scaling with one process per device cover both sizings and both launches.
@pytest.mark.slow
@pytest.mark.parametrize("weak, processes", [(True, False), (False, True)], ids=["weak", "strong-processes"])
def test_scaling_benchmark_runs_one_and_two_devices_at_smoke_size(tmp_path, weak, processes):
    """Two devices of one process, or (processes) two processes of one CPU device each joined by jax.distributed."""
    out = tmp_path / "scaling.json"
    tiny = [*TINY_PPO, "ppo.num_envs=8", "ppo.minibatch_size=64"]
    done = subprocess.run(
        [sys.executable, str(BENCHMARKS / "scaling.py"), "cartpole", *tiny, "--cycles", "2", "--out", str(out),
         *(["--weak"] if weak else []), *(["--layouts", "processes"] if processes else [])],
        cwd=BENCHMARKS,
        env=os.environ | QUICK_SUBPROCESS | ({} if processes else
                                             {"XLA_FLAGS": "--xla_force_host_platform_device_count=2"}),
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    per_device = 8 if weak else 4
    layout = "processes" if processes else "one"
    # The Markdown table: task, layout, devices, envs per device.
    assert f"| CartPole | {layout} | 2 | {per_device} |" in done.stdout
    single, double = json.loads(out.read_text())["results"]
    assert (single["devices"], double["devices"], double["envs_per_device"]) == (1, 2, per_device)
    assert double["num_envs"] == (16 if weak else 8)
    assert single["steps_per_s"] > 0 and single["scaling"] == 1.0
    assert double["scaling"] == pytest.approx(double["steps_per_s"] / single["steps_per_s"])
    assert double["efficiency"] == pytest.approx(double["scaling"] / 2)
    assert all(len(row["cycle_seconds"]) == 2 for row in (single, double))
    assert double.get("processes") == (2 if processes else None) and double["layout"] == layout
    if not weak:
        # The same training on 1 and 2 devices, up to float rounding.
        assert double["max_param_difference"] < 1e-5
        np.testing.assert_allclose(list(double["final"].values()), list(single["final"].values()), rtol=1e-5,
                                   atol=1e-5)


def _free_address() -> str:
    with socket.socket() as probe:  # a free port for the coordinator
        probe.bind(("localhost", 0))
        return f"localhost:{probe.getsockname()[1]}"


def _two_cli_processes(tmp_path: Path, overrides: list[list[str]]) -> list[subprocess.Popen]:
    """`angora-jax train cartpole --distributed` as processes 0 and 1 of one localhost job, one CPU device each,
    process i with `overrides[i]` after the shared tiny settings."""
    address = _free_address()
    shared = [*TINY_PPO, "ppo.num_envs=8", "ppo.minibatch_size=64", "logging.progress=none", "logging.report=false",
              f"logging.run_root={tmp_path}"]
    return [subprocess.Popen(
        [sys.executable, "-m", "angora_jax.cli", "train", "cartpole", "--distributed", "--coordinator", address,
         "--num-processes", "2", "--process-id", str(index), *shared, *overrides[index]],
        cwd=TESTS, env=os.environ | QUICK_SUBPROCESS, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        for index in range(2)]


def test_a_process_whose_job_never_comes_together_exits_2_naming_what_to_check(tmp_path):
    """Process 1 started with a mistyped --coordinator (no process 0 there), and process 0 of a job whose process 1
    never started, waited JAX's 5 minutes, then ended in JAX's C++ abort: exit code 134 and a stack trace. Each now
    exits 2 at --join-minutes, naming the settings to check, with nothing written. Process 0 given a port that
    another program holds ended in a traceback (JaxRuntimeError: Failed to start RPC server), exit code 1."""
    started = time.monotonic()
    with socket.socket() as taken:
        taken.bind(("localhost", 0))
        taken.listen()
        addresses = [_free_address(), _free_address(), f"localhost:{taken.getsockname()[1]}"]
        processes = [subprocess.Popen(
            [sys.executable, "-m", "angora_jax.cli", "train", "cartpole", "--distributed", "--coordinator", address,
             "--num-processes", "2", "--process-id", str(index), "--join-minutes", "0.1",
             f"logging.run_root={tmp_path}"],
            cwd=TESTS, env=os.environ | QUICK_SUBPROCESS, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
            for index, address in zip((0, 1, 0), addresses, strict=True)]
        outputs = [process.communicate(timeout=120) for process in processes]
    assert [process.returncode for process in processes] == [2, 2, 2], [err[-2000:] for _, err in outputs]
    port_taken = outputs.pop()[1]
    assert "Traceback" not in port_taken and (f"angora-jax train: --distributed: process 0 could not start the job's "
                                              f"coordinator at {addresses[2]} (") in port_taken, port_taken
    assert "another program holds that port" in port_taken and "another --coordinator port" in port_taken
    for index, (_, err) in enumerate(outputs):
        assert "Traceback" not in err and "Joining the jax.distributed job at localhost:" in err, err
        assert (f"angora-jax train: the jax.distributed job did not come together within 0.1 minutes: process "
                f"{index} of 2 waited at localhost:") in err and "the same --coordinator HOST:PORT" in err, err
        assert "own --process-id from 0 to N-1" in err and "Nothing was written." in err, err
    assert time.monotonic() - started < 90, "exited at --join-minutes, not at JAX's 5 minutes"
    assert list(tmp_path.iterdir()) == []


@pytest.mark.slow
def test_processes_started_with_other_settings_exit_2_naming_the_key_before_making_a_run_directory(tmp_path):
    # Before: process 1's ppo.gamma=0.9 trained silently into a run whose config.yaml says 0.99, and processes given
    # other run names waited for each other's checkpoint folders past orbax's 10 minutes.
    processes = _two_cli_processes(tmp_path, [["distribution.num_devices=all", "logging.run_name=one"],
                                              ["distribution.num_devices=all", "logging.run_name=two",
                                               "ppo.gamma=0.9"]])
    outputs = [process.communicate(timeout=180) for process in processes]
    assert [process.returncode for process in processes] == [2, 2], [err[-2000:] for _, err in outputs]
    for index, (_, err) in enumerate(outputs):
        assert "Traceback" not in err
        assert (f"process(es) 1 differ from process 0 in logging.run_name, ppo.gamma (this process is process {index})"
                in err and "the same CONFIG, KEY=VALUE overrides and logging.run_name" in err)
    assert list(tmp_path.iterdir()) == []


def test_agree_on_settings_names_the_keys_another_process_was_given_otherwise(monkeypatch):
    # What the all-gather returns when process 1 has another value of "b" (the real one: the test above).
    monkeypatch.setattr(distributed.jax, "process_count", lambda: 2)
    monkeypatch.setattr(distributed.multihost_utils, "process_allgather",
                        lambda digests: np.stack([digests, digests + np.array([0, 1, 0], np.int32)]))
    with pytest.raises(ConfigError, match=r"process\(es\) 1 differ from process 0 in b \(this process is process 0\)"):
        distributed.agree_on_settings({"c": [3], "a": 1, "b": "x"}, "fix")
    monkeypatch.setattr(distributed.multihost_utils, "process_allgather", lambda digests: np.stack([digests] * 2))
    distributed.agree_on_settings({"c": [3], "a": 1, "b": "x"}, "fix")


def test_a_multi_process_job_needs_num_devices_all(monkeypatch):
    # Before: with the default num_devices=1 each process trained alone on its own device into one run directory,
    # and the first checkpoint failed with orbax's traceback ("Cannot serialize host local jax.Array").
    monkeypatch.setattr(parallel.jax, "process_count", lambda: 2)
    monkeypatch.setattr(parallel.jax, "device_count", lambda: 4)  # 2 devices per process
    for setting in (1, 2):
        with pytest.raises(ValueError, match=rf"num_devices={setting} in a jax.distributed job of 2 processes, which "
                                             r"has 4 devices.*num_devices=all"):
            parallel.resolve_num_devices(setting)
    assert parallel.resolve_num_devices("all") == parallel.resolve_num_devices(4) == 4


@pytest.mark.slow
@pytest.mark.parametrize("killed", [1, 0], ids=["process 1", "process 0 (the coordinator)"])
def test_a_process_killed_mid_run_ends_the_other_with_exit_1_and_a_message_not_a_traceback(tmp_path, killed):
    # Before: the survivor printed the Gloo all-gather's ValueError with a traceback, waited out the heartbeat
    # timeout at jax.distributed's shutdown and aborted (exit 134, a C++ stack trace). Process 0 killed: JAX's
    # coordination client in process 1 aborted at once (exit 134, "Terminating process because the JAX distributed
    # service detected fatal errors") in 2 of 4 tries; the process watch (distributed.watch_the_other_processes) sees
    # the closed connection at the same moment and has been first in every try since (9 of 9), though nothing in
    # JAX guarantees it. A kill during a save: the test below.
    processes = _two_cli_processes(tmp_path, [["distribution.num_devices=all", "logging.run_name=killed",
                                               "ppo.num_cycles=100000", "checkpoint.every=100000",
                                               "checkpoint.best_metric=null"]] * 2)
    metrics = tmp_path / "killed" / "metrics.jsonl"
    deadline = time.monotonic() + 240
    while not (metrics.exists() and len(metrics.read_text().splitlines()) >= 2) and time.monotonic() < deadline:
        time.sleep(0.5)
    processes[killed].kill()
    survivor = processes[1 - killed]
    _, err = survivor.communicate(timeout=120)
    processes[killed].communicate()
    assert survivor.returncode == 1, err[-3000:]
    assert "Traceback" not in err and "Check failure" not in err, err[-6000:]
    assert "Another process of this jax.distributed job is gone" in err and "resume RUN_DIR --distributed" in err


@pytest.mark.parametrize(("message", "lost"), [
    ("INTERNAL: external/xla/xla/service/gpu/nccl_utils.cc:216: NCCL operation async_err failed: remote process exited "
     "or there was a network error", True),
    ("Gloo AllReduce failed: Connection closed by peer [127.0.0.1]:4242", True),
    ("INTERNAL: NCCL operation ncclCommInitRank(&comm, nranks, id, rank) failed: unhandled cuda error", False),
    ("RESOURCE_EXHAUSTED: Out of memory while trying to allocate 12.00GiB (NCCL buffers)", False),
])
def test_only_a_collective_that_lost_its_peer_is_reported_as_a_lost_process(monkeypatch, message, lost):
    """Any error mentioning NCCL was reported as "another process of this job is gone": a GPU's own failure (an
    unhandled cuda error at NCCL's set-up, memory) sent the user looking for a killed process."""
    monkeypatch.setattr(distributed.jax, "process_count", lambda: 2)
    cause = distributed.lost_process_cause(RuntimeError(message))
    assert (cause == message) if lost else cause is None


# Two processes of one job that join it and then wait (process 0 as at Orbax's checkpoint barriers, which wait on JAX's
# coordination service, not on a collective that would meet the closed connection) or end at once.
_JOIN_AND_WAIT = """
import sys, time
from angora_jax.experiment import distributed
distributed.initialize(sys.argv[1], 2, int(sys.argv[2]))
print("joined", flush=True)
time.sleep(float(sys.argv[3]))
"""


def _two_joined_processes(seconds: list[float]) -> list[subprocess.Popen]:
    address = _free_address()
    processes = [subprocess.Popen([sys.executable, "-c", _JOIN_AND_WAIT, address, str(index), str(seconds[index])],
                                  cwd=TESTS, env=os.environ | {"PYTHONPATH": str(TESTS.parent)},
                                  stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
                 for index in range(2)]
    for process in processes:
        assert process.stdout.readline() == "joined\n", process.communicate(timeout=60)[1][-3000:]
    return processes


@pytest.mark.slow
@pytest.mark.parametrize("killed", [1, 0], ids=["process 1", "process 0 (the coordinator)"])
def test_a_process_killed_while_the_other_waits_outside_a_collective_ends_it_at_once_with_exit_1_and_a_message(killed):
    # Before: process 1 killed during a checkpoint's save left process 0 waiting at Orbax's barrier until JAX's
    # heartbeat timeout (80-100 s), then JAX aborted it (exit 134, "Terminating process because the JAX distributed
    # service detected fatal errors" and a C++ stack trace): no collective met the closed connection first. Process 0
    # killed: JAX's coordination client aborted process 1 at once, the same way.
    processes = _two_joined_processes([120, 120])
    processes[killed].kill()
    survivor = processes[1 - killed]
    start = time.monotonic()
    _, err = survivor.communicate(timeout=60)
    processes[killed].communicate()
    assert survivor.returncode == 1 and time.monotonic() - start < 20, err[-3000:]
    assert "Check failure" not in err and "Traceback" not in err, err[-3000:]
    assert (f"Another process of this jax.distributed job is gone (process {killed}"
            f"{' (the coordinator)' * (killed == 0)} closed its connection to this one without ending normally)" in err
            and "resume RUN_DIR --distributed" in err)


@pytest.mark.slow
@pytest.mark.parametrize("seconds", [[2, 0], [0, 2]], ids=["process 1 first", "process 0 first"])
def test_a_process_that_ends_normally_before_the_other_is_not_taken_for_a_lost_one(seconds):
    # The watch's goodbye: one process ends, the other a little later, both normally.
    processes = _two_joined_processes(seconds)
    outputs = [process.communicate(timeout=120) for process in processes]
    assert [process.returncode for process in processes] == [0, 0], [err[-3000:] for _, err in outputs]
    assert not any("is gone" in err for _, err in outputs)


def test_the_process_watch_takes_only_the_jobs_own_connections_for_processes(monkeypatch):
    """Process 0's watch listens on a port of every interface: a port scanner or stray client that connected and
    closed was taken for a lost process and ended the run. Only a connection opening with the job's token (from the
    job's key-value store) is watched; a watched one that says goodbye is no loss either."""
    import threading

    lost = []
    monkeypatch.setattr(distributed, "lost_process_exit", lost.append)
    token = b"t" * distributed._TOKEN_BYTES
    server = socket.create_server(("127.0.0.1", 0))
    threading.Thread(target=distributed._watch, args=(server, {}, token), daemon=True).start()

    def connect(opening: bytes, goodbye: bool = False) -> None:
        with socket.create_connection(server.getsockname(), timeout=10) as client:
            client.sendall(opening)
            if goodbye:
                client.sendall(distributed._BYE)
            time.sleep(0.3)  # accepted and watched before it closes

    connect(b"GET / HTTP/1.0\r\n\r\n")
    connect(b"x" * distributed._TOKEN_BYTES + (1).to_bytes(4, "little"))
    connect(token + (2).to_bytes(4, "little"), goodbye=True)
    time.sleep(0.5)
    assert lost == []
    connect(token + (3).to_bytes(4, "little"))
    deadline = time.monotonic() + 10
    while not lost and time.monotonic() < deadline:
        time.sleep(0.05)
    assert lost == ["process 3 closed its connection to this one without ending normally"]
