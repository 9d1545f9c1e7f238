"""A run directory: where one experiment's config, metrics, checkpoints and report live.

    RUN_DIR/config.yaml           the resolved config (every key, defaults included); `resume` reads it back
    RUN_DIR/hyperparameters.json  the same config flattened to dotted keys, for tables and filters
    RUN_DIR/metrics.jsonl         one JSON object per cycle (see `monitor`)
    RUN_DIR/sessions.jsonl        one JSON object per train/resume call: start time and cycle, host, package
                                  versions, devices, the physics it ran on (engine, MJX implementation and why), and
                                  the file and SHA-256 of each module of its `imports`, and where its task and network
                                  were defined
    RUN_DIR/checkpoints/          Orbax checkpoints, each with its manifest (see `checkpoint`)
    RUN_DIR/writer.lock           the process that trains the run now (see `run_lock`)
    RUN_DIR/metrics.after-cycle-N.jsonl, RUN_DIR/set-aside/, RUN_DIR/previous-N/
                                  what a resume moved aside rather than overwrite (see `resume_plan`)
    RUN_DIR/tensorboard/          TensorBoard event files, when logging.tensorboard is on
    RUN_DIR/wandb/                Weights & Biases' files and the W&B run id, when logging.wandb is on
    RUN_DIR/report/               PNG learning curves and index.html (see `report`)
    RUN_DIR/videos/               cycle_NNNNNN.gif, the policy during training, when evaluation.video is on

A new run never reuses an existing directory, and nothing in one is overwritten or deleted.
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import shutil
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import yaml

from angora_jax.experiment.config import Config, ConfigError, UnreadableConfigError, flatten, load_config, to_dict
from angora_jax.registry.plugins import module_files, remember_definitions, remember_files
from angora_jax.saved_files import USE, msgpack_kind
from angora_jax.whole_files import unwritable_folder, written_whole

CONFIG_FILE = "config.yaml"
HYPERPARAMETERS_FILE = "hyperparameters.json"
# The writer lock of a run (`run_lock`): a process that trains the run holds it.
LOCK_FILE = "writer.lock"
METRICS_FILE = "metrics.jsonl"
CHECKPOINTS = "checkpoints"
SESSIONS_FILE = "sessions.jsonl"
VIDEOS = "videos"
EVALUATIONS = "evaluation"  # `angora-jax evaluate` writes its JSON and plots here
# What to do instead, said of a path that is no run directory.
START_RUNS = "Start runs with `angora-jax train` (in Python: aj.train)."


class RunDirError(ValueError):
    """A run directory that cannot be used as asked (exists already, or is not a run directory)."""


class DiskFullError(RunDirError):
    """A run's file could not be written for want of room (a full disk, a used-up quota, the file-size limit); what
    was saved before is intact."""


# The errors that say a file could not be written for want of room: the OS's words for each (which Orbax and
# TensorStore keep, some only in their messages), what happened in the user's terms, and the fix.
NO_ROOM = {
    errno.ENOSPC: ("No space left on device", "The disk is full", "free space (or move the run to a larger disk)"),
    errno.EDQUOT: ("Disk quota exceeded", "The disk quota is used up", "free space within the quota or ask for more"),
    errno.EFBIG: ("File too large", "A file grew past the size this process may write (its file-size limit, ulimit "
                  "-f)", "raise the limit (`ulimit -f unlimited`, or the job's file-size limit)"),
}


def no_room(error: BaseException | None) -> tuple[str, str] | None:
    """What happened and its fix, when `error` or an error it was raised from says a file could not be written for
    want of room (a full disk, a used-up quota, the file-size limit); None otherwise."""
    while error is not None:
        for number, (words, what, fix) in NO_ROOM.items():
            if (isinstance(error, OSError) and error.errno == number) or words in str(error):
                return what, fix
        error = error.__cause__ or error.__context__
    return None


def is_disk_full(error: BaseException) -> bool:
    """Whether `error`, or an error it was raised from, says a file could not be written for want of room
    (`no_room`)."""
    return no_room(error) is not None


def create_run_dir(config: Config, claim: Callable[[Path], None] | None = None) -> Path:
    """Make a new run directory under `config.logging.run_root` and save the resolved config in it.

    The name is `logging.run_name`, or task-network-date-time (with a -2, -3, ... suffix when taken). A directory that
    cannot be completed (a full disk) is removed again.

    Args:
        config: the run's config.
        claim: called with the new, empty directory before the config is written (the writer lock: a directory with a
            config is a run that `resume` may continue).

    Returns:
        The new run directory.

    Raises:
        RunDirError: a named run directory exists already (nothing in it is touched).
    """
    root = config.logging.root
    if (inside := in_checkpoints(root / "run")) is not None:
        raise RunDirError(f"logging.run_root={config.logging.run_root} is {inside}: choose a folder for runs outside "
                          "every run (e.g. logging.run_root=runs).")
    if (run := run_holding(root)) is not None:
        where = "the run" if run.resolve() == root.resolve() else "inside the run"
        raise RunDirError(f"logging.run_root={config.logging.run_root} is {where} {run}, and a run made there "
                          f"would be copied, moved and deleted with it: choose a folder for runs outside every run "
                          f"(e.g. logging.run_root={run.parent}). To continue {run}: `angora-jax resume {run}`.")
    root.mkdir(parents=True, exist_ok=True)
    if config.logging.run_name is not None:
        path = root / config.logging.run_name
        try:
            path.mkdir()
        except FileExistsError:
            new_name = "start a new run with another logging.run_name (or none, for a dated name)"
            if path.is_file():
                raise RunDirError(f"{path} is a file, not a run directory; it is left untouched: {new_name}.") from None
            if not (path / CONFIG_FILE).is_file():
                if (path / LOCK_FILE).exists():
                    raise RunDirError(f"Another process is starting a run in {path} (its writer lock is there) and "
                                      f"it is left to it: {new_name}.") from None
                raise RunDirError(f"{path} exists and is not a run (no {CONFIG_FILE}); it is left untouched: "
                                  f"{new_name}, or move it away.") from None
            if (path / LOCK_FILE).exists():
                raise RunDirError(
                    f"Run directory {path} already exists and is left untouched; a process holds its writer lock "
                    f"(training it now, unless it ended without releasing it: `angora-jax check {path}` says which). "
                    f"Leave it to that process, or {new_name}.") from None
            raise RunDirError(
                f"Run directory {path} already exists and is left untouched. Continue it with `angora-jax resume "
                f"{path}` (in Python: aj.resume({str(path)!r})), or {new_name}."
            ) from None
    else:
        stem = f"{config.env.task}-{config.ppo.network.name}-{time.strftime('%Y%m%d-%H%M%S')}"
        path, suffix = root / stem, 1
        while True:
            try:
                path.mkdir()
                break
            except FileExistsError:
                suffix += 1
                path = root / f"{stem}-{suffix}"
    try:
        if claim is not None:
            claim(path)
        write_run_config(path, config)
    except BaseException:
        shutil.rmtree(path, ignore_errors=True)
        raise
    return path


def run_source(source: str | Path) -> tuple[str, str | int]:
    """"RUN_DIR[:best|latest|<cycle>]" as (run directory, checkpoint: "best" when none is named, or a cycle number).
    A path that exists is a run directory whole, colons and all."""
    text = str(source)
    run_dir, _, which = text.rpartition(":") if ":" in text and not Path(text).exists() else (text, "", "")
    return run_dir, int(which) if which.isdigit() else (which or "best")


def run_dir_path(run_dir: object) -> Path:
    """`run_dir` (a str or an os.PathLike) as a Path; TypeError naming what to give for anything else: the TrainingRun
    that `train` returns (`aj.load_agent(run)` in a notebook: give `run.run_dir`), None, a number. Path() itself says
    only "expected str, bytes or os.PathLike object, not TrainingRun"."""
    if isinstance(run_dir, str | os.PathLike):
        return Path(run_dir)
    if isinstance(getattr(run_dir, "run_dir", None), Path) and hasattr(run_dir, "history"):
        raise TypeError(f"run_dir is a run directory (a str or Path): give run.run_dir ({str(run_dir.run_dir)!r}), "
                        "not the TrainingRun that train returned.")
    raise TypeError(f"run_dir is a run directory (a str or Path, e.g. 'runs/my-run'), got {_short_repr(run_dir)} "
                    f"({type(run_dir).__name__}).")


def _short_repr(value: object) -> str:
    text = repr(value)
    return text if len(text) <= 80 else f"{text[:77]}..."


def read_run_config(run_dir: str | Path) -> Config:
    """The config saved in `run_dir`; RunDirError when `run_dir` is not a run directory."""
    path = run_dir_path(run_dir) / CONFIG_FILE
    if not path.is_file():
        if has_checkpoints(run_dir):
            raise RunDirError(f"{run_dir} has checkpoints but no {CONFIG_FILE}: `angora-jax check {run_dir} "
                              "--restore-config` writes it again from the copy they keep.")
        raise RunDirError(not_a_run_dir(run_dir, START_RUNS))
    try:
        config = load_config(path)
    except UnreadableConfigError as error:  # the run's fix first: `train`'s (name a shipped config) is no fix here
        if has_checkpoints(run_dir):
            raise RunDirError(f"{path} is damaged: `angora-jax check {run_dir} --restore-config` writes it again from "
                              "the copy its checkpoints keep (the file as it is now is kept beside it). What is wrong "
                              f"with it: {error.cause}") from None
        raise RunDirError(f"{path} is damaged and {run_dir} has no checkpoint that keeps a copy of it: write it back "
                          "from a copy of your own, or start the run again with `angora-jax train CONFIG`. What is "
                          f"wrong with it: {error.cause}") from None
    except ConfigError as error:
        copy = (f" Its checkpoints keep a copy of it: `angora-jax check {run_dir} --restore-config` writes that back "
                "(the file as it is now is kept beside it).") if has_checkpoints(run_dir) else ""
        raise RunDirError(f"{path} does not load with this version of angora_jax: {error}{copy}") from None
    # Where the run found its own modules, so that one not found here (another folder, a moved file) is named with
    # its folder when the config's imports are imported (`plugins.import_modules`).
    sessions = read_sessions(run_dir)
    remember_files({name: entry["file"] for name, entry in _recorded(sessions, "imports").items()
                    if isinstance(entry, dict) and isinstance(entry.get("file"), str)})
    remember_definitions({name: where for name, where in _recorded(sessions, "definitions").items()
                          if isinstance(where, str)})
    return config


def _recorded(sessions: list[dict], key: str) -> dict[str, Any]:
    """Name -> the latest record of it under the sessions' `key` ("imports": a module's file and SHA-256;
    "definitions": where a task or network was defined); runs made before sessions recorded them: {}."""
    found: dict[str, Any] = {}
    for session in sessions:
        if isinstance(entries := session.get(key), dict):
            found.update(entries)
    return found


def changed_imports(run_dir: str | Path) -> list[str]:
    """The modules of the run's imports, as imported in this process, whose file is not the one the run's latest
    session recorded (another path, or the same path edited since: another SHA-256), as "name (file)"."""
    recorded = _recorded(read_sessions(run_dir), "imports")
    now = module_files(recorded)
    return [f"{name} ({now[name]['file']})" for name, entry in recorded.items()
            if name in now and isinstance(entry, dict)
            and (entry.get("file"), entry.get("sha256")) != (now[name]["file"], now[name]["sha256"])]


def own_code_misfit(run_dir: str | Path, misfits: str) -> str | None:
    """Why a checkpoint of `run_dir` whose parameters do not fit (`misfits`, as CheckpointError lists them) when the
    run's own modules changed since it trained, or None when they did not: the usual cause then is the config, which
    the checkpoint's own message names."""
    changed = changed_imports(run_dir)
    if not changed:
        return None
    return (f"The checkpoints of {run_dir} do not fit what its own code builds now ({misfits}): "
            f"{', '.join(changed)} changed since the run last trained (sessions.jsonl records the file and SHA-256 "
            "each session imported). Put back the version it trained with (e.g. from version control) to evaluate "
            "or resume it; to train the edited task or network, start a new run: angora-jax train CONFIG.")


