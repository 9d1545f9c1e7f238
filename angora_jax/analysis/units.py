"""Unit indices given in Python, checked in the words of every analysis that takes them: a layer's units (a visual
convolution's channels, a dense layer's outputs) and a variable's features. A unit is a whole number (an int, or a
NumPy or JAX integer scalar, not a bool, which NumPy and JAX read as 0 or 1) from 0 to the layer's count - 1; a float
such as 1.5 is refused rather than cut to 1."""

from __future__ import annotations

import numbers

import numpy as np

from angora_jax.experiment.config import ConfigError
from angora_jax.wording import counted


def unit_range(layer: str, count: int) -> str:
    """"from 0 to 3 (V1 has 4 units)": the units of `layer` ("output": the visual area's output, its features), in
    the words of every message that refuses a unit."""
    name = "the output" if layer == "output" else layer
    return f"from 0 to {count - 1} ({name} has {counted(count, 'unit')})"


def as_scalar(unit: object) -> object:
    """A NumPy or JAX scalar (0-d array) as the Python number it holds, e.g. `jnp.argmax(weights)` or an entry of
    `jnp.arange(4)`, which the unit checks then take or refuse as they do ints, floats and bools; anything else as
    given."""
    return unit.item() if hasattr(unit, "dtype") and hasattr(unit, "item") and np.ndim(unit) == 0 else unit


def is_unit(unit: object, count: int) -> bool:
    """Whether `unit` is a unit of a layer of `count` units: a whole number (an int or a numpy integer, not a bool,
    which JAX reads as 0 or 1) from 0 to `count` - 1."""
    return not isinstance(unit, bool) and isinstance(unit, numbers.Integral) and 0 <= unit < count


def checked_units(units: object, layer: str, count: int, empty: bool = False, name: str = "units",
                  counts: str | None = None) -> np.ndarray:
    """`units` (a list or array of unit indices of `layer`, which has `count`) as an int array; ConfigError naming
    the argument (`name`: "units", or "components" for an action's), the value and the range unless each is a whole
    number from 0 to `count` - 1 and, unless `empty`, there is at least one. `counts` says what the indices count, in
    the message's parentheses ("Pendulum's action has 1 component"); default: `layer`'s units (`unit_range`).
    `np.asarray(units, int)` cut [1.5] to unit 1 and read [True] as unit 0 without a word."""
    span = f"whole numbers {unit_range(layer, count) if counts is None else f'from 0 to {count - 1} ({counts})'}"
    try:
        given = None if isinstance(units, str | bytes | numbers.Number) else [as_scalar(unit) for unit in units]
    except TypeError:  # a 0-d array, an object that is no list
        given = None
    if given is None or not (given or empty):
        raise ConfigError(f"{name} must be a list of {'' if empty else 'one or more '}{span}, e.g. [0, 1]; got "
                          f"{units!r}.")
    for unit in given:
        if not is_unit(unit, count):
            raise ConfigError(f"{name} must be {span}; got {unit!r} in {given}.")
    return np.asarray(given, int)
