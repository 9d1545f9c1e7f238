"""A run directory is never lost, overwritten or silently restarted: one writer per run, resume that refuses to start
over, checkpoints checked against their manifests, a full disk, and runs killed at random points and resumed."""

import errno
import json
import os
import random
import re
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import jax
import numpy as np
import orbax.checkpoint as ocp
import pytest
import xarray as xr
import yaml
from quick_compile import QUICK_SUBPROCESS
from tiny import TINY_PPO

import angora_jax as aj
from angora_jax.cli import main
from angora_jax.experiment import checkpoint as checkpoint_module
from angora_jax.experiment import read_metrics, resume, resume_plan, runner
from angora_jax.experiment.checkpoint import CheckpointError, Checkpoints, disk_needed
from angora_jax.experiment.config import CheckpointConfig
from angora_jax.experiment.doctor import Diagnosis
from angora_jax.experiment.manifest import MANIFEST_FILE
from angora_jax.experiment.monitor import set_aside_after, set_aside_message
from angora_jax.experiment.run_check import check_run
from angora_jax.experiment.run_dir import (
    CHECKPOINTS,
    CONFIG_FILE,
    EVALUATIONS,
    VIDEOS,
    DiskFullError,
    create_run_dir,
    write_run_config,
)
from angora_jax.experiment.run_lock import LOCK_FILE, RunLock, RunLockedError, _process_start, _process_state
from angora_jax.whole_files import written_whole

# A recurrent network, so that a resumed run must restore carries and environments mid-episode.
TINY = [*TINY_PPO, "ppo.network.name=gru", "ppo.network.width=8", "ppo.network.cell_size=8",
        "logging.progress=none", "logging.report=false", "checkpoint.every=2", "checkpoint.snapshot_every=3",
        "checkpoint.best_episodes=4"]
CYCLES = 6
# Wall-clock, memory and compilation-cache readings differ between any two runs; everything else must match exactly.
UNTIMED = {"seconds", "steps_per_second", "compile_seconds", "time", "memory/host_peak_bytes", "compile_cache_hits",
           "compile_cache_misses"}

# Every run here is a few tiny cycles (tests/quick_compile.py), the processes that are killed and resumed too: their
# records must match `whole`'s exactly, so they compile as it does.
pytestmark = pytest.mark.usefixtures("quick_file_compiles")


def settings(root: Path, name: str, cycles: int = CYCLES) -> list[str]:
    return [*TINY, f"ppo.num_cycles={cycles}", f"logging.run_root={root}", f"logging.run_name={name}"]


@pytest.fixture(scope="module")
def whole(tmp_path_factory):
    """An uninterrupted run; tests copy it to damage the copy."""
    return aj.train("cartpole", settings(tmp_path_factory.mktemp("whole"), "whole"))


def copy_of(run, tmp_path: Path, name: str = "copy") -> Path:
    target = tmp_path / name
    shutil.copytree(run.run_dir, target)
    return target


def exits_2(argv: list[str], capsys) -> str:
    """Run the command; assert exit code 2 and no traceback; return what it printed on stderr."""
    code = main(argv)
    err = capsys.readouterr().err
    assert code == 2 and "Traceback" not in err, err
    return err


def untimed(records):
    return [{k: v for k, v in r.items() if k not in UNTIMED} for r in records]


def test_every_checkpoint_has_a_manifest_and_check_reports_a_sound_run(whole, capsys):
    for kind, cycles in {"latest": [6], "best": None, "snapshots": [3, 6]}.items():
        saved = sorted(int(p.name) for p in (whole.run_dir / CHECKPOINTS / kind).iterdir())
        assert saved and (cycles is None or saved == cycles)
        for cycle in saved:
            listed = json.loads((whole.run_dir / CHECKPOINTS / kind / str(cycle) / MANIFEST_FILE).read_text())
            assert any(name.startswith("state/") for name in listed["files"]), listed
    assert main(["check", str(whole.run_dir)]) == 0
    out = capsys.readouterr().out
    assert "continue from the latest checkpoint, cycle 6" in out and "OK: nothing is damaged" in out
    assert "checkpoints/snapshots: intact: cycle 3, 6" in out


