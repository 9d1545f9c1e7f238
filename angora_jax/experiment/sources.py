"""`check_sources`: a new run's saved starting values (`ppo.init_from`, `ppo.network.pretrained`) and frozen modules
(`ppo.network.frozen`) checked before it makes a run directory or compiles anything, so that a wrong module path, a
damaged file or a run of another network size is a ConfigError naming the key and the fix, not a traceback minutes
into a run."""

from __future__ import annotations

from angora_jax.envs.core import Env
from angora_jax.experiment.config import Config, ConfigError, flatten, to_dict
from angora_jax.experiment.run_dir import read_run_config, run_source
from angora_jax.ppo.cycle import SavedRunMisfit, check_saved_values


def check_sources(config: Config, env: Env) -> None:
    """ConfigError naming the key, the module path, file or run, and the fix, when a module path of
    `ppo.network.frozen` or `ppo.network.pretrained` names no module of the run's network, or a source of
    `ppo.init_from` or `ppo.network.pretrained` cannot be read or does not fit it (`ppo.cycle.check_saved_values`).
    Traces the run's initialisation once (no compiling) and reads every source, only when the config names any."""
    ppo = config.ppo
    if not (ppo.init_from or ppo.network.pretrained or ppo.network.frozen):
        return
    try:
        check_saved_values(env, ppo)
    except SavedRunMisfit as error:
        raise ConfigError(f"{error}{_trained_otherwise(config)}") from None
    except ValueError as error:
        raise ConfigError(str(error)) from None


def _trained_otherwise(config: Config) -> str:
    """What the run `ppo.init_from` names was trained with that `config` sets otherwise: its network settings, or
    where those are the same, its task (whose observations then differ in shape)."""
    saved = read_run_config(run_source(config.ppo.init_from)[0])
    if saved.env.task != config.env.task:  # no network setting makes its observations fit: say so, not the widths
        return (f" The saved run was trained on {saved.env.task} and this run is {config.env.task}, whose "
                f"observations differ: start from a run of {config.env.task}.")
    ours, theirs = flatten(to_dict(config)), flatten(to_dict(saved))
    network = [key for key in sorted(ours.keys() | theirs.keys()) if key.startswith("ppo.network.")
               and not key.startswith(("ppo.network.pretrained", "ppo.network.frozen"))]
    differing = [key for key in network if ours.get(key) != theirs.get(key)]
    if not differing:
        differing = [key for key in sorted(ours.keys() | theirs.keys()) if key.startswith("env.")
                     and ours.get(key) != theirs.get(key)]
    settings = ", ".join(f"{key}={theirs.get(key)}" for key in differing)
    here = ", ".join(f"{key}={ours.get(key)}" for key in differing)
    return f" The saved run has {settings} (this run: {here})." if differing else ""
