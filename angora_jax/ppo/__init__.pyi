# The names angora_jax.ppo gives (its __all__), each imported when first used: lazy_loader.attach_stub in
# __init__.py reads the imports here; type checkers, editors and the API pages read the imports and __all__.
# `train` is the function, also after `import angora_jax.ppo.train` (lazy_loader guards it from its module).
from .config import NetworkConfig, NormalizationConfig, PPOConfig, VisualConfig, tile_shape
from .cycle import TrainState, average_gradients, build_head, make_cycle
from .distributions import (
    Beta,
    Categorical,
    Gaussian,
    MultiCategorical,
    PolicyHead,
    list_heads,
    make_head,
    register_head,
)
from .evaluate import make_evaluate
from .train import TrainingDivergedError, format_metrics, train, training_cycles

__all__ = [
    "Beta", "Categorical", "Gaussian", "MultiCategorical", "NetworkConfig", "NormalizationConfig", "PPOConfig",
    "PolicyHead", "TrainState", "TrainingDivergedError", "VisualConfig", "average_gradients", "build_head",
    "format_metrics", "list_heads", "make_cycle", "make_evaluate", "make_head", "register_head", "tile_shape",
    "train", "training_cycles",
]
