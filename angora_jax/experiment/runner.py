"""`train` and `resume`: a config-driven run with its run directory, checkpoints, monitor and progress display.

The `angora-jax train` and `resume` commands call these functions; notebooks call them too (`angora_jax.train`).
"""

from __future__ import annotations

import contextlib
import contextvars
import inspect
import numbers
import os
import shutil
import signal
import socket
import sys
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import jax
from jax.experimental import multihost_utils

from angora_jax.envs.core import Env
from angora_jax.envs.mjx_env import on_gpu
from angora_jax.envs.registry import TASKS
from angora_jax.experiment import compilation_cache
from angora_jax.experiment.checkpoint import (
    CheckpointError,
    Checkpoints,
    describe_saved,
    disk_needed,
    refuse_files_in_place,
)
from angora_jax.experiment.config import (
    Config,
    ConfigError,
    check_count,
    check_flag,
    load_config,
    num_devices,
    to_dict,
    validate,
)
from angora_jax.experiment.cpu_sizing import cpu_note
from angora_jax.experiment.distributed import (
    ProcessFailed,
    agree_on_settings,
    agree_to_stop,
    is_main_process,
    shared_run_dir,
)
from angora_jax.experiment.doctor import devices, versions
from angora_jax.experiment.held_out import held_out_evaluation
from angora_jax.experiment.monitor import (
    Monitor,
    ended_by_stop_at,
    logged_cycles,
    set_aside_after,
    set_aside_message,
    stop_at_pool,
)
from angora_jax.experiment.programs import cycle_programs, initial_state_shape
from angora_jax.experiment.progress import Progress
from angora_jax.experiment.resume_plan import plan_resume, set_aside_checkpoints_after, set_aside_outputs
from angora_jax.experiment.run_check import edited_settings, refused_as_edited
from angora_jax.experiment.run_dir import (
    CHECKPOINTS,
    EVALUATIONS,
    VIDEOS,
    RunDirError,
    create_run_dir,
    has_checkpoints,
    own_code_misfit,
    read_run_config,
    record_session,
    run_dir_path,
    write_run_config,
)
from angora_jax.experiment.run_lock import RunLock, RunLockedError, release_own_lock
from angora_jax.experiment.sources import check_sources
from angora_jax.experiment.terminal import discard, terminal_descriptors
from angora_jax.nets.registry import NETWORKS
from angora_jax.ppo.cycle import TrainState
from angora_jax.ppo.parallel import per_device
from angora_jax.ppo.step_size import spanning_schedules
from angora_jax.ppo.train import training_cycles
from angora_jax.registry import definition
from angora_jax.registry.plugins import module_files


def _definitions(config: Config) -> dict[str, str]:
    """Where the run's task and network were defined (`registry.definition`): recorded so that a command reading the
    run later says, of a name defined in a notebook (`__main__`), to move it into a module."""
    found = {}
    for name, registry in ((config.env.task, TASKS), (config.ppo.network.name, NETWORKS)):
        if name in registry.names(plugins=False):
            found[name] = definition(registry.get(name))
    return found


@dataclass
class TrainingRun:
    """What a finished (or already complete) run returns.

    Attributes:
        run_dir: the run directory.
        state: the final TrainState.
        history: the monitor records of the cycles run by this call (see `monitor`).
        finished: all of the config's cycles are done, or `ppo.stop_at` was reached; False when the call stopped at its
            time limit (`minutes`), with a checkpoint saved, and `resume(run_dir)` continues.
        stopped_at: what ended the run early under `ppo.stop_at` ("metric/goals_reached 30.4 >= 30"), else None.
    """

    run_dir: Path
    state: TrainState
    history: list[dict[str, Any]] = field(default_factory=list)
    finished: bool = True
    stopped_at: str | None = None

    def __repr__(self) -> str:
        # A notebook shows this for a cell ending in `run`: not the parameters and every environment's state.
        return (f"TrainingRun(run_dir={str(self.run_dir)!r}, cycle={int(self.state.cycle)}, cycles_this_call="
                f"{len(self.history)}, finished={self.finished}, stopped_at={self.stopped_at!r})")


class TrainingInterrupted(Exception):
    """Training stopped on SIGINT (Ctrl-C), SIGTERM or SIGHUP (its terminal closed) after saving a checkpoint;
    `resume(run_dir)` continues."""

    def __init__(self, signum: int, run_dir: Path, cycle: int):
        self.signum, self.run_dir, self.cycle = signum, run_dir, cycle
        hangup = (" To train on after the terminal closes, start it under nohup, tmux or screen."
                  if signum == signal.SIGHUP else "")
        super().__init__(
            f"Interrupted by {signal.Signals(signum).name} after cycle {cycle}; a checkpoint of that cycle is saved. "
            f"Continue with: angora-jax resume {run_dir} (in Python: aj.resume({str(run_dir)!r})).{hangup}"
        )


