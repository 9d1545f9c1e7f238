"""The experiment config: typed frozen dataclasses loaded from YAML with `key.sub=value` overrides.

A config file has five sections, each a dataclass below: `env` (task and its options), `ppo` (`PPOConfig`, with
the model in `ppo.network` and the normalisation in `ppo.normalization`), `logging`, `checkpoint` and
`distribution`. Keys left out take the dataclass defaults. `load_config` rejects unknown keys and wrong types;
`validate` then checks the combination against the task, so that every mistake surfaces before anything compiles.
"""

from __future__ import annotations

import contextlib
import dataclasses
import difflib
import importlib.util
import itertools
import json
import math
import numbers
import os
import re
import reprlib
import shlex
import types
import typing
from dataclasses import field
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
import yaml

from angora_jax.envs.core import Env
from angora_jax.envs.mujoco_task import MujocoEnv
from angora_jax.envs.registry import is_gymnasium, list_tasks, make, unknown_option
from angora_jax.envs.rendering import CAMERAS, RenderError, SceneRenderer
from angora_jax.experiment.contracts import check_own_code
from angora_jax.experiment.wandb_logging import WANDB_INSTALL, WANDB_MODES, WandbConfig
from angora_jax.frozen_settings import settings
from angora_jax.nets.registry import list_networks
from angora_jax.ppo.config import (
    INT64_MAX,
    SEED_MAX,
    PPOConfig,
    bounded,
    count_field,
    field_bounds,
    quote_number,
)
from angora_jax.ppo.memory import estimate_memory, network_too_large
from angora_jax.ppo.parallel import per_device, resolve_num_devices
from angora_jax.registry.plugins import ModuleNameError, defined_in_a_notebook, import_modules
from angora_jax.wording import did_you_mean

# Named configs (`load_config("cartpole")`) ship inside the package (the repository's configs/ links here), so a
# name is found from any working directory and in an installed wheel.
CONFIGS = Path(__file__).resolve().parents[1] / "configs"
# A config file may start from another: `extends: shadow_ihom` (a shipped name, or a path relative to the file).
EXTENDS = "extends"


# The end of the message for a task or network name that no registry knows.
YOUR_OWN = (" One of your own: list the module that registers it under imports (e.g. imports: [my_tasks]), or install "
            "it as a plugin.")


class ConfigError(ValueError):
    """A config that cannot run; the message names the key, what is allowed and how to fix it."""


class UnreadableConfigError(ConfigError):
    """A config file that holds no settings at all: not UTF-8, not valid YAML, empty (or only comments), or no
    mapping. `cause` says which without the fix for a config given to `train` (name a shipped one), so that a run's
    config.yaml can be answered with the run's own fix (`check --restore-config`, `run_dir.read_run_config`)."""

    def __init__(self, message: str, cause: str) -> None:
        super().__init__(message)
        self.cause = cause


# Far above any real config (the largest shipped one has under 200 YAML nodes and nests 7 levels deep), far below what
# hangs: a few hundred bytes of aliases of aliases ("billion laughs") expand to 10**9 values, which copying, checking
# or printing the config would each walk.
MAX_YAML_VALUES = 10_000
MAX_YAML_DEPTH = 50
MERGE_TAG = "tag:yaml.org,2002:merge"


class YAMLRefused(yaml.YAMLError):
    """YAML that parses but that no config may hold (an alias bomb, a key given twice); the message says where."""


class ConfigLoader(yaml.SafeLoader):
    """`yaml.SafeLoader` for configs and override values: refuses a key given twice in one mapping (YAML would keep
    the last silently), an alias that refers to a node that holds it, nesting deeper than `MAX_YAML_DEPTH` and a
    document that expands to more than `MAX_YAML_VALUES` nodes once aliases are expanded. Sizes are counted per node
    as it is composed (an alias adds its node's count without walking it again), so a bomb is refused in linear time."""

    def __init__(self, stream: str) -> None:
        super().__init__(stream)
        self._open_anchors: list[str | None] = []
        self._sizes: dict[int, int] = {}

    def compose_node(self, parent: yaml.Node | None, index: Any) -> yaml.Node:
        """The next node, checked for self-reference, depth and expanded size."""
        event = self.peek_event()
        if isinstance(event, yaml.AliasEvent) and event.anchor in self._open_anchors:
            raise YAMLRefused(f"alias *{event.anchor} (line {event.start_mark.line + 1}) refers to itself (it is "
                              f"inside the value anchored &{event.anchor}), which makes an endless value; write the "
                              "value out instead.")
        if len(self._open_anchors) >= MAX_YAML_DEPTH:
            raise YAMLRefused(f"values are nested more than {MAX_YAML_DEPTH} levels deep (line "
                              f"{event.start_mark.line + 1}); no config nests more than a few levels.")
        self._open_anchors.append(getattr(event, "anchor", None))
        try:
            node = super().compose_node(parent, index)
        finally:
            self._open_anchors.pop()
        if id(node) not in self._sizes:
            children = node.value if isinstance(node, yaml.SequenceNode) else (
                [item for pair in node.value for item in pair] if isinstance(node, yaml.MappingNode) else [])
            self._sizes[id(node)] = 1 + sum(self._sizes[id(child)] for child in children)
        if self._sizes[id(node)] > MAX_YAML_VALUES:
            raise YAMLRefused(f"expands to more than {MAX_YAML_VALUES:,} values when its aliases (*name) are expanded "
                              f"(line {event.start_mark.line + 1}), far more than any config holds: an alias bomb? "
                              "Repeat fewer aliases, or write the values out.")
        return node

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict[Any, Any]:
        """The mapping of `node`, refusing a key given twice (keys merged in with `<<` may be overridden)."""
        lines: dict[Any, int] = {}
        for key_node, _ in node.value:
            key = None if key_node.tag == MERGE_TAG else self.construct_object(key_node)
            if key is None or not isinstance(key, typing.Hashable):
                continue
            line = key_node.start_mark.line + 1
            if key in lines:
                raise YAMLRefused(f"key {key!r} appears twice in one mapping, on line {lines[key]} and line {line}; "
                                  "YAML would keep only the second. Keep one of them (put all the keys of a section "
                                  "under one heading).")
            lines[key] = line
        return super().construct_mapping(node, deep=deep)

    def construct_yaml_int(self, node: yaml.ScalarNode) -> int:
        """The integer of `node`, refused when Python will not read it (over 4,300 digits: no setting takes one) or
        when YAML 1.1 reads it otherwise than it reads (`misread_number`)."""
        try:
            return self.misread_number(node, super().construct_yaml_int(node))
        except ValueError:
            digits = sum(c.isdigit() for c in node.value)
            if digits <= 4300:  # a value tagged !!int that is no integer at all
                raise YAMLRefused(f"{node.value!r} on line {node.start_mark.line + 1} is tagged !!int but is no "
                                  "integer: give a whole number, without the tag.") from None
            raise YAMLRefused(f"the integer on line {node.start_mark.line + 1} has {digits:,} digits, more than any "
                              "setting takes: give a number in the key's range.") from None

    def construct_yaml_float(self, node: yaml.ScalarNode) -> float:
        """The float of `node`, refused when it is a base-60 number (`misread_number`)."""
        return self.misread_number(node, super().construct_yaml_float(node))

    @staticmethod
    def misread_number(node: yaml.ScalarNode, value: Any) -> Any:
        """`value`, refused where YAML 1.1 reads the text as no reader expects: `010` as octal 8 and `1:30` as base 60
        (90), so that `num_envs: 010` trained 8 environments. A leading 0 that changes nothing (`007`) is kept."""
        text = node.value.replace("_", "").lstrip("+-")
        if ":" in text:
            kind = "a base-60 number"
            fix = "write the number itself, or quote the value to give it as text."
        elif re.fullmatch(r"0[0-7]+", text) and int(text, 8) != int(text, 10):
            kind = "octal"
            fix = (f"write {int(node.value.replace('_', ''))} (or {value} if octal was meant), or quote the value to "
                   "give it as text.")
        else:
            return value
        raise YAMLRefused(f"{node.value!r} (line {node.start_mark.line + 1}) is {kind} in YAML 1.1, read as {value!r}: "
                          f"{fix}")


