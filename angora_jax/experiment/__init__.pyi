# The names angora_jax.experiment gives (its __all__), each imported when first used: lazy_loader.attach_stub in
# __init__.py reads the imports here; type checkers, editors and the API pages read the imports and __all__.
from .agent import Agent, load_agent, snapshot_cycles
from .checkpoint import Checkpoints
from .config import (
    CheckpointConfig,
    Config,
    ConfigError,
    DistributionConfig,
    EnvConfig,
    LoggingConfig,
    list_configs,
    load_config,
    to_dict,
    validate,
)
from .monitor import read_metrics
from .run_dir import RunDirError
from .runner import TrainingInterrupted, TrainingRun, resume, train

__all__ = [
    "Agent", "CheckpointConfig", "Checkpoints", "Config", "ConfigError", "DistributionConfig", "EnvConfig",
    "LoggingConfig", "RunDirError", "TrainingInterrupted", "TrainingRun", "list_configs", "load_agent",
    "load_config", "read_metrics", "resume", "snapshot_cycles", "to_dict", "train", "validate",
]