def train(
    config: Config | str | Path | dict | None = None,
    overrides: Iterable[str] = (),
    on_cycle: Callable[[dict[str, Any]], None] | None = None,
    minutes: float | None = None,
) -> TrainingRun:
    """Train a new run: validate the config, create its run directory, then run all cycles.

    In a multi-process run (`angora_jax.experiment.distributed`) all processes stop after the same cycle: a signal to
    any one interrupts all, and an error in one raises ProcessFailed in the others. An error in `on_cycle` (on one
    process or several) comes after the cycle's state is whole, so every process saves that cycle before stopping.

    Args:
        config: a Config, or anything `load_config` reads (YAML path, configs/ name, dict, None for defaults).
        overrides: `key.sub=value` strings applied to a config that `load_config` reads.
        on_cycle: called with each cycle's monitor record.
        minutes: a wall-clock limit for this call, compile included: after the first cycle that ends past it, a
            checkpoint is saved and the call returns with `finished=False` (train in pieces: `resume` continues
            exactly).

    Returns:
        The run: its directory, final state and the records of the cycles run.

    Raises:
        ConfigError: a bad config (before compiling).
        RunDirError: the named run directory exists.
        TrainingInterrupted: Ctrl-C or SIGTERM (with a checkpoint saved).
        TrainingDivergedError: NaN in the losses or parameters.
    """
    _check_call(on_cycle, minutes)
    compilation_cache.enable()
    config = load_config(config, overrides)
    # Per key one level into each section (the dataclass fields, the same on every process), so the message names it.
    agree_on_settings({f"{section}.{key}" if key else section: value for section, values in to_dict(config).items()
                       for key, value in (values.items() if isinstance(values, dict) else [("", values)])},
                      "Start every process with the same command: the same CONFIG, KEY=VALUE overrides and "
                      "logging.run_name (examples/slurm_train.sh, examples/multi_gpu_host.sh).")
    env = validate(config)
    check_sources(config, env)
    lock = None

    def claim(path: Path) -> None:
        nonlocal lock
        lock = RunLock(path)
        lock.acquire()

    run_dir = shared_run_dir(config, lambda config: create_run_dir(config, claim))
    try:
        return _run(config, env, run_dir, state=None, on_cycle=on_cycle, minutes=minutes, new=True)
    except BaseException:
        # A run that failed before its first cycle was recorded holds only its config: leave no half-made directory.
        if is_main_process() and not logged_cycles(run_dir):
            shutil.rmtree(run_dir, ignore_errors=True)
            print(f"The new run directory {run_dir} was removed: no cycle was finished in it.", file=sys.stderr)
        raise
    finally:
        if lock is not None:
            lock.release()


