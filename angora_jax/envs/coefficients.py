"""`Coefficients`: the base of a task's reward-coefficient dataclass, built from a config dict."""

from __future__ import annotations

import dataclasses
from typing import Self


class Coefficients:
    """Mixed into frozen dataclasses of float coefficients, so ablations change a config dict, not code."""

    @classmethod
    def from_dict(cls, values: dict[str, float] | None) -> Self:
        """Coefficients from a dict; unknown keys raise a ValueError that lists the known ones."""
        values = dict(values or {})
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(values) - known)
        if unknown:
            raise ValueError(f"Unknown reward coefficients {unknown}; known: {sorted(known)}.")
        return cls(**{k: float(v) for k, v in values.items()})

    @classmethod
    def preset(cls, presets: dict[str, Self], name: str, overrides: dict[str, float] | None = None) -> Self:
        """The coefficients of `presets[name]` with `overrides` (coefficient name -> value) applied; a ValueError
        naming the presets, or the known coefficients, when one is unknown."""
        if name not in presets:
            raise ValueError(f"Unknown reward preset {name!r}; choose one of {sorted(presets)}.")
        cls.from_dict(overrides)  # a ValueError naming the known coefficients when one is unknown
        return dataclasses.replace(presets[name], **{k: float(v) for k, v in (overrides or {}).items()})
