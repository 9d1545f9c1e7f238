# The names angora_jax.vision gives (its __all__), each imported when first used: lazy_loader.attach_stub in
# __init__.py reads the imports here; type checkers, editors and the API pages read the imports and __all__.
from .dataset import PoseDataset, PoseRenderer, cube_masks, render_pose_dataset, render_poses
from .estimator import PoseEstimator, PoseNet, orientation_error_degrees
from .pretrain import PretrainResult, pretrain_pose_encoder

__all__ = [
    "PoseDataset", "PoseEstimator", "PoseNet", "PoseRenderer", "PretrainResult", "cube_masks",
    "orientation_error_degrees", "pretrain_pose_encoder", "render_pose_dataset", "render_poses",
]
