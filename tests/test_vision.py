"""Vision: renders of hand and cube poses (shape, dtype, determinism, the cube's pixels follow the cube), every
visual encoder's output, and pose pretraining end to end (its loss falls; the encoder is saved as a component)."""

import dataclasses
import importlib.util
import json

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from angora_jax.cli import main
from angora_jax.experiment.config import ConfigError
from angora_jax.nets.components import load_component
from angora_jax.nets.visual import VISUAL_ENCODERS, make_visual_encoder
from angora_jax.vision import PoseEstimator, PoseRenderer, pretrain_pose_encoder, render_pose_dataset
from angora_jax.vision.dataset import CUBE_REST, random_quaternions
from angora_jax.vision.estimator import orientation_error_degrees, quaternions, rotation_matrices

FAR = np.array([10.0, 10.0, 0.0])  # m: a cube here is out of every camera's view

# Every program here runs a few steps, a cycle or two or a short pretraining (tests/quick_compile.py).
pytestmark = pytest.mark.usefixtures("quick_file_compiles")


def test_renders_are_uint8_deterministic_and_the_cube_pixels_follow_the_cube(opengl):
    with PoseRenderer(("top", "front"), width=64, height=48) as renderer:
        hand = renderer.joint_range.mean(axis=1)
        upright = np.array([1.0, 0.0, 0.0, 0.0])
        frames = renderer.render(hand, CUBE_REST, upright)
        assert frames.shape == (2, 48, 64, 3) and frames.dtype == np.uint8
        np.testing.assert_array_equal(renderer.render(hand, CUBE_REST, upright), frames)
        empty = renderer.render(hand, FAR, upright)
        shifted = renderer.render(hand, CUBE_REST + [0.02, 0.0, 0.0], upright)

    def cube_pixels(image, background):
        return np.argwhere(np.any(image != background, axis=-1))

    here, there = cube_pixels(frames[0], empty[0]), cube_pixels(shifted[0], empty[0])
    assert 20 < len(here) < 0.5 * 48 * 64, "the cube is a blob of the top view, not nothing nor everything"
    assert np.linalg.norm(here.mean(0) - there.mean(0)) > 2.0, "2 cm along x moves the blob by pixels"


@pytest.mark.slow
def test_every_visual_encoder_maps_uint8_images_to_features():
    # Shapes traced through each encoder's code (`jax.eval_shape`), nothing compiled: eagerly, each of the 8 inits and
    # applies compiled every operation of its own shapes (about 6 s of CPU).
    for name in VISUAL_ENCODERS:
        encoder = make_visual_encoder(name, widths=(8, 8, 8, 8)[: 4 if name == "cornet_z" else 3], features=12)
        for size in (32, 64):
            images = jax.ShapeDtypeStruct((2, size, size, 3), jnp.uint8)
            params = jax.eval_shape(encoder.init, jax.random.key(0), images)
            features = jax.eval_shape(encoder.apply, params, images)
            assert (features.shape, features.dtype) == ((2, 12), jnp.float32), (name, size)
    with pytest.raises(ValueError, match="Unknown visual encoder 'vgg'.*cornet_z"):
        make_visual_encoder("vgg")


def test_pose_heads_output_rotation_matrices_and_quaternions_round_trip():
    q = random_quaternions(np.random.default_rng(1), 8).astype(np.float32)
    rotations = rotation_matrices(jnp.asarray(q), "quaternion")
    expected = np.zeros((8, 9))
    for row, quaternion in zip(expected, q.astype(np.float64), strict=True):
        mujoco.mju_quat2Mat(row, quaternion)  # MuJoCo's own convention (w, x, y, z)
    np.testing.assert_allclose(rotations, expected.reshape(8, 3, 3), atol=1e-6)
    back = np.asarray(quaternions(rotations))
    np.testing.assert_allclose(orientation_error_degrees(back, q), 0.0, atol=0.05)
    six = rotation_matrices(jax.random.normal(jax.random.key(0), (8, 6)), "6d")
    np.testing.assert_allclose(jnp.einsum("bij,bik->bjk", six, six), np.broadcast_to(np.eye(3), (8, 3, 3)),
                               atol=1e-5)
    np.testing.assert_allclose(np.linalg.det(np.asarray(six)), 1.0, atol=1e-5)


