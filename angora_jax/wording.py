"""How messages word what they say: the nearest known name to a misspelt one, and count words that agree with their
count. Every user-facing message goes through these, so that hints read alike and none says "1 cycles"."""

from __future__ import annotations

import difflib
from collections.abc import Iterable


def did_you_mean(value: object, allowed: Iterable[str]) -> str:
    """" Did you mean 'x'?" with the name of `allowed` closest to `value` (difflib's), or "" when none is close: the
    hint of every message that refuses an unknown name (a config's value, a registry's name)."""
    close = difflib.get_close_matches(str(value), list(allowed), n=1)
    return f" Did you mean {close[0]!r}?" if close else ""


def agreeing(count: int, word: str, many: str | None = None) -> str:
    """The form of `word` that agrees with `count`: `word` for exactly 1, else `many` (default: `word` + "s"), as in
    "line 7 holds" and "lines 7, 8 hold" (`agreeing(2, "holds", "hold")`). Every message that counts goes through it
    (or `counted`), so that none says "1 cycles" or hedges with "cycle(s)"."""
    return word if count == 1 else many or word + "s"


def counted(count: int, word: str, many: str | None = None) -> str:
    """`count` (with thousands separators) and the form of `word` that agrees with it: "1 cycle", "0 cycles",
    "2,000 cycles", `counted(1, "synergy", "synergies")`."""
    return f"{count:,} {agreeing(count, word, many)}"
