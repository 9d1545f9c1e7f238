"""Property-based tests of config parsing: for every config key, values of every wrong kind (wrong types, numbers
that are not finite or out of the key's declared range, huge integers, text with NUL, long text, nested junk), given
as `key=value` overrides in YAML, are either accepted (only when valid) or refused with a ConfigError, never another
exception, and nothing is written anywhere."""

import atexit
import dataclasses
import math
import os
import shutil
import tempfile
import typing
from pathlib import Path

import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from angora_jax.cli import main
from angora_jax.experiment.config import Config, ConfigError, load_config, validate
from angora_jax.ppo.config import Bounds, field_bounds

# Hypothesis keeps what it learns in .hypothesis in the working directory; these tests leave nothing behind, so it
# keeps it in a folder of this session.
if "HYPOTHESIS_STORAGE_DIRECTORY" not in os.environ:
    os.environ["HYPOTHESIS_STORAGE_DIRECTORY"] = tempfile.mkdtemp(prefix="angora_jax_hypothesis_")
    atexit.register(shutil.rmtree, os.environ["HYPOTHESIS_STORAGE_DIRECTORY"], ignore_errors=True)

# A small valid brain-area graph on CartPole, so that the graph's keys are reached (`areas.S1` stands for any area).
GRAPH = ["ppo.network.name=areas", "ppo.network.width=null",
         "ppo.network.graph={areas: {S1: {size: 4, inputs: [proprioception]}, M1: {size: 4, inputs: [S1, goal]}}, "
         "policy: M1}"]
# Sections that are null by default, set so that their keys are read; those CartPole cannot have (a visual area, a
# video) are refused whatever the key's value, which still checks that every value is refused cleanly.
CONTEXT = {"ppo.network.graph.": GRAPH, "ppo.stop_at.": ["ppo.stop_at={value: 1}"],
           "logging.wandb.": ["logging.wandb={}"], "ppo.network.visual.": ["ppo.network.visual={}"],
           "evaluation.video.": ["evaluation.video={}"]}


@dataclasses.dataclass(frozen=True)
class Key:
    """A config key: its dotted name (areas as `areas.S1`), type, declared range and whether it is a section."""

    name: str
    kind: typing.Any
    bounds: Bounds | None


def config_keys(cls: type = Config, prefix: str = "") -> list[Key]:
    """Every key of `cls` and of the sections it holds, sections included."""
    keys = []
    hints = typing.get_type_hints(cls)
    for f in dataclasses.fields(cls):
        kind, name = hints[f.name], f"{prefix}{f.name}"
        keys.append(Key(name, kind, field_bounds(cls, f.name)))
        inner = [arg for arg in (kind, *typing.get_args(kind)) if dataclasses.is_dataclass(arg)]
        if inner:
            keys += config_keys(inner[0], f"{name}.S1." if typing.get_origin(kind) is dict else f"{name}.")
    return keys


KEYS = [*config_keys(), Key("env.options.max_episode_steps", int, Bounds(1, 2**31 - 1))]

# Values no setting takes: text with NUL, nested junk, numbers that are not finite, huge or negative. Integers stay
# under 1,000 digits (YAML writes them out; longer ones are test_config's).
TEXT = st.text(max_size=12) | st.sampled_from(["a\0b", "\0", "x" * 10_000, "-1", "1e999", ".nan", "all", "auto"])
NUMBERS = (st.integers(-(10**6), 10**6) | st.sampled_from([-1, 0, 2**31, 2**32, 2**63, -(2**63) - 1, 10**400])
           | st.floats(allow_nan=True, allow_infinity=True) | st.sampled_from([-0.0, 1e39, -1e39, 0.5]))
SCALARS = st.none() | st.booleans() | NUMBERS | TEXT
JUNK = st.recursive(SCALARS, lambda inner: st.lists(inner, max_size=3) | st.dictionaries(
    st.text(max_size=4) | st.integers(0, 3), inner, max_size=3), max_leaves=8)


def nested(depth: int) -> list:
    """A list in a list ... `depth` levels deep."""
    value: list = []
    for _ in range(depth - 1):
        value = [value]
    return value


# Around the deepest nesting a config may have (50 levels).
DEEP = st.integers(40, 60).map(nested)
# Aliases of aliases that expand to 10**9 values ("billion laughs").
BOMB = "{" + ", ".join(["l0: &l0 [lol, lol, lol, lol, lol, lol, lol, lol, lol, lol]"] + [
    f"l{i}: &l{i} [{', '.join([f'*l{i - 1}'] * 10)}]" for i in range(1, 9)]) + "}"


NUL_TEXT = st.text(max_size=8).map(lambda text: f"{text}\0{text}")


def out_of_range(bounds: Bounds) -> st.SearchStrategy:
    """Numbers outside `bounds`: below or above it, or not finite."""
    if isinstance(bounds.low, int):
        below = st.integers(max_value=bounds.low - (0 if bounds.open_low else 1))
    else:
        below = st.floats(max_value=bounds.low, exclude_max=not bounds.open_low)
    above = st.integers(min_value=bounds.high + 1) if isinstance(bounds.high, int) else st.floats(
        min_value=bounds.high, exclude_min=True)
    return below | above | st.sampled_from([math.nan, math.inf, -math.inf, 10**400, -(10**400)])


def wrong_values(key: Key) -> st.SearchStrategy:
    """Values mostly wrong for `key`: text with NUL, numbers out of its range, values of other types."""
    others = st.booleans() | st.lists(NUL_TEXT | NUMBERS, min_size=1, max_size=2) | st.dictionaries(
        st.text(max_size=3) | st.integers(0, 3), SCALARS, min_size=1, max_size=2) | TEXT
    return NUL_TEXT | others | (out_of_range(key.bounds) if key.bounds is not None else NUMBERS)