def test_random_quaternions_are_unit_with_nonnegative_w():
    q = random_quaternions(np.random.default_rng(0), 1000)
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, rtol=1e-6)
    assert (q[:, 0] >= 0).all() and abs(q[:, 1:].mean()) < 0.05


@pytest.mark.slow
def test_pose_pretraining_lowers_its_loss_and_saves_an_encoder_component(tmp_path, capsys, opengl):
    data = render_pose_dataset(48, cameras=("top",), width=32, height=32, seed=1)
    assert data.images.shape == (48, 1, 32, 32, 3) and data.cube_quaternion.shape == (48, 4)
    train, test = data.split(0.25)
    assert (len(train), len(test)) == (36, 12)
    # Measured: the loss falls from 1.52 to about 0.5 in 200 steps (fitting 36 training samples).
    result = pretrain_pose_encoder(train, test, "cornet_z", {"widths": (8, 8, 8, 8), "features": 16}, steps=200,
                                   batch_size=16, learning_rate=3e-3, log_every=20)
    losses = [loss for _, loss in result.history]
    assert np.mean(losses[-3:]) < 0.6 * losses[0], losses
    assert {"position_mm_median", "orientation_deg_median"} <= set(result.errors)
    with pytest.raises(ValueError, match="Unknown orientation 'euler'.*6d"):
        pretrain_pose_encoder(train, test, orientation="euler")
    out = tmp_path / "encoder.msgpack"
    argv = ["pretrain-vision", "--out", str(out), "--samples", "20", "--size", "32", "--cameras", "top", "--widths",
            "8", "8", "8", "8", "--features", "16", "--steps", "5", "--batch", "8"]
    assert main(argv) == 0
    assert "orientation" in capsys.readouterr().out
    assert json.loads(out.with_suffix(".json").read_text())["learning_rate"] == "0.001, cosine decay to 0 over 5 steps"
    assert set(load_component(out, "network.vision")) == {"V1", "V2", "V4", "IT", "decoder"}
    assert main(argv) == 2 and "never overwritten" in capsys.readouterr().err
    # The whole pose network, saved beside the encoder, reads frames as it did when measured.
    estimator = PoseEstimator.load(out.with_suffix(".pose.msgpack"))
    assert (estimator.cameras, estimator.size, estimator.encoder_options["widths"]) == (("top",), 32, (8, 8, 8, 8))
    assert estimator.renderer == "cpu", "it reads OpenGL's frames, which it was trained on"
    saved = result.estimator.save(tmp_path / "pose.msgpack")
    position, quaternion = jax.jit(PoseEstimator.load(saved).__call__)(jnp.asarray(test.images))
    assert position.shape == (12, 3) and quaternion.shape == (12, 4) and bool(jnp.all(quaternion[:, 0] >= 0))
    np.testing.assert_allclose(jnp.linalg.norm(quaternion, axis=-1), 1.0, rtol=1e-5)
    errors = 1000 * np.linalg.norm(np.asarray(position) - test.cube_position, axis=-1)
    np.testing.assert_allclose(np.median(errors), result.errors["position_mm_median"], rtol=1e-4)
    with pytest.raises(ValueError, match="expects frames"):
        estimator(jnp.zeros((1, 2, 32, 32, 3), jnp.uint8))
    with pytest.raises(FileNotFoundError, match="pose.msgpack"):
        PoseEstimator.load(tmp_path / "missing.pose.msgpack")
    with pytest.raises(FileExistsError, match="never overwritten"):
        result.estimator.save(saved)


def test_model_cameras_show_exactly_what_the_free_cameras_show(opengl):
    """The fixed `vision_<name>` cameras (what MuJoCo Warp renders) against the free views of the palm used for
    videos: measured identical, pixel for pixel."""
    from angora_jax.envs.rendering import SceneRenderer, camera_named
    from angora_jax.envs.shadow_hand.cube import load_cube_scene
    from angora_jax.envs.shadow_hand.hand import PALM_BODY

    model = load_cube_scene(touch=False, cameras=("front", "top"))
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    for name in ("front", "top"):
        free = SceneRenderer(model, PALM_BODY, camera_named(name), 48, 48)
        fixed = SceneRenderer(model, None, f"vision_{name}", 48, 48)
        np.testing.assert_array_equal(free.render(data), fixed.render(data))
        free.close()
        fixed.close()


