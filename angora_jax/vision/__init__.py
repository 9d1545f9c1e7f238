"""Vision: rendered datasets of the hand and cube (`render_pose_dataset`; where the cube is in them: `cube_masks`),
pretraining of visual encoders to see the cube's pose (`pretrain_pose_encoder`) and the trained pose network as a
`PoseEstimator` (frames in, pose out); the encoders themselves are `angora_jax.nets.visual`."""

import lazy_loader

# The names this package gives (its __all__), each imported when first used: __init__.pyi lists them, where type
# checkers, editors and the API pages read them.
__getattr__, __dir__, __all__ = lazy_loader.attach_stub(__name__, __file__)
