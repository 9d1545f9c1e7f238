"""Smoke runs of the throughput and probing benchmark scripts at tiny sizes on the CPU, each in this process through
its `main(argv)`, writing its JSON into the test's folder. Each checks what the results file must hold (device,
versions, config) and what a broken script would violate: rates that are positive and divide as the table says
(sim-s/s = steps/s x timestep, ratios of rates measured in the same run), identical episodes across settings,
rows that did not fail, a robustness width of 0 that is the unrandomized evaluation. The MJX scripts run MuJoCo Warp's
CPU kernels, whose compiles are seconds where MJX's JAX implementation takes a minute per program on 2 cores;
evaluation_speed reads the session's `cortical_reach` run, robustness a reach run of one tiny cycle.
probe_trained's smoke run is in tests/test_analysis.py, after the tests whose programs it runs again. (A file of its
own, apart from tests/test_benchmarks.py's pure-JAX scripts: pytest-xdist gives each file to one worker, so the two
spread over CI's 2 cores.)"""

import json
import sys

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from benchmark_results import BENCHMARKS, results
from quick_compile import QUICK_SUBPROCESS_NO_FUSION_EMITTERS
from tiny import TINY_PPO

import angora_jax as aj
from angora_jax.envs.registry import make
from angora_jax.envs.shadow_hand import REACH_PHYSICS
from angora_jax.experiment.config import load_config
from angora_jax.experiment.evaluation import evaluate
from angora_jax.nets.visual import make_visual_encoder
from angora_jax.vision import PoseEstimator, PoseNet

sys.path.insert(0, str(BENCHMARKS))
import cell_unroll  # noqa: E402
import env_throughput  # noqa: E402
import evaluation_speed  # noqa: E402
import physics_throughput  # noqa: E402
import probe_estimator  # noqa: E402
import render_throughput  # noqa: E402
import robustness  # noqa: E402
import train_throughput  # noqa: E402

WARP = '{"physics": {"impl": "warp"}}'
REACH_FRAME_SKIP = 4  # 0.02 s per policy step of 5 ms physics steps


@pytest.mark.slow
def test_train_throughput_divides_the_training_rate_by_the_env_rate_of_the_same_batch(tmp_path):
    out = tmp_path / "train.json"
    train_throughput.main(["--task", "CartPole", "--num-envs", "4", "--model", "simple", "--rollout-length", "4",
                           "--chunk-length", "4", "--epochs", "1", "--minibatches", "2", "--repeats", "1",
                           "--out", str(out)])
    record = results(out, "train_throughput")
    dt = make("CartPole").dt
    assert record["config"]["control_dt_s"] == dt and record["config"]["args"]["num_envs"] == [4]
    (row,) = record["results"]
    assert (row["task"], row["model"], row["num_envs"], row["vision"]) == ("CartPole", "simple", 4, "pose")
    assert row["config"]["minibatch_size"] == 8 and row["config"]["rollout_length"] == 4
    assert row["raw_env_steps_per_s"] > 0 and row["train_env_steps_per_s"] > 0 and row["train_compile_s"] > 0
    assert row["train_sim_s_per_s"] == pytest.approx(row["train_env_steps_per_s"] * dt)
    assert row["train_over_raw"] == pytest.approx(row["train_env_steps_per_s"] / row["raw_env_steps_per_s"])
    assert row["train_frames_per_s"] == 0, "no cameras"