def yaml_text(value: typing.Any) -> str:
    """`value` as one line of YAML (as an override's value)."""
    return yaml.safe_dump([value], default_flow_style=True, width=math.inf).strip()[1:-1]


def must_refuse(key: Key, value: typing.Any) -> bool:
    """Whether `value` is wrong for `key` whatever the other settings: of another type, not finite, outside the
    declared range, or text with NUL. (A value of the right type in range may still be refused in combination.)"""
    kinds = [key.kind]
    options = []
    while kinds:
        kind = kinds.pop()
        if typing.get_origin(kind) is typing.Union or isinstance(kind, type(int | str)):
            kinds += typing.get_args(kind)
        else:
            options.append(kind)
    if value is None:
        return type(None) not in options and not any(dataclasses.is_dataclass(kind) for kind in options)
    return all(_wrong(kind, value, key.bounds) for kind in options if kind is not type(None))


def _wrong(kind: typing.Any, value: typing.Any, bounds: Bounds | None) -> bool:
    if dataclasses.is_dataclass(kind) or typing.get_origin(kind) is dict:
        return not isinstance(value, dict)
    if typing.get_origin(kind) is tuple:
        return not isinstance(value, list) or any(_wrong(typing.get_args(kind)[0], item, bounds) for item in value)
    if kind is bool:
        return not isinstance(value, bool)
    if kind is str:
        return not isinstance(value, str) or "\0" in value
    if kind is typing.Any:
        return False
    if isinstance(value, bool):
        return True
    if kind is float and isinstance(value, str):
        try:
            value = float(value)
        except ValueError:
            return True
    if kind is float and isinstance(value, int):
        value = float(value) if abs(value) < 2**1000 else math.inf
    if not isinstance(value, kind):
        return True
    return isinstance(value, float) and not math.isfinite(value) or bounds is not None and (
        value < bounds.low or value > bounds.high or bounds.open_low and value == bounds.low)


def check(overrides: list[str], refuse: bool, root: Path) -> None:
    """Load and validate; a ConfigError (required when `refuse`) or nothing; nothing written in `root` or here."""
    here = sorted(os.listdir())
    try:
        validate(load_config("cartpole", overrides))
        assert not refuse, f"accepted {overrides[-1][:200]!r}, which should be refused"
    except ConfigError:
        pass
    assert not any(root.iterdir()), "validating wrote into run_root"
    assert sorted(os.listdir()) == here, "validating wrote into the working directory"


@pytest.mark.parametrize("key", KEYS, ids=[key.name for key in KEYS])
@settings(max_examples=15, deadline=None, database=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data())
def test_any_value_of_any_key_is_accepted_only_if_valid_or_refused_with_a_config_error(key, data):
    value = data.draw(wrong_values(key) | JUNK | DEEP)
    if key.kind is float and isinstance(value, int) and abs(value) < 2**1000:
        value = float(value)
    with tempfile.TemporaryDirectory() as root:
        context = next((extra for section, extra in CONTEXT.items() if key.name.startswith(section)), [])
        base = [] if key.name == "logging.run_root" else [f"logging.run_root={root}"]
        check([*base, *context, f"{key.name}={yaml_text(value)}"], must_refuse(key, value), Path(root))


@settings(max_examples=30, deadline=None, database=None)
@given(key=st.sampled_from([key for key in KEYS if key.bounds is not None]), data=st.data())
def test_numbers_outside_a_keys_declared_range_are_refused(key, data):
    value = data.draw(out_of_range(key.bounds))
    if key.kind is float and isinstance(value, int) and abs(value) < 2**1000:
        value = float(value)
    with tempfile.TemporaryDirectory() as root:
        context = next((extra for section, extra in CONTEXT.items() if key.name.startswith(section)), [])
        check([f"logging.run_root={root}", *context, f"{key.name}={yaml_text(value)}"], True, Path(root))


@settings(max_examples=25, deadline=None, database=None)
@given(value=JUNK)
def test_any_yaml_file_is_refused_or_read(value):
    """A config file holding anything (not only the sections' keys) loads or is refused with a ConfigError."""
    with tempfile.TemporaryDirectory() as root:
        path = Path(root) / "run.yaml"
        path.write_text(yaml.safe_dump({"ppo": value, "logging": {"run_root": f"{root}/runs"}}))
        try:
            validate(load_config(path))
        except ConfigError:
            pass
        assert [p.name for p in Path(root).iterdir()] == ["run.yaml"]


@pytest.mark.parametrize("override", ["ppo.seed=-1", "ppo.gamma=1" + "0" * 400, "logging.run_name=" + "a" * 300,
                                      "env.options.max_episode_steps=-3", "ppo={gamma: 0.9, gamma: 0.8}",
                                      f"env.options.x={BOMB}", 'ppo.init_from="run\\0"', "ppo={1: x}"])
def test_the_cli_exits_2_with_a_message_and_makes_no_run(override, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    for command in (["train", "cartpole", f"logging.run_root={tmp_path / 'runs'}", override],
                    ["config", "show", "cartpole", override]):
        code = main(command)
        err = capsys.readouterr().err
        assert code == 2 and "Traceback" not in err and err.startswith(f"angora-jax {command[0]}: "), err
        assert len(err.strip().splitlines()) == 1, err
    assert not list(tmp_path.iterdir()), "a refused config made no run directory"