ConfigLoader.add_constructor("tag:yaml.org,2002:int", ConfigLoader.construct_yaml_int)
ConfigLoader.add_constructor("tag:yaml.org,2002:float", ConfigLoader.construct_yaml_float)


def load_yaml(text: str) -> Any:
    """`text` parsed as YAML by `ConfigLoader`; raises `YAMLRefused` or another `yaml.YAMLError`."""
    return yaml.load(text, Loader=ConfigLoader)


@settings
class EnvConfig:
    """The task a run trains on.

    Attributes:
        task: a registered task name (`angora-jax list-tasks`).
        options: keyword arguments of `angora_jax.make(task, **options)`, e.g. `max_episode_steps`, `reward`
            coefficients, `backend`.
    """

    task: str = "CartPole"
    options: dict[str, Any] = field(default_factory=dict)


@settings
class LoggingConfig:
    """Where a run is written and what is shown while it trains.

    Attributes:
        run_root: folder that holds run directories.
        run_name: the run directory's name; None makes one from task, network and start time.
        progress: "auto" (a live line on a terminal, plain log lines otherwise), "bar" (live line), "lines" (one line
            per cycle) or "none".
        tensorboard: also write TensorBoard event files (needs the tensorboardX package).
        wandb: also log to Weights & Biases (needs the wandb package): null (the default) for no, or a section
            (`logging.wandb.project=NAME`, or `logging.wandb={}` for the defaults) for yes.
        report: write the run's PNG and HTML report into `RUN_DIR/report` when training ends.
    """

    run_root: str = "runs"
    run_name: str | None = None
    progress: str = "auto"
    tensorboard: bool = False
    wandb: WandbConfig | None = None
    report: bool = True

    @property
    def root(self) -> Path:
        """`run_root` as the folder it names, a leading `~` read as the home folder: a shell leaves the `~` of
        `logging.run_root=~/runs` as it is (it expands a word's leading `~` only) and YAML never expands it, so runs
        went to a folder named `~` in the current one, which `rm -rf ~` then takes for the home folder."""
        return Path(self.run_root).expanduser()


PROGRESS_MODES = ("auto", "bar", "lines", "none")
# A run name is a folder name that every file system, shell and URL takes as it is (W&B and TensorBoard show it).
RUN_NAME = re.compile(r"[A-Za-z0-9_+=][A-Za-z0-9._+=-]*")
MAX_RUN_NAME = 100
# The longest folder name and path Linux takes (NAME_MAX, PATH_MAX less the terminating NUL); longer ones end in
# "File name too long" when the run directory is made.
MAX_NAME_BYTES, MAX_PATH_BYTES = 255, 4095
CHECKPOINT_KINDS = ("latest", "best", "snapshots")


@settings
class CheckpointConfig:
    """Which checkpoints a run keeps (all in `RUN_DIR/checkpoints`).

    Attributes:
        every: save the latest state every this many cycles (also at the end and when interrupted); the previous latest
            is replaced.
        best_metric: keep the state of the cycle with the best value of this per-cycle metric ("episode_return",
            "episode_length" or "metric/<task metric>"); None keeps no best checkpoint.
        best_mode: "max" or "min".
        best_episodes: the training metric is compared over this many of the latest episodes: the cycle's own when
            at least this many ended in it (the cube at 16,384 envs: hundreds), else pooled with the cycles before it
            (weighted by the episodes that ended in each), and no best until this many have ended. With few
            environments a cycle ends an episode or two, and a cycle whose one episode succeeded by chance (success
            1.0, which nothing later can beat) would otherwise stay the best for good. `eval/` metrics are held-out
            evaluations of their own size (`evaluation.episodes`) and are compared as they are. 1: each cycle's own.
        snapshot_every: keep a snapshot every this many cycles for good, for probing later; 0 for none.
        lean: the kinds of checkpoint ("latest", "best", "snapshots") saved without the environments' states (physics,
            recurrent carries, episode accumulators): parameters, optimizer, normalisers, PRNG key and cycle only, a
            small fraction of the size (the cube at 16,384 envs: the environments are most of a full checkpoint).
            Evaluating and probing read only parameters and normalisers, so lean best and snapshots (the default)
            lose nothing for them; best is lean by default because a learning run beats its best most cycles, and a
            full save (the cube at 16,384 envs: 300 MB, 1.6 s on an H200) then costs most of a cycle or more each time.
            Resuming from a lean checkpoint makes the environments afresh: the run goes on, but not bit for bit as if
            it had not stopped (`angora-jax resume --exact` refuses it).
    """

    every: int = count_field(10, why="cycles between latest checkpoints")
    best_metric: str | None = "episode_return"
    best_mode: str = "max"
    best_episodes: int = count_field(32, why="the episodes the best metric is compared over")
    snapshot_every: int = count_field(0, low=0, why="cycles between snapshots; 0: none")
    lean: tuple[str, ...] = ("best", "snapshots")


