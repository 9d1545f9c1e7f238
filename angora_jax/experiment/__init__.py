"""Experiments: configs from YAML, run directories, Orbax checkpoints with exact resume, the metrics monitor and
reports. The `angora-jax` command is a thin layer over these functions.

    config = load_config("cartpole", ["ppo.num_cycles=30"])   # a shipped config (list_configs()) with an override
    run = train(config)                                        # writes runs/<name>/ and returns TrainingRun
    agent = load_agent(run.run_dir)                            # best checkpoint: act, evaluate, probe
"""

import lazy_loader

# The names this package gives (its __all__), each imported when first used: __init__.pyi lists them, where type
# checkers, editors and the API pages read them.
__getattr__, __dir__, __all__ = lazy_loader.attach_stub(__name__, __file__)
