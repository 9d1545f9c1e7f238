"""PPO with recurrent truncated BPTT, compiled as one program per training cycle.

`train(config)` runs a whole experiment; `make_cycle(env, network, config)` gives the compiled pieces.
"""

from typing import TYPE_CHECKING

from angora_jax.lazy_names import lazy_names

if TYPE_CHECKING:  # the names this package gives, each imported when first used (angora_jax.lazy_names)
    from angora_jax.ppo.config import NetworkConfig, NormalizationConfig, PPOConfig, VisualConfig, tile_shape
    from angora_jax.ppo.cycle import TrainState, average_gradients, build_head, make_cycle
    from angora_jax.ppo.distributions import (
        Beta,
        Categorical,
        Gaussian,
        MultiCategorical,
        PolicyHead,
        list_heads,
        make_head,
        register_head,
    )
    from angora_jax.ppo.evaluate import make_evaluate
    from angora_jax.ppo.train import TrainingDivergedError, format_metrics, train, training_cycles

__all__ = [
    "Beta",
    "Categorical",
    "Gaussian",
    "MultiCategorical",
    "NetworkConfig",
    "VisualConfig",
    "NormalizationConfig",
    "PPOConfig",
    "PolicyHead",
    "TrainState",
    "TrainingDivergedError",
    "average_gradients",
    "build_head",
    "format_metrics",
    "list_heads",
    "make_cycle",
    "make_evaluate",
    "make_head",
    "register_head",
    "tile_shape",
    "train",
    "training_cycles",
]

lazy_names(__name__)