def resume(run_dir: str | Path, on_cycle: Callable[[dict[str, Any]], None] | None = None,
           minutes: float | None = None, exact: bool = False, start_from: str | int = "latest",
           from_scratch: bool = False, force: bool = False, num_cycles: int | None = None,
           no_stop_at: bool = False) -> TrainingRun:
    """Continue `run_dir` from its latest checkpoint up to the config's `ppo.num_cycles`, exactly as if it had
    not stopped (same device count assumed). A run that has already finished (all its cycles, or ended by its
    `ppo.stop_at`) is returned as it is, unless `num_cycles` asks for more or `no_stop_at` lifts the target.

    Nothing saved is lost or silently replaced (`resume_plan`): the process takes the run's writer lock (`run_lock`);
    a run that logged cycles but has no loadable latest checkpoint is refused rather than started over. Records logged
    after the checkpoint continued from always move to a side file (`metrics.after-cycle-N.jsonl`).

    A checkpoint without the environments' states (`checkpoint.lean`; best and snapshots often are), or whose
    environments do not fit this run (another `distribution.num_devices`: MuJoCo Warp's state holds a contact pool
    per device), continues with its parameters, optimizer, normalisers and key, and environments made afresh: not bit
    for bit, as a printed note says.

    Args:
        run_dir: the run directory to continue.
        on_cycle: called with each cycle's monitor record.
        minutes: this call's wall-clock limit, as for `train`.
        exact: refuse to continue with environments made afresh (CheckpointError naming the cause).
        start_from: "latest", "best" or a cycle with a checkpoint: continue from that one, with the later records of
            metrics.jsonl, later checkpoints and the evaluations and videos of later cycles moved aside.
        from_scratch: train again from cycle 0, with the earlier outputs moved to `RUN_DIR/previous-N/`.
        force: take over a writer lock held on another host.
        num_cycles: train to this many cycles in all instead of the config's `ppo.num_cycles` (to train a finished
            run longer, or stop one sooner), recorded in the run's config.yaml. Refused (ConfigError) below the
            cycle it continues from, and for a run whose schedules span `ppo.num_cycles` (`ppo.lr_decay`,
            `ppo.entropy_coef_final`): a new length would change them mid-run.
        no_stop_at: train on past `ppo.stop_at` (removed from the run's config.yaml), to `ppo.num_cycles`.

    Returns:
        The run as `train` returns it.

    Raises:
        RunLockedError: another process trains the run (the message names it).
        RunDirError: the run logged cycles but has no loadable latest checkpoint (the message names the choices).
        CheckpointError: a damaged checkpoint (the message names the newest intact one), or `exact` cannot hold.
        ConfigError: `num_cycles` cannot apply (the message says why).
    """
    run_dir = run_dir_path(run_dir)
    _check_call(on_cycle, minutes)
    exact, from_scratch, force, no_stop_at = (check_flag(name, flag) for name, flag in (
        ("exact", exact), ("from_scratch", from_scratch), ("force", force), ("no_stop_at", no_stop_at)))
    compilation_cache.enable()
    agree_on_settings({"RUN_DIR": str(run_dir.absolute()), "--from": start_from, "--from-scratch": from_scratch,
                       "--num-cycles": num_cycles, "--no-stop-at": no_stop_at, "--exact": exact, "--force": force},
                      f"Start every process with the same command: angora-jax resume {run_dir} --distributed, with "
                      "the same options.")
    config = on_disk = read_run_config(run_dir)
    before = config.ppo
    if num_cycles is not None:
        num_cycles = check_count("num_cycles", num_cycles)
        config = _lengthened(config, num_cycles, run_dir)
    if no_stop_at:
        config = replace(config, ppo=replace(config.ppo, stop_at=None))
    try:
        env = validate(config, new_run=False)
    except ConfigError as error:
        if (edited := refused_as_edited(run_dir, on_disk, error)) is not None:
            raise edited from None
        raise
    lock = _lock_together(run_dir, force)
    # One reader of the checkpoints for planning and restoring, so that the one resumed from is verified once.
    checkpoints = Checkpoints(run_dir / CHECKPOINTS, config.checkpoint, create=False)
    try:
        refuse_files_in_place(run_dir / CHECKPOINTS)  # before anything changes, not when the writer opens them
        plan = plan_resume(run_dir, config, start_from, from_scratch, checkpoints)
        if plan.cycle is not None:
            _refuse_edited(run_dir, on_disk, checkpoints)
        ended = None if plan.fresh_start else ended_by_stop_at(run_dir, config.ppo.stop_at, plan.cycle)
        if ended is not None and config.ppo.num_cycles != before.num_cycles:
            raise ConfigError(f"ppo.stop_at ended {run_dir} at cycle {plan.cycle} ({ended}), so --num-cycles alone "
                              f"would train nothing: add --no-stop-at to train it on to {config.ppo.num_cycles} "
                              "cycles (in Python: no_stop_at=True with num_cycles).")
        if config.ppo != before and plan.cycle is not None and config.ppo.num_cycles < plan.cycle:
            raise ConfigError(f"--num-cycles {config.ppo.num_cycles} is below cycle {plan.cycle}, where {run_dir} "
                              "continues: ask for at least that many (num_cycles in Python).")
        if plan.cycle is not None:
            _refuse_rewind_that_trains_nothing(run_dir, plan.cycle, start_from, num_cycles, config, ended,
                                               checkpoints)
        else:  # a start from cycle 0 reads its saved starting values (ppo.init_from, pretrained)
            check_sources(config, env)
        state = None
        if plan.cycle is not None:
            finished = plan.cycle >= config.ppo.num_cycles or ended is not None
            try:
                state = _restore_to_continue(checkpoints, plan.cycle, initial_state_shape(config, env), exact,
                                             run_dir, finished)
            except CheckpointError as error:
                # Its own module edited since (an observation widened): not its config.yaml, as the error would say.
                if error.misfits and (changed := own_code_misfit(run_dir, error.misfits)) is not None:
                    raise CheckpointError(changed, misfits=error.misfits) from None
                raise
        # Recorded only once the run can continue: a resume refused above changes nothing in the run.
        if config.ppo != before:
            if is_main_process():
                write_run_config(run_dir, config)
                changes = [f"ppo.num_cycles {before.num_cycles} -> {config.ppo.num_cycles}"] * (
                    config.ppo.num_cycles != before.num_cycles) + ["ppo.stop_at removed"] * (
                    config.ppo.stop_at != before.stop_at)
                print(f"{run_dir}: {', '.join(changes)}, recorded in its config.yaml.", file=sys.stderr, flush=True)
        verified = checkpoints.verified()
        checkpoints.close()  # before the checkpoints after plan.cycle are moved aside, and the writer opens them
        checkpoints = None
        if is_main_process():
            if plan.fresh_start:
                print(f"Training {run_dir} again from cycle 0; the earlier outputs are kept in "
                      f"{set_aside_outputs(run_dir)}.", file=sys.stderr, flush=True)
            elif plan.cycle is None:
                print(f"Resuming {run_dir} from cycle 0: {plan.describe}.", file=sys.stderr, flush=True)
            else:
                moved = set_aside_checkpoints_after(run_dir, plan.cycle)
                if moved is not None:
                    print(f"{_kept(moved)} after cycle {plan.cycle} are kept in {moved}.", file=sys.stderr,
                          flush=True)
                side = set_aside_after(run_dir, plan.cycle)
                if side is not None:
                    print(set_aside_message(side, plan.cycle), file=sys.stderr, flush=True)
        _together(f"angora_jax resume {run_dir}")
        return _run(config, env, run_dir, state=state, on_cycle=on_cycle, minutes=minutes, ended=ended,
                    verified=verified)
    finally:
        if checkpoints is not None:
            checkpoints.close()
        if lock is not None:
            lock.release()