@pytest.mark.slow
def test_cell_unroll_times_one_recurrent_config_looped_and_unrolled(tmp_path, quick_compiles):
    """Both ways of running a tiny GRU's cell over its 8-step chunks, the CPU's (the loop) marked as this device's,
    the rates and ratios as the table says."""
    out = tmp_path / "unroll.json"
    cell_unroll.main(["cartpole", *TINY_PPO, "ppo.network.name=gru", "ppo.network.width=8", "ppo.network.cell_size=8",
                      "--repeats", "1", "--out", str(out)])
    record = results(out, "cell_unroll")
    loop, unrolled = record["results"]
    assert (loop["way"], loop["this_device_runs"], unrolled["way"], unrolled["this_device_runs"]) == (
        "loop", True, "unrolled", False)
    assert record["config"]["resolved"]["ppo"]["network"]["name"] == "gru"
    dt = make("CartPole").dt
    for row in (loop, unrolled):
        assert row["compile_s"] > 0 and row["env_steps_per_s"] == pytest.approx(4 * 16 / row["cycle_s"])
        assert row["sim_s_per_s"] == pytest.approx(row["env_steps_per_s"] * dt)
    for name in ("compile_s", "cycle_s"):
        assert unrolled[f"{name}_over_loop"] == pytest.approx(unrolled[name] / loop[name])


@pytest.mark.slow
def test_train_throughput_trains_shipped_configs_as_they_are(tmp_path, monkeypatch):
    """`--configs`: each config's own network, rollout and minibatch share, at the given batch size; with several
    configs or sizes, each measured in its own process, all rows in one file in order. Those processes time one
    cycle each, so they compile quickly, XLA's CPU fusion emitters off (tests/quick_compile.py; they set no XLA_FLAGS
    of their own)."""
    for name, value in QUICK_SUBPROCESS_NO_FUSION_EMITTERS.items():
        monkeypatch.setenv(name, value)
    out = tmp_path / "configs.json"
    train_throughput.main(["--configs", "cartpole", "--num-envs", "4", "8", "--repeats", "1", "--out", str(out)])
    rows = results(out, "train_throughput")["results"]
    assert [(row["task"], row["model"], row["num_envs"]) for row in rows] == [
        ("CartPole", "cartpole", 4), ("CartPole", "cartpole", 8)]
    shipped = load_config("cartpole").ppo
    for row, envs in zip(rows, [4, 8], strict=True):
        assert row["config"]["network"]["name"] == shipped.network.name
        assert row["config"]["rollout_length"] == shipped.rollout_length
        assert row["config"]["minibatch_size"] == envs * shipped.minibatch_size // shipped.num_envs
        assert row["train_env_steps_per_s"] > 0 and row["control_dt_s"] == make("CartPole").dt


@pytest.mark.slow
def test_env_throughput_counts_physics_steps_and_compares_rates_of_the_same_run(tmp_path):
    out = tmp_path / "env.json"
    env_throughput.main(["--task", "ShadowHandReach", "--options", WARP, "--batch-sizes", "2", "--steps", "2",
                         "--repeats", "1", "--c-seconds", "0.2", "--out", str(out)])
    record = results(out, "env_throughput")
    config = record["config"]
    assert config["options"] == json.loads(WARP) and config["steps"] == 2
    assert (config["timestep_s"], config["frame_skip"]) == (REACH_PHYSICS.timestep, REACH_FRAME_SKIP)
    assert config["control_dt_s"] == pytest.approx(config["frame_skip"] * config["timestep_s"])
    assert config["c_mujoco_physics_steps_per_s"] > 0 and config["cpu_twin_physics_steps_per_s"] > 0
    (row,) = record["results"]
    assert row["batch"] == 2 and row["env_steps_per_s"] > 0 and row["raw_mjx_physics_steps_per_s"] > 0
    assert row["compile_s"] > 0 and row["raw_mjx_compile_s"] > 0
    assert row["physics_steps_per_s"] == pytest.approx(row["env_steps_per_s"] * REACH_FRAME_SKIP)
    assert row["sim_s_per_s"] == pytest.approx(row["physics_steps_per_s"] * REACH_PHYSICS.timestep)
    assert row["ours_over_raw_mjx"] == pytest.approx(row["physics_steps_per_s"] / row["raw_mjx_physics_steps_per_s"])
    assert row["ours_over_c_mujoco_1_thread"] == pytest.approx(
        row["physics_steps_per_s"] / config["c_mujoco_physics_steps_per_s"])


