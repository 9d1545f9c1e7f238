"""What the commands share: exit codes, argparse value types and the option groups several verbs take (each one
function that adds it to a verb's parser), and the small readings of arguments the handlers share."""

from __future__ import annotations

import argparse
import dataclasses
import sys
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from angora_jax.experiment.config import Config

EXIT_OK, EXIT_FAILED, EXIT_USAGE = 0, 1, 2


def seed(text: str) -> int:
    """An argparse type: a seed, a whole number from 0 to 2**32 - 1 (what jax.random.key distinguishes)."""
    if not text.isdigit() or int(text) >= 2**32:
        raise argparse.ArgumentTypeError(f"must be a whole number from 0 to {2**32 - 1:,}, got {text[:40]!r}")
    return int(text)


def whole_number(least: int) -> Callable[[str], int]:
    """An argparse type: a whole number >= `least` (argparse then exits with code 2 and names the option)."""

    def parse(text: str) -> int:
        if not text.isdigit() or int(text) < least:
            raise argparse.ArgumentTypeError(f"must be a whole number >= {least}, got {text!r}")
        return int(text)

    parse.__name__ = f"whole number >= {least}"
    return parse


positive_int = whole_number(1)
# Quantile bins and cross-validation folds: one bin compares nothing, one fold leaves no data to fit on.
at_least_two = whole_number(2)



# The most episodes one command runs (evaluate, render, record, analyze ablate). Each episode's reset and acting keys
# and its results are held in memory: `evaluate --episodes 1000000000` needed 16 GB for its keys alone and was killed
# by the kernel without a word. A million is hours even of CartPole on the CPU path; more is several commands, each
# with its own --seed.
MAX_EPISODES = 1_000_000
# The frame sizes `render` takes, a side: below 16 pixels a frame shows nothing of the scene; at 4,096 x 4,096 a frame
# is 50 MB in memory, an episode of 1,000 steps 50 GB (what memory holds is checked too, before rendering).
FRAME_SIDE = (16, 4096)