def _check_call(on_cycle: Any, minutes: Any) -> None:
    """Refuse, before anything is made or compiled, an `on_cycle` that cannot be called and a time limit that is no
    positive number: found after the first cycle (called with its record, compared with the clock), they ended a new
    run with that cycle logged and no checkpoint, which `resume` then refuses to start over."""
    if on_cycle is not None and not callable(on_cycle):
        raise TypeError(f"on_cycle is called with each cycle's record (a dict), e.g. on_cycle=print or "
                        f"on_cycle=records.append; got {on_cycle!r} ({type(on_cycle).__name__}).")
    if on_cycle is not None:  # one that takes no record, or more, failed alike after the first cycle
        try:
            signature = inspect.signature(on_cycle)
        except (TypeError, ValueError):  # a builtin without a signature to read: called as it is
            signature = None
        if signature is not None:
            try:
                signature.bind({})
            except TypeError:
                name = getattr(on_cycle, "__name__", type(on_cycle).__name__)
                raise TypeError(f"on_cycle is called with each cycle's record (a dict), e.g. on_cycle=print or "
                                f"on_cycle=records.append; {name} takes {signature}.") from None
    if minutes is not None and (isinstance(minutes, bool) or not isinstance(minutes, numbers.Real) or not minutes > 0):
        raise ValueError(f"minutes (the call's time limit) must be > 0, got {minutes!r}.")


def _refuse_rewind_that_trains_nothing(run_dir: Path, cycle: int, start_from: str | int, num_cycles: int | None,
                                       config: Config, ended: str | None, checkpoints: Checkpoints) -> None:
    """ConfigError when a resume from an earlier checkpoint (`--from`) would train nothing (`--num-cycles` at its
    cycle, or `ppo.stop_at` reached by then) yet set aside the later latest checkpoints: the run was left without a
    latest checkpoint, which every plain resume then refused."""
    if not (cycle >= config.ppo.num_cycles or ended is not None) or not any(
            step > cycle for step in checkpoints.steps("latest")):
        return
    why = (f"ppo.stop_at ended the run by then ({ended})" if ended is not None else
           f"--num-cycles {num_cycles}" if num_cycles is not None else f"its ppo.num_cycles ({config.ppo.num_cycles})")
    raise ConfigError(
        f"--from {start_from} with {why} trains nothing (in Python: start_from={start_from!r}"
        f"{f', num_cycles={num_cycles}' if num_cycles is not None else ''}): it would only set "
        f"aside {run_dir}'s checkpoints after cycle {cycle}, its latest among them, and leave it with no latest "
        f"checkpoint to resume from, so nothing was changed. To train on from cycle {cycle}: --num-cycles "
        f"{cycle + 1} or more{' with --no-stop-at' if ended is not None else ''}; to use that checkpoint as it is: "
        f"`angora-jax evaluate {run_dir} --checkpoint {cycle}` (or export, record, analyze with --checkpoint "
        f"{cycle}).")


def _refuse_edited(run_dir: Path, config: Config, checkpoints: Checkpoints) -> None:
    """ConfigError when the run's config.yaml (`config`) holds other task or learning settings than its checkpoints
    were trained with: continuing would make one run's records of two (`run_check.edited_settings`)."""
    edited = edited_settings(run_dir, config, checkpoints)
    if edited is not None:
        raise ConfigError(
            f"{edited.describe(run_dir)}. resume continues a run with the settings it was trained with, so that its "
            f"records stay one run's. To continue it, put them back: `angora-jax check {run_dir} --restore-config` "
            f"(the edited file is kept beside it). To train with the new settings, start a new run from its policy: "
            f"`angora-jax train CONFIG ppo.init_from={run_dir}:latest`.")


def _kept(moved: Path) -> str:
    """What `set_aside_checkpoints_after` moved into `moved`, in words: "Checkpoints", "Checkpoints and evaluations"."""
    names = [name for name, folder in (("checkpoints", CHECKPOINTS), ("evaluations", EVALUATIONS), ("videos", VIDEOS))
             if (moved / folder).exists()]
    return (", ".join(names[:-1]) + " and " + names[-1] if len(names) > 1 else names[0]).capitalize()