@pytest.mark.slow
def test_physics_throughput_measures_in_a_worker_and_checks_the_tuned_scene_against_the_stock_one(tmp_path):
    out = tmp_path / "physics.json"
    physics_throughput.main(["--configs", "reach-tuned", "--impls", "warp", "--warp-configs", "reach-tuned",
                             "--batch-sizes", "1", "--policy-steps", "1", "--repeats", "1", "--fidelity-steps", "2",
                             "--out", str(out)])
    record = results(out, "physics_throughput")
    assert record["config"]["configs"] == ["reach-tuned"] and record["config"]["scenes"] == {"reach-tuned": "reach"}
    (row,) = record["results"]
    assert "status" not in row, f"the worker failed: {row.get('status')}"
    assert (row["config"], row["impl"], row["batch"]) == ("reach-tuned", "warp", 1)
    assert (row["timestep_ms"], row["frame_skip"]) == (1e3 * REACH_PHYSICS.timestep, REACH_FRAME_SKIP)
    assert row["policy_steps_per_s"] > 0 and row["compile_s"] > 0 and row["setup_s"] > 0
    assert row["physics_steps_per_s"] == pytest.approx(row["policy_steps_per_s"] * REACH_FRAME_SKIP)
    assert row["sim_s_per_s"] == pytest.approx(row["physics_steps_per_s"] * REACH_PHYSICS.timestep)
    assert row["contacts"] > 0 and row["constraint_rows"] > 0 and row["data_kib_per_env"] > 0
    # 5 ms steps and pruned contacts move the fingertips other than Gym's 2 ms scene does, by millimetres
    assert 0 < row["tip_error_mean_mm"] <= row["tip_error_max_mm"] < 50


@pytest.mark.slow
def test_render_throughput_renders_every_camera_and_compares_the_frames_with_mujocos_renderer(tmp_path, opengl):
    out, saved = tmp_path / "render.json", tmp_path / "frames.npz"
    cameras = ("front", "top")
    render_throughput.main(["--envs", "1", "--sizes", "8", "--cameras", *cameras, "--steps", "1", "--out", str(out),
                            "--save-frames", str(saved)])
    record = results(out, "render_throughput")
    config = record["config"]
    assert config["cameras"] == list(cameras) and config["frame_skip"] * config["timestep"] == pytest.approx(0.08)
    bare, rendered = record["results"]
    assert (bare["render"], bare["size"], bare["frames_per_s"]) == (False, 0, 0.0)
    assert (rendered["render"], rendered["size"]) == (True, 8)
    for row in (bare, rendered):
        assert row["policy_steps_per_s"] == pytest.approx(1 / row["seconds"])
        assert row["sim_s_per_s"] == pytest.approx(row["policy_steps_per_s"] * 0.08)
    assert rendered["frames_per_s"] == pytest.approx(2 * rendered["policy_steps_per_s"]), "one frame per camera"
    # The comparison is of the frames the run rendered, and it measures a difference: MuJoCo's own frames of the same
    # states score zero. (Warp's score high: it draws no skybox and an untextured hand; README, 89-91% at 32-96 px.)
    frames, qpos = np.load(saved)["frames_8"], np.load(saved)["qpos_8"]
    assert frames.shape == (1, 2, 8, 8, 3) and frames.any(), "Warp drew something"
    model = render_throughput.load_cube_scene(touch=False, cameras=cameras)
    assert render_throughput.compare_frames(model, qpos, frames, cameras) == {
        key: rendered[key] for key in ("pixels_differing_over_16", "mean_abs_difference")}
    data = mujoco.MjData(model)
    data.qpos[:] = qpos[0]
    mujoco.mj_forward(model, data)
    with mujoco.Renderer(model, 8, 8) as renderer:
        own = []
        for name in cameras:
            renderer.update_scene(data, render_throughput.VISION_PREFIX + name)
            own.append(renderer.render())
    assert render_throughput.compare_frames(model, qpos, np.stack(own)[None], cameras) == {
        "pixels_differing_over_16": 0.0, "mean_abs_difference": 0.0}


