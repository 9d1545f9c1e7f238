"""Where the cube is in rendered frames (`angora_jax.vision.cube_masks`): the cube's pixels only."""

import mujoco
import numpy as np
import scipy.ndimage

from angora_jax.envs.rendering import VISION_PREFIX
from angora_jax.envs.shadow_hand.cube import CUBE_BODY, CUBE_JOINT, load_cube_scene
from angora_jax.vision import cube_masks, render_pose_dataset


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
