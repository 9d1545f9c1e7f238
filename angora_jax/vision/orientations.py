"""How a pose network outputs the cube's orientation (`estimator.PoseNet`; its module docstring says how each becomes
a rotation), apart from the network, so that `angora-jax pretrain-vision --orientation` offers them to a parser that
imports no JAX."""

ORIENTATIONS = {"quaternion": 4, "6d": 6}  # the head's outputs per orientation representation