def _lengthened(config: Config, num_cycles: int, run_dir: Path) -> Config:
    """`config` trained to `num_cycles` cycles in all; ConfigError where its schedules span its length."""
    if num_cycles == config.ppo.num_cycles:
        return config
    spanning = spanning_schedules(config.ppo)
    if spanning:
        raise ConfigError(
            f"{run_dir} anneals over its ppo.num_cycles ({' and '.join(spanning)}), so another length would change "
            f"its schedule mid-run. Start a new run from its policy instead: angora-jax train CONFIG "
            f"ppo.init_from={run_dir}:latest (the optimizer and reward statistics start afresh).")
    return replace(config, ppo=replace(config.ppo, num_cycles=num_cycles))


def _lock_together(run_dir: Path, force: bool) -> RunLock | None:
    """Process 0 takes the run's writer lock for all processes; all raise RunLockedError when it cannot (the others
    would otherwise wait for it in the first cycle). Returns the lock held by this process, if any."""
    lock, refusal = None, None
    if is_main_process():
        lock = RunLock(run_dir)
        try:
            lock.acquire(force)
        except RunLockedError as error:
            lock, refusal = None, error
    agreed = agree_to_stop(None, refusal is not None)
    if refusal is not None:
        raise refusal
    if agreed.failed:
        raise RunLockedError(f"Process 0 could not take the writer lock of {run_dir}; its output says why.")
    return lock


def _together(what: str) -> None:
    """Wait until every process of a multi-process run gets here (process 0 may be moving files the others read)."""
    if jax.process_count() > 1:
        multihost_utils.sync_global_devices(what)


def _restore_to_continue(checkpoints: Checkpoints, cycle: int, template: TrainState, exact: bool, run_dir: Path,
                         finished: bool) -> TrainState:
    """The state of the checkpoint of `cycle`, whole where it can be; else without its environments (see `resume`). A
    `finished` run's is read without them even when saved with them: nothing continues, and the cube's 16,384
    environments are most of a 301 MB checkpoint."""
    lean = template.without_environments()
    if finished:
        return checkpoints.restore(lean, cycle, partial=True).state
    if checkpoints.holds_environments(cycle):
        try:
            return checkpoints.restore(template, cycle).state
        except CheckpointError as error:
            if exact or error.misfits is None:  # asked to be exact, or unreadable rather than of another layout
                raise
            try:  # the parameters still fit, the environments' layout does not (another device count)
                state = checkpoints.restore(lean, cycle, partial=True).state
            except CheckpointError:
                raise error from None
            reason = (f"its environments' states do not fit this run ({error.misfits}): saved on another device "
                      "count (MuJoCo Warp keeps a contact pool per device) or by another version of the task")
    else:
        reason = "it is lean (checkpoint.lean): it holds no environment states"
        if exact:
            raise CheckpointError(
                f"Cannot resume {run_dir} exactly from cycle {cycle}: {reason}, so the run cannot continue bit for "
                "bit. Resume without --exact (its environments are then made afresh), or keep environments in "
                "future latest checkpoints with checkpoint.lean=[best, snapshots] (the default).")
        state = checkpoints.restore(lean, cycle, partial=True).state
    if is_main_process():
        print(f"Resuming {run_dir} from cycle {cycle} with fresh environments, not bit for bit: {reason}.",
              file=sys.stderr, flush=True)
    return state