def test_the_warp_renderer_is_asked_for_clearly():
    import importlib.util

    with pytest.raises(ValueError, match="renderer must be 'cpu' or 'warp'"):
        render_pose_dataset(2, renderer="vulkan")
    if importlib.util.find_spec("warp") is None:  # the CPU machines: Warp's batched renderer needs warp-lang
        with pytest.raises(ModuleNotFoundError, match="needs NVIDIA Warp: pip install warp-lang"):
            render_pose_dataset(2, renderer="warp")


# Camera vision in the loop (issue 20): hand tasks seeing through two 32 x 32 cameras, on MJX (MJX's JAX
# implementation renders with OpenGL through a host callback here; MuJoCo Warp inside the step on a GPU) and on the
# eager C MuJoCo path.
PIXELS = {"cameras": ["front", "top"], "width": 32, "height": 32}
SMALL_AREAS = "{SSC_1: 16, SSC_2: 16, SPL: 16, IPL: 16, IPS: 16, MCC: 16, LPFC: 16, PMC_in: 16, PMC: 16, M1: 16}"


@pytest.fixture(scope="module")
def seeing_cube(opengl):
    import angora_jax as aj

    return aj.make("ShadowHandCube", vision=PIXELS, relative_goal=False, start_pool=8)


@pytest.mark.slow
def test_camera_vision_fills_the_sensation_with_uint8_frames_that_both_paths_agree_on(seeing_cube):
    """The cube's vision replaces its pose; the MJX and eager paths draw the same frames of the same state (shown on
    reach, whose MJX reset compiles in a fraction of the cube's time on the CPU) and the frames follow the hand."""
    import angora_jax as aj

    shapes = seeing_cube.observation_shapes()
    assert shapes.vision.shape == (2, 32, 32, 3) and shapes.vision.dtype == jnp.uint8
    assert shapes.asymmetric.shape == (34,), "the cube's pose (7) moves to the value function's inputs"
    reach = aj.make("ShadowHandReach", vision=PIXELS)
    assert reach.observation_shapes().goal.shape == (20,), "reach sees its hand besides its usual inputs"
    state = jax.jit(reach.reset)(jax.random.key(3))
    frames = np.asarray(state.obs.vision)
    assert frames.shape == (2, 32, 32, 3) and frames.dtype == np.uint8 and frames.std() > 10
    np.testing.assert_array_equal(np.asarray(jax.jit(reach.reset)(jax.random.key(3)).obs.vision), frames)
    np.testing.assert_array_equal(state.final_obs.vision, frames)
    cpu = aj.make("ShadowHandReach", vision=PIXELS, backend="cpu")
    twin = cpu.reset(jax.random.key(3))
    # The same start in float32 (MJX) and float64 (C MuJoCo), drawn by the same OpenGL renderer: identical frames.
    np.testing.assert_array_equal(np.asarray(twin.obs.vision), frames)
    moved = twin
    for _ in range(5):
        moved = cpu.step(moved, jnp.ones(cpu.action_spec.shape))  # every joint towards the end of its range
    assert np.mean(np.abs(np.asarray(moved.obs.vision, int) - frames) > 16) > 0.02, "the hand moves pixels"


def test_camera_vision_options_and_the_networks_that_see_them_are_checked(seeing_cube):
    import angora_jax as aj
    from angora_jax.ppo import NetworkConfig, PPOConfig, VisualConfig

    with pytest.raises(ValueError, match="relative_goal.*reveals the cube's"):
        aj.make("ShadowHandCube", vision=PIXELS)
    with pytest.raises(ValueError, match="Unknown vision settings \\['colour'\\]"):
        aj.make("ShadowHandCube", vision={"colour": True}, relative_goal=False)
    with pytest.raises(ValueError, match="rgb: true, depth: true or both"):
        aj.make("ShadowHandCube", vision={"rgb": False}, relative_goal=False)
    with pytest.raises(ValueError, match="vision.renderer must be one of \\['cpu', 'warp'\\] or null"):
        aj.make("ShadowHandCube", vision={"renderer": "opengl"}, relative_goal=False)
    with pytest.raises(ValueError, match="needs a visual area.*ppo.network.visual"):
        PPOConfig(num_envs=2, rollout_length=16, minibatch_size=32).validate_for(seeing_cube)
    with pytest.raises(ValueError, match="the task renders none"):
        PPOConfig(num_envs=2, rollout_length=16, minibatch_size=32,
                  network=NetworkConfig(visual=VisualConfig())).validate_for(aj.make("CartPole"))


