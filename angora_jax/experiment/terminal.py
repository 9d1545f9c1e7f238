"""The process's standard output and error when their reader is gone: which of them go to a terminal (asked before
it closes: a terminal that hung up is no tty any more), and pointing them at /dev/null, so that writing to a closed
terminal (EIO) or a pipe without a reader (EPIPE) fails no more."""

from __future__ import annotations

import os

STANDARD_STREAMS = (1, 2)


def terminal_descriptors() -> list[int]:
    """Those of the standard output and error (file descriptors 1 and 2) that go to a terminal now."""
    return [descriptor for descriptor in STANDARD_STREAMS if os.isatty(descriptor)]


def discard(descriptors: list[int]) -> None:
    """Point `descriptors` at /dev/null: what is written to them from now on is dropped."""
    for descriptor in descriptors:
        os.dup2(os.open(os.devnull, os.O_WRONLY), descriptor)