# Files the commands write that a user may give where a run directory belongs: what each is, and what to do instead.
KNOWN_FILES = {
    ".nc": ("a recording (`angora-jax record`) or an analysis's numbers", "give the run it was recorded from"),
}


def not_a_run_dir(path: str | Path, otherwise: str = "") -> str:
    """Why `path` is not a run directory, and the run directory it is in or holds, where there is one (a run's
    config.yaml or checkpoints folder given for the run is a slip worth naming); else `otherwise` is added."""
    resolved = Path(path).resolve()
    if not resolved.exists():
        home = Path(path).expanduser()
        if str(path).startswith("~") and home.exists():  # a shell expands it; Path() and open() do not
            return (f"{path} is not a run directory: it does not exist. A leading ~ is the home folder to a shell, "
                    f"not in Python: give {str(home)!r} (os.path.expanduser({str(path)!r})).")
        return f"{path} is not a run directory: it does not exist. {otherwise}".rstrip()
    said = (f"{path} is a file, not a run directory." if resolved.is_file() else
            f"{path} is not a run directory: it has no {CONFIG_FILE}.")
    run = next((parent for parent in resolved.parents if (parent / CONFIG_FILE).is_file()), None)
    if run is not None:
        return f"{said} It is inside the run directory {_as_given(path, run)}: give that."
    if resolved.is_file() and (kind := msgpack_kind(resolved)) is not None:
        return f"{path} is {kind}, not the run directory this command reads: {USE[kind]}."
    if resolved.is_file() and resolved.suffix in KNOWN_FILES:
        what, instead = KNOWN_FILES[resolved.suffix]
        return f"{path} is {what}, not the run directory this command reads: {instead}."
    if resolved.is_dir():
        runs = sorted(child.name for child in resolved.iterdir() if (child / CONFIG_FILE).is_file())
        if runs:
            shown = ", ".join(runs[:5]) + (f" and {len(runs) - 5} more" if len(runs) > 5 else "")
            return f"{said} It holds run directories ({shown}): give one of them, e.g. {Path(path) / runs[-1]}."
    return f"{said} {otherwise}".rstrip()


