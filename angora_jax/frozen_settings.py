"""`settings`: the decorator of every config class (the sections of `Config` and what they nest), a frozen dataclass
whose refused assignment says how to change a value."""

from __future__ import annotations

import dataclasses
import reprlib
from typing import Any, TypeVar

Settings = TypeVar("Settings", bound=type)


def settings(cls: Settings) -> Settings:
    """`cls` as `dataclass(frozen=True)` makes it, except that assigning or deleting a field raises
    dataclasses.FrozenInstanceError naming the ways to change a value: overrides where the config is read
    (`load_config`, `train`, a loaded Config included), or a changed copy (`dataclasses.replace`). dataclasses' own
    message, "cannot assign to field 'num_envs'", named neither. Equality, hashing, pickling and
    `dataclasses.replace` are the dataclass's own."""
    cls = dataclasses.dataclass(frozen=True)(cls)
    assign, delete = cls.__setattr__, cls.__delattr__

    def __setattr__(self: Any, name: str, value: Any) -> None:
        try:
            assign(self, name, value)
        except dataclasses.FrozenInstanceError:
            change = f"{name}={reprlib.repr(value)}"
            raise dataclasses.FrozenInstanceError(_how_to_change(self, "assign to", name, change)) from None

    def __delattr__(self: Any, name: str) -> None:
        try:
            delete(self, name)
        except dataclasses.FrozenInstanceError:
            raise dataclasses.FrozenInstanceError(_how_to_change(self, "delete", name, f"{name}=...")) from None

    cls.__setattr__, cls.__delattr__ = __setattr__, __delattr__
    return cls


def _how_to_change(settings: object, verb: str, name: str, change: str) -> str:
    """The message for a field `name` of `settings` changed in place (`verb`: "assign to" or "delete", as dataclasses
    say it); `change` is the field's `name=value`."""
    kind = type(settings).__name__
    return (f"cannot {verb} field {name!r}: this {kind} is frozen (a config is checked as a whole, when it is "
            "loaded or trained). Give the change as an override where the config is read, e.g. config = "
            "aj.load_config(config, ['ppo.num_envs=8']) or aj.train(config, ['ppo.num_envs=8']); or make a changed "
            f"copy with dataclasses.replace, e.g. dataclasses.replace(section, {change}).")