@settings
class VideoConfig:
    """A video of the current policy during training: one episode, mode actions, started with seed
    `evaluation.seed` (the episode `angora-jax render RUN_DIR --seed S` shows), rendered off screen on the C MuJoCo
    path from the parameters in memory and written to `RUN_DIR/videos/cycle_NNNNNN.gif`; the run's report shows the
    latest. Needs a MuJoCo task and an OpenGL backend (MUJOCO_GL=egl or osmesa on a machine without a display).

    Attributes:
        every: a video after every this many cycles and after the last.
        steps: at most this many policy steps of the episode (rendering runs on one CPU core, about as fast as the
            episode plays).
        camera: a view of the hand or body (`angora_jax.envs.rendering.CAMERAS`).
        width: the frames' width in pixels.
        height: their height in pixels.
    """

    every: int = count_field(50, why="cycles between videos")
    steps: int = count_field(200, why="policy steps of the episode")
    camera: str = "front"
    # MuJoCo renders off screen into one OpenGL framebuffer, which GPUs and Mesa allow up to 16,384 pixels a side.
    width: int = bounded(320, 1, 16_384, why="pixels")
    height: int = bounded(240, 1, 16_384, why="pixels")


@settings
class EvaluationConfig:
    """Deterministic evaluation on held-out episodes during training. The training mean goes stale on tasks whose
    good policies end few episodes per cycle (a cube policy that keeps the cube for 50 goals), and it mixes the
    policy's exploration noise into the metric.

    Attributes:
        every: evaluate after every this many cycles (and after the last); 0 never.
        episodes: fresh environments, one episode each, run at once on the batched path (the training physics) with the
            head's mode on this process's first device.
        seed: the episodes' starts, the same at every evaluation, so that evaluations compare policies on the same
            episodes (the training seed does not draw them). An evaluated cycle's record gets `eval/episode_return`,
            `eval/episode_length` and `eval/metric/<name>` (means over the episodes), which `checkpoint.best_metric` and
            `ppo.stop_at.metric` may name.
        video: null (the default) for none, or a section (`evaluation.video={every: 50}`) for a video of the policy
            every so many cycles (see `VideoConfig`); it runs whether or not `every` does.
    """

    every: int = count_field(0, low=0, why="cycles between evaluations; 0: never")
    episodes: int = count_field(64, why="held-out episodes")
    seed: int = bounded(1, 0, SEED_MAX, why="JAX keeps a seed's low 32 bits, so other seeds repeat these")
    video: VideoConfig | None = None


@settings
class DistributionConfig:
    """The devices of a data-parallel run.

    Attributes:
        num_devices: devices to train on data-parallel, an integer or "all" (every device JAX sees); 1 is the plain
            single-device cycle. `ppo.num_envs` and `ppo.minibatch_size` are run totals, divided over the devices, so
            they must be multiples of the device count (see `angora_jax.ppo.parallel`).
    """

    num_devices: int | str = count_field(1, why='devices, or "all"')


@settings
class Config:
    """Everything one experiment needs; `to_dict(config)` is its resolved form as saved with a run.

    Attributes:
        imports: Python modules imported before anything is built, by dotted name (e.g. `[my_tasks]`), so that the
            tasks, networks, heads and components they register can be named in the config; each must be importable
            (its folder on PYTHONPATH, or installed). The run records them, and every command that reads it imports
            them again. Installed plugins (entry-point group `angora_jax.plugins`) load without being listed.
        env: the task and its options.
        ppo: the PPO run and its network.
        logging: where the run is written and what is shown.
        checkpoint: which checkpoints are kept.
        distribution: the devices of a data-parallel run.
        evaluation: held-out evaluations during training.
    """

    env: EnvConfig = field(default_factory=EnvConfig)
    ppo: PPOConfig = field(default_factory=PPOConfig)
    logging: LoggingConfig = field(default_factory=LoggingConfig)
    checkpoint: CheckpointConfig = field(default_factory=CheckpointConfig)
    distribution: DistributionConfig = field(default_factory=DistributionConfig)
    evaluation: EvaluationConfig = field(default_factory=EvaluationConfig)
    imports: tuple[str, ...] = ()


def load_config(source: str | Path | dict | None = None, overrides: typing.Iterable[str] = ()) -> Config:
    """Read a config and apply `overrides`; no validation against the task yet (see `validate`).

    A file whose top-level `extends` names another config (a shipped name, or a path relative to the file) is that
    config with the file's keys on top: sections merge key by key, other values replace.

    Args:
        source: a YAML file path, the name of a shipped config (`list_configs()`, e.g. "cartpole"), a dict with the
            same structure, a `Config` (loaded earlier; the overrides apply to a copy), or None for the defaults.
        overrides: strings `key.sub=value`, the value in YAML syntax (one such string alone is one override); a
            later one of the same key replaces an earlier (`repeated_keys` names them).

    Raises:
        ConfigError: a missing file, bad YAML, an unknown key, a value of the wrong type.
    """
    if isinstance(source, Config):  # loaded in an earlier cell: itself, checked as `train` checks one
        if not override_strings(overrides):
            return checked(source)
        data = to_dict(checked(source))  # the form a run's config.yaml keeps, which loads back to the same Config
    else:
        data = _read(source)
    for override in override_strings(overrides):
        _apply_override(data, override)
    return _build(Config, data, "")


def override_strings(overrides: typing.Iterable[str] | str | None, name: str = "overrides") -> list[str]:
    """`overrides` as a list of KEY=VALUE strings: one string alone is one override, None none. ConfigError naming
    the list to give for a dict (`{"ppo.num_envs": 8}`, nested or not) or items that are not strings (pairs)."""
    if overrides is None:
        return []
    if isinstance(overrides, str):
        return [overrides]
    items = list(flatten(overrides).items()) if isinstance(overrides, dict) else list(overrides)
    if not isinstance(overrides, dict) and all(isinstance(item, str) for item in items):
        return items
    odd = next(item for item in items if not isinstance(item, str))
    given = "a dict" if isinstance(overrides, dict) else f"{_shorten(odd)} ({type(odd).__name__})"
    pairs = [item if isinstance(item, str) else f"{item[0]}={_yaml_text(item[1])}" for item in items
             if isinstance(item, str) or (isinstance(item, tuple | list) and len(item) == 2)]
    raise ConfigError(f"{name} are KEY=VALUE strings, the value in YAML syntax: give "
                      f"{pairs or ['ppo.num_cycles=20']!r}, not {given}.")


def repeated_keys(overrides: typing.Iterable[str]) -> list[str]:
    """A sentence per key that the KEY=VALUE strings `overrides` give more than once, naming its overrides and that
    the last one is used (`load_config` applies them in order). Command lines built from a shared part and a
    particular one (`angora-jax train cartpole $COMMON ppo.num_envs=8`) repeat keys on purpose; a key pasted twice
    (`ppo.learning_rate=1e-3 ppo.learning_rate=2e-3`) trained at 2e-3 without a word."""
    given: dict[str, list[str]] = {}
    for override in overrides:
        given.setdefault(override.partition("=")[0].strip(), []).append(override)
    return [f"{key} is given {len(each)} times ({', then '.join(repr(o) for o in each)}): the last one is used."
            for key, each in given.items() if len(each) > 1]


