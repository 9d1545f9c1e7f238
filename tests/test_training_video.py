"""Videos of the policy during training (`evaluation.video`): written on the cycles due, from the parameters in
memory, shown in the run's report, and refused before anything compiles where they cannot be made."""

import imageio.v3 as iio
import numpy as np
import pytest
from tiny import TINY_PPO

import angora_jax as aj
from angora_jax.experiment.config import ConfigError, validate
from angora_jax.experiment.run_dir import latest_video
from angora_jax.experiment.training_video import training_videos


@pytest.mark.slow
def test_a_run_writes_a_video_on_each_due_cycle_and_its_report_shows_the_latest(tmp_path, opengl, quick_compiles):
    """InvertedPendulum on MJX (the cheapest MuJoCo scene to compile), 3 cycles, a video every 2: cycles 2 and 3
    (the last) get one, each the reset frame plus `steps` frames (the pole stands that long); the last one is the
    episode that `render_frames` plays from the run's checkpoint of that cycle; a cycle's second video (a resumed
    run repeats the cycles after its checkpoint) is written beside the first and is then the latest."""
    video = "{every: 2, steps: 3, camera: side, width: 32, height: 24}"
    overrides = [*TINY_PPO, "env.task=InvertedPendulum", "ppo.num_cycles=3", f"evaluation.video={video}",
                 "evaluation.seed=5", "checkpoint.every=1", f"logging.run_root={tmp_path}", "logging.run_name=pole",
                 "logging.progress=none"]
    run = aj.train("locomotion", overrides)
    videos = sorted(p.name for p in (run.run_dir / "videos").iterdir())
    assert videos == ["cycle_000002.gif", "cycle_000003.gif"]
    last = iio.imread(run.run_dir / "videos" / "cycle_000003.gif")
    assert last.shape == (4, 24, 32, 3)
    frames = aj.render_frames(run.run_dir, checkpoint="latest", camera="side", width=32, height=24, seed=5)
    np.testing.assert_array_equal(last, np.stack(frames[:4]))
    page = (run.run_dir / "report" / "index.html").read_text()
    assert '<img src="../videos/cycle_000003.gif"' in page and "cycle_000002" not in page

    again = training_videos(aj.load_agent(run.run_dir).config, run.run_dir)(run.state)
    assert again.name == "cycle_000003-2.gif" == latest_video(run.run_dir).name
    np.testing.assert_array_equal(iio.imread(again), last)


@pytest.mark.parametrize("setting, message", [
    ("{every: 0}", r"evaluation.video.every must be >= 1, got 0"),
    ("{camera: behind}", r"'behind' for evaluation.video.camera. Allowed cameras: front, side"),
    ("{steps: -3}", r"evaluation.video.steps must be >= 1"),
])
def test_a_bad_video_section_is_refused_naming_the_key(setting, message):
    with pytest.raises(ConfigError, match=message):
        validate(aj.load_config("locomotion", ["env.task=InvertedPendulum", f"evaluation.video={setting}"]))


def test_a_run_without_a_video_section_renders_nothing(tmp_path):
    """The fast tier's check of the training videos (the run above is in the slow tier): no section, no renderer."""
    assert training_videos(aj.load_config("locomotion", ["env.task=InvertedPendulum"]), tmp_path) is None
    assert not (tmp_path / "videos").exists()


def test_a_task_without_a_scene_gets_no_video_and_is_told_so():
    with pytest.raises(ConfigError, match=r"evaluation.video needs a MuJoCo task.*CartPole.*evaluation.video=null"):
        validate(aj.load_config("cartpole", ["evaluation.video={}"]))