@pytest.mark.parametrize("damage", ["truncate", "flip", "delete", "meta", "checkpoint_metadata"])
def test_a_damaged_checkpoint_is_named_with_the_newest_intact_one_by_every_verb(damage, whole, tmp_path, capsys,
                                                                                 caplog):
    run = copy_of(whole, tmp_path)
    folder = run / CHECKPOINTS / "latest" / "6"
    victim = max((p for p in (folder / "state").rglob("*") if p.is_file()), key=lambda p: p.stat().st_size)
    if damage == "truncate":
        victim.write_bytes(victim.read_bytes()[:10])
    elif damage == "flip":
        data = bytearray(victim.read_bytes())
        data[len(data) // 2] ^= 0xFF
        victim.write_bytes(bytes(data))
    elif damage == "delete":
        victim.unlink()
    elif damage == "meta":
        victim = folder / "meta" / "metadata"
        victim.write_text(victim.read_text()[:7])
    else:  # Orbax's own record of the checkpoint, which it reads (and logged the content of) before ours is checked
        victim = folder / "_CHECKPOINT_METADATA"
        victim.write_text("garbage{")
    before = sorted(p.relative_to(run) for p in run.rglob("*"))
    for argv in (["resume", str(run)], ["evaluate", str(run), "--checkpoint", "latest", "--episodes", "1"],
                 ["export", str(run), "--checkpoint", "latest", "--out", str(tmp_path / "p.msgpack")],
                 ["record", str(run), "--checkpoint", "latest", "--episodes", "1", "--out", str(tmp_path / "a.nc")]):
        err = exits_2(argv, capsys)
        assert f"Checkpoint {folder} is damaged: {victim}" in err, err
        # Of cycle 6's intact checkpoints, best before snapshots (the order of latest, best, snapshots).
        assert "The newest intact checkpoint is best of cycle 6: read it with --checkpoint best (resume: --from " \
               "best)" in err, err
        assert "Failed to json parse" not in caplog.text, "one message, without Orbax's log of the file's content"
    assert sorted(p.relative_to(run) for p in run.rglob("*")) == before, "a refused command changed the run"
    assert main(["check", str(run)]) == 2
    out = capsys.readouterr().out
    assert f"PROBLEM: checkpoint latest/6 is damaged: {victim}" in out and "checkpoints/latest: damaged: cycle 6" in out
    # Told to, resume falls back to the intact checkpoint and keeps the damaged one aside.
    assert main(["resume", str(run), "--from", "6"]) == 0
    assert (run / "set-aside" / "resumed-from-cycle-6" / CHECKPOINTS / "latest" / "6").is_dir()
    assert main(["export", str(run), "--checkpoint", "6", "--out", str(tmp_path / "p.msgpack")]) == 0


def test_the_newest_intact_checkpoint_is_found_without_verifying_the_older_ones(whole, tmp_path, monkeypatch):
    """Naming the newest intact checkpoint (`check --restore-config`, a damaged latest's message) hashes checkpoints
    newest first and stops at the first intact one: a cube run's older checkpoints are 301 MB each."""
    run = copy_of(whole, tmp_path)
    verified, verify = [], checkpoint_module.verify
    monkeypatch.setattr(checkpoint_module, "verify",
                        lambda path: verified.append(path.relative_to(run)) or verify(path))
    kept = Checkpoints(run / CHECKPOINTS, aj.load_config("cartpole").checkpoint, create=False)
    assert verified == [], "a reader does not read the best one's value (a writer's business)"
    try:  # of one cycle's checkpoints latest first, then best and snapshots
        assert kept.newest_intact() == ("latest", 6) and len(verified) == 1, verified
        assert kept.newest_intact(skip=("latest", 6)) == ("best", 6) and len(verified) == 2, verified
    finally:
        kept.close()


def test_resume_never_starts_over_by_itself(whole, tmp_path, capsys):
    run = copy_of(whole, tmp_path)
    shutil.rmtree(run / CHECKPOINTS / "latest")
    metrics = (run / "metrics.jsonl").read_text()
    err = exits_2(["resume", str(run)], capsys)
    assert "has no latest checkpoint to resume from" in err and f"logged {CYCLES} cycles" in err
    assert f"and keeps checkpoints (best of cycle {CYCLES}; snapshots of cycles 3, 6). Resuming now" in err, err
    assert "`--from 6` continues from the newest intact checkpoint" in err and "`--from-scratch`" in err
    assert (run / "metrics.jsonl").read_text() == metrics
    shutil.rmtree(run / CHECKPOINTS)  # no checkpoint at all: the same
    assert "has no latest checkpoint" in exits_2(["resume", str(run)], capsys)
    assert check_run(run).resume.startswith("refuses: ")
    # Asked to, it trains again from cycle 0 and keeps the earlier files aside, with what was made from its checkpoints.
    (run / EVALUATIONS).mkdir()
    made = [run / EVALUATIONS / "best-cycle6-mode-seed0.json", run / "ablation.png", run / "ablation-2.nc"]
    for path in made:
        path.write_text("made from the earlier training's checkpoints")
    fresh = resume(run, from_scratch=True)
    assert (run / "previous-1" / "metrics.jsonl").read_text() == metrics
    assert not any(path.exists() for path in made)
    assert all((run / "previous-1" / path.relative_to(run)).exists() for path in made)
    assert (run / "previous-1" / "config.yaml").read_text() == (run / "config.yaml").read_text(), "a run of its own"
    assert untimed(read_metrics(run)) == untimed(whole.history) and fresh.finished


def test_ctrl_c_while_a_fresh_start_compiles_says_the_run_starts_over_and_where_the_earlier_training_is(
        whole, tmp_path, monkeypatch, capsys):
    """Interrupted before its first cycle, a `--from-scratch` start holds no checkpoint (the earlier ones moved to
    previous-N): the message says where they are and that resume starts from cycle 0, not that it continues."""
    run = copy_of(whole, tmp_path)
    resume_plan.set_aside_outputs(run)
    monkeypatch.setattr(runner.os, "_exit", lambda code: (_ for _ in ()).throw(SystemExit(code)))
    with pytest.raises(SystemExit) as ended:
        runner._exit_while_preparing(signal.SIGINT, run, new=False)
    err = capsys.readouterr().err
    assert ended.value.code == 130 and f"the earlier training is kept in {run / 'previous-1'}" in err, err
    assert "starts it from cycle 0 again" in err and "keeps its checkpoints" not in err


def test_a_start_over_killed_after_it_moved_the_earlier_outputs_aside_resumes_from_cycle_0(whole, tmp_path):
    """SIGKILL between `--from-scratch` moving the outputs to previous-1 and its first record: nothing of the new
    training exists, so a plain resume trains from cycle 0 to the uninterrupted result, the earlier training kept."""
    run = copy_of(whole, tmp_path)
    resume_plan.set_aside_outputs(run)
    argv, fresh = continuing(run)
    assert argv == ["resume", str(run)] and not fresh
    assert resume(run).finished and untimed(read_metrics(run)) == untimed(whole.history)
    assert untimed(read_metrics(run / "previous-1")) == untimed(whole.history)
    assert check_run(run).problems == []


def test_records_after_the_checkpoint_continued_from_move_to_a_side_file_with_damaged_lines(whole, tmp_path, capsys):
    """`--from 3` sets aside the later records and checkpoints, and the evaluations and training videos of the later
    cycles: the cycles trained again are other policies under the same numbers."""
    run = copy_of(whole, tmp_path)
    with (run / "metrics.jsonl").open("a") as log:
        log.write('{"cycle": 7, "episode_ret')  # a record cut short by a crash, then another process's line
        log.write("\n" + json.dumps({"cycle": 8}) + "\n")
    assert "metrics.jsonl line 7 holds no cycle's record" in check_run(run).format()
    for checkpoint in ("3", "latest"):
        assert main(["evaluate", str(run), "--checkpoint", checkpoint, "--episodes", "1"]) == 0
    (run / VIDEOS).mkdir()
    for cycle in (3, 6):
        (run / VIDEOS / f"cycle_{cycle:06d}.gif").write_bytes(b"GIF89a")
    capsys.readouterr()
    resume(run, start_from=3)
    aside = run / "set-aside" / "resumed-from-cycle-3"
    err = capsys.readouterr().err
    assert f"Checkpoints, evaluations and videos after cycle 3 are kept in {aside}." in err
    side_file = run / "metrics.after-cycle-3.jsonl"
    assert f"Records after cycle 3 and 1 damaged line of metrics.jsonl are kept in {side_file}." in err, err
    assert sorted(p.name for p in (aside / EVALUATIONS).iterdir()) == ["latest-cycle6-mode-seed0.json",
                                                                       "latest-cycle6-mode-seed0.png"]
    assert sorted(p.name for p in (run / EVALUATIONS).iterdir()) == ["cycle3-mode-seed0.json",
                                                                     "cycle3-mode-seed0.png"]
    assert [p.name for p in (aside / VIDEOS).iterdir()] == ["cycle_000006.gif"]
    assert [p.name for p in (run / VIDEOS).iterdir()] == ["cycle_000003.gif"]
    assert [r["cycle"] for r in read_metrics(run)] == list(range(1, CYCLES + 1))
    side = (run / "metrics.after-cycle-3.jsonl").read_text().splitlines()
    assert [json.loads(line)["cycle"] for line in side[:3]] == [4, 5, 6] and side[3].startswith('{"cycle": 7, "ep')
    assert sorted(p.name for p in (run / "set-aside" / "resumed-from-cycle-3" / CHECKPOINTS / "latest").iterdir()) \
        == ["6"]


def test_the_set_aside_message_names_later_records_and_damaged_lines_apart(tmp_path):
    """A resume past a last line cut mid-write moves only that line: the message named it "Records after cycle 3"."""
    for lines, said in ((['{"cycle": 4}'], "Records after cycle 3 are"), (['{"cycle": 4, "ep'], "1 damaged line of "
                        "metrics.jsonl is"), (['{"cycle": 4, "ep', "x"], "2 damaged lines of metrics.jsonl are")):
        (tmp_path / "metrics.jsonl").write_text('{"cycle": 3}\n' + "\n".join(lines) + "\n")
        side = set_aside_after(tmp_path, 3)
        assert set_aside_message(side, 3) == f"{said} kept in {side}."


def test_a_second_writer_is_refused_and_a_dead_holder_is_taken_over(whole, tmp_path, capsys):
    run = copy_of(whole, tmp_path)
    alive = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        lock = {"host": socket.gethostname(), "pid": alive.pid, "process_start": None, "since": time.time()}
        (run / LOCK_FILE).write_text(json.dumps(lock))
        # --force too: it took over a live trainer's lock on this host, wrote beside it and released its lock.
        for argv in (["resume", str(run)], ["resume", str(run), "--from-scratch"], ["resume", str(run), "--force"]):
            err = exits_2(argv, capsys)
            assert f"is being trained by process {alive.pid} on host {socket.gethostname()}" in err
            assert f"kill {alive.pid}" in err and "--force takes over only a lock this host cannot check" in err
        err = exits_2(["train", "cartpole", f"logging.run_root={run.parent}", f"logging.run_name={run.name}"], capsys)
        assert "a process holds its writer lock (training it now, unless it ended without releasing it" in err, err
        assert main(["evaluate", str(run), "--episodes", "1"]) == 0, "readers take no lock"
        capsys.readouterr()
        assert main(["check", str(run)]) == 0
        assert f"writer: process {alive.pid} on host {socket.gethostname()}, since " in (out := capsys.readouterr().out)
        assert "(running on this host: resume is refused until it stops)" in out, out
        assert json.loads((run / LOCK_FILE).read_text())["pid"] == alive.pid
    finally:
        alive.kill()
        alive.wait()
    capsys.readouterr()
    assert main(["resume", str(run)]) == 0
    assert f"lock of {run} from process {alive.pid} on host {socket.gethostname()}" in capsys.readouterr().err
    assert not (run / LOCK_FILE).exists(), "released at the end"
    # Held on another host: never broken without --force.
    (run / LOCK_FILE).write_text(json.dumps({**lock, "host": "elsewhere"}))
    assert "resume with --force" in exits_2(["resume", str(run)], capsys)
    assert main(["check", str(run)]) == 0
    assert "(on another host, so this one cannot tell whether it runs: resume is refused, --force takes the lock " \
           "over once that process is certainly gone)" in capsys.readouterr().out
    assert main(["resume", str(run), "--force"]) == 0
    assert "forced (--force)" in capsys.readouterr().err


def test_a_run_trained_on_more_devices_than_this_machine_has_is_told_where_its_device_count_lives(
        whole, tmp_path, capsys):
    """resume takes no KEY=VALUE, so 'use num_devices<=1' alone left a run trained on 2 forced CPU devices (or 4
    GPUs) with no way on here."""
    run = copy_of(whole, tmp_path)
    config = (run / CONFIG_FILE).read_text()
    assert "  num_devices: 1\n" in config
    (run / CONFIG_FILE).write_text(config.replace("  num_devices: 1\n", "  num_devices: 64\n"))
    err = exits_2(["resume", str(run)], capsys)
    assert "distribution.num_devices=64 but JAX sees only" in err
    assert "A run's device count is distribution.num_devices in its config.yaml: edit it there (resume lays the run " \
           "out again on the devices it gets" in err, err


def test_resume_verifies_the_checkpoint_it_continues_from_once(whole, tmp_path, monkeypatch):
    """Verifying hashes every file of a checkpoint (the cube's latest: 301 MB); resume verified the latest three times
    (planning, comparing the saved config, taking up the best metric's pool: each with a reader of its own), and a
    snapshot of the same cycle, which it never reads. The best (lean by default: parameters only) the writer reads."""
    run = copy_of(whole, tmp_path)
    verified = []
    real = checkpoint_module.verify
    monkeypatch.setattr(checkpoint_module, "verify",
                        lambda path: verified.append(f"{Path(path).parent.name}/{Path(path).name}") or real(path))
    aj.resume(run, num_cycles=CYCLES + 1)
    assert verified.count(f"latest/{CYCLES}") == 1, verified
    assert verified == [f"latest/{CYCLES}", f"best/{CYCLES}"], "the best's value, read by the writer; no snapshot"


def test_the_lock_is_taken_by_one_of_two_processes_at_once(tmp_path):
    first, second = RunLock(tmp_path), RunLock(tmp_path)
    first.acquire()
    with pytest.raises(RunLockedError, match="already being written by this process"):
        second.acquire()
    first.release()
    second.acquire()
    assert RunLock(tmp_path).holder().pid == os.getpid()
    second.release()
    assert RunLock(tmp_path).holder() is None


@pytest.mark.parametrize("damage", [{"pid": 10 ** 20}, {"pid": -5}, {"pid": 0}, {"pid": 1.5}, {"since": 1e300},
                                    {"since": "nan"}, {"process_start": "0"}])
def test_a_lock_file_with_a_value_no_writer_writes_reads_as_unreadable_not_a_traceback(damage, tmp_path):
    """A lock file edited or damaged into a process id out of range (10**20), a time no clock shows (1e300, NaN) or
    a start that is no number ended `check` and `resume` in OverflowError or ValueError tracebacks (os.kill,
    time.localtime); a negative id, or a start no process has, was taken for a holder that ended, and the lock of a
    process alive on this host (pid 1) taken over without --force. Each reads as unreadable now: a holder unknown,
    refused without --force, described without a traceback."""
    lock = {"host": socket.gethostname(), "pid": 1, "process_start": None, "since": time.time(), **damage}
    (tmp_path / LOCK_FILE).write_text(json.dumps(lock))
    holder = RunLock(tmp_path).holder()
    assert holder.pid == -1 and not holder.is_gone() and not holder.runs_here()
    assert "the lock file is unreadable: edited or damaged" in holder.describe()
    with pytest.raises(RunLockedError, match="if no process trains it now, resume with --force to take the lock over"):
        RunLock(tmp_path).acquire()
    taker = RunLock(tmp_path)
    taker.acquire(force=True)
    assert RunLock(tmp_path).holder().pid == os.getpid()
    taker.release()


def takes_over(run: Path, lock: dict) -> None:
    """With LOCK written as the run's lock, this process acquires it (the holder is taken for gone) and releases it."""
    (run / LOCK_FILE).write_text(json.dumps(lock))
    taker = RunLock(run)
    taker.acquire()
    assert RunLock(run).holder().pid == os.getpid()
    taker.release()


@pytest.mark.skipif(not Path("/proc/self/stat").is_file(), reason="process starts are read from Linux's /proc")
def test_a_live_holder_is_told_from_a_later_process_with_its_id_by_its_start(tmp_path):
    """The lock records its holder's start (field 22 of /proc/<pid>/stat, clock ticks since boot), so that a process
    given the same id later is not taken for the holder. The start read is the process's own: a child started just
    now started within a minute of the machine's uptime (a neighbouring field, such as the memory it uses, is not);
    a live holder with that start is refused, and a lock whose recorded start differs (the id was reused) is taken
    over."""
    alive = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        start = _process_start(alive.pid)
        uptime = float(Path("/proc/uptime").read_text().split()[0])
        assert 0 <= uptime - start / os.sysconf("SC_CLK_TCK") < 60, (start, uptime)
        lock = {"host": socket.gethostname(), "pid": alive.pid, "process_start": start, "since": time.time()}
        (tmp_path / LOCK_FILE).write_text(json.dumps(lock))
        with pytest.raises(RunLockedError, match=f"is being trained by process {alive.pid} on host"):
            RunLock(tmp_path).acquire()
        takes_over(tmp_path, {**lock, "process_start": start - 1})
    finally:
        alive.kill()
        alive.wait()


@pytest.mark.skipif(not Path("/proc/self/stat").is_file(), reason="process states are read from Linux's /proc")
def test_a_holder_killed_but_never_reaped_is_taken_over(tmp_path):
    """A trainer killed with SIGKILL whose parent does not reap it (a container without an init, a launcher that
    died first) stays a zombie: its id still answers `kill 0`, but it writes nothing more, so its lock is taken
    over, and the lock's start matches (it is the same process)."""
    dead = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        start = _process_start(dead.pid)
        dead.kill()
        deadline = time.monotonic() + 30
        while _process_state(dead.pid) != "Z":  # not reaped: no wait() yet
            assert time.monotonic() < deadline, _process_state(dead.pid)
            time.sleep(0.05)
        os.kill(dead.pid, 0)  # the id still answers
        takes_over(tmp_path, {"host": socket.gethostname(), "pid": dead.pid, "process_start": start,
                              "since": time.time()})
    finally:
        dead.wait()


def test_a_run_copied_while_it_trains_is_resumed_and_the_original_keeps_its_writer(whole, tmp_path, capsys):
    """`cp -r` of a run while it trained copied its writer.lock: `resume` of the copy said the copy "is being trained
    by process N" and told to kill it (the original's trainer), `--force` was refused, and `check` called that
    process the copy's writer. The lock records the run directory it was taken for, so the copy's is taken over; the
    original's is not."""
    original = copy_of(whole, tmp_path, "original")
    holder = subprocess.Popen(
        [sys.executable, "-c", "import sys, time; from angora_jax.experiment.run_lock import RunLock; "
                               "RunLock(sys.argv[1]).acquire(); print('held', flush=True); time.sleep(120)",
         str(original)], stdout=subprocess.PIPE, text=True, cwd=Path(__file__).parent.parent)
    try:
        assert holder.stdout.readline() == "held\n"
        copy = tmp_path / "copy"
        shutil.copytree(original, copy)
        assert (copy / LOCK_FILE).is_file()
        assert f"the lock was copied with the run from {original.resolve()}" in check_run(copy).format()
        capsys.readouterr()
        assert main(["resume", str(copy), "--num-cycles", str(CYCLES + 1)]) == 0
        err = capsys.readouterr().err
        assert f"it was copied with the run from {original.resolve()}, which process {holder.pid}" in err, err
        assert [r["cycle"] for r in read_metrics(copy)][-1] == CYCLES + 1 and not (copy / LOCK_FILE).exists()
        assert f"is being trained by process {holder.pid}" in exits_2(["resume", str(original)], capsys)
        assert RunLock(original).holder().pid == holder.pid
    finally:
        holder.kill()
        holder.wait()


def test_a_save_cut_short_by_a_killed_writer_is_named_by_check_and_removed_by_resume(whole, tmp_path, capsys):
    """A writer killed while Orbax wrote a checkpoint in the background leaves its temporary folder (renamed to the
    cycle only once whole): `check` names it as unfinished, not as damage, and the next writer removes it before it
    saves anything, without Orbax's warning about a folder that already exists, and says what it removed."""
    run = copy_of(whole, tmp_path)
    for kind, cycle in (("latest", CYCLES + 1), ("snapshots", CYCLES + 3)):
        unfinished = run / CHECKPOINTS / kind / f"{cycle}.orbax-checkpoint-tmp-1234"
        unfinished.mkdir()
        (unfinished / "_CHECKPOINT_METADATA").write_text("{")
    report = check_run(run)
    assert report.problems == [] and "unfinished (its writer stopped mid-save" in report.format()
    assert f"checkpoints/latest: intact: cycle {CYCLES}; unfinished" in report.format()
    with RunLock(run):  # while a writer holds the run, its newest save is being written, not cut short
        assert f"unfinished (being written now): cycle {CYCLES + 1}" in check_run(run).format()
    assert main(["resume", str(run)]) == 0
    err = capsys.readouterr().err
    assert "orbax-checkpoint-tmp" not in err
    assert f"stopped mid-save left in {run / CHECKPOINTS} (latest of cycle {CYCLES + 1}; snapshots of cycle " \
           f"{CYCLES + 3}): unfinished" in err
    assert not list((run / CHECKPOINTS).glob("*/*.orbax-*")), "removed by the writer"
    assert "unfinished" not in check_run(run).format()


def test_a_full_disk_keeps_the_previous_checkpoint_and_says_so(whole, tmp_path, monkeypatch):
    """A save that fails for want of space (injected from the fourth save on: Orbax's temporary folder written in part,
    then TensorStore's error) leaves the checkpoints saved before; with space 'freed', the run resumes and ends as
    the uninterrupted run. The real thing is below, on a small tmpfs."""
    real_save = ocp.CheckpointManager.save
    saves = []

    def save_until_full(self, step, *args, **kwargs):
        saves.append(step)
        if len(saves) <= 3:
            return real_save(self, step, *args, **kwargs)
        partial = Path(self.directory) / f"{step}.orbax-checkpoint-tmp-1" / "state"
        partial.mkdir(parents=True)
        (partial / "d").write_bytes(b"written in part")
        raise ValueError("RESOURCE_EXHAUSTED: Error writing ...: Failed to write 1016 bytes to file 17: No space "
                         "left on device [os_error_code='28']")

    real_close = ocp.CheckpointManager.close

    def close_raising_the_failure_again(self):
        real_close(self)
        if saves[3:]:  # as Orbax's background writer can: the failed save's bare OSError, once more, on close
            raise OSError(errno.ENOSPC, "No space left on device")

    root = tmp_path / "runs"
    monkeypatch.setattr(ocp.CheckpointManager, "save", save_until_full)
    monkeypatch.setattr(ocp.CheckpointManager, "close", close_raising_the_failure_again)
    with pytest.raises(DiskFullError) as full:
        aj.train("cartpole", settings(root, "full"))
    monkeypatch.undo()
    message = str(full.value)
    # The checkpoints kept, in words ("latest of cycle 2; ..."), not as a Python dict.
    assert "The disk is full:" in message and "The checkpoints saved before are intact (latest of cycle 2; best of " \
        "cycle" in message, message
    assert f"continue with `angora-jax resume {root / 'full'}`" in message
    assert not list((root / "full" / CHECKPOINTS).rglob("*orbax-checkpoint-tmp*")), "the failed save left its folder"
    assert check_run(root / "full").problems == []
    resumed = resume(root / "full")
    assert untimed(read_metrics(root / "full")) == untimed(whole.history) and resumed.finished


def test_a_record_cut_short_by_a_full_disk_is_removed(whole, tmp_path):
    from angora_jax.experiment import monitor

    run = copy_of(whole, tmp_path)
    before = (run / "metrics.jsonl").read_bytes()
    log = monitor.Monitor(run)
    real_write = log._file.write
    log._file.write = lambda data: real_write(data[:20])  # the disk filled after 20 bytes
    with pytest.raises(DiskFullError, match="Cannot write the record of cycle 7 .* records and checkpoints written"):
        log.record({"cycle": 7, "env_steps": 1.0}, whole.state)

    def too_large(data):
        raise OSError(errno.EFBIG, os.strerror(errno.EFBIG))

    log._file.write = too_large
    with pytest.raises(DiskFullError, match=r"size this process may write .*raise the limit \(`ulimit -f unlimited`"):
        log.record({"cycle": 7, "env_steps": 1.0}, whole.state)
    log.close()
    assert (run / "metrics.jsonl").read_bytes() == before


@pytest.mark.slow
def test_a_checkpoint_past_the_file_size_limit_ends_in_one_message_naming_the_limit(tmp_path):
    """`ulimit -f` (a job's file-size limit): Orbax's save failed with EFBIG inside an OUT_OF_RANGE ValueError, and the
    command ended in 836 lines of tracebacks with exit 1, the code of a diverged run."""
    import resource

    limit = lambda: resource.setrlimit(resource.RLIMIT_FSIZE, (20 * 1024, 20 * 1024))  # noqa: E731
    argv = ["train", "cartpole", *settings(tmp_path, "limited")]
    # The compilation cache off (the suite's, shared through JAX_COMPILATION_CACHE_DIR, and ours): under the limit
    # its entries would be written cut short, for later tests to read.
    environment = {key: value for key, value in os.environ.items() if key != "JAX_COMPILATION_CACHE_DIR"}
    environment["ANGORA_JAX_CACHE"] = "off"
    done = subprocess.run([sys.executable, "-m", "angora_jax.cli", *argv], capture_output=True, text=True,
                          timeout=300, preexec_fn=limit, env=environment)
    assert done.returncode == 2 and done.stderr.count("\n") == 1, done.stderr[-3000:]
    assert done.stderr.startswith("angora-jax train: A file grew past the size this process may write") and \
        "`ulimit -f unlimited`" in done.stderr, done.stderr


def mounted_tmpfs(path: Path, size: str) -> bool:
    path.mkdir()
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(path)], capture_output=True)
    return done.returncode == 0