def _run(
    config: Config,
    env: Env,
    run_dir: Path,
    state: TrainState | None,
    on_cycle: Callable[[dict[str, Any]], None] | None,
    minutes: float | None = None,
    new: bool = False,
    ended: str | None = None,
    verified: dict[tuple[str, int], str | None] | None = None,
) -> TrainingRun:
    deadline = None if minutes is None else time.monotonic() + 60.0 * minutes
    # A run that its ppo.stop_at ended is as complete as one that did all its cycles (`ended`: what ended it).
    finished = state is not None and (int(state.cycle) >= config.ppo.num_cycles or ended is not None)
    stop_at, stopped_at = config.ppo.stop_at, ended
    # The cycles whose episodes the target's next comparison pools, taken up where a resumed run stopped.
    stop_pool = stop_at_pool(run_dir, stop_at, int(state.cycle))[1] if stop_at and state is not None and not new else []
    history: list[dict[str, Any]] = []
    resolved = to_dict(config)
    checkpoints = Checkpoints(run_dir / CHECKPOINTS, config.checkpoint, verified=verified)
    if state is not None and not new:
        checkpoints.continue_from(int(state.cycle))
    if is_main_process() and checkpoints.removed_unfinished:
        cut_short = describe_saved(checkpoints.removed_unfinished)
        print(f"Removed what a writer stopped mid-save left in {run_dir / CHECKPOINTS} ({cut_short}): unfinished, "
              "never checkpoints; the checkpoints saved before them are intact.", file=sys.stderr, flush=True)
    evaluate = held_out_evaluation(config, env)
    # Under jax.distributed only process 0 logs; all processes take part in saving checkpoints (Orbax coordinates
    # them: each writes the shards of its own devices, process 0 the replicated arrays and metadata).
    main = is_main_process()
    video = None
    if main and config.evaluation.video is not None:
        # Imported here: the video renders through an Agent, and the agent module imports this one.
        from angora_jax.experiment.training_video import training_videos

        video = training_videos(config, run_dir)
    monitor = Monitor(run_dir, config.logging.tensorboard, config.logging.wandb, resolved) if main else None
    progress = Progress(config.ppo.num_cycles, config.logging.progress if main else "none",
                        shown=config.checkpoint.best_metric)
    if main:
        devices_used = num_devices(config)
        physics = env.physics_info(per_device(config.ppo, devices_used).num_envs) | {"num_devices": devices_used}
        start = 0 if state is None else int(state.cycle)
        record_session(run_dir, {"time": time.time(), "start_cycle": start, "num_cycles": config.ppo.num_cycles,
                                 "host": socket.gethostname(),
                                 "processes": jax.process_count(), "devices": devices(), "versions": versions(),
                                 "physics": physics, "imports": module_files(config.imports),
                                 "definitions": _definitions(config)})
        if ended:
            plan = f"nothing to train (ppo.stop_at ended it at cycle {start})"
        elif finished:
            plan = f"nothing to train (cycle {start} of {config.ppo.num_cycles}: already complete)"
        else:
            plan = f"compiling the first cycle (from cycle {start} of {config.ppo.num_cycles}) ..."
        notes = [note] if (note := cpu_note(config, physics, on_gpu())) else []
        if physics.get("impl") == "warp" and devices_used > 1 and jax.process_count() == 1 and on_gpu():
            notes.append("Note: one process driving several GPUs on MuJoCo Warp is measured over whole runs on 2 "
                         "H100s but for 10 cycles only on 4 (3.87x); one process per GPU is measured over whole runs "
                         "on 2 and 4 (3.94x on 4 H100s): examples/multi_gpu_host.sh, or --distributed under SLURM.")
        # The notes first: the line that says it compiles is the last before the (long) compile.
        announcement = "\n".join([*notes, f"{run_dir}: {config.env.task} on {describe_physics(physics)}; {plan}"])
    try:
        # The wake-up fd first: a signal that finds the stop handlers installed then also reaches the watcher.
        with _preparation(run_dir, new) as prepared, _stop_requests() as stop:
            if main:
                progress.announce(announcement)
            # Divergence (TrainingDivergedError) is decided inside training_cycles from a metric that the compiled
            # cycle reduces over all devices, so every process raises it after the same cycle; every other reason to
            # stop is this process's own and goes through agree_to_stop, so that all processes stop together.
            cached_before = compilation_cache.counts()
            programs = cycle_programs(config, env)
            if main:
                _warn_if_disk_is_small(run_dir, config, initial_state_shape(config, env), config.ppo.num_cycles - start)
            cycles = () if ended else training_cycles(config.ppo, env, None, state, num_devices(config), programs)
            for latest, metrics in cycles:
                if "compile_seconds" in metrics:  # the programs this session compiled, and those read from the cache
                    cached = compilation_cache.counts()
                    metrics |= {f"compile_cache_{kind}": cached[kind] - cached_before[kind] for kind in cached}
                prepared()
                if evaluate is not None:
                    metrics |= evaluate(latest)
                if video is not None:
                    video(latest)
                state, failure, in_on_cycle = latest, None, False
                try:
                    record = monitor.record(metrics, state) if monitor is not None else metrics
                    history.append(record)
                    progress.update(record)
                    in_on_cycle = on_cycle is not None
                    if in_on_cycle:
                        on_cycle(record)
                except Exception as error:  # re-raised below, once the other processes know to stop too
                    failure = error
                # Read the request once: a signal arriving during the save is acted on after the next cycle.
                out_of_time = deadline is not None and time.monotonic() > deadline
                decision = agree_to_stop(stop.signum, failure is not None, out_of_time,
                                         failure is not None and in_on_cycle)
                if failure is not None or decision.failed:
                    if decision.in_on_cycle:  # the user's code failed after the cycle: every process saves it
                        _save_together(checkpoints, state, record, resolved, True, run_dir)
                    if failure is not None:
                        if decision.in_on_cycle:
                            failure.add_note(f"angora_jax: the run stopped after cycle {record['cycle']}, whose "
                                             f"checkpoint is saved; fix on_cycle, then continue with "
                                             f"aj.resume({str(run_dir)!r}, on_cycle=...).")
                        raise failure
                    raise ProcessFailed(decision.failed, int(metrics["cycle"]), run_dir, decision.in_on_cycle)
                # The compiled cycle reduces its metrics over every device, so all processes decide this alike.
                if stop_at is not None:
                    value, stop_pool = stop_at.compared(stop_pool, metrics)
                    stopped_at = stop_at.ended(value)
                finished = record["cycle"] == config.ppo.num_cycles or stopped_at is not None
                stopping = decision.signum is not None or decision.out_of_time
                _save_together(checkpoints, state, record, resolved, stopping or finished, run_dir)
                if decision.signum is not None:
                    raise TrainingInterrupted(decision.signum, run_dir, int(record["cycle"]))
                if (decision.out_of_time and not finished) or stopped_at is not None:
                    break
    finally:
        progress.close()
        if monitor is not None:
            monitor.close()
        checkpoints.close()
    if config.logging.report and main:
        from angora_jax.experiment.report import write_report  # matplotlib is loaded only when a report is made

        try:
            write_report([run_dir], run_dir / "report")
        except (OSError, RunDirError) as error:  # the run is saved; its report can be drawn again at any time
            print(f"Warning: the run's report was not written ({error}). The run is saved: fix the cause, then "
                  f"`angora-jax report {run_dir}` draws it.", file=sys.stderr, flush=True)
    return TrainingRun(run_dir, state, history, finished, stopped_at)