@pytest.mark.slow
def test_a_pose_estimator_gives_the_policy_the_pose_it_reads_from_the_cameras(tmp_path, opengl):
    """Dactyl's way to the cube from pixels: `pose_estimator` renders the estimator's cameras and puts the pose it
    reads from them (and the relative goal from its orientation) where the pose-input policy reads the true
    pose, in inputs of the same shapes (a pose-trained network reads them unchanged); the network needs no
    visual area. An untrained estimator shows the plumbing on the eager C MuJoCo path, and the batched MJX path
    starts with the same estimate (its reset compiles in about 17 s here; its step, about 35 s, is left to the
    GPU)."""
    import angora_jax as aj
    from angora_jax.envs.shadow_hand.ihom import rotation_between, rotation_matrix
    from angora_jax.ppo import PPOConfig
    from angora_jax.vision.estimator import PoseNet

    network = PoseNet(make_visual_encoder("cornet_z", widths=(8, 8, 8, 8), features=8))
    params = network.init(jax.random.key(0), jnp.zeros((1, 2, 32, 32, 3), jnp.uint8))["params"]
    estimator = PoseEstimator(params, "cornet_z", {"widths": (8, 8, 8, 8), "features": 8}, "6d", ("front", "top"),
                              32, CUBE_REST.astype(np.float32), np.full(3, 0.01, np.float32))
    file = estimator.save(tmp_path / "cube.pose.msgpack")
    with pytest.raises(ValueError, match="give no vision option"):
        aj.make("ShadowHandCube", pose_estimator=str(file), vision=PIXELS, backend="cpu")
    env = aj.make("ShadowHandCube", pose_estimator=str(file), start_pool=8, backend="cpu")
    shapes = env.observation_shapes()
    assert shapes == aj.make("ShadowHandCube", start_pool=8).observation_shapes()
    assert (shapes.vision.shape, shapes.vision.dtype, shapes.goal.shape) == ((7,), jnp.float32, (13,))
    assert not env.sees_images
    PPOConfig(num_envs=2, rollout_length=16, minibatch_size=32).validate_for(env)
    state = env.step(env.reset(jax.random.key(3)), jnp.zeros(env.action_spec.shape))
    position, quaternion = PoseEstimator.load(file)(jnp.asarray(env.cameras.frames(env.data))[None])
    np.testing.assert_allclose(state.obs.vision, jnp.concatenate([position[0], quaternion[0]]), rtol=1e-5, atol=1e-6)
    goal = state.info["goal"]
    np.testing.assert_allclose(state.obs.goal, jnp.concatenate([goal, rotation_matrix(rotation_between(
        quaternion[0], goal))]), rtol=1e-5, atol=1e-6)
    true_pose = np.asarray(env.task.cube_pose(env.task.snapshot(env.data)))
    # An estimator trained on Warp's renders is not fed OpenGL's, which look different; its task still loads (a run
    # that used it can be probed anywhere), and refuses when it would render.
    warp_file = dataclasses.replace(estimator, renderer="warp").save(tmp_path / "warp.pose.msgpack")
    warp_trained = aj.make("ShadowHandCube", pose_estimator=str(warp_file), start_pool=8, backend="cpu")
    with pytest.raises(ValueError, match="trained on MuJoCo Warp's images.*evaluate: --path batched --env-option "
                                         "physics.impl=warp"):
        warp_trained.reset(jax.random.key(3))
    assert np.abs(np.asarray(state.obs.vision) - true_pose).max() > 0.01, "the estimate, not the true pose"
    batched = jax.jit(aj.make("ShadowHandCube", pose_estimator=str(file), start_pool=8).reset)(jax.random.key(3))
    twin = env.reset(jax.random.key(3))
    np.testing.assert_allclose(batched.obs.vision, twin.obs.vision, atol=1e-5)
    np.testing.assert_allclose(batched.obs.goal, twin.obs.goal, atol=1e-5)


