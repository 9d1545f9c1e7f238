"""Experiments: configs from YAML, run directories, Orbax checkpoints with exact resume, the metrics monitor and
reports. The `angora-jax` command is a thin layer over these functions.

    config = load_config("cartpole", ["ppo.num_cycles=30"])   # a shipped config (list_configs()) with an override
    run = train(config)                                        # writes runs/<name>/ and returns TrainingRun
    agent = load_agent(run.run_dir)                            # best checkpoint: act, evaluate, probe
"""

from typing import TYPE_CHECKING

from angora_jax.lazy_names import lazy_names

if TYPE_CHECKING:  # the names this package gives, each imported when first used (angora_jax.lazy_names)
    from angora_jax.experiment.agent import Agent, load_agent, snapshot_cycles
    from angora_jax.experiment.checkpoint import Checkpoints
    from angora_jax.experiment.config import (
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
    from angora_jax.experiment.monitor import read_metrics
    from angora_jax.experiment.run_dir import RunDirError
    from angora_jax.experiment.runner import TrainingInterrupted, TrainingRun, resume, train

__all__ = [
    "Agent",
    "CheckpointConfig",
    "Checkpoints",
    "Config",
    "ConfigError",
    "DistributionConfig",
    "EnvConfig",
    "LoggingConfig",
    "RunDirError",
    "TrainingInterrupted",
    "TrainingRun",
    "list_configs",
    "load_agent",
    "load_config",
    "read_metrics",
    "resume",
    "snapshot_cycles",
    "to_dict",
    "train",
    "validate",
]

lazy_names(__name__)