def test_evaluation_speed_gets_the_same_episodes_from_every_batch_and_worker_setting(tmp_path, cortical_reach):
    out = tmp_path / "evaluation.json"
    evaluation_speed.main([str(cortical_reach.run_dir), "--episodes", "4", "--settings", "1x1", "2x2",
                           "--repeats", "1", "--out", str(out)])
    record = results(out, "evaluation_speed_ShadowHandReach")
    config = record["config"]
    assert (config["task"], config["network"], config["episodes"]) == ("ShadowHandReach", "cortical", 4)
    assert 0 < config["mean_episode_length"] <= 30
    first, second = record["results"]
    assert [(row["batch"], row["workers"]) for row in (first, second)] == [(1, 1), (2, 2)]
    assert first["identical"] and second["identical"], "a batch or thread count changed an episode"
    assert first["speedup"] == 1.0 and second["speedup"] == pytest.approx(first["seconds"] / second["seconds"])
    for row in (first, second):
        assert row["episodes_per_s"] == pytest.approx(4 / row["seconds"])
        assert row["env_steps_per_s"] == pytest.approx(row["episodes_per_s"] * config["mean_episode_length"])


@pytest.mark.slow
def test_robustness_scales_the_ranges_by_width_and_width_0_is_the_unrandomized_evaluation(tmp_path, quick_compiles):
    """A reach run of one tiny cycle (Warp) evaluated at widths 0 and 1 of reference ranges that hold a cube key (left
    out for reach): width 0 gives zero-width ranges and the unrandomized batched evaluation's episodes exactly, width 1
    the reference ranges and other episodes; the JSON names the metric, ranges and runs, and the plot is written.
    `--each` then evaluates each range alone."""
    run = aj.train("shadow_reach", [*TINY_PPO, "ppo.num_cycles=1", "env.options.physics={impl: warp}",
                                    "env.options.max_episode_steps=20", "logging.progress=none",
                                    "logging.report=false", "checkpoint.best_metric=null",
                                    f"logging.run_root={tmp_path}", "logging.run_name=reach"]).run_dir
    reference = {"friction": [0.5, 1.5], "actuator_gain": [0.2, 1.0], "observation_noise": 0.01}
    out = tmp_path / "robustness.json"
    record = robustness.main([f"{run}:latest", "--label", "tiny", "--widths", "0", "1", "--episodes", "3",
                              "--ranges", json.dumps({**reference, "cube_mass": [0.5, 1.5]}), "--out", str(out)])
    assert record == results(out, "robustness_ShadowHandReach")
    config = record["config"]
    assert (config["metric"], config["widths"], config["episodes"]) == ("metric/success", [0.0, 1.0], 3)
    assert config["reference_ranges"] == reference and config["runs"][0]["checkpoint"] == "latest"
    zero, one = record["results"]
    assert (zero["run"], zero["width"], one["width"]) == ("tiny", 0.0, 1.0)
    assert zero["ranges"] == {"friction": [1.0, 1.0], "actuator_gain": [1.0, 1.0], "observation_noise": 0.0}
    assert one["ranges"] == reference
    plain = evaluate(run, "latest", episodes=3, save=False, path="batched")
    assert zero["per_episode"] == plain.episodes["metric/success"].tolist()
    assert zero["per_episode_return"] == plain.episodes["episode_return"].tolist()
    assert (zero["return_mean"], zero["mean"]) == (plain.summary["episode_return"]["mean"],
                                                   plain.summary["metric/success"]["mean"])
    assert one["return_mean"] != zero["return_mean"], "width 1 evaluated the unrandomized task"
    assert out.with_suffix(".png").stat().st_size > 0
    # --each adds each range alone, the others off: friction alone is another world than all three together.
    each = robustness.main([f"{run}:latest", "--label", "tiny", "--widths", "1", "--episodes", "3", "--each",
                            "--ranges", json.dumps(reference), "--out", str(tmp_path / "each.json")])["results"]
    assert [(row["run"], row["only"], row["ranges"]) for row in each] == [
        ("tiny", None, reference), *((f"tiny ({key} only)", key, {key: value}) for key, value in reference.items())]
    assert each[0]["per_episode_return"] == one["per_episode_return"]
    assert each[1]["return_mean"] != one["return_mean"], "friction alone evaluated all the ranges"
    # Past width 1 a minimum is clipped: at 0, or above 0 for the cube's mass.
    assert robustness.scaled({"cube_mass": [0.5, 1.5], "friction": [0.3, 1.3], "action_noise": 0.1,
                              "action_delay": [1, 3]}, 2) == {
        "cube_mass": [robustness.POSITIVE_FLOOR, 2.0], "friction": [0.0, pytest.approx(1.6)], "action_noise": 0.2,
        "action_delay": [2, 6]}
    assert robustness.scaled({"action_delay": [1, 3], "cube_size": [0.95, 1.05]}, 0) == {
        "action_delay": [0, 0], "cube_size": [1.0, 1.0]}