@pytest.mark.slow
@pytest.mark.skipif(importlib.util.find_spec("warp") is None, reason="MuJoCo Warp needs warp-lang")
def test_warp_frames_are_each_envs_own_and_outlive_the_sized_env_that_compiled_them():
    """On MuJoCo Warp (run where warp-lang is installed, a GPU or the CPU): a fixed start (reach's) reaches Warp
    unbatched, which renders every world; each env still gets one set of frames, those of its own state. A program
    compiled ahead of time (as evaluate's) names the render context by key only: it still runs after the caller
    dropped the sized environment, which its unsized parent keeps."""
    import gc

    import angora_jax as aj

    env = aj.make("ShadowHandReach", vision={"cameras": ["front", "top"], "width": 16, "height": 16},
                  physics={"impl": "warp"})
    keys = jax.random.split(jax.random.key(0), 3)
    reset = jax.jit(jax.vmap(env.sized_for(3).reset)).lower(keys).compile()
    assert env.sized_for(3) is env.sized_for(3)
    gc.collect()
    state = reset(keys)
    assert state.obs.vision.shape == (3, 2, 16, 16, 3) and state.obs.vision.dtype == jnp.uint8
    sized = env.sized_for(3)
    rendered = jax.jit(jax.vmap(lambda data: sized._frames(data, 1)))(state.physics)
    np.testing.assert_array_equal(state.obs.vision, rendered)
    stepped = jax.jit(jax.vmap(sized.step))(state, jnp.ones((3, *env.action_spec.shape)))
    assert stepped.obs.vision.shape == (3, 2, 16, 16, 3) and np.any(stepped.obs.vision != state.obs.vision)