def check_count(name: str, value: object, least: int = 1) -> int:
    """`value` as an int; ConfigError unless it is a whole number of at least `least` (an int or a numpy integer,
    not a bool): a count of episodes or environments given in Python, where 0 gave NaN means and a float or text
    failed deep inside JAX. ConfigError is a ValueError, which this raised before."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < least:
        raise ConfigError(f"{name} must be a whole number of at least {least}, got {value!r}.")
    return int(value)


def check_flag(name: str, value: object) -> bool:
    """`value` as a bool; TypeError unless it is True or False (a numpy bool too): "no" or "false" from a widget or
    a file, and any non-zero number, are true values that would silently do what was declined."""
    if not isinstance(value, bool | np.bool_):
        raise TypeError(f"{name} must be True or False, got {value!r} ({type(value).__name__})"
                        f"{': a non-empty string counts as True' if isinstance(value, str) else ''}.")
    return bool(value)


def check_seed(name: str, value: object) -> int:
    """`value` as an int; ConfigError unless it is a seed, a whole number from 0 to SEED_MAX (an int or a numpy
    integer, not a bool), as ppo.seed is checked in a config: a seed given in Python as 1.5 or "3" failed inside a
    compiled JAX program ("PRNG key seed must be an integer; got JitTracer(~float32[])")."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral) or not 0 <= value <= SEED_MAX:
        raise ConfigError(f"{name} must be a whole number from 0 to {SEED_MAX:,}, got {value!r}.")
    return int(value)


def check_number(name: str, value: object, low: float, high: float = math.inf, open_low: bool = False,
                 open_high: bool = False) -> float:
    """`value` as a float; ConfigError unless it is a finite real number (an int, a float or a numpy number, not a
    bool) from `low` (above it, with `open_low`) to `high` (below it, with `open_high`): a fraction or a rate given in
    Python, where text failed inside JAX ("Only integer scalar arrays can be converted to a scalar index") and a
    number out of range (a blur of 2, a negative learning rate, NaN) gave a result without a word."""
    try:
        number = math.nan if isinstance(value, bool) or not isinstance(value, numbers.Real) else float(value)
    except OverflowError:  # an int past a float's range
        number = math.nan
    above = low < number if open_low else low <= number
    below = number < high if open_high else number <= high
    if not math.isfinite(number) or not above or not below:
        start = "above" if open_low else "from" if high < math.inf and not open_high else "of at least"
        end = ("" if high == math.inf else f" and below {high:g}" if open_high
               else f" up to {high:g}" if open_low else f" to {high:g}")
        raise ConfigError(f"{name} must be a number {start} {low:g}{end}, got {quote_number(value)}.")
    return number


def _yaml_text(value: Any) -> str:
    """`value` as the text of an override's value."""
    return value if isinstance(value, str) else json.dumps(value, default=str)


def list_configs() -> dict[str, str]:
    """The shipped configs, name -> the first sentence of the file's leading comment (what it trains)."""
    described = {}
    for path in sorted(CONFIGS.glob("*.yaml")):
        comment = itertools.takewhile(lambda line: line.startswith("#"), path.read_text().splitlines())
        text = " ".join(line.lstrip("# ").strip() for line in comment)
        described[path.stem] = re.split(r"(?<!\bal)(?<!Fig)[.:;]\s", text, maxsplit=1)[0].rstrip(".:;")
    return described


def checked(config: Config) -> Config:
    """`config` as `load_config` reads it from its dict: ConfigError naming a key of the wrong type or range in a
    Config made or changed in Python (`dataclasses.replace`), which skipped those checks, and a Path or numpy number
    made plain, as its run's config.yaml must hold it."""
    return load_config(to_dict(config))


def to_dict(config: Config) -> dict[str, Any]:
    """The config as nested plain dicts (what config.yaml in a run directory holds)."""
    return dataclasses.asdict(config)