def _as_given(path: str | Path, run: Path) -> Path:
    """`run` (an ancestor of `path`) written as the user wrote `path`: relative stays relative."""
    given = Path(path)
    depth = len(given.resolve().relative_to(run).parts)
    short = given.parents[depth - 1] if depth <= len(given.parents) else run
    return short if short.resolve() == run else run


def _run_of_checkpoints(path: str | Path) -> Path | None:
    """The run (as `path` names it) inside whose checkpoint folder `path` is, or None."""
    folder = next((parent for parent in Path(path).resolve().parents
                   if parent.name == CHECKPOINTS and (parent.parent / CONFIG_FILE).is_file()), None)
    return None if folder is None else _as_given(path, folder.parent)


def run_holding(path: str | Path) -> Path | None:
    """The run directory that `path` is or is inside (as `path` names it), or None. A run is a folder with a
    config.yaml and one of the files or folders training writes beside it: a folder holding only a user's own
    config.yaml is no run."""
    traces = (HYPERPARAMETERS_FILE, CHECKPOINTS, SESSIONS_FILE, METRICS_FILE)
    path = Path(path)
    resolved = path.resolve()
    run = next((folder for folder in (resolved, *resolved.parents) if (folder / CONFIG_FILE).is_file()
                and any((folder / trace).exists() for trace in traces)), None)
    if run is None:
        return None
    given = path if run == resolved else _as_given(path, run)
    return run if given == Path() else given  # the working folder, named