@pytest.mark.slow
def test_the_brain_area_model_trains_from_pixels_through_a_pretrained_frozen_visual_area(tmp_path, opengl):
    """The brain-area model (`cortical`, whose parietal areas read the visual area's features) on reach seeing its hand
    through two cameras (the reach physics compiles in a third of the cube's time on the CPU; the cube's frames are
    checked above and its pixel config trained on the GPU), its visual area loaded from a component file and frozen:
    two cycles train, the visual area's parameters stay exactly the file's while the rest learn, the C MuJoCo path
    evaluates the saved agent from its own OpenGL frames, and a step records the visual area per camera."""
    from flax import serialization

    import angora_jax as aj
    from angora_jax.analysis.recording import layer_activity
    from angora_jax.experiment import train as train_run
    from angora_jax.nets.components import save_component

    encoder = make_visual_encoder("cornet_z", widths=(8, 8, 8, 8), features=8)
    pretrained = encoder.init(jax.random.key(7), jnp.zeros((1, 32, 32, 3), jnp.uint8))["params"]
    component = save_component({"encoder": pretrained}, "encoder", tmp_path / "encoder.msgpack")
    overrides = ["ppo.num_envs=2", "ppo.rollout_length=16", "ppo.chunk_length=8", "ppo.minibatch_size=32",
                 "ppo.num_epochs=1", "ppo.num_cycles=2", "ppo.network.name=cortical", "ppo.network.cell=gru",
                 "ppo.network.width=32", f"ppo.network.areas={SMALL_AREAS}", "env.options.max_episode_steps=20",
                 "env.options.vision={cameras: [front, top], width: 32, height: 32}",
                 "ppo.network.visual={encoder: cornet_z, widths: [8, 8, 8, 8], features: 8}",
                 f"ppo.network.pretrained={{visual: {component}}}", "ppo.network.frozen=[visual]",
                 f"logging.run_root={tmp_path}", "logging.run_name=pixels", "logging.progress=none",
                 "logging.report=false", "checkpoint.best_metric=null", "checkpoint.snapshot_every=1"]
    run = train_run("shadow_reach", overrides)
    assert run.finished and all(metrics["finite"] == 1.0 for metrics in run.history)
    params = jax.device_get(run.state.params)
    expected = serialization.msgpack_restore(component.read_bytes())
    jax.tree.map(np.testing.assert_array_equal, params["visual"], expected)
    first = jax.device_get(aj.load_agent(run.run_dir, 1).params)
    assert any(np.abs(a - b).max() > 0 for a, b in zip(jax.tree.leaves(first["network"]),
                                                       jax.tree.leaves(params["network"]), strict=True))

    evaluation = aj.evaluate(run.run_dir, episodes=2, batch=2, save=False)
    assert evaluation.episodes["episode_return"].shape == (2,)
    assert np.isfinite(evaluation.episodes["episode_return"]).all()
    assert aj.load_agent(run.run_dir).config.env.options["vision"]["renderer"] == "cpu", "trained on OpenGL frames"
    # A pixel policy trained on Warp's frames is refused OpenGL's, unless the option is lifted.
    sessions = run.run_dir / "sessions.jsonl"
    sessions.write_text(sessions.read_text().replace('"impl": "jax"', '"impl": "warp"'))
    with pytest.raises(ConfigError, match="trained on MuJoCo Warp's images"):  # before compiling: exit 2, no traceback
        aj.evaluate(run.run_dir, episodes=2, batch=2, save=False)
    from angora_jax.analysis import record_activity

    with pytest.raises(ValueError, match="trained on MuJoCo Warp's images"):
        record_activity(run.run_dir, episodes=2, steps=2)
    lifted = aj.load_agent(run.run_dir, env_overrides=["vision.renderer=null"])
    assert lifted.config.env.options["vision"]["renderer"] is None

    agent = aj.load_agent(run.run_dir)
    obs = jax.tree.map(lambda s: jnp.zeros((3, *s.shape), s.dtype), agent.env.observation_shapes())
    _, _, _, layers = layer_activity(agent, agent.initial_carry(3), obs)
    assert layers["visual.decoder"].shape == (3, 2 * 8), "each environment's two cameras, 8 features each"
    assert layers["network.IPS"].shape == (3, 16), "the parietal areas see"

    # `angora-jax record --images` keeps the frames the policy saw (uint8 through NetCDF), without it they are left out.
    # Recorded on MuJoCo Warp (its physics and renderer): its recording program compiled in 6 s here, MJX's JAX
    # implementation's in 24 s (2 loaded cores). What is checked is what record keeps of the frames, whoever drew them.
    import xarray as xr

    from angora_jax.cli import main

    kept, lean = tmp_path / "with.nc", tmp_path / "without.nc"
    on_warp = ["--env-option", "vision.renderer=null", "--env-option", "physics={impl: warp}"]
    assert main(["record", str(run.run_dir), "--out", str(kept), "--episodes", "2", "--steps", "3", "--images",
                 *on_warp]) == 0
    assert main(["record", str(run.run_dir), "--out", str(lean), "--episodes", "2", "--steps", "3", *on_warp]) == 0
    with xr.open_dataset(kept) as recording, xr.open_dataset(lean) as without:
        frames = recording["input_vision"]
        assert frames.dims == ("episode", "time", "camera", "y", "x", "channel") and frames.dtype == np.uint8
        assert frames.shape == (2, 3, 2, 32, 32, 3) and int(frames.max()) > int(frames.min()), "images, not blanks"
        assert "input_vision" not in without and recording.attrs["camera_images"] == 1
        seen_by_camera_1 = frames.values[0, :2, 1]

    # `angora-jax analyze visual`: inside the visual area, on the recorded frames of one camera.
    out = tmp_path / "visual.png"
    assert main(["analyze", "visual", str(kept), "--run", str(run.run_dir), "--frames", "2", "--camera", "1",
                 "--units", "2", "--steps", "4", "--out", str(out), "--env-option", "vision.renderer=null"]) == 0
    with xr.open_dataset(out.with_suffix(".nc")) as seen:
        assert seen["preferred"].shape == (4, 2, 32, 32, 3) and seen["saliency"].shape == (2, 2, 32, 32)
        np.testing.assert_array_equal(seen["frames"].values, seen_by_camera_1)
    assert out.read_bytes()[:4] == b"\x89PNG"
    assert main(["analyze", "visual", str(kept), "--run", str(run.run_dir), "--camera", "2"]) == 2
    assert main(["analyze", "visual", str(lean), "--run", str(run.run_dir)]) == 2, "no images kept"


