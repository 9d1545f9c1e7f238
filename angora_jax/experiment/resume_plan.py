"""What `resume` does with a run directory, decided before anything is changed: `resume` carries the plan out, and
`angora-jax check` prints it.

A resume never starts over by itself: a run that logged cycles but has no loadable latest checkpoint is refused with
the choices (`--from best` or a cycle, `--from-scratch`), and whatever a choice replaces is moved aside, never deleted.
"""

from __future__ import annotations

import re
import shutil
from dataclasses import dataclass
from pathlib import Path

from angora_jax.experiment.checkpoint import KINDS, Checkpoints, describe_saved
from angora_jax.experiment.config import Config
from angora_jax.experiment.manifest import verify
from angora_jax.experiment.monitor import logged_cycles
from angora_jax.experiment.run_dir import (
    CHECKPOINTS,
    CONFIG_FILE,
    EVALUATIONS,
    HYPERPARAMETERS_FILE,
    METRICS_FILE,
    VIDEOS,
    RunDirError,
    numbered_paths,
)
from angora_jax.wording import counted

# What a fresh start moves aside (into RUN_DIR/previous-N/): everything the earlier training wrote but its config and
# the session log, which goes on, and what was made from its checkpoints (evaluations, `analyze ablate`'s default
# files): left beside the new run's, they would read as its own. Checkpoints first: a start over killed halfway then
# leaves records without checkpoints, which resume refuses, rather than checkpoints without the records before them.
TRAINING_OUTPUTS = (CHECKPOINTS, METRICS_FILE, "tensorboard", VIDEOS, "report", "wandb", EVALUATIONS)
# Files beside those: the records earlier resumes set aside, and `analyze ablate`'s default files.
SIDE_FILES = ("metrics.after-cycle-*.jsonl", "ablation*.png", "ablation*.nc")
# The cycle in the name of an evaluation (`best-cycle26-mode-seed0.json`) and of a training video (`cycle_000026.gif`).
EVALUATION_CYCLE, VIDEO_CYCLE = re.compile(r"-cycle(\d+)-"), re.compile(r"cycle_(\d+)")


@dataclass(frozen=True)
class ResumePlan:
    """How `resume` continues a run, decided before anything is moved or loaded.

    Attributes:
        kind: the kind of the checkpoint to continue from (None: train from cycle 0).
        cycle: the cycle of that checkpoint (None: train from cycle 0).
        fresh_start: the earlier outputs move aside first (`--from-scratch`).
        describe: the plan in words.
    """

    kind: str | None
    cycle: int | None
    fresh_start: bool
    describe: str