@pytest.mark.slow
@pytest.mark.parametrize("size", ["16k", "2500k"])
def test_a_real_full_disk_ends_in_one_message_and_leaves_no_half_made_run(size, tmp_path):
    """On a small tmpfs (where this machine lets the test mount one; the injected test above runs everywhere)."""
    disk = tmp_path / "disk"
    if not mounted_tmpfs(disk, size):
        pytest.skip("cannot mount a tmpfs here (not root, or no mount namespace)")
    try:
        # TINY's snapshot_every left out rather than overridden: stderr is read line by line, and a key given twice
        # is named there.
        every = [s for s in settings(disk, "full", 100_000) if not s.startswith("checkpoint.snapshot_every=")]
        argv = ["train", "cartpole", *every, "checkpoint.snapshot_every=1"]
        done = subprocess.run([sys.executable, "-m", "angora_jax.cli", *argv], capture_output=True, text=True,
                              timeout=300)
        assert done.returncode == 2 and "Traceback" not in done.stderr, done.stderr[-3000:]
        said = ("Warning: the checkpoints of this run need", "The new run directory", "angora-jax train: ")
        assert all(line.startswith(said) for line in done.stderr.strip().splitlines()), done.stderr[-3000:]
        if size == "16k":  # full before the first record: at the config, or at the first cycle's record
            assert "No space left on device" in done.stderr and not (disk / "full").exists(), done.stderr
        else:
            assert "The disk is full:" in done.stderr and "are intact" in done.stderr, done.stderr
            assert "OK: nothing is damaged" in check_run(disk / "full").format()
    finally:
        subprocess.run(["umount", str(disk)], check=False)