# pretrain-vision's usage errors: refused with exit 2, the cause and the fix, before anything is rendered or written.
def never_renders(*args, **kwargs):
    raise AssertionError("rendered, although the arguments were refusable before")


def pretrain_vision_refused(tmp_path, capsys, *options: str) -> str:
    """stderr of `angora-jax pretrain-vision` with `options` into `tmp_path`, which must exit 2 without a traceback
    and leave `tmp_path` as it was."""
    before = sorted(tmp_path.rglob("*"))
    argv = ["pretrain-vision", "--out", str(tmp_path / "encoder.msgpack"), "--samples", "20", "--cameras", "top",
            "--steps", "2", "--batch", "4", *options]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and sorted(tmp_path.rglob("*")) == before, "nothing written"
    return err


@pytest.mark.parametrize("options, message", [
    (["--size", "100000"], "do not fit the cube scene's offscreen framebuffer of 640 x 480"),
    (["--size", "481"], "render at most 480 pixels square (--size), or with MuJoCo Warp on a GPU (--renderer warp)"),
    (["--samples", "1000000", "--size", "480"], "more than this machine's"),
    (["--samples", "1"], "--samples must be at least 2"),
    (["--batch", "21"], "--batch (21) must be at most --samples (20)"),
    (["--widths", "8", "8"], "cornet_z does not take features 256 and widths (8, 8)"),
    (["--widths", "8", "8"], "its default widths are (32, 64, 128, 256)"),
    (["--encoder", "resnet"], "unknown encoder 'resnet'"),
    (["--features", "10000000000"], "GB, four times that with their gradients and Adam's moments, more than"),
])
def test_pretrain_vision_refuses_what_it_cannot_do_before_rendering(options, message, tmp_path, capsys, monkeypatch):
    import angora_jax.vision

    monkeypatch.setattr(angora_jax.vision, "render_pose_dataset", never_renders)
    assert message in pretrain_vision_refused(tmp_path, capsys, *options)


def test_pretrain_vision_refuses_an_out_it_cannot_write_before_rendering(tmp_path, capsys, monkeypatch):
    import angora_jax.vision

    monkeypatch.setattr(angora_jax.vision, "render_pose_dataset", never_renders)
    (tmp_path / "notes").write_text("a file, not a folder")
    err = pretrain_vision_refused(tmp_path, capsys, "--out", str(tmp_path / "notes" / "encoder.msgpack"))
    assert f"--out {tmp_path / 'notes' / 'encoder.msgpack'}" in err and f"{tmp_path / 'notes'} is a file" in err


def test_pretrain_vision_overwrites_none_of_its_three_outputs(tmp_path, capsys, monkeypatch):
    import angora_jax.vision

    monkeypatch.setattr(angora_jax.vision, "render_pose_dataset", never_renders)
    (tmp_path / "encoder.json").write_text("{}")
    assert "encoder.json exists; numbers are never overwritten" in pretrain_vision_refused(tmp_path, capsys)
    err = pretrain_vision_refused(tmp_path, capsys, "--out", str(tmp_path / "encoder.pose.json"))
    assert "the numbers (.json) would overwrite the encoder" in err and "--out ending in .msgpack" in err


def test_pretrain_vision_without_opengl_or_warp_exits_2_naming_what_to_install(tmp_path, capsys, monkeypatch):
    """No OpenGL context (simulated: MuJoCo's renderer refuses, as it does without EGL), or --renderer warp without
    MuJoCo Warp: the cause and what to install, no traceback."""
    from angora_jax.envs.rendering import GL_HINT, RenderError
    from angora_jax.vision import dataset

    def no_opengl(*args, **kwargs):
        raise RenderError(f"MuJoCo cannot render with MUJOCO_GL=egl: no EGL display. {GL_HINT}")

    def no_warp():
        raise ModuleNotFoundError("physics impl 'warp' needs NVIDIA Warp: pip install warp-lang")

    monkeypatch.setattr(dataset, "SceneRenderer", no_opengl)
    err = pretrain_vision_refused(tmp_path, capsys, "--size", "32")
    assert "libegl1 libegl-mesa0" in err and "MUJOCO_GL=egl" in err and "--renderer warp" in err
    monkeypatch.setattr(dataset, "require_warp", no_warp)
    monkeypatch.setattr(dataset, "_render_warp", never_renders)
    assert "pip install warp-lang" in pretrain_vision_refused(tmp_path, capsys, "--renderer", "warp")


