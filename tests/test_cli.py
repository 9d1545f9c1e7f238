"""The `angora-jax` command: exit codes, messages, SIGTERM on a real process, and the progress display."""

import argparse
import contextlib
import errno
import io
import json
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import jax
import mujoco
import numpy as np
import pytest
from flax import serialization
from quick_compile import QUICK_SUBPROCESS, QUICK_SUBPROCESS_NO_FUSION_EMITTERS
from tiny import TINY_PPO

import angora_jax as aj
from angora_jax import cli
from angora_jax.cli import main, parser
from angora_jax.cli.errors import device_memory_message, os_error_message
from angora_jax.experiment import compilation_cache, runner
from angora_jax.experiment.config import load_config, validate
from angora_jax.experiment.config_reference import reference_markdown
from angora_jax.experiment.cpu_sizing import cpu_note
from angora_jax.experiment.distributed import ProcessFailed, StopDecision
from angora_jax.experiment.live_report import LiveReport
from angora_jax.experiment.monitor import read_metrics
from angora_jax.experiment.progress import Progress, progress_line
from angora_jax.experiment.run_check import check_run
from angora_jax.experiment.run_dir import read_sessions
from angora_jax.experiment.runner import TrainingInterrupted

TINY = [
    *TINY_PPO,
    "logging.progress=lines",
    "logging.report=false",
]

# The runs in this process are a cycle or a few of a tiny task (tests/quick_compile.py); its processes say for
# themselves how they compile.
pytestmark = pytest.mark.usefixtures("quick_file_compiles")


def test_list_commands(capsys):
    assert main(["list-tasks"]) == 0
    assert "CartPole" in capsys.readouterr().out.split()
    assert main(["list-models"]) == 0
    out = capsys.readouterr().out
    assert "lstm" in out and "beta" in out
    assert main(["list-configs"]) == 0
    out = capsys.readouterr().out
    assert re.search(r"shadow_ihom_paper +In-hand cube reorientation \(IHOM\) as in the paper \(Weidler", out)
    assert re.search(r"shadow_reach_cortical +Shadow hand reach with the brain-area model", out)


def test_doctor_reports_the_physics_choice_and_exits_0_on_the_cpu(capsys, monkeypatch, gl_problem):
    renders = gl_problem is None  # this machine's own answer, asked of MuJoCo directly
    assert main(["doctor"]) == 0
    out = capsys.readouterr().out
    assert "mujoco-mjx" in out and "cpu:0" in out and "OK: angora_jax can train here." in out
    assert "MJX jax implementation (physics.impl auto: JAX runs on the CPU" in out
    verdict = re.search(r"off screen +(.*)", out).group(1)
    assert verdict.startswith(f"yes, MUJOCO_GL={os.environ['MUJOCO_GL']}" if renders else "no: MUJOCO_GL=")
    assert ("Videos (angora-jax render) cannot be made" in out) != renders
    # Where no OpenGL context can be made, the verdict says no and the advice names what to install (exit 0: only
    # training is required).
    monkeypatch.setattr(mujoco, "Renderer", lambda *args: (_ for _ in ()).throw(mujoco.FatalError("gladLoadGL error")))
    assert main(["doctor"]) == 0
    out = capsys.readouterr().out
    assert re.search(r"off screen +no: MUJOCO_GL=\S+ \(gladLoadGL error\)", out)
    assert re.search(r"advice: Videos \(angora-jax render\) cannot be made.*libegl-mesa0.*MUJOCO_GL=egl", out)


@pytest.mark.parametrize(
    "argv, message",
    [
        (["train", "cartpole", "ppo.gama=0.9"], "Unknown key 'ppo.gama'"),
        (["train", "cartpole", "ppo.head=beta"], "needs continuous actions"),
        (["train", "no-such-config"], "not found"),
        (["resume", "no/such/run"], "not a run directory"),
        (["evaluate", "no/such/run"], "not a run directory"),
        (["report", "no/such/run"], "not a run directory"),
        (["monitor", "no/such/run"], "not a run directory"),
        (["train", "cartpole", "ppo.learning_rate=nan"], "ppo.learning_rate must be a finite number"),
        (["train", "cartpole", "ppo.num_envs=10000000000"], "cannot fit: it needs at least"),
        (["train", "cartpole", "--num-processes", "2", "--process-id", "1"], "set up a jax.distributed job: add "
                                                                               "--distributed"),
        # One device is "1 device", not "1 device(s)".
        (["train", "cartpole", "distribution.num_devices=3"], "distribution.num_devices=3 but JAX sees only 1 "
                                                              "device ("),
        (["train", "cartpole", "checkpoint.lean=[latest, everything]"], "Unknown value 'everything' for "
                                                                        "checkpoint.lean"),
        (["train", "cartpole", "logging.run_name=../escape"], "must be a plain folder name"),
        (["train", "binary.yaml"], "binary.yaml is not a text file (not UTF-8)"),
        (["train", "empty.yaml"], "empty.yaml holds no settings"),
    ],
)
def test_bad_input_exits_2_with_the_cause(argv, message, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "binary.yaml").write_bytes(bytes(range(128, 256)))
    (tmp_path / "empty.yaml").write_text("")
    assert main(argv) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "runs").exists() or not any((tmp_path / "runs").iterdir())
    assert sorted(path.name for path in tmp_path.iterdir() if path.name != "runs") == ["binary.yaml", "empty.yaml"]


def test_resume_num_cycles_past_the_cycle_counter_names_the_option(capsys):
    """`resume --num-cycles 100000000000` was refused as "ppo.num_cycles must be <= 2,147,483,647", a setting the
    command line does not take, after the run was loaded."""
    with pytest.raises(SystemExit) as ended:
        main(["resume", "no/such/run", "--num-cycles", "100000000000"])
    err = capsys.readouterr().err
    assert ended.value.code == 2 and "argument --num-cycles: must be a whole number from 1 to 2,147,483,647" in err