def continuing(run: Path) -> tuple[list[str], bool]:
    """How a user continues a stopped run, by what `check` says resume would do: the resume arguments, and whether
    it starts over (a run killed before its first latest checkpoint is refused until told --from-scratch; a start
    over killed after it moved the earlier outputs to previous-N, before its first record, trains from cycle 0)."""
    plan = check_run(run).resume
    assert plan.startswith(("continue from the latest checkpoint", "train from cycle 0: nothing was logged")) or \
        "has no latest checkpoint" in plan, plan
    fresh = plan.startswith("refuses")
    return ["resume", str(run), *["--from-scratch"] * fresh], fresh


def kill_at_random(root: Path, name: str, rng: random.Random) -> None:
    """Train NAME (or continue it) in a process of its own and SIGKILL it at a random point: after a random number of
    logged cycles and a random fraction of a cycle more (while it trains, saves, or writes its records)."""
    run, logged, fresh = root / name, 0, False
    if run.exists():
        argv, fresh = continuing(run)
        logged = 0 if fresh else len(read_metrics(run))
    else:
        argv = ["train", "cartpole", *settings(root, name)]
    earlier = len(list(run.glob("previous-*")))
    process = subprocess.Popen([sys.executable, "-m", "angora_jax.cli", *argv], stdout=subprocess.DEVNULL,
                               stderr=subprocess.PIPE, text=True, env=os.environ | QUICK_SUBPROCESS)
    target = rng.randint(logged + 1, CYCLES - 1)
    deadline = time.monotonic() + 120
    logged_now = lambda: len(read_metrics(run)) if run.exists() else 0  # noqa: E731  (the process makes the run)
    while logged_now() < target or (fresh and len(list(run.glob("previous-*"))) == earlier):
        assert process.poll() is None and time.monotonic() < deadline, process.communicate()
        time.sleep(0.01)
    time.sleep(rng.uniform(0.0, 0.2))
    process.send_signal(signal.SIGKILL)
    process.wait()


