"""Evaluation on the eager CPU path (statistics, JSON, box plot, clear errors) and videos of MuJoCo tasks."""

import json
import shutil

import mujoco
import numpy as np
import pytest
from tiny import TINY_PPO

import angora_jax as aj
from angora_jax.cli import main
from angora_jax.envs.rendering import RenderError

PNG_MAGIC = b"\x89PNG"


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    root = tmp_path_factory.mktemp("runs")
    overrides = [*TINY_PPO, "ppo.num_cycles=20", f"logging.run_root={root}", "logging.run_name=cartpole",
                 "logging.report=false", "logging.progress=none"]
    return aj.train(aj.load_config("cartpole", overrides)).run_dir


def gl_problem() -> str | None:
    """Why MuJoCo cannot render here, or None when it can."""
    try:
        mujoco.Renderer(mujoco.MjModel.from_xml_string("<mujoco/>"), 8, 8).close()
    except Exception as error:
        return f"no OpenGL backend for MuJoCo ({error}); install libegl-mesa0 and set MUJOCO_GL=egl"
    return None


def test_evaluate_writes_statistics_json_and_box_plot_without_overwriting(run_dir):
    result = aj.evaluate(run_dir, "latest", episodes=6)
    record = json.loads(result.json_path.read_text())
    returns = np.array(record["per_episode"]["episode_return"])
    assert returns.shape == (6,) and np.all(returns >= 1)
    # CartPole pays 1 per step, so a return is the episode's length.
    assert record["per_episode"]["episode_length"] == record["per_episode"]["episode_return"]
    assert record["summary"]["episode_return"]["mean"] == pytest.approx(returns.mean())
    assert record["summary"]["episode_return"]["median"] == pytest.approx(np.median(returns))
    assert record["cycle"] == 20 and record["stochastic"] is False
    assert result.plot_path.read_bytes().startswith(PNG_MAGIC) and result.plot_path.stat().st_size > 5000
    first = result.json_path.read_text()
    again = aj.evaluate(run_dir, "latest", episodes=6)
    assert again.json_path != result.json_path and result.json_path.read_text() == first
    # Mode actions from the same keys: the same episodes again.
    assert again.episodes["episode_return"].tolist() == returns.tolist()


def test_cpu_and_batched_paths_agree_within_three_standard_errors(run_dir):
    episodes = 16
    cpu = aj.evaluate(run_dir, "latest", episodes=episodes, save=False)
    batched = aj.load_agent(run_dir, "latest").evaluate(num_envs=episodes, seed=0)
    stats = cpu.summary["episode_return"]
    # Both paths start episode i from the same key and act with the mode, so the means agree far more closely than
    # the statistical error; the bound is 3 standard errors of the CPU mean (+1 for one rounding-flipped step).
    assert abs(batched["episode_return"] - stats["mean"]) <= 3 * stats["stderr"] + 1


def test_missing_and_corrupt_checkpoints_exit_2_naming_cause_and_fix(run_dir, tmp_path, capsys):
    assert main(["evaluate", str(run_dir), "--checkpoint", "999", "--episodes", "1"]) == 2
    assert "No checkpoint 999" in capsys.readouterr().err
    corrupt = tmp_path / "corrupt"
    shutil.copytree(run_dir, corrupt, ignore=shutil.ignore_patterns("evaluation"))
    for path in (corrupt / "checkpoints" / "latest").rglob("*"):
        if path.is_file() and path.stat().st_size > 0:
            path.write_bytes(b"not a checkpoint")
    assert main(["evaluate", str(corrupt), "--checkpoint", "latest", "--episodes", "1"]) == 2
    err = capsys.readouterr().err
    assert "cannot be read" in err and "corrupt" in err and "--checkpoint" in err
    assert not (corrupt / "evaluation").exists()
    shutil.rmtree(corrupt / "checkpoints")
    assert main(["evaluate", str(corrupt), "--episodes", "1"]) == 2
    assert "saved none yet" in capsys.readouterr().err


def test_cli_evaluate_prints_statistics_and_the_files(run_dir, capsys):
    assert main(["evaluate", str(run_dir), "--checkpoint", "latest", "--episodes", "2", "--stochastic"]) == 0
    out = capsys.readouterr().out
    assert "episode_return" in out and "median" in out and "Written:" in out and "stochastic" in out


def test_render_frames_of_random_actions_differ():
    if problem := gl_problem():
        pytest.skip(problem)
    frames = aj.render_frames(task="ShadowHandReach", task_options={"max_episode_steps": 4}, camera="side")
    assert len(frames) == 5 and frames[0].shape == (240, 320, 3) and frames[0].dtype == np.uint8
    assert frames[0].std() > 10  # a scene, not a blank image
    assert not np.array_equal(frames[0], frames[-1])


def test_cli_render_writes_a_video_and_refuses_to_overwrite(run_dir, tmp_path, capsys):
    if problem := gl_problem():
        pytest.skip(problem)
    out = tmp_path / "reach.mp4"
    assert main(["render", "--task", "ShadowHandReach", "--out", str(out), "--width", "160", "--height", "120"]) == 0
    size = out.stat().st_size
    assert size > 1000
    assert main(["render", "--task", "ShadowHandReach", "--out", str(out)]) == 2
    assert "exists already" in capsys.readouterr().err and out.stat().st_size == size
    assert main(["render", str(run_dir), "--checkpoint", "latest", "--out", str(tmp_path / "cartpole.gif")]) == 2
    assert "no MuJoCo scene" in capsys.readouterr().err


def test_no_gl_backend_is_reported_with_the_package_to_install(monkeypatch):
    def fail(*args, **kwargs):
        raise mujoco.FatalError("gladLoadGL error")

    monkeypatch.setattr(mujoco, "Renderer", fail)
    with pytest.raises(RenderError, match="libegl-mesa0.*MUJOCO_GL=egl.*libosmesa6"):
        aj.render_frames(task="ShadowHandReach", task_options={"max_episode_steps": 1})