def in_checkpoints(path: str | Path) -> str | None:
    """Why nothing but training may write at `path`, or None: it is inside a run's checkpoint folder (a file there
    is deleted with the checkpoint it sits in when a later one replaces it, or sits where the run's checkpoints are
    listed), said as "inside RUN/checkpoints, the checkpoint folder of the run RUN, ..." with RUN as `path` names it."""
    run = _run_of_checkpoints(path)
    return None if run is None else _inside_checkpoints_of(run)


def _inside_checkpoints_of(run: Path) -> str:
    return (f"inside {run / CHECKPOINTS}, the checkpoint folder of the run {run}, which only training writes (a file "
            "there is deleted with the checkpoint it sits in, or taken for one)")


def unwritable_out(out: str | Path) -> str | None:
    """Why a command may write no file at `out` (an evaluation, an export, a recording, an analysis, a video, an
    encoder, a report), or None: `unwritable_folder`'s reasons, or it is `in_checkpoints`."""
    if (run := _run_of_checkpoints(out)) is not None:
        return f"that is {_inside_checkpoints_of(run)}: write outside it, e.g. in {run / EVALUATIONS}"
    return unwritable_folder(out)


def has_checkpoints(run_dir: str | Path) -> bool:
    """Whether `run_dir` holds a checkpoint of any kind (each keeps the run's config)."""
    return any(Path(run_dir, CHECKPOINTS).glob("*/[0-9]*"))


