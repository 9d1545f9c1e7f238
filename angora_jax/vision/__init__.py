"""Vision: rendered datasets of the hand and cube (`render_pose_dataset`; where the cube is in them: `cube_masks`),
pretraining of visual encoders to see the cube's pose (`pretrain_pose_encoder`) and the trained pose network as a
`PoseEstimator` (frames in, pose out); the encoders themselves are `angora_jax.nets.visual`."""

from typing import TYPE_CHECKING

from angora_jax.lazy_names import lazy_names

if TYPE_CHECKING:  # the names this package gives, each imported when first used (angora_jax.lazy_names)
    from angora_jax.vision.dataset import PoseDataset, PoseRenderer, cube_masks, render_pose_dataset, render_poses
    from angora_jax.vision.estimator import PoseEstimator, PoseNet, orientation_error_degrees
    from angora_jax.vision.pretrain import PretrainResult, pretrain_pose_encoder

__all__ = ["PoseDataset", "PoseEstimator", "PoseNet", "PoseRenderer", "PretrainResult", "cube_masks",
           "orientation_error_degrees", "pretrain_pose_encoder", "render_pose_dataset", "render_poses"]

lazy_names(__name__)