def test_cameras_the_garbage_collector_drops_are_closed_later_never_inside_the_collection(opengl):
    """A finalizer runs wherever collection strikes, even inside a lock its thread holds: cameras dropped while a
    thread pool holds concurrent.futures' global lock (as Orbax's does while it starts a thread) must not wait for
    that lock (a test process hung so). Their renderers are closed, on their GL thread, when cameras are made again."""
    import concurrent.futures.thread
    import gc
    import threading

    import angora_jax as aj
    from angora_jax.envs import cameras as cameras_module

    task = aj.make("ShadowHandReach", vision=PIXELS).task
    held = [cameras_module.HostCameras(task.model, task.vision)]
    gl = held[0]._gl

    def drop_while_holding_the_lock():
        with concurrent.futures.thread._global_shutdown_lock:
            held.clear()
            gc.collect()

    dropper = threading.Thread(target=drop_while_holding_the_lock, daemon=True)
    dropper.start()
    dropper.join(timeout=60)
    assert not dropper.is_alive(), "the finalizer waited for the lock its own thread held"
    assert [pool for pool, _ in cameras_module._dropped] == [gl]
    again = cameras_module.HostCameras(task.model, task.vision)
    assert not cameras_module._dropped and gl._shutdown, "the dropped cameras' GL thread was not closed"
    again.close()


def test_no_display_is_one_message_naming_glfw_s_first_warning_and_no_warnings_before_it(monkeypatch):
    """Without MUJOCO_GL and a display, GLFW printed two warning blocks before the message that says what to do."""
    import warnings

    from angora_jax.envs import rendering

    def glfw_without_display(*args, **kwargs):
        warnings.warn("(65550) b'X11: The DISPLAY environment variable is missing'", UserWarning, stacklevel=2)
        warnings.warn("(65537) b'The GLFW library is not initialized'", UserWarning, stacklevel=2)
        raise mujoco.FatalError("an OpenGL platform library has not been loaded into this process")

    monkeypatch.setattr(rendering.mujoco, "Renderer", glfw_without_display)
    model = mujoco.MjModel.from_xml_string("<mujoco/>")
    with warnings.catch_warnings(record=True) as leaked:
        warnings.simplefilter("always")
        with pytest.raises(rendering.RenderError, match=r"cannot render with MUJOCO_GL=.*has not been loaded into this "
                                                        r"process \(first, \(65550\) b'X11: The DISPLAY environment "
                                                        r"variable is missing'\)\. Rendering needs an OpenGL backend"):
            rendering.SceneRenderer(model, None, rendering.CAMERAS["front"])
    assert leaked == [], [str(w.message) for w in leaked]


def test_mujoco_gl_set_after_the_import_is_named_as_such(monkeypatch):
    """A notebook that sets MUJOCO_GL=egl in a later cell was told to set MUJOCO_GL=egl: MuJoCo had loaded GLFW."""
    from angora_jax import opengl_backend
    from angora_jax.envs import rendering

    def no_context(*args, **kwargs):
        raise mujoco.FatalError("an OpenGL platform library has not been loaded into this process")

    monkeypatch.setattr(rendering.mujoco, "Renderer", no_context)
    monkeypatch.setattr(opengl_backend, "LOADED", None)
    monkeypatch.setenv("MUJOCO_GL", "egl")
    message = (r"^MuJoCo cannot render: MUJOCO_GL=egl was set after MuJoCo was imported, which loaded its default "
               r"\(GLFW, which needs a display\) then and keeps it: set MUJOCO_GL=egl before importing angora_jax")
    with pytest.raises(rendering.RenderError, match=message):
        rendering.SceneRenderer(mujoco.MjModel.from_xml_string("<mujoco/>"), None, rendering.CAMERAS["front"])