def write_run_config(run_dir: str | Path, config: Config) -> None:
    """Write `config` as the run's `config.yaml` (and its flat view, `hyperparameters.json`), each file whole."""
    resolved = to_dict(config)
    for name, text in ((CONFIG_FILE, yaml.safe_dump(resolved, sort_keys=False)),
                       (HYPERPARAMETERS_FILE, json.dumps(flatten(resolved), indent=1))):
        with written_whole(Path(run_dir) / name) as draft:
            draft.write_text(text)


def record_session(run_dir: str | Path, entry: dict) -> None:
    """Append one session's record (see the module docstring) to `RUN_DIR/sessions.jsonl`."""
    with (Path(run_dir) / SESSIONS_FILE).open("a") as file:
        file.write(json.dumps(entry) + "\n")


def read_sessions(run_dir: str | Path) -> list[dict]:
    """The session records of `run_dir`, oldest first ([] for a run made before they were written); damaged lines
    are left out."""
    path = Path(run_dir) / SESSIONS_FILE
    records = []
    for line in path.read_text(errors="replace").splitlines() if path.exists() else []:
        with contextlib.suppress(ValueError):
            record = json.loads(line)
            if isinstance(record, dict) and isinstance(record.get("time"), int | float):
                records.append(record)
    return records


def latest_video(run_dir: str | Path) -> Path | None:
    """The run's video of its latest cycle (`evaluation.video`; of two for one cycle, which a resume that repeated
    cycles makes, the later), or None when it has none."""
    videos = sorted(Path(run_dir, VIDEOS).glob("cycle_*.gif"),
                    key=lambda p: (p.stem.partition("-")[0], p.stat().st_mtime))
    return videos[-1] if videos else None


def numbered_paths(directory: Path, stem: str, extension: str) -> Iterator[Path]:
    """`directory/<stem><extension>`, then the same with `-2`, `-3`, ... `-9999` before the extension: the names to
    try, in order, for a file that must not overwrite an earlier one (evaluations, videos)."""
    yield directory / f"{stem}{extension}"
    for number in range(2, 10_000):
        yield directory / f"{stem}-{number}{extension}"
