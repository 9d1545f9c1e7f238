"""The config reference: every key of `Config`, with its type, default and description, read from the typed
dataclasses themselves (each field is described in its class's docstring, in its Google-style `Attributes:` section),
so the reference cannot drift from the code. `angora-jax config reference` prints it; docs/config.md holds it."""

from __future__ import annotations

import dataclasses
import inspect
import re
import types
import typing
from dataclasses import dataclass
from typing import Any

from angora_jax.experiment.config import Config


@dataclass(frozen=True)
class ConfigKey:
    """One key of the config reference.

    Attributes:
        key: dotted name, e.g. `ppo.network.width`.
        type: the type as written in the code.
        default: the default, as YAML-like text.
        description: the sentence(s) of its class's docstring ("" when the docstring has none).
    """

    key: str
    type: str
    default: str
    description: str


def config_keys(cls: type = Config, prefix: str = "") -> list[ConfigKey]:
    """Every key of the config dataclass `cls` and of the sections inside it, depth first in field order."""
    hints = typing.get_type_hints(cls)
    described = field_descriptions(cls)
    keys = []
    for field in dataclasses.fields(cls):
        kind = hints[field.name]
        default = field.default_factory() if field.default_factory is not dataclasses.MISSING else field.default
        section = next((a for a in (kind, *typing.get_args(kind)) if dataclasses.is_dataclass(a)), None)
        shown = "(section)" if dataclasses.is_dataclass(default) else _yaml(default)
        keys.append(ConfigKey(prefix + field.name, _type_name(kind), shown, described.get(field.name, "")))
        if section is not None:
            # A mapping of sections (name -> section) has its keys under each name: `areas.<name>.size`.
            named = "<name>." if typing.get_origin(kind) is dict else ""
            keys.extend(config_keys(section, f"{prefix}{field.name}.{named}"))
    return keys


def field_descriptions(cls: type) -> dict[str, str]:
    """`name -> description` of `cls`'s fields from its docstring's `Attributes:` section (Google style: a line
    `name: description` per field, continued on more deeply indented lines; the section ends at a line indented no
    deeper than its title). Lines of other names are not fields and are left out."""
    lines = inspect.cleandoc(cls.__doc__ or "").splitlines()
    title = next((i for i, line in enumerate(lines) if line.strip() == "Attributes:"), None)
    if title is None:
        return {}
    fields = {field.name for field in dataclasses.fields(cls)}
    entries: dict[str, list[str]] = {}
    name, entry_indent = None, None
    for line in lines[title + 1:]:
        depth = _indent(line)
        if line.strip() and depth <= _indent(lines[title]):
            break
        entry = re.match(r"(\w+)(?: \(.*?\))?: (.*)", line.strip())
        if entry and depth == (entry_indent or depth):
            entry_indent, name = depth, entry.group(1)
            entries[name] = [entry.group(2)]
        elif name is not None:
            entries[name].append(line.strip())
    return {name: " ".join(" ".join(text).split()) for name, text in entries.items() if name in fields}


def _indent(line: str) -> int:
    return len(line) - len(line.lstrip())


def reference_markdown() -> str:
    """The reference as a Markdown table: key, type, default, description."""
    rows = ["| key | type | default | description |", "|---|---|---|---|"]
    for key in config_keys():
        rows.append(f"| `{key.key}` | `{key.type}` | `{key.default}` | {_outside_code(key.description)} |")
    return ("# Config reference\n\nEvery key of an experiment config (`angora_jax.experiment.config.Config`), "
            "generated from the typed dataclasses by `angora-jax config reference`. A YAML file gives any of them "
            "(missing keys take these defaults); `angora-jax config show CONFIG` prints what a run would use. One "
            "top-level key is no setting: `extends: NAME` starts the file from another config (a shipped name, or a "
            "YAML path relative to the file) and sets the file's keys on top of it, section by section.\n\n"
            + "\n".join(rows) + "\n")


def _outside_code(text: str) -> str:
    """`text` for a table cell: its pipes escaped, except inside code spans (every other part between backticks),
    where the site's Markdown (Python-Markdown) splits no cell and would print the backslash with the pipe."""
    parts = text.split("`")
    parts[::2] = [part.replace("|", "\\|") for part in parts[::2]]
    return "`".join(parts)


def _type_name(kind: Any) -> str:
    if isinstance(kind, types.UnionType) or typing.get_origin(kind) is typing.Union:
        return " | ".join(_type_name(a) for a in typing.get_args(kind))
    if typing.get_origin(kind) is not None:  # e.g. dict[str, angora_jax.nets.area_graph.AreaSpec]: names only
        return re.sub(r"\b(?:\w+\.)+(\w+)", r"\1", str(kind))
    return "None" if kind is type(None) else kind.__name__


def _yaml(value: Any) -> str:
    if value is dataclasses.MISSING:
        return "(required)"
    if value is None:
        return "null"
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, tuple):
        return "[" + ", ".join(map(str, value)) + "]"
    return str(value)