def flatten(data: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    """Nested dicts as one dict with dotted keys (`{"ppo": {"gamma": 0.99}}` -> `{"ppo.gamma": 0.99}`)."""
    flat: dict[str, Any] = {}
    for key, value in data.items():
        if isinstance(value, dict) and value:
            flat |= flatten(value, f"{prefix}{key}.")
        else:
            flat[f"{prefix}{key}"] = value
    return flat


def _check_video(video: VideoConfig, env: Env) -> None:
    """Refuse a video section that cannot be rendered, before anything compiles."""
    if not isinstance(env, MujocoEnv):
        raise ConfigError(f"evaluation.video needs a MuJoCo task (one with a scene to render); {type(env).__name__} "
                          "has none: set evaluation.video=null.")
    if video.camera not in CAMERAS:
        raise ConfigError(_unknown("evaluation.video.camera", video.camera, sorted(CAMERAS), "cameras"))
    try:  # an OpenGL context now, rather than a failed video after hours of training
        SceneRenderer(mujoco.MjModel.from_xml_string("<mujoco/>"), None, CAMERAS[video.camera], 16, 16).close()
    except RenderError as error:
        raise ConfigError(f"evaluation.video cannot render here: {error} Or set evaluation.video=null.") from None


def best_metric_choices(env: Env, evaluation: EvaluationConfig | None = None) -> list[str]:
    """Per-cycle metrics that `checkpoint.best_metric` and `ppo.stop_at.metric` may name for `env`: the training
    means, and with `evaluation.every` the held-out evaluation's (`eval/...`)."""
    names = ["episode_return", "episode_length", *(f"metric/{name}" for name in env.metric_names)]
    return names + [f"eval/{name}" for name in names] if evaluation is not None and evaluation.every else names


def validate(config: Config, new_run: bool = True) -> Env:
    """Check the whole config, the task included, without compiling anything; return the task's environment.

    Args:
        config: the config to check.
        new_run: also check where a new run directory would be made (`check_run_location`); False for the config of a
            run that exists (resuming or reading it), whose directory was made under the rules of its time.

    Raises:
        ConfigError: naming the key (e.g. `ppo.minibatch_size`), the allowed values and the fix.
        UserCodeError: a task or network of one's own that cannot be imported or breaks its contract
            (`contracts.check_own_code`: traced, not run).
    """
    # First: the user's modules register the tasks and networks that the checks below look up (UserCodeError: one
    # that cannot be imported here, which says nothing of the config itself; a name no module can have does).
    try:
        import_modules(config.imports,
                       "listed under imports in the config; a run's config.yaml lists those it trained with")
    except ModuleNameError as error:
        raise ConfigError(str(error)) from None
    config = checked(config)  # a Config made or changed in Python skipped load_config's checks of types and ranges
    if config.env.task not in list_tasks() and not is_gymnasium(config.env.task):
        raise ConfigError(_unknown("env.task", config.env.task, list_tasks(), "tasks") +
                          " Any Gymnasium environment: gym:<id>, e.g. gym:LunarLander-v3." +
                          (defined_in_a_notebook(config.env.task) or YOUR_OWN))
    _check_options(config.env.options, "env.options")
    unknown = None if is_gymnasium(config.env.task) else unknown_option(config.env.task, config.env.options)
    if unknown is not None:
        raise ConfigError(f"env.options do not fit task {config.env.task!r}: it {unknown}")
    try:
        env = make(config.env.task, **config.env.options)
    except (TypeError, ValueError) as error:
        raise ConfigError(f"env.options do not fit task {config.env.task!r}: {error}") from None
    except ModuleNotFoundError as error:  # an optional package the task needs (its message names the install)
        raise ConfigError(f"Task {config.env.task!r} cannot be made: {error}") from None
    if config.ppo.network.name not in list_networks():
        raise ConfigError(_unknown("ppo.network.name", config.ppo.network.name, list_networks(), "networks") +
                          (defined_in_a_notebook(config.ppo.network.name) or YOUR_OWN))
    check_own_code(config.env.task, config.ppo.network, env)
    try:
        config.ppo.validate_for(env)
    except ValueError as error:
        raise ConfigError(f"ppo section: {error}") from None
    logging, checkpoint = config.logging, config.checkpoint
    if logging.progress not in PROGRESS_MODES:
        raise ConfigError(_unknown("logging.progress", logging.progress, PROGRESS_MODES, "modes"))
    if new_run:
        check_run_location(logging)
    if logging.tensorboard and importlib.util.find_spec("tensorboardX") is None:
        raise ConfigError(
            "logging.tensorboard=true needs the tensorboardX package: pip install -c constraints.txt -e "
            "'.[tensorboard]' in a clone of angora_jax (or pip install tensorboardX), or set "
            "logging.tensorboard=false (metrics.jsonl is always written)."
        )
    if logging.wandb is not None:
        if logging.wandb.mode not in WANDB_MODES:
            raise ConfigError(_unknown("logging.wandb.mode", logging.wandb.mode, WANDB_MODES, "modes"))
        if importlib.util.find_spec("wandb") is None:
            raise ConfigError(f"logging.wandb needs the wandb package: {WANDB_INSTALL}; or set logging.wandb=null "
                              "(metrics.jsonl is always written).")
    for kind in checkpoint.lean:
        if kind not in CHECKPOINT_KINDS:
            raise ConfigError(_unknown("checkpoint.lean", kind, CHECKPOINT_KINDS, "kinds of checkpoint"))
    if checkpoint.best_mode not in ("max", "min"):
        raise ConfigError(_unknown("checkpoint.best_mode", checkpoint.best_mode, ("max", "min"), "modes"))
    if config.evaluation.video is not None:
        _check_video(config.evaluation.video, env)
    choices = best_metric_choices(env, config.evaluation)
    named = {"checkpoint.best_metric": (checkpoint.best_metric, [*choices, "null"]),
             "ppo.stop_at.metric": (config.ppo.stop_at.metric if config.ppo.stop_at else None, choices)}
    for key, (name, allowed) in named.items():
        if name is None or name in choices:
            continue
        if name.startswith("eval/") and not config.evaluation.every:
            raise ConfigError(f"{key}={name!r} names a held-out evaluation's metric, but none runs: set "
                              "evaluation.every=N (evaluate every N cycles).")
        raise ConfigError(_unknown(key, name, allowed, "metrics"))
    try:
        devices = num_devices(config)
    except ConfigError as error:
        if new_run:
            raise
        raise ConfigError(f"{error} A run's device count is distribution.num_devices in its config.yaml: edit it there "
                          "(resume lays the run out again on the devices it gets; only its env and ppo settings must "
                          "stay as trained).") from None
    try:
        per_device(config.ppo, devices)
    except ValueError as error:
        raise ConfigError(str(error)) from None
    if (too_large := network_too_large(config.ppo, env)) is not None:
        raise ConfigError(too_large)
    memory = estimate_memory(config.ppo, env, devices)
    if not memory.fits():
        raise ConfigError(
            f"ppo.num_envs={config.ppo.num_envs:,} with ppo.rollout_length={config.ppo.rollout_length} cannot fit: "
            f"it needs {memory.describe()}. Use ppo.num_envs <= {memory.max_envs * devices:,} (or a "
            "shorter rollout, or more devices with distribution.num_devices)."
        )
    return env


def check_run_location(logging: LoggingConfig) -> None:
    """ConfigError unless `logging.run_name` is a portable folder name and `logging.run_root` a path a folder can be
    made at."""
    name = logging.run_name
    if name is not None and (len(name) > MAX_RUN_NAME or not RUN_NAME.fullmatch(name)):
        raise ConfigError(
            f"logging.run_name={_shorten(name)} must be a plain folder name: at most {MAX_RUN_NAME} characters"
            f"{f' (it has {len(name)})' if len(name) > MAX_RUN_NAME else ''} of letters, digits, '.', '_', '-', '+' "
            "and '=', not starting with '.' or '-' (so no '/', '\\' or '..'): the run directory is made inside "
            f"logging.run_root ({_shorten(logging.run_root)}); to write elsewhere, change logging.run_root."
        )
    _check_folder("logging.run_root", str(logging.root))  # the folder made: a leading ~ expanded
    # A file where the folder (or a folder on its way) would be made: mkdir says only "File exists"/"Not a directory".
    existing = next((path for path in (logging.root, *logging.root.parents) if path.exists()), None)
    if existing is not None and not existing.is_dir():
        raise ConfigError(f"logging.run_root={_shorten(logging.run_root)} cannot hold run directories: {existing} is a "
                          "file. Choose a folder for runs (e.g. logging.run_root=runs).")


def num_devices(config: Config) -> int:
    """The number of devices the run trains on (`distribution.num_devices` resolved); ConfigError if unavailable."""
    try:
        return resolve_num_devices(config.distribution.num_devices)
    except ValueError as error:
        raise ConfigError(str(error)) from None


def _yaml_problem(error: yaml.YAMLError) -> str:
    """PyYAML's error as one sentence with its line, and the fix for a tab (YAML indents with spaces only), which
    PyYAML calls "found character '\\t' that cannot start any token" and leaves the reader to work out."""
    if (parts := _yaml_parts(error)) is None:
        return str(error)
    problem, mark = parts
    where = f"{problem} (line {mark.line + 1}, column {mark.column + 1})"
    if "'\\t'" in problem:
        return (f"{where}: YAML indents with spaces, never tabs: replace the tabs on that line with spaces (an "
                "editor's 'convert indentation to spaces' does the whole file).")
    return f"{where}: fix that line or the one before it (a missing ':', bracket or quote is usual)."


def _yaml_parts(error: yaml.YAMLError) -> tuple[str, Any] | None:
    """PyYAML's problem (its last line, without the snippet and caret) and where it is; None when it names none."""
    mark = getattr(error, "problem_mark", None)
    problem = getattr(error, "problem", None)
    return None if mark is None or problem is None else (problem, mark)


def _override_problem(override: str, key: str, text: str, error: yaml.YAMLError) -> str:
    """A value of an override that is not valid YAML (`ppo.num_envs=[1`) in one sentence: PyYAML's problem and the
    character it is at, what closes a bracket or quote left open (when that makes it valid), and the override with
    the value quoted as text. Each fix is written as a shell takes it (quoted where the shell would otherwise change
    it), the way the override was most likely given."""
    parts = _yaml_parts(error)
    problem = (f"{parts[0]} at character {parts[1].column + 1}" if parts and parts[1].line == 0 else
               parts[0] if parts else str(error).splitlines()[-1].strip())
    closer = _closing(text)
    closes = ""
    if closer:
        with contextlib.suppress(yaml.YAMLError, YAMLRefused):
            load_yaml(text + closer)
            closes = f"add the missing {closer!r} ({shlex.quote(f'{key}={text}{closer}')}) or "
    quoted = shlex.quote(f"{key}={json.dumps(text, ensure_ascii=False)}")
    return (f"Override {_shorten(override)}: its value is not valid YAML ({problem}); {closes}quote the value to give "
            f"it as text ({quoted}).")


def _closing(text: str) -> str:
    """What closes the quote and the brackets that `text` leaves open, innermost first ("" when none is open)."""
    stack: list[str] = []
    quote = None
    for char in text:
        if quote is not None:
            quote = None if char == quote else quote
        elif char in "\"'":
            quote = char
        elif char in "[{":
            stack.append("]" if char == "[" else "}")
        elif stack and char == stack[-1]:
            stack.pop()
    return (quote or "") + "".join(reversed(stack))


def _read(source: str | Path | dict | None, chain: tuple[Path, ...] = ()) -> dict[str, Any]:
    if source is None:
        return {}
    if isinstance(source, dict):
        return _deep_copy(source)
    if not isinstance(source, str | os.PathLike):  # Path() would say only "expected str, bytes or os.PathLike object"
        raise ConfigError(f"A config is the name of a shipped config (e.g. 'cartpole'), a YAML file's path, a dict or "
                          f"a Config; got {_shorten(source)} ({type(source).__name__}).")
    path = Path(source).expanduser()  # `extends: ~/configs/base.yaml`: no shell expands a `~` inside a file
    if not path.exists() and path.suffix == "" and (CONFIGS / f"{source}.yaml").exists():
        path = CONFIGS / f"{source}.yaml"
    if not path.exists():
        shipped = list_configs()
        raise ConfigError(
            f"Config file {str(source)!r} not found{f' (extended by {chain[-1]})' if chain else ''}."
            f"{did_you_mean(source, shipped)} Give a YAML path or the name of a shipped config: "
            f"{', '.join(shipped)} (angora-jax list-configs)."
        )
    if path.is_dir():
        raise ConfigError(f"{path} is a directory; give a config's YAML file (to continue a run: angora-jax resume "
                          f"{path}).")
    try:
        data = load_yaml(path.read_text(encoding="utf-8"))
    except YAMLRefused as error:
        raise ConfigError(f"{path}: {error}") from None
    except UnicodeDecodeError:
        raise UnreadableConfigError(
            f"{path} is not a text file (not UTF-8): a config is a YAML file such as {CONFIGS / 'cartpole.yaml'}, or "
            "the name of a shipped config (angora-jax list-configs).", "it is not a text file (not UTF-8).") from None
    except yaml.YAMLError as error:
        problem = _yaml_problem(error)
        raise UnreadableConfigError(f"{path} is not valid YAML: {problem}",
                                    f"it is not valid YAML: {problem.rstrip('.')}.") from None
    if data is None:
        raise UnreadableConfigError(
            f"{path} holds no settings (it is empty or only comments). Name a shipped config instead "
            f"({', '.join(list_configs())}), or start the file with `{EXTENDS}: NAME` and the keys to change.",
            "it holds no settings (it is empty or only comments).")
    if not isinstance(data, dict):
        raise UnreadableConfigError(
            f"{path} must hold a mapping of sections (env, ppo, ...), got {type(data).__name__}.",
            f"it holds a {type(data).__name__}, not a mapping of sections (env, ppo, ...).")
    if EXTENDS not in data:
        return data
    # `extends: NAME` (a shipped config or a path relative to this file): that config with this file's keys on top.
    base = data.pop(EXTENDS)
    if not isinstance(base, str):
        raise ConfigError(f"{path}: {EXTENDS} names one config (a shipped name or a YAML path), got {base!r}.")
    here = path.resolve()
    if here in chain:
        raise ConfigError(f"{path}: {EXTENDS} goes round in a circle: {' -> '.join(map(str, (*chain, here)))}.")
    relative = here.parent / base
    return _merge(_read(relative if relative.suffix and relative.exists() else base, (*chain, here)), data)


def _merge(base: dict[str, Any], top: dict[str, Any]) -> dict[str, Any]:
    """`top` over `base`: sections merge key by key, any other value (lists included) replaces the base's."""
    merged = dict(base)
    for key, value in top.items():
        both = isinstance(value, dict) and isinstance(merged.get(key), dict)
        merged[key] = _merge(merged[key], value) if both else value
    return merged


def _deep_copy(data: Any) -> Any:
    """A copy of a config's dict, with the values a notebook gives that YAML cannot save made plain: a Path as its
    text, a numpy number as Python's."""
    if isinstance(data, dict):
        return {key: _deep_copy(value) for key, value in data.items()}
    if isinstance(data, list):
        return [_deep_copy(value) for value in data]
    if isinstance(data, Path):
        return str(data)
    return data.item() if isinstance(data, np.generic) else data


def _apply_override(data: dict[str, Any], override: str) -> None:
    key, sep, text = override.partition("=")
    if not sep or not key or any(not part for part in key.split(".")):
        spaced = override.split(None, 1)
        colon = re.fullmatch(r"([\w.]+):\s*(\S.*)", override) if not sep else None  # YAML's `key: value`
        example = (f"{colon[1]}={colon[2]}" if colon else "=".join(spaced) if not sep and len(spaced) == 2 else
                   f"{key}=VALUE" if key and not sep and all(key.split(".")) else "ppo.num_cycles=20")
        raise ConfigError(f"Override {override!r} must look like key.sub=value, e.g. {example}.")
    try:
        value = load_yaml(text)
    except YAMLRefused as error:
        raise ConfigError(f"Override {_shorten(override)}: {error}") from None
    except yaml.YAMLError as error:
        raise ConfigError(_override_problem(override, key, text, error)) from None
    *sections, leaf = key.split(".")
    node = data
    for depth, section in enumerate(sections):
        node = node.setdefault(section, {})
        if not isinstance(node, dict):
            raise ConfigError(f"Override {override!r}: {'.'.join(sections[: depth + 1])} is a value, not a section.")
    both = isinstance(value, dict) and isinstance(node.get(leaf), dict) and _is_section(key)
    node[leaf] = _merge(node[leaf], value) if both else value  # a section merges, as over `extends`


def _is_section(key: str) -> bool:
    """Whether the dotted `key` names a section of `Config` (`ppo`, `logging.wandb`), not a value such as a mapping
    of named entries (`ppo.network.graph.areas`), which an override replaces whole."""
    def section(kind: Any) -> Any:  # the dataclass of `kind` or of `kind | None`, else None
        options = typing.get_args(kind) if isinstance(kind, types.UnionType) else (kind,)
        return next((option for option in options if dataclasses.is_dataclass(option)), None)

    kind: Any = Config
    for part in key.split("."):
        fields = typing.get_type_hints(cls) if (cls := section(kind)) is not None else {}
        if part not in fields:
            return False
        kind = fields[part]
    return section(kind) is not None


def _paths_below(cls: type, key: str, prefix: str = "") -> list[str]:
    """Dotted paths of the keys named `key` in the sections below `cls` (`seed` -> ppo.seed, evaluation.seed): a key
    given at the wrong level is most often one of these."""
    hints = typing.get_type_hints(cls)
    found = []
    for name in (f.name for f in dataclasses.fields(cls)):
        for kind in (hints[name], *typing.get_args(hints[name])):
            if dataclasses.is_dataclass(kind):
                section = f"{prefix}{name}"
                found += [f"{section}.{key}"] if key in {f.name for f in dataclasses.fields(kind)} else []
                found += _paths_below(kind, key, f"{section}.")
    return found


def _build(cls: type, data: Any, path: str) -> Any:
    where = path or "the config"
    if not isinstance(data, dict):
        raise ConfigError(f"{where} must be a mapping of keys to values, got {_shorten(data)}.")
    names = [f.name for f in dataclasses.fields(cls)]
    for key in data:
        if not isinstance(key, str):
            raise ConfigError(f"Key {_shorten(key)} ({type(key).__name__}) of {where} is not a name: keys are words "
                              f"such as {names[0]!r} (keys of {where}: {', '.join(names)}); quote it if it is one.")
        if key not in names:
            full = f"{path}.{key}" if path else str(key)
            if "." in key and key.split(".")[0] in names:
                raise ConfigError(_dotted_key(full, data[key]) + _misspelt_below(cls, key, path))
            prefix = f"{path}." if path else ""
            close = [prefix + name for name in difflib.get_close_matches(str(key), names, n=1)]
            guesses = close or [prefix + below for below in _paths_below(cls, str(key))]
            hint = f" Did you mean {' or '.join(map(repr, guesses))}?" if guesses else ""
            raise ConfigError(f"Unknown key {full!r}.{hint} Keys of {where}: {', '.join(names)}.")
    required = [f for f in dataclasses.fields(cls)
                if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING and f.name not in data]
    if required:
        needed = ", ".join(f.name + (f" ({f.metadata['bounds'].why})" if "bounds" in f.metadata else "")
                           for f in required)
        raise ConfigError(f"{where} needs {needed} (keys of {where}: {', '.join(names)}).")
    hints = typing.get_type_hints(cls)
    values = {}
    for key, value in data.items():
        full = f"{path}.{key}" if path else key
        values[key] = _convert(hints[key], value, full)
        bounds = field_bounds(cls, key)
        if bounds is not None:
            try:
                bounds.check(full, values[key])
            except ValueError as error:
                raise ConfigError(str(error)) from None
    return cls(**values)


def _dotted_key(full: str, value: Any) -> str:
    """The message for a dotted key in a file (`ppo.num_envs: 8`), which YAML reads as one key named so: the file's
    way to write it (nested), and where a dotted key belongs (an override)."""
    shown = yaml.safe_dump(value, default_flow_style=True, width=1000).strip().removesuffix("...").strip()
    shown = shown if len(shown) <= 60 and "\n" not in shown else "VALUE"
    *sections, leaf = full.split(".")
    lines = [f"`{'  ' * depth}{section}:`" for depth, section in enumerate(sections)]
    nested = " then ".join([*lines, f"`{'  ' * len(sections)}{leaf}: {shown}`"])
    return (f"Unknown key {full!r}: in a YAML file, write it nested ({nested}); dotted keys are for command-line "
            f"overrides ({full}={shown}).")


def _misspelt_below(cls: type, dotted: str, path: str) -> str:
    """For a dotted key in a file: whether nesting it alone would fix it, or a part of it is no key either
    (`ppo.num_envz`), said now rather than after the user has nested it."""
    prefix = f"{path}." if path else ""
    for part in dotted.split("."):
        names = [f.name for f in dataclasses.fields(cls)]
        if part not in names:
            close = difflib.get_close_matches(part, names, n=1)
            guess = f": did you mean {prefix + close[0]!r}?" if close else f" (keys there: {', '.join(names)})."
            return f" Nested, it is still unknown: there is no key {prefix + part!r}{guess}"
        kind = typing.get_type_hints(cls)[part]
        options = [kind, *typing.get_args(kind)]  # an optional section (`StopAt | None`)
        sections = [option for option in options if dataclasses.is_dataclass(option)]
        if not sections:
            return ""
        cls, prefix = sections[0], f"{prefix}{part}."
    return ""


def _convert(kind: Any, value: Any, key: str, nullable: bool = False) -> Any:
    if dataclasses.is_dataclass(kind):
        if value is None:  # `ppo:` with its keys commented out, or `ppo=null`: over a shipped config, its keys lost
            raise ConfigError(f"{key} is empty (null), which would set all its keys to their defaults: give its keys "
                              f"under it, or leave it out (to keep what the config it extends sets).")
        return _build(kind, value, key)
    if isinstance(kind, types.UnionType) or typing.get_origin(kind) is typing.Union:
        options = [arg for arg in typing.get_args(kind) if arg is not type(None)]
        if value is None and type(None) in typing.get_args(kind):
            return None
        for option in options[:-1]:
            with contextlib.suppress(ConfigError):
                return _convert(option, value, key)
        if len(options) > 1 and all(option in _SCALAR_WORDS for option in options):
            # the last option's own refusal would name it alone ("must be a string" for `int | str`)
            with contextlib.suppress(ConfigError):
                return _convert(options[-1], value, key)
            raise _not_a(" or ".join(_SCALAR_WORDS[option] for option in options), key, value,
                         nullable=type(None) in typing.get_args(kind))
        return _convert(options[-1], value, key, nullable=type(None) in typing.get_args(kind))
    if kind is Any:
        return value
    if typing.get_origin(kind) is tuple:
        if not isinstance(value, list | tuple):
            raise ConfigError(f"{key} must be a list, got {_shorten(value)}.")
        item = typing.get_args(kind)[0]
        return tuple(_convert(item, entry, f"{key}[{i}]") for i, entry in enumerate(value))
    if typing.get_origin(kind) is dict:
        if not isinstance(value, dict) or not all(isinstance(k, str) for k in value):
            raise ConfigError(f"{key} must be a mapping with string keys, got {_shorten(value)}.")
        for name in value:
            _check_text(f"{key} key", name)
        item = typing.get_args(kind)[1]
        converted = {}
        for name, entry in value.items():
            try:
                converted[name] = _convert(item, entry, f"{key}.{name}")
            except ConfigError as error:
                # A misspelt name in an override (`graph.areas.PCM.size=8` for PMC) makes a new entry, which then
                # lacks keys the real one has: name the entry it most likely meant (only then, so that an error
                # inside an entry that is whole is not blamed on its name).
                others = [other for other in value if other != name]
                partial = dataclasses.is_dataclass(item) and isinstance(entry, dict) and any(
                    field.name not in entry for field in dataclasses.fields(item)
                    if field.default is dataclasses.MISSING and field.default_factory is dataclasses.MISSING)
                misspelt = difflib.get_close_matches(name, others, n=1) if partial else []
                if not misspelt:
                    raise
                raise ConfigError(f"{error} Did you mean {key}.{misspelt[0]}? {name!r} is not one of {key}'s "
                                  f"entries ({', '.join(others)}), so an override of it makes a new one.") from None
        return converted
    if kind is bool and isinstance(value, bool):
        return value
    if kind is int and isinstance(value, int) and not isinstance(value, bool):
        return value
    if kind is float and not isinstance(value, bool) and isinstance(value, int | float | str):
        try:  # YAML 1.1 reads `1e-3` (no dot) as a string
            number = float(value)
        except ValueError:
            number = None
        except OverflowError:  # an integer beyond any float
            number = math.inf
        if number is not None and not math.isfinite(number):
            shown = _shorten(value) if isinstance(value, str) else quote_number(value)
            raise ConfigError(f"{key} must be a finite number, got {shown}.")
        if number is not None:
            return number
    if kind is str and isinstance(value, str):
        return _check_text(key, value)
    raise _not_a(_SCALAR_WORDS.get(kind, str(kind)), key, value, nullable)


_SCALAR_WORDS = {bool: "true or false", int: "an integer", float: "a number", str: "a string"}


def _not_a(allowed: str, key: str, value: Any, nullable: bool) -> ConfigError:
    """The refusal of `value` for `key`, which must be `allowed` (words); a yes/no word that YAML read as a bool where
    no bool goes is named as such, with the quoting that gives it as text."""
    shown = quote_number(value) if isinstance(value, int) else _shorten(value)
    hint = (" YAML reads yes, no, on, off, true and false as true or false: quote the value to give it as text."
            if isinstance(value, bool) and "true" not in allowed else "")
    return ConfigError(f"{key} must be {allowed}{' or null' if nullable else ''}, got {shown} "
                       f"({type(value).__name__}).{hint}")


def _check_options(value: Any, key: str) -> None:
    """Refuse in the task's options (any structure) what no option can mean: a number that is not finite or that no
    64-bit integer holds, a key that is not a name, text that no name or path holds. Each task checks its own."""
    if isinstance(value, dict):
        for name, item in value.items():
            if not isinstance(name, str):
                raise ConfigError(f"Key {_shorten(name)} ({type(name).__name__}) of {key} is not a name: options are "
                                  "keyword arguments of the task; quote it if it is one.")
            _check_options(item, f"{key}.{_check_text(f'{key} key', name)}")
    elif isinstance(value, list):
        for index, item in enumerate(value):
            _check_options(item, f"{key}[{index}]")
    elif isinstance(value, float) and not math.isfinite(value):
        raise ConfigError(f"{key} must be a finite number, got {value}.")
    elif isinstance(value, int) and not isinstance(value, bool) and abs(value) > INT64_MAX:
        raise ConfigError(f"{key} must be an integer of at most {INT64_MAX:,} in size (what numpy and JAX hold), "
                          f"got {quote_number(value)}.")
    elif isinstance(value, str):
        _check_text(key, value)


def _check_folder(key: str, path: str) -> None:
    """Refuse a folder path that no directory can be made at: too long, or with a name too long (in bytes)."""
    size = len(os.fsencode(path))
    if size > MAX_PATH_BYTES:
        raise ConfigError(f"{key}={_shorten(path)} is {size:,} bytes long; file systems allow paths of "
                          f"{MAX_PATH_BYTES:,}: choose a shorter folder.")
    for part in Path(path).parts:
        if len(os.fsencode(part)) > MAX_NAME_BYTES:
            raise ConfigError(f"{key}={_shorten(path)} has a folder name of {len(os.fsencode(part)):,} bytes "
                              f"({_shorten(part)}); file systems allow {MAX_NAME_BYTES}: shorten it.")


def _check_text(key: str, text: str) -> str:
    """`text`, refused when no name or path could hold it: a NUL character, or a lone surrogate (not Unicode)."""
    if "\0" in text:
        raise ConfigError(f"{key}={_shorten(text)} holds a NUL character (\\0), which no name or path may hold: "
                          "remove it.")
    try:
        text.encode("utf-8")
    except UnicodeEncodeError as error:
        raise ConfigError(f"{key}={_shorten(text)} is not valid Unicode text ({error.reason}: "
                          f"{text[error.start:error.end]!r}): remove the escape.") from None
    return text


# Values quoted in messages are cut short: a message is one paragraph however long or deep the value given.
_QUOTE = reprlib.Repr()
_QUOTE.maxstring = _QUOTE.maxother = 80


def _shorten(value: Any) -> str:
    return _QUOTE.repr(value)


def _unknown(key: str, value: Any, allowed: typing.Iterable[str], plural: str) -> str:
    allowed = list(allowed)
    return (f"Unknown value {value!r} for {key}.{did_you_mean(value, allowed)} Allowed {plural}: "
            f"{', '.join(map(str, allowed))}.")