@pytest.mark.slow
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_run_killed_at_random_points_resumes_to_the_uninterrupted_result(seed, whole, tmp_path):
    rng = random.Random(seed)
    kill_at_random(tmp_path, "killed", rng)
    if rng.random() < 0.5 and len(read_metrics(tmp_path / "killed")) < CYCLES - 2:
        kill_at_random(tmp_path, "killed", rng)  # the resumed process killed too
    _, fresh = continuing(tmp_path / "killed")
    resumed = resume(tmp_path / "killed", from_scratch=fresh)
    assert resumed.finished
    assert untimed(read_metrics(tmp_path / "killed")) == untimed(whole.history)
    for a, b in zip(jax.tree.leaves(whole.state.params), jax.tree.leaves(resumed.state.params), strict=True):
        np.testing.assert_array_equal(a, b)
    assert check_run(tmp_path / "killed").problems == []


def test_a_run_made_under_older_name_rules_is_still_read_and_resumed(whole, tmp_path, capsys):
    """New runs get portable names; a run directory made before that rule keeps working."""
    run = copy_of(whole, tmp_path, "my old run")
    config = run / "config.yaml"
    config.write_text(config.read_text().replace("run_name: whole", "run_name: my old run"))
    assert main(["check", str(run)]) == 0, capsys.readouterr()
    assert main(["resume", str(run)]) == 0 and main(["evaluate", str(run), "--episodes", "1"]) == 0


