"""The `angora-jax` command: exit codes, messages, SIGTERM on a real process, and the progress display."""

import io
import signal
import subprocess
import sys
import time

import pytest
from tiny import TINY_PPO

import angora_jax as aj
from angora_jax import cli
from angora_jax.cli import main
from angora_jax.experiment.distributed import ProcessFailed
from angora_jax.experiment.monitor import read_metrics
from angora_jax.experiment.progress import Progress, progress_line

TINY = [
    *TINY_PPO,
    "logging.progress=lines",
    "logging.report=false",
]


def test_list_commands(capsys):
    assert main(["list-tasks"]) == 0
    assert "CartPole" in capsys.readouterr().out.split()
    assert main(["list-models"]) == 0
    out = capsys.readouterr().out
    assert "lstm" in out and "beta" in out


@pytest.mark.parametrize(
    "argv, message",
    [
        (["train", "cartpole", "ppo.gama=0.9"], "Unknown key 'ppo.gama'"),
        (["train", "cartpole", "ppo.head=beta"], "needs continuous actions"),
        (["train", "no-such-config"], "not found"),
        (["resume", "no/such/run"], "not a run directory"),
        (["evaluate", "no/such/run"], "not a run directory"),
        (["report", "no/such/run"], "not a run directory"),
    ],
)
def test_bad_input_exits_2_with_the_cause(argv, message, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "runs").exists() or not any((tmp_path / "runs").iterdir())


def test_another_process_failing_exits_1_with_the_message_not_a_traceback(capsys, tmp_path, monkeypatch):
    def fail(config, overrides, minutes=None):
        raise ProcessFailed((1,), 3, tmp_path / "run")

    monkeypatch.setattr(cli, "train", fail)
    assert main(["train", "cartpole"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("angora-jax train: Process(es) 1 of this run failed after cycle 3")
    assert "Traceback" not in err and f"angora-jax resume {tmp_path / 'run'} --distributed" in err


def test_overrides_may_follow_the_options_and_other_strays_are_usage_errors(capsys, monkeypatch):
    seen = []
    monkeypatch.setattr(cli, "train", lambda config, overrides, minutes: seen.append((config, overrides)) or "run")
    monkeypatch.setattr(cli, "print_finished", lambda run: None)
    assert main(["train", "cartpole", "ppo.seed=1", "--coordinator", "localhost:1", "ppo.num_envs=8"]) == 0
    assert seen == [("cartpole", ["ppo.seed=1", "ppo.num_envs=8"])]
    with pytest.raises(SystemExit) as stop:
        main(["train", "cartpole", "--coordinator", "localhost:1", "stray"])
    assert stop.value.code == 2 and "unrecognized arguments: stray" in capsys.readouterr().err


@pytest.mark.parametrize("command", ["evaluate", "render"])
def test_episode_count_below_one_is_a_usage_error(command, capsys):
    with pytest.raises(SystemExit) as stop:
        main([command, "no/such/run", "--episodes", "0"])
    assert stop.value.code == 2
    assert "--episodes" in capsys.readouterr().err


def test_train_then_evaluate_exit_0(capsys, tmp_path):
    argv = ["train", "cartpole", *TINY, "ppo.num_cycles=3", f"logging.run_root={tmp_path}", "logging.run_name=r"]
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert "cycle 3/3" in out and "Run " in out and "angora-jax evaluate" in out
    assert main(["evaluate", str(tmp_path / "r"), "--checkpoint", "latest", "--num-envs", "2"]) == 0
    assert "episode_return" in capsys.readouterr().out
    assert main(argv) == 2  # the run directory exists: refused, untouched
    assert "already exists" in capsys.readouterr().err


def test_minutes_stop_training_with_the_command_to_continue(capsys, tmp_path):
    argv = ["train", "cartpole", *TINY, "ppo.num_cycles=3", f"logging.run_root={tmp_path}", "logging.run_name=p"]
    assert main([*argv, "--minutes", "1e-9"]) == 0
    out = capsys.readouterr().out
    assert "cycle 1/3" in out and "cycle 2/3" not in out
    assert f"Stopped at the time limit (--minutes) with a checkpoint of cycle 1; continue with: angora-jax resume " \
           f"{tmp_path / 'p'}" in out
    assert [r["cycle"] for r in read_metrics(tmp_path / "p")] == [1]  # resuming is tests/test_checkpoint.py's
    with pytest.raises(SystemExit) as exit_info:
        main(["resume", str(tmp_path / "p"), "--minutes", "0"])
    assert exit_info.value.code == 2 and "--minutes: must be > 0" in capsys.readouterr().err


def test_sigterm_stops_the_command_with_a_checkpoint(tmp_path):
    command = [sys.executable, "-m", "angora_jax.cli", "train", "cartpole", *TINY]
    command += ["ppo.num_cycles=100000", f"logging.run_root={tmp_path}", "logging.run_name=long"]
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    metrics = tmp_path / "long" / "metrics.jsonl"
    deadline = time.monotonic() + 120
    while not (metrics.exists() and metrics.read_text().count("\n") >= 2):
        assert process.poll() is None and time.monotonic() < deadline, process.communicate()
        time.sleep(0.2)
    process.send_signal(signal.SIGTERM)
    out, err = process.communicate(timeout=120)
    assert process.returncode == 128 + signal.SIGTERM, err
    assert "Interrupted by SIGTERM" in err and f"angora-jax resume {tmp_path / 'long'}" in err
    cycles = len(read_metrics(tmp_path / "long"))
    agent = aj.load_agent(tmp_path / "long", "latest")
    assert agent.cycle == cycles >= 2


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

