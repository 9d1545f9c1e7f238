"""Inside the visual system of a cube pose estimator (angora_jax.analysis.visual on a `PoseEstimator`, a tiny one with
its initial weights): the visual analyses read its encoder as they read an agent's visual area, the saliency of the
pose it reads is the gradient it claims to be, saliency shares and mask edges are what a hand count gives, and cube
masks mark the cube's pixels only."""

import dataclasses
from types import SimpleNamespace

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
import scipy.ndimage

import angora_jax as aj
from angora_jax.analysis import visual
from angora_jax.envs.rendering import VISION_PREFIX
from angora_jax.envs.shadow_hand.cube import CUBE_BODY, CUBE_JOINT, load_cube_scene
from angora_jax.nets.visual import make_visual_encoder
from angora_jax.vision import PoseEstimator, PoseNet, cube_masks, render_pose_dataset

# Every program here runs once or twice on a few 32 x 32 frames: compiling is nearly all of the time.
pytestmark = pytest.mark.usefixtures("quick_file_compiles")

SIZE = 32
CAMERAS = ("front", "side")
OPTIONS = {"widths": (4, 4, 4, 4), "features": 6}


@pytest.fixture(scope="module")
def estimator() -> PoseEstimator:
    """Two 32 x 32 cameras through a CORnet-Z of 4 channels per area and 6 features, a 6D orientation head."""
    network = PoseNet(make_visual_encoder("cornet_z", **OPTIONS), orientation="6d")
    params = network.init(jax.random.key(0), jnp.zeros((1, len(CAMERAS), SIZE, SIZE, 3), jnp.uint8))["params"]
    return PoseEstimator(params, "cornet_z", OPTIONS, "6d", CAMERAS, SIZE, np.zeros(3), np.ones(3))


@pytest.fixture(scope="module")
def frames() -> np.ndarray:
    return np.random.default_rng(0).integers(0, 256, (2, len(CAMERAS), SIZE, SIZE, 3), dtype=np.uint8)


@pytest.mark.slow
def test_the_visual_analyses_read_an_estimators_encoder_as_an_agents_visual_area(estimator, frames):
    """An agent whose visual area holds the estimator's encoder parameters gives the same filters, maps and saliency."""
    config = aj.load_config("shadow_reach", [
        "ppo.network.visual={encoder: cornet_z, widths: [4, 4, 4, 4], features: 6}",
        f"env.options.vision={{cameras: [front], width: {SIZE}, height: {SIZE}}}"])
    agent = SimpleNamespace(config=config, params={"visual": estimator.params["encoder"]})
    images = frames.reshape(-1, SIZE, SIZE, 3)
    assert visual.conv_layers(estimator) == ["V1", "V2", "V4", "IT"]
    np.testing.assert_array_equal(visual.first_layer_filters(estimator),
                                  np.moveaxis(estimator.params["encoder"]["V1"]["kernel"], -1, 0))
    own, theirs = visual.feature_maps(estimator, images), visual.feature_maps(agent, images)
    for layer in own:
        np.testing.assert_array_equal(own[layer], theirs[layer])
    np.testing.assert_array_equal(visual.saliency(estimator, images, unit=1), visual.saliency(agent, images, unit=1))
    found, _ = visual.preferred_stimuli(estimator, "V1", [0], steps=2)
    assert found.shape == (1, SIZE, SIZE, 3), "the estimator's own camera size"
    # Every layer's preferred stimuli come from one program: each layer's as preferred_stimuli finds it alone.
    result = visual.visual_analysis(estimator, images, units=1, steps=2, layers=["V1", "V2"])
    assert result["saliency"].shape == (4, 1, SIZE, SIZE) and result["preferred"].shape == (2, 1, SIZE, SIZE, 3)
    np.testing.assert_array_equal(result["preferred"].values[0], found)


def test_the_saliency_of_several_linear_outputs_is_their_largest_weight():
    weights = np.random.default_rng(1).normal(size=(4, 2, SIZE, SIZE, 3)).astype(np.float32)  # (K, cameras, ...)
    images = np.random.default_rng(2).integers(0, 256, (3, 2, SIZE, SIZE, 3), dtype=np.uint8)
    found = visual.gradient_saliency(lambda pixels: jnp.einsum("nchwr,kchwr->nk", pixels, weights), images)
    expected = np.abs(weights).max(axis=(0, -1))
    np.testing.assert_allclose(found, np.broadcast_to(expected, (3, 2, SIZE, SIZE)), rtol=1e-6)