_EXIT_WHILE_PREPARING = contextvars.ContextVar("exit_while_preparing", default=False)


@contextlib.contextmanager
def signals_exit_while_preparing() -> Iterator[None]:
    """Inside this context (the `angora-jax` command), SIGINT or SIGTERM before a run's first cycle has ended ends
    the process at once with exit code 128 + signal number, instead of after the first cycle: compiling and the first
    cycle can take minutes and nothing is saved yet. A new run's directory is removed; a resumed run keeps its
    checkpoints. Outside it (Python: notebooks, scripts) only SIGTERM does so, the request of a scheduler or `kill`
    to end the process, which would otherwise wait out the compile and be killed before it saves; SIGINT (a
    notebook's interrupt, which must not kill the kernel) stops after the current cycle, as it does later in every
    run."""
    token = _EXIT_WHILE_PREPARING.set(True)
    try:
        yield
    finally:
        _EXIT_WHILE_PREPARING.reset(token)


@contextlib.contextmanager
def _preparation(run_dir: Path, new: bool) -> Iterator[Callable[[], None]]:
    """Yield a function to call when the first cycle has ended. Before that, a thread woken by Python's signal
    wake-up fd (the main thread may be inside a compile for minutes and runs no Python until it returns) exits the
    process on SIGTERM, and on SIGINT too under `signals_exit_while_preparing`."""
    preparing = threading.Event()
    if threading.current_thread() is not threading.main_thread():
        yield preparing.set
        return
    exits = (signal.SIGTERM, signal.SIGHUP, *[signal.SIGINT] * _EXIT_WHILE_PREPARING.get())
    receive, send = socket.socketpair()
    send.setblocking(False)
    previous = signal.set_wakeup_fd(send.fileno(), warn_on_full_buffer=False)

    def watch():
        with contextlib.suppress(OSError):
            while (data := receive.recv(1)) and not preparing.is_set():
                if data[0] in exits:
                    _exit_while_preparing(signal.Signals(data[0]), run_dir, new)

    threading.Thread(target=watch, name="angora_jax signal watch", daemon=True).start()
    try:
        yield preparing.set
    finally:
        preparing.set()
        signal.set_wakeup_fd(previous)
        send.close()
        receive.close()


def _exit_while_preparing(signum: signal.Signals, run_dir: Path, new: bool) -> None:
    if new and is_main_process():
        shutil.rmtree(run_dir, ignore_errors=True)
        outcome = f"nothing was trained yet, so the new run directory {run_dir} was removed"
    else:
        release_own_lock(run_dir)
        if has_checkpoints(run_dir):
            outcome = (f"the run directory {run_dir} keeps its checkpoints; continue with: angora-jax resume {run_dir} "
                       f"(in Python: aj.resume({str(run_dir)!r}))")
        else:  # a --from-scratch start, or a run that saved none yet
            earlier = sorted(run_dir.glob("previous-*"), key=lambda path: path.stat().st_mtime)
            kept = f"; the earlier training is kept in {earlier[-1]}" if earlier else ""
            outcome = (f"{run_dir} holds no checkpoint of this training{kept}; `angora-jax resume {run_dir}` (in "
                       f"Python: aj.resume({str(run_dir)!r})) starts it from cycle 0 again")
    with contextlib.suppress(OSError):  # SIGHUP: the terminal is gone, and writing to it fails
        print(f"\nInterrupted by {signum.name} before the first cycle ended (while compiling or running it): "
              f"{outcome}.", file=sys.stderr, flush=True)
    os._exit(128 + signum)


