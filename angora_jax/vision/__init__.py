"""Vision: rendered datasets of the hand and cube (`render_pose_dataset`) and pretraining of visual encoders to see
the cube's pose (`pretrain_pose_encoder`); the encoders themselves are `angora_jax.nets.visual`."""

from angora_jax.vision.dataset import PoseDataset, PoseRenderer, render_pose_dataset
from angora_jax.vision.pretrain import PoseNet, PretrainResult, orientation_error_degrees, pretrain_pose_encoder

__all__ = ["PoseDataset", "PoseNet", "PoseRenderer", "PretrainResult", "orientation_error_degrees",
           "pretrain_pose_encoder", "render_pose_dataset"]
