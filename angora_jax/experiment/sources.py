"""`check_sources`: a new run's saved starting values (`ppo.init_from`, `ppo.network.pretrained`) and frozen modules
(`ppo.network.frozen`) checked before it makes a run directory or compiles anything, so that a wrong module path, a
damaged file or a run of another network size is a ConfigError naming the key and the fix, not a traceback minutes
into a run."""

from __future__ import annotations

from angora_jax.envs.core import Env
from angora_jax.envs.registry import make
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
        raise ConfigError(f"{error}{_trained_otherwise(config, env)}") from None
    except ValueError as error:
        raise ConfigError(str(error)) from None


def _trained_otherwise(config: Config, env: Env) -> str:
    """What the run `ppo.init_from` names was trained with that `config` sets otherwise: its network settings, or
    where those are the same, its task (whose observations then differ in shape) or the task options that change
    this run's observation or action shapes (`_reshaping_options`; not every option that differs)."""
    saved = read_run_config(run_source(config.ppo.init_from)[0])
    if saved.env.task != config.env.task:  # no network setting makes its observations fit: say so, not the widths
        return (f" The saved run was trained on {saved.env.task} and this run is {config.env.task}, whose "
                f"observations differ: start from a run of {config.env.task}.")
    ours, theirs = flatten(to_dict(config)), flatten(to_dict(saved))
    network = [key for key in sorted(ours.keys() | theirs.keys()) if key.startswith("ppo.network.")
               and not key.startswith(("ppo.network.pretrained", "ppo.network.frozen"))]
    differing = [key for key in network if ours.get(key) != theirs.get(key)]
    if not differing:
        options = [key for key in sorted(ours.keys() | theirs.keys()) if key.startswith("env.options.")
                   and ours.get(key) != theirs.get(key)]
        reshaping = _reshaping_options(config, saved, env, {key.split(".")[2] for key in options})
        differing = [key for key in options if key.split(".")[2] in reshaping] or options
    settings = ", ".join(_setting(key, theirs) for key in differing)
    here = ", ".join(_setting(key, ours) for key in differing)
    return f" The saved run has {settings} (this run: {here})." if differing else ""


def _setting(key: str, values: dict[str, object]) -> str:
    """`key=value`, or `key not set` where the config leaves it to its default (printed as None before)."""
    return f"{key}={values[key]}" if key in values else f"{key} not set"


def _reshaping_options(config: Config, saved: Config, env: Env, names: set[str]) -> set[str]:
    """Of the task options `names` (env.options' top-level names) that `saved` sets otherwise, those whose saved
    value, given alone to this run's task (`env`), changes its observation or action shapes: what makes the saved
    network misfit. A randomization range or an episode length that also differs changes none, and listing them
    (every randomization key of a randomized run, each as None in the saved run) hid the one that mattered. An option
    whose saved value makes no task with this run's other options is kept: its effect cannot be told apart."""
    ours, theirs = config.env.options, saved.env.options
    reshaping = set()
    for name in sorted(names):
        options = {key: value for key, value in ours.items() if key != name} | (
            {name: theirs[name]} if name in theirs else {})
        try:
            if _shapes(make(config.env.task, **options)) != _shapes(env):
                reshaping.add(name)
        except (TypeError, ValueError):
            reshaping.add(name)
    return reshaping


def _shapes(env: Env) -> tuple[object, ...]:
    """The shapes a network's parameters depend on: each observation modality's and the action's."""
    observations = {name: leaf.shape for name, leaf in vars(env.observation_shapes()).items()}
    return observations, env.action_spec.shape, env.action_spec.num_actions