@pytest.mark.slow
def test_probe_estimator_measures_saliency_on_the_cube_against_the_cubes_share_of_pixels(tmp_path, quick_compiles):
    """A tiny estimator with its initial weights (two 32 x 32 cameras) and two poses whose cube is a square: each
    camera's row per measure holds shares of saliency between 0 and 1, the square's share of pixels as chance, and
    the figures exist. Its few hundred programs each run once or twice on two frames: they compile quickly."""
    options, cameras = {"widths": (4, 4, 4, 4), "features": 6}, ("front", "top")
    network = PoseNet(make_visual_encoder("cornet_z", **options))
    params = network.init(jax.random.key(0), jnp.zeros((1, 2, 32, 32, 3), jnp.uint8))["params"]
    estimator = PoseEstimator(params, "cornet_z", options, "6d", cameras, 32, np.zeros(3), np.ones(3)).save(
        tmp_path / "tiny.pose.msgpack")
    no_cube = np.random.default_rng(0).integers(0, 256, (2, 2, 32, 32, 3), dtype=np.uint8)
    images = no_cube.copy()
    images[:, :, 8:16, 8:12] = np.where(no_cube[:, :, 8:16, 8:12] < 128, 255, 0)  # an 8 x 4 "cube"
    np.savez(tmp_path / "frames.npz", images=images, no_cube=no_cube)
    probe_estimator.main([str(estimator), "--frames", str(tmp_path / "frames.npz"), "--analysis-frames", "1",
                          "--units", "1", "--ascent-steps", "2", "--name", "tiny", "--out-dir", str(tmp_path)])
    record = results(tmp_path / "tiny_cpu.json", "tiny")
    config = record["config"]
    assert config["estimator_config"]["cameras"] == list(cameras) and config["summary"]["poses"] == 2
    rows = record["results"]
    assert [(row["camera"], row["measure"]) for row in rows] == [
        (camera, measure) for measure in ("orientation saliency", "position saliency", "IT mean map")
        for camera in cameras]
    for row in rows:
        assert row["cube_pixels"] == 32 / 32**2 and row["edge_pixels"] == 20 / 32**2
        assert 0 < row["edge_share"] < row["cube_share"] < 1
        assert row["cube_over_chance"] == pytest.approx(row["cube_share"] / row["cube_pixels"])
    for figure in ("tiny_visual.png", "tiny_saliency.png"):
        assert (tmp_path / figure).read_bytes()[:4] == b"\x89PNG"