def test_a_path_in_or_above_a_run_names_the_run_directory(capsys, tmp_path, monkeypatch):
    """A run's config.yaml or checkpoints folder given for the run, or the folder of runs, names the run directory
    to give instead (relative as typed); a missing path says it does not exist; a run given for a recording says to
    record it; an exported policy or a recording given for a run says what it is and what to do instead."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "runs" / "a" / "checkpoints").mkdir(parents=True)
    (tmp_path / "runs" / "a" / "config.yaml").write_text("env: {task: CartPole}\n")
    (tmp_path / "policy.msgpack").write_bytes(serialization.msgpack_serialize({"format": 1, "state": {"a": 1}}))
    (tmp_path / "encoder.msgpack").write_bytes(serialization.msgpack_serialize({"IT": {"bias": np.zeros(2)}}))
    (tmp_path / "act.nc").write_bytes(b"")
    for argv, said in [
        (["evaluate", "policy.msgpack"], "policy.msgpack is an exported policy (`angora-jax export`), not the run "
                                         "directory this command reads: act with it in Python, `aj.load_policy"),
        (["evaluate", "encoder.msgpack"], "encoder.msgpack is a network component (`angora-jax pretrain-vision "
                                          "--out OUT` writes its encoder as OUT;"),
        (["analyze", "ablate", "act.nc", "--lesion", "network.M1"], "act.nc is a recording (`angora-jax record`) or "
                                                                   "an analysis's numbers, not the run directory"),
        (["evaluate", "runs/a/config.yaml"], "runs/a/config.yaml is a file, not a run directory. It is inside the run "
                                             "directory runs/a: give that."),
        (["check", "runs/a/checkpoints"], "runs/a/checkpoints is not a run directory: it has no config.yaml. It is "
                                          "inside the run directory runs/a: give that."),
        (["report", "runs"], "runs is not a run directory: it has no config.yaml. It holds run directories (a): give "
                             "one of them, e.g. runs/a."),
        (["resume", "runs/b"], "runs/b is not a run directory: it does not exist. Start runs with `angora-jax "
                               "train` (in Python: aj.train)."),
        (["analyze", "decode", "runs/a"], "runs/a is a run directory, not a recording: record its activity first, "
                                          "angora-jax record runs/a --out a.nc, then analyze that file."),
        (["analyze", "decode", "runs"], "runs is a folder, not a recording: give the file that angora-jax record "
                                        "wrote"),  # it was "No recording runs", of a folder in plain sight
    ]:
        assert main(argv) == 2, argv
        assert said in capsys.readouterr().err, argv


@pytest.mark.parametrize("text", ["", "# only a comment\n", "env: {task: [CartPole\n", "- env\n"])
def test_a_run_whose_config_is_empty_or_damaged_is_answered_with_the_runs_fix(text, capsys, tmp_path):
    """A run's config.yaml emptied, cut short or holding no mapping is answered, on every command that reads the run,
    with `check --restore-config` first, not with `train`'s advice to name one of the shipped configs; a run without
    checkpoints (nothing keeps a copy) says so."""
    run = tmp_path / "run"
    (run / "checkpoints" / "latest" / "3").mkdir(parents=True)  # what `has_checkpoints` looks for
    (run / "config.yaml").write_text(text)
    for verb in (["evaluate"], ["resume"], ["check"], ["export", "--out", str(tmp_path / "p.msgpack")]):
        assert main([*verb, str(run)]) == 2, verb
        err = capsys.readouterr().err
        assert f"{run / 'config.yaml'} is damaged: `angora-jax check {run} --restore-config` writes it again" in err
        assert "shipped config" not in err and "cartpole" not in err and "Traceback" not in err, err
    assert (run / "config.yaml").read_text() == text
    shutil.rmtree(run / "checkpoints")
    assert main(["evaluate", str(run)]) == 2
    assert f"{run} has no checkpoint that keeps a copy of it" in capsys.readouterr().err


def test_an_out_inside_a_runs_checkpoint_folder_is_refused_before_anything_is_written(capsys, tmp_path,
                                                                                     monkeypatch):
    """`evaluate RUN --out RUN/checkpoints/latest/2` wrote its JSON and plot into the checkpoint, which training
    deletes with it when a later one replaces it (and `record`, `export`, `analyze`, `render`, `pretrain-vision` the
    same into any run's checkpoints): each --out there is refused by name now, before the run is read, naming the
    folder, and nothing in the checkpoints changes. `record` now checks its folder first, as the others did."""
    import angora_jax.experiment.video as video

    monkeypatch.setattr(video, "render_episodes", lambda *args, **kwargs: pytest.fail("rendered"))
    monkeypatch.chdir(tmp_path)
    run = tmp_path / "runs" / "a"
    (run / "checkpoints" / "latest" / "3").mkdir(parents=True)
    (run / "config.yaml").write_text("env: {task: CartPole}\n")
    write_recording(tmp_path / "act.nc")
    for argv in (["evaluate", "runs/a", "--out", "runs/a/checkpoints/latest/3"],
                 ["evaluate", "runs/a", "--out", "runs/a/checkpoints"],
                 ["export", "runs/a", "--out", "runs/a/checkpoints/latest/p.msgpack"],
                 ["export", "runs/a", "--out", "runs/a/checkpoints/"],
                 ["record", "runs/a", "--out", "runs/a/checkpoints/act.nc"],
                 ["analyze", "ablate", "runs/a", "--lesion", "network.M1", "--out", "runs/a/checkpoints/new/a.png"],
                 ["analyze", "decode", "act.nc", "--out", "runs/a/checkpoints/decode.png"],
                 ["render", "--task", "ShadowHandReach", "--out", "runs/a/checkpoints/v.gif"],
                 ["pretrain-vision", "--out", "runs/a/checkpoints/latest/encoder.msgpack"]):
        assert main(argv) == 2, argv
        err = capsys.readouterr().err
        assert "runs/a/checkpoints, the checkpoint folder of the run runs/a, which only training writes" in err, err
        assert "Traceback" not in err, err
    assert sorted(path.relative_to(run).as_posix() for path in run.rglob("*")) == [
        "checkpoints", "checkpoints/latest", "checkpoints/latest/3", "config.yaml"]
    # record checked no folder before its episodes either: a file on the way ended it only after them.
    (tmp_path / "notes.txt").write_text("mine")
    assert main(["record", "runs/a", "--out", "notes.txt/act.nc"]) == 2
    assert f"--out notes.txt/act.nc: {tmp_path / 'notes.txt'} is a file" in capsys.readouterr().err
    # A folder named checkpoints that is in no run is any folder.
    assert main(["analyze", "decode", "act.nc", "--out", "checkpoints/decode.png"]) == 0


def test_a_run_root_inside_a_runs_checkpoint_folder_is_refused_before_the_run_is_made(capsys, tmp_path, monkeypatch):
    """`train CONFIG logging.run_root=RUN/checkpoints` made the new run inside the other run's checkpoint folder, which
    only training writes, and trained it there, exit 0. Refused now, naming the folder, before any directory is made."""
    monkeypatch.chdir(tmp_path)
    run = tmp_path / "runs" / "a"
    (run / "checkpoints" / "latest" / "3").mkdir(parents=True)
    (run / "config.yaml").write_text("env: {task: CartPole}\n")
    for root in ("runs/a/checkpoints", "runs/a/checkpoints/latest/new"):
        assert main(["train", "cartpole", *TINY, "ppo.num_cycles=1", f"logging.run_root={root}"]) == 2
        err = capsys.readouterr().err
        assert f"logging.run_root={root} is inside runs/a/checkpoints, the checkpoint folder of the run runs/a, " \
               "which only training writes" in err and "Traceback" not in err, err
    assert sorted(path.relative_to(run).as_posix() for path in run.rglob("*")) == [
        "checkpoints", "checkpoints/latest", "checkpoints/latest/3", "config.yaml"]


def test_a_run_root_that_is_a_run_or_inside_one_is_refused_and_a_folder_with_only_a_config_is_not(capsys, tmp_path,
                                                                                                     monkeypatch):
    """`train CONFIG logging.run_root=runs/a` (the run, not the folder of runs) made the new run inside runs/a, exit 0,
    to be copied, moved and deleted with it; so did `train` started inside a run's folder. Both refused now, naming the
    run and the folder to give. A folder holding only the user's own config.yaml is no run: runs are made there."""
    monkeypatch.chdir(tmp_path)
    run = tmp_path / "runs" / "a"
    run.mkdir(parents=True)
    (run / "config.yaml").write_text("env: {task: CartPole}\n")
    (run / "sessions.jsonl").write_text("")
    for root, where in (("runs/a", "is the run runs/a"), ("runs/a/sweep/x", "is inside the run runs/a")):
        assert main(["train", "cartpole", *TINY, "ppo.num_cycles=1", f"logging.run_root={root}"]) == 2
        err = capsys.readouterr().err
        assert f"logging.run_root={root} {where}, and a run made there would be copied, moved and deleted with it: " \
               "choose a folder for runs outside every run (e.g. logging.run_root=runs). To continue runs/a: " \
               "`angora-jax resume runs/a`." in err and "Traceback" not in err, err
    monkeypatch.chdir(run)
    assert main(["train", "cartpole", *TINY, "ppo.num_cycles=1"]) == 2
    assert f"logging.run_root=runs is inside the run {run}," in capsys.readouterr().err
    assert sorted(path.name for path in run.iterdir()) == ["config.yaml", "sessions.jsonl"]
    project = tmp_path / "project"
    project.mkdir()
    (project / "config.yaml").write_text("extends: cartpole\n")
    monkeypatch.chdir(project)
    assert main(["train", "config.yaml", *TINY, "ppo.num_cycles=1", "logging.run_name=mine"]) == 0
    assert (project / "runs" / "mine" / "config.yaml").is_file()


def test_an_evaluation_written_into_another_run_is_refused_before_any_episode(capsys, tmp_path, monkeypatch):
    """`evaluate runs/a --out runs/b/evaluation` wrote a's evaluation among b's, where it reads as b's (and a resume of
    b from an earlier cycle sets it aside as one of b's later cycles). Refused now, exit 2, naming both runs; a folder
    of its own run, or outside every run, is written as before."""
    from angora_jax.experiment.evaluation import check_save_folder

    monkeypatch.chdir(tmp_path)
    for name in ("a", "b"):
        (tmp_path / "runs" / name / "checkpoints" / "latest" / "3").mkdir(parents=True)
        (tmp_path / "runs" / name / "config.yaml").write_text("env: {task: CartPole}\n")
    assert main(["evaluate", "runs/a", "--episodes", "2", "--out", "runs/b/evaluation"]) == 2
    err = capsys.readouterr().err
    assert "save (--out) runs/b/evaluation is inside the run runs/b, not runs/a: an evaluation of runs/a there would " \
           "be read as runs/b's. Give runs/a/evaluation (the default) or a folder outside every run." in err, err
    assert "Traceback" not in err and not (tmp_path / "runs" / "b" / "evaluation").exists()
    for own in ("runs/a/evaluation", "runs/a/mine", "elsewhere", str(tmp_path / "runs" / "a" / "x")):
        check_save_folder(own, "runs/a")


def write_recording(path: Path) -> Path:
    """A small recording's layout (the episode and time dimensions, the alive mask, one layer) as NetCDF."""
    import xarray as xr

    xr.Dataset({"alive": (("episode", "time"), np.ones((8, 50), bool)),
                "network.M1": (("episode", "time", "unit"), np.zeros((8, 50, 4), np.float32))}).to_netcdf(path)
    return path


@pytest.mark.parametrize("size", [0, 12, 100, 2000])
def test_a_recording_cut_short_is_named_as_unreadable_not_a_traceback(size, capsys, tmp_path):
    """A recording cut short (a copy interrupted, a full disk) fails in scipy's NetCDF reader with ValueError, or
    with IndexError where its header is cut: both are a file this machine cannot read, exit 2."""
    whole = write_recording(tmp_path / "whole.nc")
    (tmp_path / "act.nc").write_bytes(whole.read_bytes()[:size])
    assert main(["analyze", "timescales", str(tmp_path / "act.nc")]) == 2
    err = capsys.readouterr().err
    assert "act.nc is not a recording that this machine can read" in err and ".. " not in err, err
    # Past its first bytes it is recognisably NetCDF, so the likely cause (a copy or a write cut short) is named.
    assert ("likely cut short or damaged" in err) == (size >= 4), err
    assert sorted(path.name for path in tmp_path.iterdir()) == ["act.nc", "whole.nc"]


@pytest.mark.parametrize("out", ["act.decode.nc", "decoding", "plot.xyz"])
def test_an_analysis_out_that_is_no_image_is_refused_before_the_analysis(out, capsys, tmp_path):
    """--out names the plot, whose format matplotlib takes from the suffix, and the numbers are written beside it as
    .nc: a name ending in .nc (plot and numbers one file), or in no image format, failed in matplotlib's savefig
    after the analysis was computed, a traceback and exit 1."""
    write_recording(tmp_path / "act.nc")
    for analysis in ("decode", "timescales"):
        assert main(["analyze", analysis, str(tmp_path / "act.nc"), "--out", str(tmp_path / out)]) == 2
        assert f"give e.g. {tmp_path / Path(out).with_suffix('.png')}, not {out}." in capsys.readouterr().err
    assert sorted(path.name for path in tmp_path.iterdir()) == ["act.nc"]


def test_another_process_failing_exits_1_with_the_message_not_a_traceback(capsys, tmp_path, monkeypatch):
    def fail(config, minutes=None):
        raise ProcessFailed((1,), 3, tmp_path / "run")

    monkeypatch.setattr(runner, "train", fail)
    assert main(["train", "cartpole"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("angora-jax train: Process(es) 1 of this run failed after cycle 3")
    assert "Traceback" not in err and f"angora-jax resume {tmp_path / 'run'} --distributed" in err


def test_an_interrupted_job_says_so_once_from_process_0(capsys, tmp_path, monkeypatch):
    """Ctrl-C reaches every process of a multi-process job on one terminal (examples/multi_gpu_host.sh), and each
    printed the same "Interrupted by SIGINT after cycle N" line; the others now exit with the code alone."""
    def interrupted(config, minutes=None):
        raise TrainingInterrupted(signal.SIGINT, tmp_path / "run", 3)

    monkeypatch.setattr(runner, "train", interrupted)
    monkeypatch.setattr(jax, "process_index", lambda: 1)
    assert main(["train", "cartpole"]) == 128 + signal.SIGINT and capsys.readouterr().err == ""
    monkeypatch.setattr(jax, "process_index", lambda: 0)
    assert main(["train", "cartpole"]) == 128 + signal.SIGINT
    assert capsys.readouterr().err.startswith("angora-jax train: Interrupted by SIGINT after cycle 3; a checkpoint")


def test_overrides_may_follow_the_options_and_other_strays_are_usage_errors(capsys, monkeypatch):
    seen = []
    monkeypatch.setattr(runner, "train", lambda config, minutes: seen.append(config) or "run")
    monkeypatch.setattr(cli.training, "print_finished", lambda run: None)
    assert main(["train", "cartpole", "ppo.seed=1", "--minutes", "5", "ppo.num_envs=8"]) == 0
    assert [(config.ppo.seed, config.ppo.num_envs) for config in seen] == [(1, 8)]
    with pytest.raises(SystemExit) as stop:
        main(["train", "cartpole", "--minutes", "5", "stray"])
    assert stop.value.code == 2 and "unrecognized arguments: stray" in capsys.readouterr().err
    with pytest.raises(SystemExit) as stop:  # a resumed run keeps its settings: the message says what can change
        main(["resume", "runs/r", "ppo.lr_max=1e-3"])
    err = capsys.readouterr().err
    assert stop.value.code == 2 and "resume continues a run with the settings it was trained with" in err
    assert "(ppo.lr_max=1e-3)" in err and "--num-cycles N" in err and "ppo.init_from=RUN_DIR:latest" in err


def test_version_is_printed_and_only_the_config_is_asked_for(capsys):
    """`angora-jax --version` was "the following arguments are required: command"; `angora-jax train` alone said
    "required: config, KEY=VALUE", as if overrides were."""
    from importlib.metadata import version

    with pytest.raises(SystemExit) as stop:
        main(["--version"])
    assert stop.value.code == 0 and capsys.readouterr().out == f"angora-jax {version('angora-jax')}\n"
    for verb in (["train"], ["config", "show"]):
        with pytest.raises(SystemExit) as stop:
            main(verb)
        assert stop.value.code == 2 and capsys.readouterr().err.rstrip().endswith(
            "error: the following arguments are required: config")


@pytest.mark.parametrize("command", ["evaluate", "render"])
def test_episode_count_below_one_is_a_usage_error(command, capsys):
    with pytest.raises(SystemExit) as stop:
        main([command, "no/such/run", "--episodes", "0"])
    assert stop.value.code == 2
    assert "--episodes" in capsys.readouterr().err


@pytest.mark.parametrize("port", ["99999", "-1", "http"])
def test_a_port_outside_0_to_65535_is_a_usage_error(port, capsys):
    """`monitor --port 99999` was an OverflowError traceback from the socket's bind."""
    with pytest.raises(SystemExit) as stop:
        main(["monitor", "no/such/run", f"--port={port}"])
    assert stop.value.code == 2 and "must be a port from 0 (any free one) to 65535" in capsys.readouterr().err


@pytest.mark.parametrize("every", ["inf", "1e300", "86401"])
def test_a_monitor_interval_no_timer_can_wait_is_a_usage_error(every, capsys):
    """`monitor --every inf` ended in an OverflowError traceback at the first update (exit 1); `--every 1e300` killed
    the updating thread with a traceback while the monitor went on waiting, its page never updated again."""
    with pytest.raises(SystemExit) as stop:
        main(["monitor", "no/such/run", f"--every={every}", "--no-serve"])
    err = capsys.readouterr().err
    assert stop.value.code == 2 and f"--every: must be at most 86,400 seconds (a day), got '{every}'" in err, err


def test_every_argument_of_every_command_says_what_it_is():
    """The command-line reference (docs/cli.md) is the commands' --help: 28 arguments (render's --width, run's
    --seed, resume's RUN_DIR, ...) showed a bare name and no default."""

    def unexplained(command: argparse.ArgumentParser, prog: str):
        for action in command._actions:
            if isinstance(action, argparse._SubParsersAction):
                for name, sub in action.choices.items():
                    yield from unexplained(sub, f"{prog} {name}")
            elif not isinstance(action, argparse._HelpAction) and not (action.help or "").strip():
                yield f"{prog} {'/'.join(action.option_strings) or action.dest}"

    assert list(unexplained(parser(), "angora-jax")) == []


def test_train_then_evaluate_exit_0(capsys, tmp_path):
    argv = ["train", "cartpole", *TINY, "ppo.num_cycles=3", f"logging.run_root={tmp_path}", "logging.run_name=r",
            "checkpoint.best_metric=episode_length"]
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert "cycle 3/3" in out and "Run " in out and "angora-jax evaluate" in out
    records = read_metrics(tmp_path / "r")
    # The return, then the run's best_metric (the task's own measure), first cycle against last (3 cycles: a tenth is 1)
    assert f"Episode return: {records[0]['episode_return']:.1f} in the first tenth of cycles, " \
           f"{records[-1]['episode_return']:.1f} in the last tenth.\n" \
           f"episode_length: {records[0]['episode_length']:.4g} in the first tenth of cycles, " \
           f"{records[-1]['episode_length']:.4g} in the last tenth.\n" in out, out
    session = read_sessions(tmp_path / "r")[0]  # what the run ran on, for later readers of the run directory
    assert session["start_cycle"] == 0 and session["physics"]["engine"] == "pure JAX" and session["versions"]["jax"]
    assert main(["evaluate", str(tmp_path / "r"), "--checkpoint", "latest", "--num-envs", "2"]) == 0
    written = json.loads(Path(capsys.readouterr().out.split("Written: ")[1].split(" and ")[0]).read_text())
    assert (written["checkpoint"], written["cycle"], written["episodes"]) == ("latest", 3, 2)
    returns = written["per_episode"]["episode_return"]
    assert returns == written["per_episode"]["episode_length"], "CartPole pays 1 per step"
    assert written["summary"]["episode_return"]["mean"] == sum(returns) / 2
    assert main(argv) == 2  # the run directory exists: refused, untouched
    err = capsys.readouterr().err
    assert "already exists" in err and f"(in Python: aj.resume({str(tmp_path / 'r')!r}))" in err, err


@pytest.mark.slow
def test_minutes_stop_training_with_the_command_to_continue(capsys, tmp_path):
    argv = ["train", "cartpole", *TINY, "ppo.num_cycles=3", f"logging.run_root={tmp_path}", "logging.run_name=p"]
    assert main([*argv, "--minutes", "1e-9"]) == 0
    out = capsys.readouterr().out
    assert "cycle 1/3" in out and "cycle 2/3" not in out
    assert f"Stopped at the time limit (--minutes) with a checkpoint of cycle 1; continue with: angora-jax resume " \
           f"{tmp_path / 'p'}" in out
    assert [r["cycle"] for r in read_metrics(tmp_path / "p")] == [1]  # exactness is tests/test_checkpoint.py's
    with pytest.raises(SystemExit) as exit_info:
        main(["resume", str(tmp_path / "p"), "--minutes", "0"])
    assert exit_info.value.code == 2 and "--minutes: must be > 0" in capsys.readouterr().err
    # The command it names continues the run to its end.
    assert main(["resume", str(tmp_path / "p")]) == 0
    out = capsys.readouterr().out
    assert "cycle 3/3" in out and f"Run {tmp_path / 'p'}: 3 cycles done (2 in this session)." in out
    assert [r["cycle"] for r in read_metrics(tmp_path / "p")] == [1, 2, 3]
    assert main(["resume", str(tmp_path / "p")]) == 0, "a finished run is returned as it is"
    assert "3 cycles done (0 in this session)" in capsys.readouterr().out


def test_monitor_writes_the_page_and_refuses_a_busy_port_and_another_machine_s_address(capsys, tmp_path, monkeypatch):
    assert main(["train", "cartpole", *TINY, "ppo.num_cycles=1", f"logging.run_root={tmp_path}",
                 "logging.run_name=m", "logging.report=false"]) == 0
    capsys.readouterr()
    # --no-serve: the page is written on disk and named; Ctrl-C (here at the first wait) ends the monitor, exit 0.
    monkeypatch.setattr(LiveReport, "wait", lambda self: (_ for _ in ()).throw(KeyboardInterrupt))
    out_dir = tmp_path / "page"
    assert main(["monitor", str(tmp_path / "m"), "--no-serve", "--out", str(out_dir)]) == 0
    out = capsys.readouterr().out
    assert f"Monitoring 1 run: {(out_dir / 'index.html').resolve().as_uri()}" in out and "Monitor stopped." in out
    assert "1/1" in (out_dir / "index.html").read_text()
    with socket.socket() as busy:  # a port another program holds
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        assert main(["monitor", str(tmp_path / "m"), "--port", str(port), "--out", str(out_dir)]) == 2
    err = capsys.readouterr().err
    assert f"cannot serve on 127.0.0.1:{port}" in err
    assert "pick another --port (0: any free one) or use --no-serve" in err
    # An address that is not this machine's (TEST-NET-1) is the host's fault, which no other port mends.
    assert main(["monitor", str(tmp_path / "m"), "--host", "192.0.2.1", "--port", "0", "--out", str(out_dir)]) == 2
    err = capsys.readouterr().err
    assert "cannot serve on 192.0.2.1:0" in err and "give --host an address of this machine" in err
    assert "another --port" not in err


def test_run_rolls_out_a_random_policy_and_names_an_unknown_task(capsys):
    assert main(["run", "--task", "CartPole", "--num-envs", "2", "--steps", "300"]) == 0
    out = capsys.readouterr().out
    assert "CartPole: random policy, 2 envs x 300 steps on cpu" in out
    assert re.search(r"mean_reward: 1\n", out), "CartPole pays 1 per step"
    assert float(re.search(r"episodes_ended: ([\d.]+)", out).group(1)) >= 10, "random play drops the pole in ~22 steps"
    assert main(["run", "--task", "CartPol"]) == 2
    assert "CartPole" in capsys.readouterr().err


def test_run_says_no_episode_ended_instead_of_a_nan_metric(capsys, monkeypatch):
    from angora_jax.envs.classic.cartpole import CartPole
    from angora_jax.envs.registry import TASKS

    class Tilted(CartPole):
        metric_names = ("angle",)

        def _step(self, physics, info, action, key):
            *step, _ = super()._step(physics, info, action, key)
            return *step, {"angle": physics[2]}

    monkeypatch.setattr(TASKS, "_factories", {**TASKS._factories, "Tilted": Tilted})
    assert main(["run", "--task", "Tilted", "--num-envs", "2", "--steps", "3"]) == 0
    out = capsys.readouterr().out
    assert "episodes_ended: 0\n" in out and "episode_angle: - (no episode ended: more --steps)\n" in out, out


def test_another_process_failing_to_save_stops_this_one_after_its_own_save(tmp_path, monkeypatch):
    """A save that fails on one process of several must stop all: the others would wait in the next cycle."""
    calls = []

    def agree(signum, failed, out_of_time=False, in_on_cycle=False):  # two per cycle; the second is the save's
        calls.append(failed)
        save_failed_elsewhere = len(calls) == 4  # cycle 2's save
        return StopDecision(signum, (1,) if save_failed_elsewhere else (), out_of_time)

    monkeypatch.setattr(runner, "agree_to_stop", agree)
    with pytest.raises(ProcessFailed, match=r"Process\(es\) 1 of this run failed after cycle 2"):
        aj.train("cartpole", [*TINY, "ppo.num_cycles=5", "checkpoint.every=1", f"logging.run_root={tmp_path}",
                              "logging.run_name=r"])
    assert [r["cycle"] for r in read_metrics(tmp_path / "r")] == [1, 2] and len(calls) == 4
    assert aj.load_agent(tmp_path / "r", "latest").cycle == 2  # this process's own save went through


def test_a_failure_before_the_first_cycle_leaves_no_run_dir(tmp_path, monkeypatch):
    def out_of_memory(*args):
        raise RuntimeError("RESOURCE_EXHAUSTED: out of memory while compiling")
        yield

    monkeypatch.setattr(runner, "training_cycles", out_of_memory)
    with pytest.raises(RuntimeError, match="RESOURCE_EXHAUSTED"):
        aj.train("cartpole", [*TINY, f"logging.run_root={tmp_path}", "logging.run_name=failed"])
    assert not (tmp_path / "failed").exists()


@pytest.mark.parametrize("failure", [
    "RESOURCE_EXHAUSTED: Out of memory while trying to allocate 10.00GiB.",
    # MuJoCo Warp's kernel load on a GPU whose memory another process holds (benchmarks/results/myohand)
    "FFI callback error: Exception: Failed to load CUDA module 'mujoco.mjx.third_party.mujoco_warp._src.smooth'",
])
def test_the_gpu_out_of_memory_exits_2_naming_the_share_and_the_smaller_batch(failure, capsys, tmp_path, monkeypatch):
    def out_of_memory(*args):
        raise jax.errors.JaxRuntimeError(failure)
        yield

    monkeypatch.setattr(runner, "training_cycles", out_of_memory)
    monkeypatch.setattr(jax, "default_backend", lambda: "gpu")
    assert main(["train", "cartpole", *TINY, f"logging.run_root={tmp_path}", "logging.run_name=r"]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and not (tmp_path / "r").exists()
    assert "XLA_PYTHON_CLIENT_MEM_FRACTION=0.45" in err and "ppo.num_envs" in err and "angora-jax resume" in err


def test_out_of_memory_on_the_cpu_names_the_batch_and_no_gpu(capsys, tmp_path, monkeypatch):
    """`angora-jax run --num-envs 100000000000` on a CPU machine was told that the GPU ran out and to share it."""
    def out_of_memory(*args):
        raise jax.errors.JaxRuntimeError("INTERNAL: Error dispatching computation: Out of memory allocating 16 bytes.")
        yield

    monkeypatch.setattr(runner, "training_cycles", out_of_memory)
    assert jax.default_backend() == "cpu"
    assert main(["train", "cartpole", *TINY, f"logging.run_root={tmp_path}", "logging.run_name=r"]) == 2
    err = capsys.readouterr().err
    assert "the machine ran out of memory (INTERNAL" in err and "Use fewer environments (train: ppo.num_envs" in err
    assert "GPU" not in err and "Traceback" not in err


def test_other_runtime_errors_and_a_full_disk_are_not_taken_for_the_gpu_out_of_memory():
    assert device_memory_message(jax.errors.JaxRuntimeError("INTERNAL: an XLA bug")) is None
    assert device_memory_message(RuntimeError("RESOURCE_EXHAUSTED: out of memory")) is None, "not from JAX"
    full = jax.errors.JaxRuntimeError("RESOURCE_EXHAUSTED: Failed to write: No space left on device")
    assert device_memory_message(full) is None
    try:
        raise ValueError("while compiling") from jax.errors.JaxRuntimeError("RESOURCE_EXHAUSTED: Out of memory")
    except ValueError as wrapped:
        assert device_memory_message(wrapped).startswith("the machine ran out of memory (RESOURCE_EXHAUSTED")
    # Only a verb that trains stops a run: `run` or `evaluate` told of checkpoints kept sent users looking for harm.
    memory = jax.errors.JaxRuntimeError("RESOURCE_EXHAUSTED: Out of memory allocating 16 bytes.")
    assert "angora-jax resume RUN_DIR" in device_memory_message(memory, "resume")
    for command in ("run", "evaluate", "record"):
        said = device_memory_message(memory, command)
        assert "checkpoint" not in said and said.endswith("run: fewer --num-envs)."), said


def test_distributed_outside_a_cluster_without_its_settings_exits_2_naming_them(capsys):
    """In a process of its own, as a user starts it: jax.distributed must start before JAX's backend does, which
    this test process has long started."""
    cluster = ("SLURM_", "OMPI_", "JAX_COORDINATOR", "KUBERNETES_")
    environment = {name: value for name, value in os.environ.items() if not name.startswith(cluster)}
    done = subprocess.run([sys.executable, "-m", "angora_jax.cli", "train", "cartpole", "--distributed"],
                          capture_output=True, text=True, env=environment, timeout=300)
    assert done.returncode == 2 and "Traceback" not in done.stderr, done.stderr[-2000:]
    assert "--distributed could not set up the job: coordinator_address should be defined." in done.stderr
    assert "--coordinator HOST:PORT" in done.stderr
    with pytest.raises(SystemExit) as usage:
        main(["train", "cartpole", "--distributed", "--coordinator", "node01"])
    assert usage.value.code == 2 and "must be host:port, e.g. node01:12355" in capsys.readouterr().err


def test_an_opengl_backend_that_cannot_load_exits_2_naming_it_and_fails_the_import_with_its_name():
    """MuJoCo loads MUJOCO_GL's backend when it is imported, so an unknown or missing one failed every command (and
    `import angora_jax`) with a traceback from inside PyOpenGL or MuJoCo. In processes of their own: MuJoCo is imported
    once per process."""
    environment = os.environ | {"MUJOCO_GL": "nonesuch"}
    for command in (["-m", "angora_jax.cli", "list-tasks"], ["-c", "from angora_jax.cli import main; main()"]):
        done = subprocess.run([sys.executable, *command], capture_output=True, text=True, env=environment, timeout=300)
        if command[0] == "-m":
            assert done.returncode == 2 and "Traceback" not in done.stderr, done.stderr[-2000:]
            assert done.stderr.startswith("angora-jax: MuJoCo cannot be imported with MUJOCO_GL=nonesuch (RuntimeError")
            assert "unset MUJOCO_GL where nothing is rendered" in done.stderr and "MUJOCO_GL=egl" in done.stderr
        else:  # Python that imports the package: an ImportError with the same words, not an exit
            assert done.returncode == 1 and "OpenGLBackendError: MuJoCo cannot be imported with MUJOCO_GL=nonesuch" \
                in done.stderr, done.stderr[-2000:]


def test_a_folder_where_a_runs_own_file_belongs_is_named_with_the_fix(capsys, tmp_path):
    """A folder named metrics.jsonl (or sessions.jsonl, writer.lock) in a run was answered "the path is a folder: give
    a file", though the user gave no such path: the run's file is what must be moved away."""
    assert main(["train", "cartpole", *TINY, "ppo.num_cycles=1", f"logging.run_root={tmp_path}",
                 "logging.run_name=r"]) == 0
    run = tmp_path / "r"
    (run / "metrics.jsonl").unlink()
    (run / "metrics.jsonl").mkdir()
    assert main(["resume", str(run), "--num-cycles", "2"]) == 2
    err = capsys.readouterr().err
    assert f"Is a directory ({run / 'metrics.jsonl'}): a folder is where a file belongs" in err
    assert "where it is a run's own file, such as RUN_DIR/metrics.jsonl, move the folder away" in err, err


def test_a_full_disk_tells_of_the_runs_checkpoints_only_under_a_verb_that_trains():
    """render, export or report meeting a full disk ended with "A run stopped by it keeps every checkpoint saved
    before: `angora-jax check RUN_DIR` shows them", though they stop no run: the user went looking for harm."""
    full = OSError(errno.ENOSPC, "No space left on device", "v.gif")
    for command in ("train", "resume"):
        assert "A run stopped by it keeps every checkpoint saved before" in os_error_message(full, command)
    for command in ("render", "export", "report", "evaluate"):
        message = os_error_message(full, command)
        assert message.startswith("No space left on device (v.gif): free space") and "run stopped" not in message


def test_a_run_one_may_only_read_is_evaluated_with_out_and_resumed_as_ones_own_copy():
    """A colleague's run (or one on a shared mount) that this user may not write to: evaluate said "choose another
    place or fix its permissions" without naming --out, the place it takes; resume, which can write nowhere else,
    offered another place too."""
    denied = OSError(errno.EACCES, "Permission denied", "runs/ro/evaluation")
    message = os_error_message(denied, "evaluate")
    assert message.startswith("Permission denied (runs/ro/evaluation): you may not write or read there") and \
        "--out FOLDER" in message and "logging.run_root" in message, message
    message = os_error_message(OSError(errno.EPERM, "Operation not permitted", "runs/ro/writer.lock"), "resume")
    assert "resume writes into the run: fix its permissions, or copy the run" in message, message
    assert "chmod -R u+w MY_RUN" in message and "--out" not in message, message


def test_a_jax_platforms_this_machine_cannot_start_exits_2_naming_it_even_in_doctor():
    """`JAX_PLATFORMS=cuda` (a cluster's job script) where JAX has no CUDA plugin: JAX's bare AssertionError, then
    another while the CLI asked whether a process of a distributed job was lost, two tracebacks and exit 1, in
    `doctor` too, the verb that says what to install; `rocm` likewise with JAX's RuntimeError. In a process of its
    own: JAX starts its backends once per process."""
    platform = "rocm" if jax.default_backend() == "gpu" else "cuda"
    done = subprocess.run([sys.executable, "-m", "angora_jax.cli", "doctor"], capture_output=True, text=True,
                          env=os.environ | {"JAX_PLATFORMS": platform}, timeout=300)
    assert done.returncode == 2 and "Traceback" not in done.stderr, done.stderr[-2000:]
    assert done.stderr.startswith(f"angora-jax doctor: JAX cannot start the platform that JAX_PLATFORMS={platform} "
                                  "names on this machine (") and "unset JAX_PLATFORMS" in done.stderr, done.stderr


@pytest.fixture
def reaped():
    """`reaped(process)` returns `process`, killed when the test ends if it still runs: a test that failed while its
    process trained on (100,000 cycles) left it taking the cores from the tests after it."""
    processes = []
    yield lambda process: processes.append(process) or process
    for process in processes:
        if process.poll() is None:
            process.kill()
            process.wait()


def command_with_sighup(disposition: str = "SIG_DFL", before: str = "") -> list[str]:
    """`angora-jax` started with SIGHUP at `disposition` (SIG_DFL, or SIG_IGN as under nohup) after the Python
    statements `before`: a suite run under nohup passes its SIGHUP ignored on to every process it starts."""
    return [sys.executable, "-c", f"import os, signal, sys; {before}signal.signal(signal.SIGHUP, "
            f"signal.{disposition}); os.execv(sys.executable, [sys.executable, '-m', 'angora_jax.cli', *sys.argv[1:]])"]


def start_training(argv: list[str]) -> tuple[subprocess.Popen, str]:
    """`angora-jax` ARGV in a process of its own; returns it once it announces that it compiles, with that line."""
    process = subprocess.Popen([*command_with_sighup(), *argv], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                               text=True)
    line = process.stdout.readline()
    assert "compiling the first cycle" in line, (line, process.communicate())
    return process, line


@pytest.mark.slow
@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT, signal.SIGHUP])
def test_a_signal_while_compiling_stops_at_once_and_removes_the_new_run_dir(signum, tmp_path):
    """Reach compiles for a minute on 2 CPU cores: the command must not wait for it, nor leave a run directory."""
    argv = ["train", "shadow_reach", *TINY, f"logging.run_root={tmp_path}", "logging.run_name=new"]
    process, line = start_training(argv)
    assert "MuJoCo MJX (JAX implementation) on cpu:0 (physics.impl auto: JAX runs on the CPU" in line
    started = time.monotonic()
    process.send_signal(signum)
    _, err = process.communicate(timeout=30)
    assert process.returncode == 128 + signum and time.monotonic() - started < 10, err
    assert f"Interrupted by {signal.Signals(signum).name} before the first cycle ended" in err
    assert f"the new run directory {tmp_path / 'new'} was removed" in err
    assert not (tmp_path / "new").exists()


@pytest.mark.slow
def test_sigterm_while_python_compiles_ends_the_process_at_once(tmp_path):
    """`aj.train` in a script under a scheduler: SIGTERM during a minutes-long compile waited for the first cycle, and
    the scheduler's SIGKILL came first. It now ends the process as the command does (SIGINT, a notebook's interrupt,
    still stops after the first cycle)."""
    script = f"import angora_jax as aj; aj.train('shadow_reach', {[*TINY, f'logging.run_root={tmp_path}']!r} + " \
             "['logging.run_name=new'])"
    process = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                               text=True)
    while "compiling the first cycle" not in (line := process.stdout.readline()):
        assert line, process.communicate()
    started = time.monotonic()
    process.send_signal(signal.SIGTERM)
    _, err = process.communicate(timeout=30)
    assert process.returncode == 128 + signal.SIGTERM and time.monotonic() - started < 10, err
    assert "Interrupted by SIGTERM before the first cycle ended" in err and not (tmp_path / "new").exists()


@pytest.mark.slow
def test_sigint_stops_a_command_started_with_sigint_ignored_as_a_scripts_background_job_is(tmp_path, reaped):
    """A script's background job starts with SIGINT ignored (bash without job control), and examples/multi_gpu_host.sh
    forwards Ctrl-C to its processes with kill -INT: training must still stop with a checkpoint. (SIGHUP ignored,
    nohup's request, is kept: the closed-terminal test.)"""
    argv = ["train", "cartpole", *TINY, "ppo.num_cycles=100000", f"logging.run_root={tmp_path}", "logging.run_name=bg"]
    start = command_with_sighup(before="signal.signal(signal.SIGINT, signal.SIG_IGN); ")
    process = reaped(subprocess.Popen([*start, *argv], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True))
    logged_while_shown(process, None, tmp_path / "bg" / "metrics.jsonl", 2)
    process.send_signal(signal.SIGINT)
    _, err = process.communicate(timeout=120)
    assert process.returncode == 128 + signal.SIGINT and "Interrupted by SIGINT" in err, err
    assert aj.load_agent(tmp_path / "bg", "latest").cycle == len(read_metrics(tmp_path / "bg")) >= 2


@pytest.mark.slow
def test_sigterm_stops_the_command_with_a_checkpoint_and_a_second_one_does_not_cut_its_save_short(tmp_path):
    """A second SIGTERM (a launcher forwarding one that the process group got too) killed the process mid-save, with no
    message, half-written checkpoints and its lock left behind, and exit 143 that says a checkpoint was saved."""
    command = [sys.executable, "-m", "angora_jax.cli", "train", "cartpole", *TINY]
    command += ["ppo.num_cycles=100000", f"logging.run_root={tmp_path}", "logging.run_name=long"]
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    logged_while_shown(process, None, tmp_path / "long" / "metrics.jsonl", 2)
    process.send_signal(signal.SIGTERM)
    time.sleep(0.1)
    process.send_signal(signal.SIGTERM)
    out, err = process.communicate(timeout=120)
    assert process.returncode == 128 + signal.SIGTERM, err
    assert "Interrupted by SIGTERM" in err and f"angora-jax resume {tmp_path / 'long'}" in err
    assert "SIGTERM again: still finishing the cycle and saving its checkpoint" in err, err
    assert not (tmp_path / "long" / "writer.lock").exists() and check_run(tmp_path / "long").problems == []
    cycles = len(read_metrics(tmp_path / "long"))
    agent = aj.load_agent(tmp_path / "long", "latest")
    assert agent.cycle == cycles >= 2


def on_a_terminal(argv: list[str], ignore_hangup: bool = False) -> tuple[subprocess.Popen, int]:
    """`angora-jax ARGV` in a session of its own whose controlling terminal, input and output are a new
    pseudo-terminal, as when typed in a terminal window or an ssh session. `ignore_hangup`: started with SIGHUP
    ignored (`nohup`, or bash's `disown -h`). Returns the process and the terminal's own end: closing that end is
    closing the window (the kernel hangs the terminal up, sends the process SIGHUP, and fails its writes to it)."""
    terminal, process_end = os.openpty()
    start = command_with_sighup("SIG_IGN" if ignore_hangup else "SIG_DFL",
                                "import fcntl, termios; fcntl.ioctl(0, termios.TIOCSCTTY, 0); ")
    process = subprocess.Popen([*start, *argv], stdin=process_end, stdout=process_end, stderr=process_end,
                               start_new_session=True)
    os.close(process_end)
    os.set_blocking(terminal, False)
    return process, terminal


def logged_while_shown(process: subprocess.Popen, terminal: int | None, metrics: Path, cycles: int) -> None:
    """Wait until METRICS holds CYCLES records, reading the terminal meanwhile (when the process writes to one) as a
    terminal window does (a terminal nobody reads fills and blocks the process's writes)."""
    deadline = time.monotonic() + 120
    while not (metrics.exists() and metrics.read_text().count("\n") >= cycles):
        assert process.poll() is None and time.monotonic() < deadline, process.communicate()
        if terminal is not None:
            with contextlib.suppress(BlockingIOError, OSError):
                os.read(terminal, 65536)
        time.sleep(0.1)


@pytest.mark.slow
def test_closing_the_terminal_stops_training_with_a_checkpoint_and_with_sighup_ignored_it_trains_on(tmp_path, reaped):
    """Closing the terminal that runs `train` (a window, a dropped ssh session) sends SIGHUP, which killed the process
    with the cycles since its last checkpoint and left its lock. It now stops after its cycle and saves, as on
    SIGTERM, though every write to the closed terminal fails. Started with SIGHUP ignored, it trains on to its end;
    the failed writes ended it before with "the disk or network file system failed" (exit 2)."""
    argv = ["train", "cartpole", *TINY, "logging.progress=bar", "ppo.num_cycles=100000", "checkpoint.every=1000",
            f"logging.run_root={tmp_path}", "logging.run_name=closed"]
    process, terminal = on_a_terminal(argv)
    reaped(process)
    logged_while_shown(process, terminal, tmp_path / "closed" / "metrics.jsonl", 2)
    os.close(terminal)
    assert process.wait(timeout=120) == 128 + signal.SIGHUP
    run = tmp_path / "closed"
    assert not (run / "writer.lock").exists() and check_run(run).problems == []
    assert aj.load_agent(run, "latest").cycle == len(read_metrics(run)) >= 2

    # Training for 9 s, of which the terminal is open for the first cycle only.
    argv = [*argv[:-2], f"logging.run_root={tmp_path}", "logging.run_name=ignored", "--minutes", "0.15"]
    process, terminal = on_a_terminal(argv, ignore_hangup=True)
    reaped(process)
    logged_while_shown(process, terminal, tmp_path / "ignored" / "metrics.jsonl", 1)
    os.close(terminal)
    closed_at = len(read_metrics(tmp_path / "ignored"))
    assert process.wait(timeout=120) == 128 + signal.SIGHUP  # its work done, its last lines lost
    cycles = len(read_metrics(tmp_path / "ignored"))
    assert cycles > closed_at + 10 and aj.load_agent(tmp_path / "ignored", "latest").cycle == cycles


class Terminal(io.StringIO):
    def isatty(self):
        return True


def metrics(cycle, seconds=0.5):
    return {
        "cycle": cycle,
        "env_steps": 2048 * cycle,
        "steps_per_second": 4096.0,
        "seconds": seconds,
        "episode_return": float("nan") if cycle == 1 else 100.0 + cycle,
        "metric/success": 0.25,
    }


def test_progress_is_a_live_line_on_a_terminal_and_log_lines_elsewhere():
    assert progress_line(metrics(2), 10, 65) == (
        "cycle 2/10  env steps 4,096  4,096 steps/s  return 102.0  success 0.250  ETA 0:01:05"
    )
    assert "return -" in progress_line(metrics(1), 10, 0)
    cube = metrics(2) | {"metric/dropped": 0.5, "metric/goals_reached": 3.0}
    assert "dropped 0.500" in progress_line(cube, 10, 0)  # the first by name
    assert "goals_reached 3.000" in progress_line(cube, 10, 0, shown="metric/goals_reached")
    assert "dropped 0.500" in progress_line(cube, 10, 0, shown="episode_return")  # not a task metric: ignored
    terminal, log = Terminal(), io.StringIO()
    for stream in (terminal, log):
        progress = Progress(10, "auto", stream)
        progress.update(metrics(1, seconds=30.0) | {"compile_seconds": 30.0})
        progress.update(metrics(2))
        progress.close()
    assert terminal.getvalue().count("\r") == 2 and terminal.getvalue().endswith("\n")
    lines = log.getvalue().splitlines()
    assert len(lines) == 2 and "\r" not in log.getvalue()
    assert lines[1].endswith("ETA 0:00:04")  # 8 cycles left at 0.5 s: the compiling first cycle is not counted



def test_a_reader_of_the_output_that_leaves_stops_neither_training_nor_its_checkpoints(tmp_path):
    """`angora-jax train ... | head -2`: the progress line after head had left raised BrokenPipeError, which ended
    training before its first checkpoint with "Broken pipe: fix the cause and retry." (exit 2). Now the run trains to
    its end and saves; the command ends as a writer that SIGPIPE ends, 141, without a word or a traceback."""

    class Gone(io.StringIO):
        def write(self, text):
            raise BrokenPipeError(errno.EPIPE, "Broken pipe")

    progress = Progress(10, "lines", Gone())
    progress.announce("compiling ...")
    progress.update(metrics(1))
    assert progress.mode == "none"
    done = subprocess.Popen([sys.executable, "-m", "angora_jax.cli", "train", "cartpole", *TINY, "ppo.num_cycles=3",
                             f"logging.run_root={tmp_path}", "logging.run_name=r"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=os.environ | QUICK_SUBPROCESS)
    done.stdout.close()  # before the command writes anything: as `| head -0`
    err = done.communicate(timeout=300)[1]
    assert done.returncode == 128 + signal.SIGPIPE and "Traceback" not in err and "Broken pipe" not in err, err
    assert len(read_metrics(tmp_path / "r")) == 3 and (tmp_path / "r" / "checkpoints" / "latest" / "3").is_dir()


@pytest.mark.slow
def test_a_second_run_reads_every_program_from_the_compilation_cache(tmp_path, monkeypatch):
    """`train` keeps compiled programs in ANGORA_JAX_CACHE: the same config run again compiles nothing (counted by
    JAX's cache events in the first cycle's record), and neither does `resume` in a new process (its state, read from
    a checkpoint, runs the fresh run's programs); ANGORA_JAX_CACHE=off, or several processes without a directory
    named, leave it off."""
    environment = {k: v for k, v in os.environ.items() if k != "JAX_COMPILATION_CACHE_DIR"}  # conftest's own cache
    cache = tmp_path / "cache"
    train = ["train", "cartpole", *TINY, "ppo.num_cycles=3", f"logging.run_root={tmp_path}"]
    for command in ([*train, "logging.run_name=first"], [*train, "logging.run_name=second", "--minutes", "1e-9"],
                    ["resume", str(tmp_path / "second")]):
        subprocess.run([sys.executable, "-m", "angora_jax.cli", *command], env=environment | {"ANGORA_JAX_CACHE": str(
            cache)}, check=True, capture_output=True, timeout=300)
    first, (second, resumed, after) = read_metrics(tmp_path / "first")[0], read_metrics(tmp_path / "second")
    assert first["compile_cache_hits"] == 0 and first["compile_cache_misses"] >= 2, "init and the cycle at least"
    assert second["compile_cache_misses"] == 0 and second["compile_cache_hits"] == first["compile_cache_misses"]
    assert resumed["cycle"] == 2 and resumed["compile_cache_misses"] == 0 and resumed["compile_cache_hits"] >= 1
    assert any(cache.iterdir())
    assert "compile_cache_hits" not in after, "the first cycle of a session only"
    ours = jax.config.jax_compilation_cache_dir  # this test process's (conftest's), which enable() would keep
    jax.config.update("jax_compilation_cache_dir", None)
    try:
        monkeypatch.setenv("ANGORA_JAX_CACHE", "off")
        assert compilation_cache.enable() is None
        monkeypatch.delenv("ANGORA_JAX_CACHE")
        monkeypatch.setattr(jax, "process_count", lambda: 2)
        assert compilation_cache.enable() is None and jax.config.jax_compilation_cache_dir is None
    finally:
        jax.config.update("jax_compilation_cache_dir", ours)


def test_the_host_launcher_without_angora_jax_on_path_or_without_gpus_exits_2_saying_what_to_do(tmp_path):
    """It ended with 'nvidia-smi: command not found' (exit 127) on a machine without NVIDIA's driver, and with
    'angora-jax: command not found' from every process outside the environment."""
    script = Path(__file__).resolve().parents[1] / "examples" / "multi_gpu_host.sh"
    no_gpu = tmp_path / "bin"
    no_gpu.mkdir()
    (no_gpu / "nvidia-smi").write_text("#!/bin/sh\necho 'NVIDIA-SMI has failed' >&2\nexit 9\n")
    (no_gpu / "nvidia-smi").chmod(0o755)
    system = "/usr/bin:/bin"
    environment = {k: v for k, v in os.environ.items() if k != "GPUS"}
    done = subprocess.run(["bash", str(script), "cartpole"], env=environment | {"PATH": system}, capture_output=True,
                          text=True, timeout=60)
    assert done.returncode == 2 and "angora-jax is not on PATH: activate the environment" in done.stderr, done.stderr
    path = f"{no_gpu}:{Path(sys.executable).parent}:{system}"
    done = subprocess.run(["bash", str(script), "cartpole"], env=environment | {"PATH": path}, capture_output=True,
                          text=True, timeout=60)
    assert done.returncode == 2 and "no NVIDIA GPU found (nvidia-smi lists none)" in done.stderr, done.stderr
    assert "Set GPUS=N to start N processes anyway" in done.stderr and "NVIDIA-SMI has failed" not in done.stderr


@pytest.mark.slow
def test_one_process_per_device_through_the_command_and_the_host_launcher(tmp_path):
    """examples/multi_gpu_host.sh starts `angora-jax train ... --distributed --coordinator --num-processes
    --process-id --local-devices` once per device (here 2 CPU processes for 2 "GPUs"): one run directory, logged by
    process 0, trained over both. Two cycles: the processes compile quickly (tests/quick_compile.py)."""
    script = Path(__file__).resolve().parents[1] / "examples" / "multi_gpu_host.sh"
    environment = os.environ | QUICK_SUBPROCESS | {"PATH": f"{Path(sys.executable).parent}:{os.environ['PATH']}",
                                                   "GPUS": "2", "RUN_NAME": "two", "PORT": str(free_port())}
    tiny = [*TINY, "ppo.num_envs=8", "ppo.num_cycles=2", f"logging.run_root={tmp_path}"]
    done = subprocess.run(["bash", str(script), "cartpole", *tiny], env=environment, capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    assert done.stdout.count("cycle 2/2") == 1, "process 0 alone logs"
    assert [record["cycle"] for record in read_metrics(tmp_path / "two")] == [1, 2]
    session = read_sessions(tmp_path / "two")[0]
    assert session["processes"] == 2 and session["physics"]["num_devices"] == 2


@pytest.mark.slow
def test_seeds_of_one_config_run_as_one_single_device_run_each(tmp_path):
    """examples/seeds_one_per_gpu.sh with 3 seeds on 2 "GPUs": seed i trains as <name>-seed<i> with ppo.seed=i, the
    third waiting for the first's GPU; every run is an ordinary run that finished its cycles."""
    script = Path(__file__).resolve().parents[1] / "examples" / "seeds_one_per_gpu.sh"
    environment = os.environ | QUICK_SUBPROCESS | {"PATH": f"{Path(sys.executable).parent}:{os.environ['PATH']}",
                                                   "GPUS": "2", "SEEDS_FROM": "5"}
    tiny = [*TINY, "ppo.num_cycles=1", "logging.progress=none", f"logging.run_root={tmp_path}"]
    done = subprocess.run(["bash", str(script), "cartpole", "3", *tiny], env=environment, capture_output=True,
                          text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    for seed in (5, 6, 7):
        run = tmp_path / f"cartpole-seed{seed}"
        assert load_config(run / "config.yaml").ppo.seed == seed
        assert [record["cycle"] for record in read_metrics(run)] == [1]


CURRICULUM = Path(__file__).resolve().parents[1] / "examples" / "myohand_pose_curriculum.sh"
# MyoHandPose shrunk for the CPU: MuJoCo Warp, 4 hands, 4-step episodes (so a cycle of 8 steps ends episodes and the
# best checkpoint by success exists), one cycle per stage, a 16-unit MLP.
TINY_POSE = ["env.options.physics={impl: warp}", "env.options.max_episode_steps=4", "ppo.num_cycles=1",
             "ppo.num_envs=4", "ppo.rollout_length=8", "ppo.chunk_length=8", "ppo.minibatch_size=16",
             "ppo.num_epochs=1", "ppo.network.width=16", "checkpoint.snapshot_every=0", "logging.progress=none",
             "logging.report=false"]


def run_curriculum(arguments: list[str], cwd: Path, path: str, **environment: str) -> subprocess.CompletedProcess:
    """examples/myohand_pose_curriculum.sh with `arguments`, its commands found on `path` first."""
    environment = os.environ | environment | {"PATH": f"{path}:{os.environ['PATH']}"}
    return subprocess.run([shutil.which("bash"), str(CURRICULUM), *arguments], cwd=cwd, env=environment,
                          capture_output=True, text=True, timeout=600)


@pytest.mark.slow
def test_the_myohand_pose_curriculum_trains_two_stages_then_evaluates_records_and_analyzes(tmp_path):
    """examples/myohand_pose_curriculum.sh on the CPU, shrunk (TINY_POSE; 3 evaluation and 5 recorded episodes; 90-110
    s of CPU on 2 cores): stage 1's config.yaml holds start_spread 0.4, stage 2's 1.0 and stage 1's latest checkpoint as
    init_from; the evaluation JSON (of start_spread 1), the recording and both analyses' numbers exist, parse and are
    printed where they went. Run again on the same ROOT it exits 2 naming the existing run, and changes nothing."""
    pytest.importorskip("myo_sim")
    import xarray as xr

    root = tmp_path / "pose"
    venv = str(Path(sys.executable).parent)
    done = run_curriculum([str(root), *TINY_POSE], tmp_path, venv, EPISODES="3", RECORD_EPISODES="5",
                          **QUICK_SUBPROCESS_NO_FUSION_EMITTERS)
    assert done.returncode == 0, done.stderr[-3000:]
    first, second = (load_config(root / stage / "config.yaml") for stage in ("stage1", "stage2"))
    assert first.env.options["start_spread"] == 0.4 and first.ppo.init_from is None
    assert second.env.options["start_spread"] == 1.0 and second.ppo.init_from == f"{root / 'stage1'}:latest"
    assert [[record["cycle"] for record in read_metrics(root / stage)] for stage in ("stage1", "stage2")] == [[1], [1]]
    (evaluation,) = (root / "stage2" / "evaluation").glob("*.json")
    record = json.loads(evaluation.read_text())
    assert record["task_options"]["start_spread"] == 1.0 and len(record["per_episode"]["metric/success"]) == 3
    synergies = xr.load_dataset(root / "recording.synergies.nc")
    # Fitted until the VAF reached 90% (or one synergy per muscle): the last count fitted is the one chosen.
    assert 1 <= synergies["vaf"].sizes["count"] == synergies.attrs["count"] <= 39
    muscles = xr.load_dataset(root / "recording.muscles-or-movements.nc")
    assert set(muscles["kind_name"].values) == {"muscle", "movement"} and "control_kind_r2" in muscles
    for line in (f"evaluation (3 episodes, start_spread 1): {evaluation}",
                 f"recording (5 episodes): {root}/recording.nc", f"synergies: {root}/recording.synergies.png",
                 f"muscles or movements: {root}/recording.muscles"):
        assert line in done.stdout, line
    files = {path: path.stat().st_mtime_ns for path in root.rglob("*")}
    again = run_curriculum([str(root), *TINY_POSE], tmp_path, venv)
    assert again.returncode == 2 and f"Run directory {root / 'stage1'} already exists" in again.stderr
    assert "give another ROOT" in again.stderr
    assert {path: path.stat().st_mtime_ns for path in root.rglob("*")} == files


@pytest.mark.parametrize(("arguments", "environment", "message"), [
    ([], {}, "give ROOT, the folder for the two runs and the results, first"),
    (["ppo.seed=1"], {}, "give ROOT"),
    (["runs/pose"], {"STAGE2_MINUTES": "abc"}, "STAGE2_MINUTES=abc is not a positive number of minutes"),
    (["runs/pose"], {"STAGE1_MINUTES": "0.0"}, "STAGE1_MINUTES=0.0 is not a positive number of minutes"),
    (["runs/pose"], {"EPISODES": "0"}, "EPISODES=0 is not a positive whole number of episodes"),
    (["runs/pose"], {"RECORD_EPISODES": "4"}, "5 folds; give at least 5"),
    (["runs/pose"], {"CHECKPOINT": "worst"}, "CHECKPOINT=worst: give best, latest or a cycle number"),
    (["runs/pose", "ppo.seed=1", "env.options.start_spread=0.3"], {}, "start_spread as SPREAD=..."),
    (["runs/pose", "logging.run_root=elsewhere"], {}, "the place as ROOT."),
])
def test_the_curriculum_scripts_argument_errors_exit_2_before_anything_runs(arguments, environment, message, tmp_path):
    """The fast counterpart of the curriculum's run: each wrong argument exits 2 naming it, and no `angora-jax`
    command starts (a stand-in on PATH would leave a mark)."""
    stand_in = tmp_path / "bin" / "angora-jax"
    stand_in.parent.mkdir()
    stand_in.write_text(f"#!/bin/sh\ntouch {tmp_path}/ran\n")
    stand_in.chmod(0o755)
    done = run_curriculum(arguments, tmp_path, str(stand_in.parent), **environment)
    assert done.returncode == 2 and message in done.stderr and "usage:" in done.stderr, done.stderr
    assert not (tmp_path / "ran").exists() and not (tmp_path / "runs").exists()


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("localhost", 0))
        return probe.getsockname()[1]


@pytest.mark.slow
def test_a_gpu_sized_config_started_without_a_gpu_says_so_before_compiling(capsys, tmp_path, monkeypatch):
    """`angora-jax train shadow_ihom` on a CPU: before anything compiles, the note gives the env steps per cycle, the
    time per cycle at the CPU rate measured for the cube, and an override that makes a valid CPU-sized run."""

    def compile_nothing(*args, **kwargs):
        raise RuntimeError("stopped before compiling")

    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(runner, "training_cycles", compile_nothing)
    with pytest.raises(RuntimeError, match="stopped before compiling"):
        runner.train("shadow_ihom", ["logging.progress=lines"])
    out = capsys.readouterr().out
    assert "Note: no GPU found, and this config is sized for one: 16,384 envs x 16 steps = 262,144 env steps" in out
    assert out.index("Note: no GPU found") < out.index("compiling the first cycle"), "the note first: said before"
    assert "about 1.7 hours per cycle (138 days for its 2,000 cycles) at the 44 env steps/s" in out
    assert "compiling the first cycle adds about a minute" in out, "a newcomer waited a minute it did not mention"
    reach = load_config("shadow_reach_cortical")  # 38 s a cycle, but 1.6 hours in all: said too
    assert "(1.6 hours for its 150 cycles)" in cpu_note(reach, {"engine": "MuJoCo MJX (JAX implementation)"}, False)
    override = re.search(r"For a CPU run, add: (.*?);", out).group(1).split()
    assert override == ["ppo.num_envs=32", "ppo.minibatch_size=128"], "at most 32 (cpu_sizing.CPU_ENVS)"
    validate(load_config("shadow_ihom", override))
    assert cpu_note(load_config("shadow_ihom", override), {"engine": "MuJoCo MJX (JAX implementation)"}, False) is None
    assert cpu_note(load_config("shadow_ihom"), {"engine": "MuJoCo MJX (MuJoCo Warp implementation)"}, True) is None
    assert cpu_note(load_config("cartpole", ["ppo.num_envs=100000"]), {"engine": "pure JAX"}, False) is None


@pytest.mark.parametrize("override, message", [
    ("ppo.init_from={gone}", "ppo.init_from='{gone}': '{gone}' is neither a file nor a run directory: it does not "
                             "exist. Give a component file, or a run as RUN_DIR[:best|latest|<cycle>]."),
    ("ppo.network.frozen=[network.policy_trunc]", "did you mean 'network.policy_trunk'?"),
])
def test_config_show_checks_the_saved_sources_as_train_does(override, message, capsys, tmp_path):
    """`config show` ran `validate` but not the sources' check that `train` makes next: a missing ppo.init_from or a
    misspelt frozen module printed the config and exit 0, and the job failed only when it started."""
    gone = tmp_path / "no_such_run"
    assert main(["config", "show", "cartpole", override.format(gone=gone)]) == 2
    captured = capsys.readouterr()
    assert captured.out == "" and message.format(gone=gone) in captured.err and "Traceback" not in captured.err


@pytest.mark.slow
def test_config_show_prints_the_resolved_config_a_run_would_use(capsys, tmp_path):
    """`config show` prints every key of the resolved config as YAML that trains the same run when saved, and a bad
    override gets the same exit 2 and message as `train`."""
    assert main(["config", "show", "shadow_ihom_4gpu", "ppo.seed=3"]) == 0
    shown = capsys.readouterr().out
    assert shown.startswith("# shadow_ihom_4gpu ppo.seed=3: what `angora-jax train` would use\n")
    assert "  rollout_length: 16\n" in shown and "  seed: 3\n" in shown and "extends" not in shown
    (tmp_path / "shown.yaml").write_text(shown)
    assert load_config(tmp_path / "shown.yaml") == load_config("shadow_ihom_4gpu", ["ppo.seed=3"])
    assert main(["config", "show", "cartpole", "ppo.gama=1"]) == 2
    assert "Unknown key 'ppo.gama'. Did you mean 'ppo.gamma'?" in capsys.readouterr().err
    assert main(["config", "reference"]) == 0
    assert capsys.readouterr().out == reference_markdown()