def bounded_int(low: int, high: int, fix: str) -> Callable[[str], int]:
    """An argparse type: a whole number from `low` to `high`. Outside them argparse exits 2, naming the option, the
    range and `fix` (what to do instead), before anything is loaded or compiled: an absurd size otherwise reached
    XLA or NumPy as an allocation the kernel killed the process for."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            value = None
        if value is None or not low <= value <= high:
            raise argparse.ArgumentTypeError(f"must be a whole number from {low:,} to {high:,}, got {text[:40]!r}"
                                             f"{'' if value is None or value < low else f'; {fix}'}")
        return value

    parse.__name__ = f"whole number from {low} to {high}"
    return parse


episode_count = bounded_int(1, MAX_EPISODES, "run more episodes as several commands, each with its own --seed")
frame_side = bounded_int(*FRAME_SIDE, "a frame that large is 50 MB in memory, an episode's video tens of GB")


def port(text: str) -> int:
    """An argparse type: a TCP port, 0 (any free one) to 65535."""
    if not text.isdigit() or int(text) > 65535:
        raise argparse.ArgumentTypeError(f"must be a port from 0 (any free one) to 65535, got {text!r}")
    return int(text)


def positive_float(text: str) -> float:
    value = float(text)
    if not value > 0:
        raise argparse.ArgumentTypeError(f"must be > 0, got {text}")
    return value


# The longest wait between two updates of `monitor`'s page: a timer waits no longer than the platform's time_t (past
# it `--every 1e300` killed the updating thread with a traceback, and `inf` failed at the first update), and a page
# drawn less than once a day is `report`'s.
LONGEST_UPDATE = 86_400.0


def update_interval(text: str) -> float:
    """An argparse type: seconds between updates, > 0 and at most LONGEST_UPDATE (a day)."""
    value = positive_float(text)
    if not value <= LONGEST_UPDATE:
        raise argparse.ArgumentTypeError(f"must be at most {LONGEST_UPDATE:,.0f} seconds (a day), got {text[:40]!r}; "
                                         "for a page drawn once: angora-jax report")
    return value



def non_negative_int(text: str) -> int:
    """An argparse type: a whole number >= 0."""
    if not text.isdigit():
        raise argparse.ArgumentTypeError(f"must be a whole number >= 0, got {text!r}")
    return int(text)


def device_ids(text: str) -> list[int]:
    """An argparse type: comma-separated device indices, e.g. "0" or "2,3"."""
    return [non_negative_int(part.strip()) for part in text.split(",")]



def host_port(text: str) -> str:
    """An argparse type: "host:port", the port a whole number from 1 to 65535."""
    host, _, port = text.rpartition(":")
    if not host or not port.isdigit() or not 1 <= int(port) <= 65535:
        raise argparse.ArgumentTypeError(f"must be host:port, e.g. node01:12355, got {text!r}")
    return text


def add_env_option(command: argparse.ArgumentParser) -> None:
    command.add_argument("--env-option", action="append", default=[], metavar="KEY=VALUE",
                         help="a task option that differs from the run's (repeatable; the network must still fit "
                              "the observations), e.g. pose_estimator=encoder.pose.msgpack for the cube")


def add_time_limit(command: argparse.ArgumentParser) -> None:
    command.add_argument(
        "--minutes", type=positive_float,
        help="stop after the first cycle that ends past this wall time (compile included), with a checkpoint; "
             "'angora-jax resume RUN_DIR' continues exactly (train in pieces shorter than a job's time limit)")


def add_distributed_flags(command: argparse.ArgumentParser) -> None:
    """--distributed and its optional settings (left out, they come from the cluster, e.g. SLURM)."""
    command.add_argument(
        "--distributed", action="store_true",
        help="join a jax.distributed job, one process per GPU (under SLURM each takes the GPU of its local rank; "
             "elsewhere give --local-devices); see examples/slurm_train.sh")
    command.add_argument("--coordinator", type=host_port,
                         help="host:port of process 0 (default: from the cluster environment)")
    command.add_argument("--num-processes", type=positive_int,
                         help="processes in the job (default: from the cluster)")
    command.add_argument("--process-id", type=non_negative_int, help="this process's index (default: from the cluster)")
    command.add_argument("--local-devices", type=device_ids, metavar="IDS",
                         help="this process's GPUs on its host, e.g. 0 or 2,3 (default: from the cluster, else all)")
    command.add_argument("--join-minutes", type=positive_float, default=5.0, metavar="MINUTES",
                         help="how long each process waits for all of the job's processes to join before it exits "
                              "with code 2 naming the settings to check (default: 5)")



def checkpoint_of(text: str) -> str | int:
    """A --checkpoint argument: "best", "latest" or a cycle number."""
    return int(text) if text.isdigit() else text


def refused_existing(command: str, out: Path, what: str) -> bool:
    """True (after saying so on stderr) when `out` exists: outputs are never overwritten."""
    if out.exists():
        print(f"angora-jax {command}: {out} exists; {what} are never overwritten: give another --out.", file=sys.stderr)
    return out.exists()



def add_import_option(command: argparse.ArgumentParser) -> None:
    """--import MODULE (repeatable), which every verb takes: user code imported before the verb runs."""
    command.add_argument(
        "--import", dest="imports", action="append", default=[], metavar="MODULE",
        help="import this Python module first (its folder on PYTHONPATH, or installed), so that the tasks and models "
             "it registers can be named; repeatable; a run that train starts records it (the config's imports), so "
             "later commands on the run import it again")


def config_with_imports(args: argparse.Namespace) -> Config:
    """The config that `train` would use: `args.config` with `args.overrides`, and the --import modules added to its
    `imports` (after the config's own, each once), so that the run records them."""
    from angora_jax.experiment.config import load_config, repeated_keys  # JAX: not for parsing the command line

    for repeated in repeated_keys(args.overrides):
        print(f"angora-jax: {repeated}", file=sys.stderr)
    config = load_config(args.config, args.overrides)
    return dataclasses.replace(config, imports=tuple(dict.fromkeys([*config.imports, *args.imports])))