@pytest.mark.slow
def test_pose_saliency_is_the_largest_gradient_of_the_pose_read(estimator, frames):
    """Position: the largest of its 3 outputs' single-output saliencies. Orientation: zero on a camera that the head
    does not read, and the rotation matrix, not the head's raw outputs, is differentiated."""
    network = estimator.network()

    def pose(pixels):
        return network.apply({"params": estimator.params}, pixels)

    position = visual.pose_saliency(estimator, frames, "position")
    assert position.shape == (2, len(CAMERAS), SIZE, SIZE) and position.min() >= 0
    each = [visual.gradient_saliency(lambda pixels, k=k: pose(pixels)[0][:, k], frames) for k in range(3)]
    np.testing.assert_allclose(position, np.max(each, axis=0), rtol=1e-5)
    rotation = [visual.gradient_saliency(lambda pixels, k=k: pose(pixels)[1].reshape(-1, 9)[:, k], frames)
                for k in range(9)]
    np.testing.assert_allclose(visual.pose_saliency(estimator, frames), np.max(rotation, axis=0), rtol=1e-5)

    # The head reads the cameras' features concatenated: zero the second camera's rows and it sees the first only.
    params = jax.tree.map(np.array, estimator.params)
    params["head_hidden"]["kernel"][OPTIONS["features"]:] = 0.0
    one_eyed = visual.pose_saliency(dataclasses.replace(estimator, params=params), frames)
    assert one_eyed[:, 0].any(axis=(1, 2)).all() and not one_eyed[:, 1].any()
    with pytest.raises(ValueError, match="orientation' or 'position"):
        visual.pose_saliency(estimator, frames, "velocity")
    with pytest.raises(ValueError, match=r"expects frames \(batch, 2, 32, 32, 3\)"):
        visual.pose_saliency(estimator, frames[:, :1])


def test_saliency_share_and_mask_edges_match_a_hand_count():
    saliency = np.array([[[1.0, 2.0], [3.0, 4.0]], [[0.0, 0.0], [0.0, 5.0]], [[0.0, 0.0], [0.0, 0.0]]])
    mask = np.array([[True, False], [False, True]])
    share = visual.saliency_share(saliency, mask)
    np.testing.assert_allclose(share[:2], [5 / 10, 1.0])
    assert np.isnan(share[2]), "no saliency: no share"
    square = np.zeros((2, 6, 6), bool)
    square[0, 1:5, 1:5] = True  # 4 x 4 inside the image: its ring of 12 is the edge
    square[1, :3, :3] = True  # 3 x 3 in a corner: the image's border is no edge, 5 pixels are
    edges = visual.mask_edges(square)
    assert edges.sum(axis=(1, 2)).tolist() == [12, 5] and not (edges & ~square).any()
    assert not edges[0, 2:4, 2:4].any() and not edges[1, 0, 0]


@pytest.mark.slow
def test_cube_masks_mark_the_cube_and_the_rim_its_edges_blend_into(opengl):
    """The mask holds every pixel that MuJoCo's segmentation gives the cube and nothing beyond a one-pixel rim around
    them (OpenGL's antialiasing blends the cube's edges into its neighbours)."""
    cameras = ("front", "side", "top")
    dataset = render_pose_dataset(2, cameras, 16, 16, seed=0)
    masks = cube_masks(dataset)
    model = load_cube_scene(touch=False, cameras=cameras)
    data, cube, body = mujoco.MjData(model), int(model.joint(CUBE_JOINT).qposadr[0]), model.body(CUBE_BODY).id
    segmented = np.zeros_like(masks)
    with mujoco.Renderer(model, 16, 16) as renderer:
        renderer.enable_segmentation_rendering()
        for i in range(len(dataset)):
            data.qpos[:cube] = dataset.hand_qpos[i]
            data.qpos[cube:cube + 7] = np.concatenate([dataset.cube_position[i], dataset.cube_quaternion[i]])
            mujoco.mj_forward(model, data)
            for c, name in enumerate(cameras):
                renderer.update_scene(data, VISION_PREFIX + name)
                ids, types = np.moveaxis(renderer.render(), -1, 0)
                geom = (types == mujoco.mjtObj.mjOBJ_GEOM) & (ids >= 0)
                segmented[i, c] = geom & (model.geom_bodyid[np.where(geom, ids, 0)] == body)
    assert masks.shape == (2, 3, 16, 16) and segmented.sum(axis=(2, 3)).min() > 0, "the cube is in every view"
    assert not (segmented & ~masks).any()
    rim = scipy.ndimage.binary_dilation(segmented, np.ones((1, 1, 3, 3), bool))
    assert not (masks & ~rim).any()