def _save_together(checkpoints: Checkpoints, state: TrainState, record: dict[str, Any], config: dict[str, Any],
                   final: bool, run_dir: Path) -> None:
    """Save what is due after this cycle; with several processes, all learn whether every save succeeded. Without
    that, a process whose save failed (a full disk, a lost mount) would stop while the others went on into the next
    cycle's collectives and waited for it forever."""
    try:
        checkpoints.save(state, record, config, final=final)
        error = None
    except Exception as failure:  # re-raised below, once the other processes know
        error = failure
    saved = agree_to_stop(None, error is not None)  # on one process: no communication
    if error is None and saved.failed:
        raise ProcessFailed(saved.failed, int(record["cycle"]), run_dir)
    if error is not None:
        raise error


def _warn_if_disk_is_small(run_dir: Path, config: Config, state: TrainState, cycles_left: int) -> None:
    """Say before training when the checkpoints the run will save need more space than its disk has free."""
    needed, free = disk_needed(config.checkpoint, state, cycles_left), shutil.disk_usage(run_dir).free
    if needed > free:
        print(f"Warning: the checkpoints of this run need up to {_size(needed)} (latest and best, each written "
              f"before the last is removed, and the snapshots due), but {run_dir}'s disk has {_size(free)} free. A "
              "save that finds the disk full stops the run, keeping the checkpoints saved before; free space now, or "
              "keep fewer (checkpoint.snapshot_every, checkpoint.lean).",
              file=sys.stderr, flush=True)


def _size(count: int) -> str:
    for unit, scale in (("GiB", 2**30), ("MiB", 2**20)):
        if count >= scale:
            return f"{count / scale:.1f} {unit}"
    return f"{count / 2**10:.1f} KiB"


def describe_physics(physics: dict[str, Any]) -> str:
    """`Env.physics_info()` as one phrase: engine, device(s), Warp's buffer size and why this implementation."""
    devices_used = physics.get("num_devices", 1)
    where = f"{devices_used} devices" if devices_used > 1 else physics["device"]
    text = f"{physics['engine']} on {where}"
    if "warp_max_envs" in physics:
        each = f" on each of the {devices_used} devices" if devices_used > 1 else ""
        text += f", Warp buffers for {physics['warp_max_envs']:,} envs{each}"
    return text + (f" ({physics['why']})" if "why" in physics else "")


@dataclass
class _StopRequest:
    signum: int | None = None


@contextlib.contextmanager
def _stop_requests() -> Iterator[_StopRequest]:
    """Turn the first SIGINT, SIGTERM or SIGHUP into a request to stop after the current cycle (the compiled cycle
    cannot be stopped halfway, and stopping between cycles lets the run save a checkpoint). A second Ctrl-C acts as
    usual, at once. A second SIGTERM or SIGHUP does not cut the stopping save short: one signal often arrives twice (a
    launcher, or the shell of a closed terminal, forwards it to a process that its process group's signal reached
    already), and SIGKILL remains for a user who means it; in the command, whose process ends after the stop, they
    are not restored to kill the process on its way out. SIGHUP, sent when the terminal closes (an ssh session
    dropped), killed the process with the cycles since its last checkpoint; its output to that terminal now goes
    nowhere, as writing to a closed terminal fails. A SIGHUP ignored when training starts (`nohup`) stays ignored.
    Signal handlers can only be set from the main thread; elsewhere signals are left alone."""
    request = _StopRequest()
    if threading.current_thread() is not threading.main_thread():
        yield request
        return
    signals = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
    previous = {signum: signal.getsignal(signum) for signum in signals}
    # SIGHUP ignored is nohup's request to train on; SIGINT ignored is only how a script starts a background job
    # (examples/multi_gpu_host.sh forwards Ctrl-C to its processes with kill -INT), which must still stop the run.
    held = [signum for signum in signals if signum != signal.SIGHUP or previous[signum] is not signal.SIG_IGN]
    terminals = terminal_descriptors()  # now: once the terminal has hung up, isatty says no

    def again(signum, frame):
        if signum == signal.SIGTERM:
            print("SIGTERM again: still finishing the cycle and saving its checkpoint, then the run stops; kill -9 "
                  "(SIGKILL) ends it at once, keeping the checkpoints saved before.", file=sys.stderr, flush=True)
        signal.signal(signum, lambda signum, frame: None)  # said once

    def handle(signum, frame):
        if signum == signal.SIGHUP:  # the terminal is gone: each write to it would fail and end the run unsaved
            discard(terminals)
        request.signum = signum
        signal.signal(signal.SIGINT, previous[signal.SIGINT])
        for later in {signal.SIGTERM, signal.SIGHUP} & set(held):
            signal.signal(later, again)

    for signum in held:
        signal.signal(signum, handle)
    try:
        yield request
    finally:
        signal.signal(signal.SIGINT, previous[signal.SIGINT])
        if request.signum is None or not _EXIT_WHILE_PREPARING.get():
            for signum in {signal.SIGTERM, signal.SIGHUP} & set(held):
                signal.signal(signum, previous[signum])