def plan_resume(run_dir: Path, config: Config, start_from: str | int = "latest", from_scratch: bool = False,
                checkpoints: Checkpoints | None = None) -> ResumePlan:
    """Decide where `resume` continues `run_dir` from; raise RunDirError (CheckpointError for a damaged checkpoint)
    naming what is missing and the choices when it cannot continue as asked. Reads only. `checkpoints`: the run's,
    opened by the caller to restore from next (each checkpoint's files are then verified once, gigabytes for the
    cube); None opens and closes them here."""
    if from_scratch:
        if start_from != "latest":
            raise RunDirError("--from-scratch trains again from cycle 0: it cannot be combined with --from (in Python: "
                              "from_scratch=True without start_from).")
        return ResumePlan(None, None, True, f"train again from cycle 0; the earlier {', '.join(TRAINING_OUTPUTS)} "
                                            f"move to {run_dir}/previous-N/")
    logged = logged_cycles(run_dir)
    own = checkpoints is None
    if own:
        checkpoints = Checkpoints(run_dir / CHECKPOINTS, config.checkpoint, create=False)
    try:
        if start_from == "latest":
            latest = checkpoints.steps("latest")
            if latest:
                checkpoints.check_intact("latest", latest[-1])
                return ResumePlan("latest", latest[-1], False,
                                  f"continue from the latest checkpoint, cycle {latest[-1]}")
            saved = {kind: checkpoints.steps(kind) for kind in KINDS if checkpoints.steps(kind)}
            if logged or saved:
                older = checkpoints.newest_intact()
                choice = (f"`--from {older[1]}` continues from the newest intact checkpoint ({older[0]}, cycle "
                          f"{older[1]}), or " if older else "")
                python = " or ".join(([f"aj.resume({str(run_dir)!r}, start_from={older[1]})"] if older else []) +
                                     [f"aj.resume({str(run_dir)!r}, from_scratch=True)"])
                raise RunDirError(
                    f"{run_dir} has no latest checkpoint to resume from (checkpoints/latest is empty or missing), "
                    f"but it logged {counted(len(logged), 'cycle')} (up to cycle {max(logged, default=0)}) in "
                    f"{METRICS_FILE}"
                    f"{f' and keeps checkpoints ({describe_saved(saved)})' if saved else ''}. Resuming now would start "
                    "over and lose that curve, "
                    f"so nothing was changed. Choose: {choice}`--from-scratch` trains again from cycle 0 with the "
                    f"earlier files moved to {run_dir}/previous-N/ (in Python: {python}). `angora-jax check {run_dir}` "
                    "shows what the run holds.")
            return ResumePlan(None, None, False, "train from cycle 0: nothing was logged or saved before it stopped")
        try:
            kind, cycle = checkpoints.locate(start_from)
        except FileNotFoundError as error:
            raise RunDirError(f"--from {start_from} (in Python start_from={start_from!r}): {error}") from None
        checkpoints.check_intact(kind, cycle)
        later = [c for c in logged if c > cycle]
        return ResumePlan(kind, cycle, False,
                          f"continue from the {kind} checkpoint of cycle {cycle}" +
                          (f"; the {counted(len(later), 'cycle')} logged after it, and later checkpoints with their "
                           "evaluations and videos, are set aside" if later else ""))
    finally:
        if own:
            checkpoints.close()


def set_aside_checkpoints_after(run_dir: Path, cycle: int) -> Path | None:
    """Move the checkpoints of cycles after `cycle` (a resume from an earlier checkpoint recomputes those cycles), and
    damaged latest ones (the next resume would read them), into `RUN_DIR/set-aside/resumed-from-cycle-<cycle>[-n]/`,
    with the evaluations and training videos of those later cycles (the cycles trained again are other policies of
    the same numbers); returns that folder, or None when there was nothing to move. Only latest checkpoints are
    verified: checksumming every snapshot on each resume would cost time and change nothing."""
    later = [path for kind in KINDS for path in (run_dir / CHECKPOINTS / kind).glob("*")
             if path.name.isdigit() and (int(path.name) > cycle or (
                 kind == "latest" and verify(path) not in (None, "no manifest")))]
    later += [path for folder, pattern in ((EVALUATIONS, EVALUATION_CYCLE), (VIDEOS, VIDEO_CYCLE))
              for path in sorted((run_dir / folder).glob("*"))
              if (found := pattern.search(path.name)) and int(found.group(1)) > cycle]
    if not later:
        return None
    target = next(path for path in numbered_paths(run_dir / "set-aside", f"resumed-from-cycle-{cycle}", "")
                  if not path.exists())
    for path in later:
        destination = target / path.relative_to(run_dir)
        destination.parent.mkdir(parents=True, exist_ok=True)
        shutil.move(path, destination)
    return target


def set_aside_outputs(run_dir: Path) -> Path:
    """Move the run's training outputs (`TRAINING_OUTPUTS`) into a new `RUN_DIR/previous-N/` with a copy of its
    config, so that the earlier training stays a run of its own (`evaluate`, `report`, `check` read it), and return
    it."""
    target = next(path for path in (run_dir / f"previous-{n}" for n in range(1, 10_000)) if not path.exists())
    target.mkdir()
    for name in (CONFIG_FILE, HYPERPARAMETERS_FILE):
        if (run_dir / name).is_file():
            shutil.copy2(run_dir / name, target / name)
    for name in TRAINING_OUTPUTS:
        if (run_dir / name).exists():
            shutil.move(run_dir / name, target / name)
    for side in [path for pattern in SIDE_FILES for path in run_dir.glob(pattern)]:
        shutil.move(side, target / side.name)
    return target
