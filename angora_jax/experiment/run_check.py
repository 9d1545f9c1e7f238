"""`angora-jax check RUN_DIR`: what a run directory holds, whether it is intact, and what `resume` would do with it.

Reads only: the config (does it load and fit this version), the writer lock, metrics.jsonl (damaged lines, records
without their env_steps, and each cycle logged once and in order), every checkpoint against its manifest, and the resume
plan (`resume_plan`). `restore_config` (`check --restore-config`) is its one repair: a damaged config.yaml, or one whose
task or learning settings were edited after training, written again from the copy that the checkpoints keep.
`edited_settings` finds such an edit; `resume` refuses to continue through one.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from angora_jax.experiment.checkpoint import KINDS, CheckpointError, Checkpoints, cycle_ranges, refuse_files_in_place
from angora_jax.experiment.config import (
    CheckpointConfig,
    Config,
    ConfigError,
    flatten,
    load_config,
    to_dict,
    validate,
)
from angora_jax.experiment.monitor import bare_metric_records, damaged_metric_lines, ended_by_stop_at, logged_cycles
from angora_jax.experiment.resume_plan import plan_resume
from angora_jax.experiment.run_dir import (
    CHECKPOINTS,
    CONFIG_FILE,
    METRICS_FILE,
    RunDirError,
    has_checkpoints,
    numbered_paths,
    read_run_config,
    write_run_config,
)
from angora_jax.experiment.run_lock import RunLock
from angora_jax.registry.plugins import UserCodeError
from angora_jax.wording import agreeing, counted

# The settings that make a run what it is: the task and the learning. The others (logging, checkpoint, distribution,
# evaluation, imports) may change between sessions; so may the two that `resume` itself records (--num-cycles,
# --no-stop-at).
LEARNING_SETTINGS = ("env.", "ppo.")
RECORDED_BY_RESUME = ("ppo.num_cycles", "ppo.stop_at")


@dataclass(frozen=True)
class EditedSettings:
    """Task or learning settings of a run's config.yaml that differ from those its checkpoints were trained with.

    Attributes:
        kind, cycle: the checkpoint whose saved config was compared (the newest intact one).
        saved: the config saved with that checkpoint.
        changes: one "key: saved -> now" line per setting that differs.
    """

    kind: str
    cycle: int
    saved: Config
    changes: tuple[str, ...]

    def describe(self, run_dir: Path) -> str:
        shown = "; ".join(self.changes[:6]) + (f"; and {len(self.changes) - 6} more" if len(self.changes) > 6 else "")
        return (f"{run_dir / CONFIG_FILE} was edited after the {self.kind} checkpoint of cycle {self.cycle} was "
                f"saved: {shown}")


def edited_settings(run_dir: str | Path, config: Config, checkpoints: Checkpoints | None = None
                    ) -> EditedSettings | None:
    """Where `config` (the run's config.yaml as loaded) differs from the config saved with `run_dir`'s newest intact
    checkpoint in its task or learning settings (`env.*`, `ppo.*` but `ppo.num_cycles` and `ppo.stop_at`); None when
    they agree, or no checkpoint keeps a copy that loads with this version. `checkpoints`: the run's, opened by the
    caller (None: opened and closed here)."""
    run_dir = Path(run_dir)
    if not has_checkpoints(run_dir):
        return None
    reader = checkpoints or Checkpoints(run_dir / CHECKPOINTS, CheckpointConfig(), create=False)
    try:
        found = reader.saved_config()
    finally:
        if checkpoints is None:
            reader.close()
    if found is None:
        return None
    kind, cycle, data = found
    try:
        saved = load_config(data)
    except ConfigError:  # saved by a version whose config this one cannot read: nothing to compare
        return None
    before, now = flatten(to_dict(saved)), flatten(to_dict(config))
    changes = tuple(f"{key}: {_shown(before.get(key))} -> {_shown(now.get(key))}"
                    for key in sorted(before.keys() | now.keys())
                    if key.startswith(LEARNING_SETTINGS) and not key.startswith(RECORDED_BY_RESUME)
                    and before.get(key) != now.get(key))
    return EditedSettings(kind, cycle, saved, changes) if changes else None


def refused_as_edited(run_dir: str | Path, config: Config, error: ConfigError) -> ConfigError | None:
    """`error` (the run's config.yaml, as loaded in `config`, refused by `validate`) with what of it was edited since
    its checkpoints were saved and how to write theirs back; None when it was not edited (the error is then the
    whole story). A file cut short mid-word (`task: CartPol`) was otherwise answered as if the user had asked for
    that task."""
    edited = edited_settings(run_dir, config)
    if edited is None:
        return None
    return ConfigError(f"{edited.describe(Path(run_dir))}, and it no longer loads: {error} `angora-jax check {run_dir} "
                       "--restore-config` writes back the config it was trained with (the edited file is kept beside "
                       "it).")


def _shown(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


@dataclass
class RunCheck:
    """What `angora-jax check` found in a run directory.

    Attributes:
        findings: what was found, one line each.
        problems: what is damaged or inconsistent, with the fix (empty for a sound run).
        resume: what `angora-jax resume` would do, or why it would refuse.
    """

    findings: list[str] = field(default_factory=list)
    problems: list[str] = field(default_factory=list)
    resume: str = ""

    def format(self) -> str:
        lines = [*self.findings, f"resume: {self.resume}"]
        lines += [f"PROBLEM: {problem}" for problem in self.problems] or ["OK: nothing is damaged or missing."]
        return "\n".join(lines)


def check_run(run_dir: str | Path) -> RunCheck:
    """Check `run_dir` (see the module docstring); RunDirError when it is no run directory at all."""
    run_dir = Path(run_dir)
    result = RunCheck()
    config = read_run_config(run_dir)  # RunDirError: not a run directory, or a config this version cannot read
    described = (f"config: {config.env.task}, {config.ppo.network.name} network, "
                 f"{counted(config.ppo.num_cycles, 'cycle')}")
    try:
        validate(config, new_run=False)
        result.findings.append(described)
    except ConfigError as error:
        result.problems.append(f"config.yaml does not run with this version of angora_jax: {error}")
    except UserCodeError as error:  # the run's own code, not the run: nothing in it is damaged
        result.findings.append(f"{described}; its own code cannot be used here, so resume and evaluate cannot either "
                               f"(the checks below do not need it): {error}")
    edited = edited_settings(run_dir, config)
    if edited is not None:
        result.problems.append(f"{edited.describe(run_dir)}. resume refuses to continue the run with other settings; "
                               f"`angora-jax check {run_dir} --restore-config` puts them back")

    lock = RunLock(run_dir)
    holder = lock.holder()
    copied = None if holder is None else lock.copied_from(holder)
    gone = holder is not None and (copied is not None or holder.is_gone())
    if holder is None:
        result.findings.append("writer: none (no process trains it now)")
    else:
        state = (f"the lock was copied with the run from {copied}, which that process trains: nobody writes this copy, "
                 "so resume takes the lock over" if copied is not None else
                 "ended, so resume takes the lock over" if gone else
                 "cannot tell whether it runs: resume --force takes the lock over" if holder.pid < 0 else
                 "running on this host: resume is refused until it stops" if holder.runs_here() else
                 "on another host, so this one cannot tell whether it runs: resume is refused, --force takes the "
                 "lock over once that process is certainly gone")
        result.findings.append(f"writer: {holder.describe()} ({state})")
    # While a writer may be training the run, its newest saves are still being written, not cut short.
    live = holder is not None and holder.pid >= 0 and not gone

    cycles = logged_cycles(run_dir)
    result.findings.append(f"{METRICS_FILE}: {counted(len(cycles), 'cycle')} logged"
                           + (f", {cycles[0]} to {cycles[-1]}" if len(cycles) > 1 else
                              f", cycle {cycles[0]}" if cycles else ""))
    damaged = damaged_metric_lines(run_dir)
    if damaged:
        result.problems.append(f"{METRICS_FILE} {agreeing(len(damaged), 'line')} {', '.join(map(str, damaged[:10]))} "
                               f"{agreeing(len(damaged), 'holds', 'hold')} no cycle's record "
                               "(edited or cut short); resume moves them to a side file")
    bare = bare_metric_records(run_dir)
    expected = list(range(cycles[0], cycles[0] + len(cycles))) if cycles else []
    uneven = bool(cycles) and (cycles != expected or cycles[0] != 1)
    sides = sorted(p.name for p in run_dir.glob("metrics.after-cycle-*.jsonl"))
    if sides:
        result.findings.append(f"set aside by earlier resumes: {', '.join(sides)}")

    try:
        refuse_files_in_place(run_dir / CHECKPOINTS)
    except CheckpointError as error:  # resume refuses it too
        result.problems.append(str(error))
    checkpoints = Checkpoints(run_dir / CHECKPOINTS, config.checkpoint, create=False)
    sound: set[int] = set()
    try:
        for kind in KINDS:
            verdicts = {cycle: checkpoints.damage(kind, cycle) for cycle in checkpoints.steps(kind)}
            if live:  # a checkpoint the writer replaced while it was verified is not damage
                verdicts = {cycle: damage for cycle, damage in verdicts.items()
                            if (run_dir / CHECKPOINTS / kind / str(cycle)).is_dir()}
            intact = [cycle for cycle, damage in verdicts.items() if damage is None]
            unverified = [cycle for cycle, damage in verdicts.items() if damage == "no manifest"]
            sound.update(intact)
            kept = [f"intact: cycle {cycle_ranges(intact, every=True)}"] * bool(intact)
            kept += [f"without a manifest{' yet (the writer adds it once the save is whole)' if live else ''}, "
                     f"unverifiable: cycle {cycle_ranges(unverified, every=True)}"] * bool(unverified)
            damaged = [cycle for cycle in verdicts if cycle not in intact and cycle not in unverified]
            kept += [f"damaged: cycle {cycle_ranges(damaged, every=True)}"] * bool(damaged)
            unfinished = checkpoints.unfinished(kind)
            stopped = ("being written now" if live else
                       "its writer stopped mid-save; never a checkpoint, resume removes it")
            kept += [f"unfinished ({stopped}): cycle {cycle_ranges(unfinished, every=True)}"] * bool(unfinished)
            result.findings.append(f"checkpoints/{kind}: {'; '.join(kept) or 'none'}")
            result.problems += [f"checkpoint {kind}/{cycle} is damaged: {damage}" for cycle, damage in verdicts.items()
                                if damage not in (None, "no manifest")]
            if not live:  # nothing to verify them by: read them whole instead
                result.problems += [f"checkpoint {kind}/{cycle} has no manifest and cannot be read ({why}); resume "
                                    f"--from another checkpoint, or restore the folder from a copy"
                                    for cycle in unverified if (why := checkpoints.unreadable(kind, cycle))]
        latest = checkpoints.steps("latest")
    finally:
        checkpoints.close()
    if uneven:
        result.problems.append(f"{METRICS_FILE} does not log each cycle once and in order from cycle 1 "
                               f"({cycle_ranges(cycles)}): records were lost or two processes wrote the run"
                               + _relog(run_dir, cycles, sound))
    if latest and cycles and latest[-1] > cycles[-1]:
        result.problems.append(f"the latest checkpoint (cycle {latest[-1]}) is newer than the last cycle logged "
                               f"({cycles[-1]}): records were lost")
    elif (saved := max(sound, default=0)) and not cycles:
        state = "is empty" if (run_dir / METRICS_FILE).exists() else "is missing"
        result.problems.append(f"{METRICS_FILE} {state}, but checkpoints were saved up to cycle {saved}: the training "
                               "curve's records were lost. Put the file back from a copy if there is one; resume "
                               "would continue and log only the cycles after it")

    plan = None
    try:
        plan = plan_resume(run_dir, config)
        result.resume = plan.describe + _ended(run_dir, config, plan.cycle)
    except RunDirError as refusal:
        result.resume = f"refuses: {refusal}"
    if bare:
        result.problems.append(_bare(run_dir, bare, None if plan is None else plan.cycle, sound))
    if plan is None:
        result.problems.append("resume cannot continue as it is: see above")
    return result


def _bare(run_dir: Path, bare: list[tuple[int, int]], after: int | None, sound: set[int]) -> str:
    """The problem of records without env_steps (`bare_metric_records`: (line, cycle) each) and its fix: none past
    `after`, the cycle resume continues from (None: it refuses), where resume sets them aside with the later
    records; else put the file back, or train those cycles again."""
    count, cycles = len(bare), [cycle for _, cycle in bare]
    said = (f"{METRICS_FILE} {agreeing(count, 'line')} {', '.join(str(line) for line, _ in bare[:10])} "
            f"{agreeing(count, 'holds', 'hold')} {agreeing(count, 'cycle')} {', '.join(map(str, cycles[:10]))} "
            f"without {agreeing(count, 'its', 'their')} env_steps, which every record the trainer writes carries: "
            "the file was edited, or another program wrote to it")
    if after is not None and min(cycles) > after:
        return (f"{said}; resume continues from cycle {after} and moves {agreeing(count, 'it', 'them')} to a side "
                "file with the later records")
    return (f"{said}; resume would keep {agreeing(count, 'it', 'them')}, {agreeing(count, 'a cycle', 'cycles')} "
            f"without a point on the curves: put the file back from a copy if there is one, or "
            f"{_log_again(run_dir, min(cycles), sound)}")


def _relog(run_dir: Path, cycles: list[int], sound: set[int]) -> str:
    """How to log every cycle again where records were lost (cycles missing, each logged once and in order): train
    again from the newest intact checkpoint before the first missing cycle; "" when the records are otherwise out of
    order (two writers), which no resume mends."""
    if len(set(cycles)) != len(cycles) or cycles != sorted(cycles):
        return ""
    missing = next(cycle for cycle in range(1, cycles[-1] + 1) if cycle not in set(cycles))
    return f"; {_log_again(run_dir, missing, sound)}"


def _log_again(run_dir: Path, cycle: int, sound: set[int]) -> str:
    """How to log `cycle` and those after it again: train again from the newest intact checkpoint before it."""
    before = [saved for saved in sound if saved < cycle]
    if not before:
        return f"`angora-jax resume {run_dir} --from-scratch` trains it again with each cycle logged"
    return (f"`angora-jax resume {run_dir} --from {max(before)}` trains again from the checkpoint before cycle "
            f"{cycle}, so that each cycle is logged (the later records and checkpoints are kept aside)")


def _ended(run_dir: Path, config: Config, cycle: int | None) -> str:
    """Why a run that resume would continue from `cycle` trains no further, and how to go on; "" when it would."""
    if cycle is None:
        return ""
    if cycle >= config.ppo.num_cycles:
        return (f"; the run is complete ({cycle} of {counted(config.ppo.num_cycles, 'cycle')}): `angora-jax resume "
                f"{run_dir} --num-cycles N` trains it longer")
    ended = ended_by_stop_at(run_dir, config.ppo.stop_at, cycle)
    if ended is not None:
        return (f"; ppo.stop_at ended it ({ended}): resume leaves it as it is; `angora-jax resume {run_dir} "
                "--no-stop-at` trains on past it")
    return ""


def restore_config(run_dir: str | Path) -> str:
    """Write `run_dir`'s config.yaml (and hyperparameters.json) again from the config saved with its newest intact
    checkpoint, when config.yaml is missing or does not load; the file as it was is kept beside it
    (`config.yaml.damaged`, then `config.yaml-2.damaged`, ...). Holds the run's writer lock meanwhile. Returns what
    was done; RunDirError when no checkpoint keeps a loadable copy, RunLockedError while another process trains the
    run."""
    run_dir = Path(run_dir)
    path = run_dir / CONFIG_FILE
    if path.is_file():
        try:
            config = read_run_config(run_dir)
        except RunDirError:
            pass
        else:
            return _undo_edit(run_dir, config)
    checkpoints_dir = run_dir / CHECKPOINTS
    if not has_checkpoints(run_dir):
        raise RunDirError(f"{run_dir} has no checkpoint that keeps a copy of its config: restore {path} from a copy "
                          "of your own.")
    lock = RunLock(run_dir)
    lock.acquire()
    try:
        checkpoints = Checkpoints(checkpoints_dir, CheckpointConfig(), create=False)
        try:
            saved = checkpoints.saved_config()
        finally:
            checkpoints.close()
        if saved is None:
            raise RunDirError(f"No intact checkpoint of {run_dir} keeps a copy of its config: restore {path} from a "
                              "copy of your own.")
        kind, cycle, data = saved
        try:
            config = load_config(data)
        except ConfigError as error:
            raise RunDirError(f"The config saved with the {kind} checkpoint of cycle {cycle} does not load with this "
                              f"version of angora_jax either: {error}") from None
        kept = ""
        if path.exists():
            aside = next(name for name in numbered_paths(run_dir, CONFIG_FILE, ".damaged") if not name.exists())
            path.rename(aside)
            kept = f"; the file as it was is kept as {aside}"
        write_run_config(run_dir, config)
    finally:
        lock.release()
    return f"Restored {path} from the config saved with the {kind} checkpoint of cycle {cycle}{kept}."


def _undo_edit(run_dir: Path, config: Config) -> str:
    """Put back the task and learning settings of a config.yaml that loads but was edited after training (keeping
    its other settings, and the file as it was beside it); what was done."""
    path = run_dir / CONFIG_FILE
    lock = RunLock(run_dir)
    lock.acquire()
    try:
        edited = edited_settings(run_dir, config)
        if edited is None:
            return f"{path} loads and holds the settings the run was trained with; nothing was restored."
        saved = edited.saved
        restored = replace(config, env=saved.env, ppo=replace(saved.ppo, num_cycles=config.ppo.num_cycles,
                                                              stop_at=config.ppo.stop_at))
        aside = next(name for name in numbered_paths(run_dir, CONFIG_FILE, ".edited") if not name.exists())
        path.rename(aside)
        write_run_config(run_dir, restored)
    finally:
        lock.release()
    return (f"Put back in {path} the settings saved with the {edited.kind} checkpoint of cycle {edited.cycle} "
            f"({'; '.join(edited.changes)}); the edited file is kept as {aside}.")