def test_a_damaged_or_lost_config_is_written_again_from_the_checkpoints_copy(whole, tmp_path, capsys):
    """A config.yaml damaged (a half-saved edit) or deleted stops every verb with the way back; `check
    --restore-config` writes the config saved with the newest checkpoint, keeps the damaged file, and the run resumes
    and evaluates again. A config that loads is left alone."""
    run = copy_of(whole, tmp_path)
    config = run / "config.yaml"
    original = config.read_text()
    config.write_text(original[: len(original) // 2] + "\n  [")
    for verb in (["resume"], ["evaluate", "--episodes", "1"]):
        err = exits_2([*verb, str(run)], capsys)
        assert f"config.yaml is damaged: `angora-jax check {run} --restore-config` writes it again" in err
    assert main(["check", str(run), "--restore-config"]) == 0
    out = capsys.readouterr().out
    assert f"Restored {config} from the config saved with the latest checkpoint of cycle {CYCLES}" in out
    assert aj.load_config(config) == aj.load_config(yaml.safe_load(original))
    assert (run / "config.yaml.damaged").read_text().endswith("\n  [")
    assert main(["resume", str(run)]) == 0 and main(["evaluate", str(run), "--episodes", "1"]) == 0
    assert main(["check", str(run), "--restore-config"]) == 0
    assert "loads and holds the settings the run was trained with; nothing was restored" in capsys.readouterr().out
    config.unlink()
    assert f"has checkpoints but no config.yaml: `angora-jax check {run} --restore-config`" in exits_2(
        ["resume", str(run)], capsys)
    assert main(["check", str(run), "--restore-config"]) == 0 and config.is_file()
    assert not (run / "config.yaml-2.damaged").exists(), "nothing to keep: there was no file"


def test_an_edited_config_is_refused_by_resume_found_by_check_and_put_back(whole, tmp_path, capsys):
    """A config.yaml whose task or learning settings were edited after training (it still loads) would make one run's
    records of two: resume refuses it, naming each change and both ways on, before anything changes; check reports it;
    `check --restore-config` puts those settings back, keeps the edited file and the settings a run may change between
    sessions, and the run resumes. What resume itself records (--num-cycles) is no edit."""
    run = copy_of(whole, tmp_path)
    config = run / "config.yaml"
    original = aj.load_config(config)
    edited = config.read_text().replace("learning_rate: 0.001", "learning_rate: 0.0001")
    edited = edited.replace("num_envs: 4", "num_envs: 2").replace("every: 2", "every: 3")
    assert edited.count("0.0001") == 1 and "num_envs: 2" in edited and "every: 3" in edited
    config.write_text(edited)
    before = {path: path.stat().st_mtime_ns for path in run.rglob("*") if path.is_file()}
    err = exits_2(["resume", str(run), "--num-cycles", str(CYCLES + 2)], capsys)
    assert f"{config} was edited after the latest checkpoint of cycle {CYCLES} was saved" in err
    assert "ppo.learning_rate: 0.001 -> 0.0001" in err and "ppo.num_envs: 4 -> 2" in err
    assert "checkpoint.every" not in err, "checkpoints may be kept otherwise from one session to the next"
    assert f"angora-jax check {run} --restore-config" in err and f"ppo.init_from={run}:latest" in err
    assert {path: path.stat().st_mtime_ns for path in run.rglob("*") if path.is_file()} == before
    assert main(["check", str(run)]) == 2 and "resume refuses" in capsys.readouterr().out
    assert main(["check", str(run), "--restore-config"]) == 0
    assert "the edited file is kept as" in capsys.readouterr().out
    assert (run / "config.yaml.edited").read_text() == edited
    restored = aj.load_config(config)
    assert restored.ppo == original.ppo and restored.env == original.env
    assert restored.checkpoint.every == 3, "settings a run may change between sessions stay as edited"
    assert main(["resume", str(run), "--num-cycles", str(CYCLES + 1)]) == 0
    capsys.readouterr()
    assert main(["check", str(run)]) == 0, "the length that resume recorded is no edit"


def test_an_emptied_checkpoint_folder_is_damage_that_check_lists_and_resume_from_gets_past(whole, tmp_path, capsys):
    """An empty `latest/N` (no manifest, no meta) passed as an unverifiable old checkpoint, then reading its saved
    config failed: `check` printed one line and listed nothing, and every resume, `--from` included, was refused."""
    run = copy_of(whole, tmp_path)
    latest = run / CHECKPOINTS / "latest" / str(CYCLES)
    shutil.rmtree(latest)
    latest.mkdir()
    assert main(["check", str(run)]) == 2
    out = capsys.readouterr().out
    assert f"PROBLEM: checkpoint latest/{CYCLES} is damaged: {latest / 'meta'} is missing or empty" in out, out
    assert f"checkpoints/best: intact: cycle {CYCLES}" in out and "checkpoints/snapshots: intact: cycle 3, 6" in out
    err = exits_2(["resume", str(run)], capsys)
    assert f"latest/{CYCLES} is damaged" in err and "(resume: --from best)" in err, err
    assert main(["resume", str(run), "--from", "best", "--num-cycles", str(CYCLES + 1)]) == 0


def test_a_file_where_a_checkpoint_kind_keeps_its_folder_is_named_before_anything_changes(whole, tmp_path, capsys):
    """`checkpoints/latest` replaced by a file: resume printed Orbax's traceback from a background thread, after it had
    already recorded a new --num-cycles in config.yaml (and with --num-cycles trained cycles before it failed)."""
    run = copy_of(whole, tmp_path)
    shutil.rmtree(run / CHECKPOINTS / "latest")
    (run / CHECKPOINTS / "latest").write_text("x")
    before = {path: path.read_bytes() for path in run.rglob("*") if path.is_file()}
    assert main(["check", str(run)]) == 2
    out = capsys.readouterr().out
    assert f"PROBLEM: {run / CHECKPOINTS / 'latest'} is a file, where the run keeps its latest checkpoints" in out, out
    for argv in (["--from", "best", "--num-cycles", str(CYCLES + 2)], ["--from-scratch"]):
        err = exits_2(["resume", str(run), *argv], capsys)
        assert err.count("\n") == 1 and "checkpoints/latest is a file" in err and "Move the file away" in err, err
    assert {path: path.read_bytes() for path in run.rglob("*") if path.is_file()} == before


def test_a_resume_from_an_earlier_checkpoint_that_trains_nothing_is_refused_before_anything_moves(whole, tmp_path,
                                                                                                  capsys):
    """`--from 3 --num-cycles 3` trained nothing, exit 0 ("It was already complete"), after it had set aside the
    latest checkpoint and the later records and cut config.yaml to 3 cycles: the run was left without a latest
    checkpoint, which `check` called a problem and every plain resume refused."""
    run = copy_of(whole, tmp_path)
    before = {path: path.read_bytes() for path in run.rglob("*") if path.is_file()}
    err = exits_2(["resume", str(run), "--from", "3", "--num-cycles", "3"], capsys)
    assert "--from 3 with --num-cycles 3 trains nothing" in err and "--num-cycles 4" in err, err
    assert "`angora-jax evaluate" in err and "--checkpoint 3" in err, err
    assert {path: path.read_bytes() for path in run.rglob("*") if path.is_file()} == before
    assert check_run(run).problems == []


def test_a_run_root_under_the_home_folder_written_with_a_tilde_is_made_there(tmp_path, monkeypatch):
    """`logging.run_root=~/runs` reaches the config unexpanded (a shell expands a word's leading `~` only): the run
    goes to the home folder, never to a folder named `~` in the current one."""
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    monkeypatch.chdir(tmp_path)
    run_dir = create_run_dir(aj.load_config("cartpole", ["logging.run_root=~/runs", "logging.run_name=x"]))
    assert run_dir == tmp_path / "home" / "runs" / "x" and (run_dir / CONFIG_FILE).is_file()
    assert not (tmp_path / "~").exists()


def test_the_words_that_count_agree_with_their_count(tmp_path, capsys):
    """A run of one cycle was "config: CartPole, simple network, 1 cycles", "metrics.jsonl: 1 cycles logged, 1 to 1"
    with "lines 2 hold no cycle's record" in `check`, resume refused it as having "logged 1 cycles", the training
    curve's reader warned that "line(s) 2 are not records", and doctor counted "1 problem(s): fix them". Each word now
    agrees with its count (`wording.counted`, `agreeing`): 1 cycle, 2 cycles."""
    run = tmp_path / "one"
    run.mkdir()
    write_run_config(run, aj.load_config("cartpole", ["ppo.num_cycles=1"]))
    (run / "metrics.jsonl").write_text(json.dumps({"cycle": 1, "env_steps": 64, "time": 1.0}) + "\nnot a record\n")
    found = check_run(run).format()
    for said in ("config: CartPole, simple network, 1 cycle\n", "metrics.jsonl: 1 cycle logged, cycle 1\n",
                 "PROBLEM: metrics.jsonl line 2 holds no cycle's record (edited or cut short)",
                 "but it logged 1 cycle (up to cycle 1) in metrics.jsonl"):
        assert said in found, found
    assert [record["cycle"] for record in read_metrics(run)] == [1]
    assert "metrics.jsonl: line 2 is not a record of a cycle and is skipped" in capsys.readouterr().err
    with (run / "metrics.jsonl").open("a") as log:
        log.write(json.dumps({"cycle": 2, "env_steps": 128, "time": 2.0}) + "\nnor this\n")
    found = check_run(run).format()
    for said in ("metrics.jsonl: 2 cycles logged, 1 to 2\n", "PROBLEM: metrics.jsonl lines 2, 4 hold no cycle's",
                 "but it logged 2 cycles (up to cycle 2)"):
        assert said in found, found
    read_metrics(run)
    assert "metrics.jsonl: lines 2, 4 are not records of a cycle and are skipped" in capsys.readouterr().err
    doctor = Diagnosis([("machine", "cpu", "x86_64")], ["no GPU"])
    assert doctor.format().endswith("\n1 problem: fix it as shown above."), doctor.format()
    doctor.problems.append("no disk")
    assert doctor.format().endswith("\n2 problems: fix them as shown above."), doctor.format()


def test_check_names_a_deleted_or_emptied_metrics_file_of_a_run_with_checkpoints(whole, tmp_path):
    """The training curve deleted (or emptied) passed as "0 cycles logged ... OK: nothing is damaged"."""
    run = copy_of(whole, tmp_path)
    (run / "metrics.jsonl").write_text("")
    found = check_run(run).format()
    assert f"PROBLEM: metrics.jsonl is empty, but checkpoints were saved up to cycle {CYCLES}" in found, found
    (run / "metrics.jsonl").unlink()
    assert "PROBLEM: metrics.jsonl is missing, but checkpoints" in check_run(run).format()


def test_check_names_a_record_without_its_env_steps_with_what_resume_does_with_it(whole, tmp_path, capsys):
    """A metrics.jsonl ending in `{"cycle": 7}` past the latest checkpoint (cycle 6) passed as "7 cycles logged, 1 to
    7 ... OK: nothing is damaged". The trainer never writes such a line (each record it writes carries env_steps, and
    a record cut short does not parse), so it is damage, named as such with what resume does about it: past the
    checkpoint resume continues from, it goes to the side file with the later records; before it, resume keeps it,
    and the fix is a copy of the file or those cycles trained again."""
    run = copy_of(whole, tmp_path)
    with (run / "metrics.jsonl").open("a") as log:
        log.write(json.dumps({"cycle": 7}) + "\n")
    said = ("metrics.jsonl line 7 holds cycle 7 without its env_steps, which every record the trainer writes "
            "carries: the file was edited, or another program wrote to it")
    assert check_run(run).problems == [f"{said}; resume continues from cycle 6 and moves it to a side file with the "
                                       "later records"]
    assert main(["check", str(run)]) == 2 and f"PROBLEM: {said}" in capsys.readouterr().out
    assert set_aside_after(run, 6).read_text() == '{"cycle": 7}\n'
    lines = (run / "metrics.jsonl").read_text().splitlines()
    lines[3:5] = [json.dumps({"cycle": 4}), json.dumps({"cycle": 5, "episode_return": 1.0})]
    (run / "metrics.jsonl").write_text("\n".join(lines) + "\n")
    assert check_run(run).problems == [
        "metrics.jsonl lines 4, 5 hold cycles 4, 5 without their env_steps, which every record the trainer writes "
        "carries: the file was edited, or another program wrote to it; resume would keep them, cycles without a point "
        f"on the curves: put the file back from a copy if there is one, or `angora-jax resume {run} --from 3` trains "
        "again from the checkpoint before cycle 4, so that each cycle is logged (the later records and checkpoints are "
        "kept aside)"]


def test_the_saved_config_comes_from_the_next_checkpoint_when_the_newest_cannot_be_read(whole, monkeypatch):
    """While a run trains, `check` compared its config with the newest latest checkpoint's, which the writer removed
    as it was read: check failed with that checkpoint "corrupt or incomplete" (3 of 10 tries in a user's trial)."""
    read = Checkpoints._read_meta

    def removed_first(self, kind, cycle):
        if (kind, cycle) == ("latest", CYCLES):
            raise CheckpointError("cannot be read (FileNotFoundError): removed by the writer")
        return read(self, kind, cycle)

    monkeypatch.setattr(Checkpoints, "_read_meta", removed_first)
    checkpoints = Checkpoints(whole.run_dir / CHECKPOINTS, CheckpointConfig(), create=False)
    try:
        kind, cycle, config = checkpoints.saved_config()
    finally:
        checkpoints.close()
    assert (kind, cycle) == ("best", CYCLES) and config["env"]["task"] == "CartPole"
    assert check_run(whole.run_dir).problems == []


def test_a_checkpoint_without_its_manifest_is_read_whole_by_check_and_a_damaged_one_is_one_line(whole, tmp_path,
                                                                                                 capfd):
    """A checkpoint without a manifest (cut off between Orbax's save and the manifest, or its manifest lost) cannot be
    verified by one: `check` reads it whole instead, passes it when it reads and reports it when it does not. Reading a
    damaged one ends in one message naming resume's --from, without Orbax's and TensorStore's tracebacks and specs
    (dozens to thousands of lines)."""
    run = copy_of(whole, tmp_path)
    latest = run / "checkpoints" / "latest" / str(CYCLES)
    (latest / "manifest.json").unlink()
    assert main(["check", str(run)]) == 0, capfd.readouterr()
    assert "without a manifest, unverifiable: cycle" in capfd.readouterr().out
    largest = max((path for path in (latest / "state").rglob("*") if path.is_file()), key=lambda p: p.stat().st_size)
    with largest.open("r+b") as file:
        file.truncate(10)
    assert main(["check", str(run)]) == 2
    out, err = capfd.readouterr()
    assert f"PROBLEM: checkpoint latest/{CYCLES} has no manifest and cannot be read" in out, out
    assert err == "", err[:2000]
    for verb in (["resume", str(run)], ["evaluate", str(run), "--checkpoint", "latest", "--episodes", "1"]):
        assert main(verb) == 2
        err = capfd.readouterr().err
        assert err.count("\n") == 1 and f"latest/{CYCLES} cannot be read (" in err, err[:2000]
        assert "TensorStore" not in err and "or to resume's --from" in err


def test_a_lost_record_is_reported_with_the_resume_that_logs_every_cycle_again(whole, tmp_path, capsys):
    """A record lost from metrics.jsonl (a damaged line that resume set aside) failed `check` for good, with no way
    on: check names the resume from the checkpoint before the gap, after which every cycle is logged again."""
    run = copy_of(whole, tmp_path)
    lines = (run / "metrics.jsonl").read_text().splitlines(keepends=True)
    (run / "metrics.jsonl").write_text("".join(lines[:4] + lines[5:]))  # cycle 5's record is gone
    assert main(["check", str(run)]) == 2
    out = capsys.readouterr().out
    said = out.split("does not log each cycle once")[1]
    assert "(1-4, 6): records were lost" in said and f"angora-jax resume {run} --from " in said, out
    start = int(said.split("--from ")[1].split("`")[0])
    assert start < 5
    assert main(["resume", str(run), "--from", str(start)]) == 0
    capsys.readouterr()
    assert main(["check", str(run)]) == 0, capsys.readouterr().out
    assert [record["cycle"] for record in read_metrics(run)] == list(range(1, CYCLES + 1))


def test_a_run_whose_checkpoints_will_not_fit_says_so_before_training(whole, tmp_path, monkeypatch, capsys):
    run = copy_of(whole, tmp_path)
    monkeypatch.setattr(runner.shutil, "disk_usage", lambda path: shutil._ntuple_diskusage(1 << 30, 1 << 30, 1 << 10))
    resume(run, start_from=3)
    needed = disk_needed(aj.load_config("cartpole", TINY).checkpoint, whole.state, CYCLES - 3)
    assert needed > 1 << 10
    err = capsys.readouterr().err
    assert f"Warning: the checkpoints of this run need up to {needed / 2**10:.1f} KiB" in err and "1.0 KiB free" in err


def test_a_recording_larger_than_memory_is_refused_after_its_first_steps(whole, tmp_path, capsys):
    out = tmp_path / "huge.nc"
    err = exits_2(["record", str(whole.run_dir), "--episodes", "2", "--steps", "1000000000", "--out", str(out)], capsys)
    assert "Recording 2 episodes x 1,000,000,000 steps takes" in err and "record fewer episodes or steps" in err
    assert not out.exists()


def test_a_result_file_is_written_whole_or_not_at_all_and_never_over_a_kept_one(tmp_path):
    path = tmp_path / "result.json"
    with pytest.raises(KeyboardInterrupt), written_whole(path) as draft:
        draft.write_text('{"half": ')
        raise KeyboardInterrupt
    assert list(tmp_path.iterdir()) == [], "neither the file nor its draft is left"
    with written_whole(path) as draft:
        draft.write_text("{}")
    with pytest.raises(FileExistsError, match=f"^{re.escape(str(path))} exists and is never overwritten"), \
            written_whole(path, replace=False) as draft:  # as a second render to the same --out is told
        draft.write_text('{"new": 1}')
    assert path.read_text() == "{}" and list(tmp_path.iterdir()) == [path]
    elsewhere = tmp_path / "no such folder" / "result.json"
    with pytest.raises(FileNotFoundError) as failed, written_whole(elsewhere) as draft:
        draft.write_text("{}")
    assert failed.value.filename == str(elsewhere), "the error names the file asked for, not its draft"


def test_a_kept_file_is_refused_before_anything_is_written_and_never_lost_to_a_second_writer(tmp_path, monkeypatch):
    """Refused before the block runs: a full disk met while writing under a name that is taken (an evaluation's
    first numbered name) named the kept file. And published by a hard link, which the system refuses over a file that
    another writer made after the check: a check and a rename replaced it."""
    kept = tmp_path / "result.json"
    kept.write_text("kept")
    ran = []
    with pytest.raises(FileExistsError, match="exists and is never overwritten"), \
            written_whole(kept, replace=False) as draft:
        ran.append(draft)
    assert not ran and kept.read_text() == "kept"
    late = tmp_path / "late.json"
    with pytest.raises(FileExistsError, match="exists and is never overwritten"), \
            written_whole(late, replace=False) as draft:
        draft.write_text("ours")
        late.write_text("the other writer's")
        monkeypatch.setattr(Path, "exists", lambda self: False)  # the check, had it come after the other writer
    monkeypatch.undo()
    assert late.read_text() == "the other writer's" and sorted(tmp_path.iterdir()) == [late, kept]


def test_ctrl_c_while_a_recording_is_written_exits_130_and_leaves_no_half_file(whole, tmp_path, monkeypatch, capsys):
    """A recording cut off while it is written would block the next `record` to the same --out ("exists"); it is
    written to a draft instead, renamed when whole."""
    import xarray as xr

    def cut_off(dataset, path, **options):
        Path(path).write_bytes(b"CDF\x01 half")
        raise KeyboardInterrupt

    monkeypatch.setattr(xr.Dataset, "to_netcdf", cut_off)
    out = tmp_path / "activity.nc"
    try:
        code = main(["record", str(whole.run_dir), "--episodes", "2", "--steps", "5", "--out", str(out)])
    except KeyboardInterrupt:  # caught here, or pytest would stop the whole session
        pytest.fail("Ctrl-C left `angora-jax record` as a traceback")
    assert code == 130
    err = capsys.readouterr().err
    assert err.startswith("angora-jax record: interrupted (Ctrl-C)") and "Traceback" not in err
    assert list(tmp_path.iterdir()) == []


def test_a_second_ablation_of_a_run_keeps_the_first(whole, tmp_path, capsys):
    run = copy_of(whole, tmp_path)
    for _ in range(2):
        assert main(["analyze", "ablate", str(run), "--silence", "proprioception", "--episodes", "2"]) == 0
    assert {"ablation.png", "ablation.nc", "ablation-2.png", "ablation-2.nc"} <= {p.name for p in run.iterdir()}
    assert "numbers: " + str(run / "ablation-2.nc") in capsys.readouterr().out


def test_record_refuses_images_of_a_task_without_a_camera_before_running(whole, tmp_path, capsys):
    """`record --images` of CartPole (no image modality) used to record without images and say nothing."""
    assert main(["record", str(whole.run_dir), "--images", "--episodes", "2", "--out", str(tmp_path / "r.nc")]) == 2
    err = capsys.readouterr().err
    assert "CartPole sees through no camera" in err and "record without it" in err and "Traceback" not in err
    assert not (tmp_path / "r.nc").exists()


def test_analyses_of_a_recording_keep_earlier_results_and_refuse_a_taken_out(whole, tmp_path, capsys):
    """A second analysis of a kind (other options, the same recording) takes the next free name; --out naming an
    existing plot, or a plot whose numbers exist, exits 2 before computing, and the files keep their bytes."""
    recording = tmp_path / "rec.nc"
    assert main(["record", str(whole.run_dir), "--episodes", "2", "--steps", "6", "--out", str(recording)]) == 0
    for lag in (2, 3):
        assert main(["analyze", "timescales", str(recording), "--max-lag", str(lag)]) == 0
    assert {"rec.timescales.png", "rec.timescales.nc", "rec.timescales-2.png", "rec.timescales-2.nc"} <= {
        p.name for p in tmp_path.iterdir()}
    first = {p: p.read_bytes() for p in (tmp_path / "rec.timescales.png", tmp_path / "rec.timescales.nc")}
    capsys.readouterr()
    (tmp_path / "other.nc").write_bytes(b"someone's numbers")
    for out in (tmp_path / "rec.timescales.png", tmp_path / "other.png"):
        assert main(["analyze", "timescales", str(recording), "--out", str(out)]) == 2
        err = capsys.readouterr().err
        assert "exists; analyses are never overwritten: give another --out" in err and "Traceback" not in err
    assert main(["analyze", "ablate", str(whole.run_dir), "--silence", "proprioception", "--out",
                 str(tmp_path / "rec.timescales.png")]) == 2
    assert all(p.read_bytes() == data for p, data in first.items())
    assert (tmp_path / "other.nc").read_bytes() == b"someone's numbers" and not (tmp_path / "other.png").exists()
    capsys.readouterr()
    assert main(["analyze", "visual", str(recording), "--run", str(whole.run_dir)]) == 2
    assert "task (CartPole) sees through no camera: the visual analysis is for agents that see pixels" in (
        capsys.readouterr().err), "not: record it with --images, which CartPole refuses"
    older = xr.load_dataset(recording)
    del older.attrs["camera_images"]  # a recording from before the attribute: it cannot say the task has no camera
    older.to_netcdf(tmp_path / "older.nc")
    assert main(["analyze", "visual", str(tmp_path / "older.nc"), "--run", str(whole.run_dir)]) == 2
    assert "kept no camera images: record it with angora-jax record RUN_DIR --images" in capsys.readouterr().err
