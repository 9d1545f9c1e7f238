"""Checkpoints of a run with Orbax: the latest state, the best state by a training metric, and kept snapshots.

Each checkpoint holds the whole `TrainState` (params, optimizer state, normaliser statistics, environment states,
recurrent carries, PRNG keys, cycle counter) plus JSON metadata (cycle, env steps, the cycle's metrics, the resolved
config and whether it holds the environments), so that a resumed run continues bit-for-bit; the kinds named in
`checkpoint.lean` leave the environments' part out (`TrainState.without_environments`).
Layout: `checkpoints/{latest,best,snapshots}/<cycle>/`. Each checkpoint's folder ends with a manifest (`manifest`):
loading checks it first, so a damaged file is named before Orbax reads it.
Each leaf is stored under its own path (`to_storable`), so a sub-tree (e.g. only params and normaliser statistics for
acting) can be read without the rest (`Checkpoints.restore(..., partial=True)`): the environment states' layout may
have changed since saving.
"""

from __future__ import annotations

import contextlib
import errno
import gc
import logging
import math
import numbers
import os
import shutil
import sys
import time
import warnings
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import orbax.checkpoint as ocp

from angora_jax.experiment.config import CHECKPOINT_KINDS as KINDS
from angora_jax.experiment.config import CheckpointConfig
from angora_jax.experiment.distributed import LOST_PEER, is_main_process
from angora_jax.experiment.manifest import MANIFEST_FILE, verify, write_manifest
from angora_jax.experiment.run_dir import NO_ROOM, DiskFullError, RunDirError, is_disk_full, no_room
from angora_jax.ppo.episode_pool import Pool, compared_value


def to_storable(state: Any) -> dict[str, jax.Array]:
    """The state as a flat dict that Orbax can write: keyed by the leaf's path (`params.Dense_0.kernel`), typed PRNG
    keys (`jax.random.key`) as their raw uint32 data, and empty arrays (modalities a task lacks) left out."""
    leaves = jax.tree_util.tree_flatten_with_path(state)[0]
    return {_path(path): jax.random.key_data(x) if _is_key(x) else x for path, x in leaves if x.size}


def from_storable(template: Any, stored: dict[str, jax.Array]) -> Any:
    """Inverse of `to_storable`: the tree of `template` (arrays or `jax.ShapeDtypeStruct`s) filled from `stored`,
    with keys wrapped back into typed keys and empty arrays recreated."""

    def fill(path, t):
        if not t.size:
            return jnp.zeros(t.shape, t.dtype)
        x = stored[_path(path)]
        return jax.random.wrap_key_data(x) if _is_key(t) else x

    return jax.tree_util.tree_map_with_path(fill, template)


def _path(path: tuple) -> str:
    return ".".join(str(getattr(entry, "name", getattr(entry, "key", getattr(entry, "idx", entry)))) for entry in path)


def _is_key(x: Any) -> bool:
    return jax.dtypes.issubdtype(x.dtype, jax.dtypes.prng_key)


class CheckpointError(RunDirError):
    """A checkpoint that exists but cannot be read (corrupt, incomplete or from an incompatible version); `misfits`
    lists the leaves that differ from what was asked for, when that is the cause."""

    def __init__(self, message: str, misfits: str | None = None):
        super().__init__(message)
        self.misfits = misfits


@dataclass(frozen=True)
class Restored:
    """A state read back from a checkpoint (shaped like the template it was restored into) and its metadata (cycle,
    env_steps, metrics, config)."""

    state: Any
    meta: dict[str, Any]


# Reads of a checkpoint that a training process replaced meanwhile, before giving up (`Checkpoints._read_newest`).
_REPLACED_RETRIES = 5


def _manager(directory: Path, kind: str, create: bool) -> ocp.CheckpointManager:
    """Orbax's manager of one kind's checkpoints. Opening one lists its steps and reads each one's time: a reader of a
    run being trained meets a step that the writer removes meanwhile, and lists them again."""
    for attempt in range(_REPLACED_RETRIES):
        try:
            return ocp.CheckpointManager(
                directory,
                options=ocp.CheckpointManagerOptions(
                    max_to_keep={"latest": 1, "best": 1}.get(kind), create=create, enable_async_checkpointing=create,
                    # A writer killed mid-save leaves Orbax's unfinished folder (never a checkpoint): the next writer
                    # removes it before anything else, instead of Orbax warning when it saves that cycle again.
                    cleanup_tmp_directories=create,
                    # The kinds' background writes run at once; across processes each needs barriers of its own.
                    multiprocessing_options=ocp.options.MultiprocessingOptions(barrier_sync_key_prefix=kind),
                ),
                # Handlers named up front: the stored shapes can be read (item_metadata) before anything is restored.
                item_handlers={"state": ocp.PyTreeCheckpointHandler(), "meta": ocp.JsonCheckpointHandler()},
            )
        except FileNotFoundError:
            if create or attempt == _REPLACED_RETRIES - 1:
                raise
            time.sleep(0.05)
    raise AssertionError("unreachable")


def refuse_files_in_place(directory: Path) -> None:
    """CheckpointError when a file stands where the run's checkpoints folder `directory` keeps a kind's folder: a
    writer's Orbax managers fail on it with a traceback from a background thread."""
    for kind in KINDS:
        if (Path(directory) / kind).exists() and not (Path(directory) / kind).is_dir():
            raise CheckpointError(
                f"{Path(directory) / kind} is a file, where the run keeps its {kind} checkpoints in a folder of that "
                "name: nothing was changed. Move the file away (it is not a checkpoint; a copy of the run's folder "
                "from a backup restores the checkpoints it replaced).")


def checkpoint_name(which: Any) -> Any:
    """`which` as checkpoints are named: "latest" and "best" as they are, a cycle as an int also when it comes as
    digits ("2", as typed) or as a numpy integer (a cycle read from an array, e.g. of `read_metrics`); TypeError for
    anything else (True read as cycle 1, in a folder named "True"; 2.0 as no checkpoint)."""
    if isinstance(which, str):
        return int(which) if which.isdigit() else which
    if isinstance(which, bool) or not isinstance(which, numbers.Integral):
        raise TypeError(f"A checkpoint is 'best', 'latest' or a cycle (a whole number, e.g. 2), got {which!r} "
                        f"({type(which).__name__}).")
    return int(which)


def cycles_to_offer(cycles: list[int], asked: object) -> str:
    """The saved cycles an error names instead of a missing one: the 8 nearest to a cycle asked for (a run keeping
    hundreds of snapshots answered a request for cycle 50 with its last 8, as if nothing earlier were kept), else
    the latest 8."""
    if isinstance(asked, int) and not isinstance(asked, bool):
        near = sorted(sorted(cycles, key=lambda cycle: (abs(cycle - asked), cycle))[:8])
        return f"a cycle near {asked} ({', '.join(map(str, near))})"
    return f"a cycle ({', '.join(map(str, cycles[-8:]))})"


def describe_saved(saved: Mapping[str, list[int]]) -> str:
    """`{"latest": [6], "snapshots": [3, 6, 9]}` in words: "latest of cycle 6; snapshots of cycles 3-9 every 3"."""
    return "; ".join(f"{kind} of cycle{'s' if len(cycles) > 1 else ''} {cycle_ranges(sorted(cycles), every=True)}"
                     for kind, cycles in saved.items() if cycles)


def cycle_ranges(cycles: list[int], every: bool = False) -> str:
    """Cycles as ranges in order, e.g. "1-5, 3-8" (two in a row as "3, 4"), at most eight; every: a range may step by
    the first difference (snapshots: "20-380 every 20")."""
    step = cycles[1] - cycles[0] if every and len(cycles) > 1 and cycles[1] > cycles[0] else 1
    spans, start = [], 0
    for i in range(1, len(cycles) + 1):
        if i == len(cycles) or cycles[i] != cycles[i - 1] + step:
            first, last = cycles[start], cycles[i - 1]
            spans.append(str(first) if first == last else f"{first}, {last}" if i - start == 2 else
                         f"{first}-{last}" + (f" every {step}" if step > 1 else ""))
            start = i
    return ", ".join(spans[:8]) + (", ..." if len(spans) > 8 else "")


class Checkpoints:
    """The checkpoints of one run directory: decides what to save after a cycle, and restores.

    Saves are written in the background while the next cycle runs: `save` returns once Orbax has copied the state to
    host memory, and the files are written behind it (on one H200 the 32-step fast cube spent 11% of its wall time in
    synchronous saves: benchmarks/results/cube_one_gpu/README.md). The next `save`, a `final` one, a restore and
    `close` wait for what is still being written, write its manifest and raise its errors (a full disk) there, so a
    checkpoint is complete on disk when the run stops, and a process killed mid-write leaves the checkpoint before it
    intact (Orbax removes an old checkpoint only once the new one is whole). The best state is copied in the cycle
    that reaches it, although while a policy improves that is nearly every cycle: holding the best cycle's device
    arrays until a later save made XLA place each cycle's buffers at new addresses, MuJoCo Warp captured a CUDA graph
    for each new set, and 4 processes of one H100 each ran out of GPU memory inside Warp after 58 and 108 cycles of
    the fast cube (benchmarks/results/cube_multi_gpu/ihom_4gpu_warp_graphs_4xh100.md); the copy to host frees them.
    """

    def __init__(self, directory: Path, config: CheckpointConfig, create: bool = True,
                 verified: Mapping[tuple[str, int], str | None] | None = None):
        """directory: the run's checkpoints folder; create=False to only read an existing run's checkpoints;
        verified: what another reader of this folder found of its checkpoints (`Checkpoints.verified`), while this
        process held the run's lock, so that they are not hashed again."""
        self.config = config
        self._directory = Path(directory).resolve()
        if create:
            refuse_files_in_place(self._directory)
        else:  # a reader of a run being trained meets checkpoints mid-removal; `_read_newest` handles them
            logging.getLogger("absl").addFilter(_mid_removal)
        # Orbax logs an ERROR with the file's content when a checkpoint's metadata does not parse; the manifest's
        # check names that damage and its fix in one message.
        logging.getLogger("absl").addFilter(_damaged_metadata)
        # Read before the managers below remove them, so that the writer can say what it removed.
        self.removed_unfinished = {kind: cycles for kind in KINDS if create and (cycles := self.unfinished(kind))}
        self._managers = {kind: _manager(self._directory / kind, kind, create) for kind in KINDS}
        # Each checkpoint's verification (checksums of all its files, gigabytes for the cube) is done once per object:
        # resuming asks about the same checkpoint when planning, locating, reading its metadata and restoring it.
        self._damage: dict[tuple[str, int], str | None] = dict(verified or {})
        self._writing: list[tuple[str, int]] = []  # saves returned but still being written, in the order started
        self._failed = False  # a save failed and `finish` said so
        self._quiet: _QuietWriters | None = None  # while they are written
        # A writer compares each cycle with the best so far; a reader never does, and reading it means verifying it.
        best = self._managers["best"].latest_step() if create else None
        try:
            meta = None if best is None else self._read_meta("best", best)
            # Checkpoints saved before best_episodes recorded the cycle's own value.
            self.best_value = None if meta is None else meta.get("best_value", meta["metrics"].get(config.best_metric))
        except CheckpointError:  # a damaged best checkpoint: the next improvement saves a new one
            self.best_value = None
        self._recent: Pool = []  # the cycles that the best metric's next value pools

    def continue_from(self, cycle: int) -> None:
        """Take up the best metric's pool of recent episodes as it was after `cycle`, from a checkpoint of that cycle
        (a run resumed from it then picks its best as if it had not stopped)."""
        for kind in KINDS:
            if cycle in self._managers[kind].all_steps():
                try:
                    self._recent = [list(entry) for entry in self._read_meta(kind, cycle).get("best_pool", [])]
                    return
                except CheckpointError:  # a damaged copy of that cycle: another kind may hold it whole
                    continue

    def steps(self, kind: str) -> list[int]:
        """Cycles at which checkpoints of `kind` ("latest", "best", "snapshots") exist, ascending."""
        return sorted(self._managers[kind].all_steps())

    def unfinished(self, kind: str) -> list[int]:
        """Cycles of `kind` whose save was cut short (its writer killed mid-write), ascending: never checkpoints, and
        removed when a writer opens the run."""
        return sorted({int(path.name.partition(".")[0]) for path in self._temporary(kind)})

    def _temporary(self, kind: str, cycle: int | None = None) -> list[Path]:
        """Orbax's folders of saves not yet whole (`<cycle>.orbax-checkpoint-tmp*`, renamed to the cycle once whole)
        of `kind`, of one cycle or of all."""
        return [path for path in (self._directory / kind).glob(f"{'*' if cycle is None else cycle}.*")
                if path.name.partition(".")[0].isdigit()]

    def save(
        self, state: Any, metrics: dict[str, float], config: dict[str, Any], final: bool = False
    ) -> list[str]:
        """Save what is due after this cycle (latest every `every` cycles or when `final`; best when the metric
        improved; a snapshot every `snapshot_every` cycles) and return the kinds saved. The files are written in the
        background, except after a `final` save, which returns once everything is on disk; the saves of the cycle
        before are finished first, and a full disk met by either raises DiskFullError here."""
        self.finish()
        cycle = int(state.cycle)
        value = self._best_candidate(metrics)
        meta = {"cycle": cycle, "env_steps": metrics.get("env_steps"), "metrics": _finite(metrics), "config": config,
                "best_value": value if math.isfinite(value) else None, "best_pool": [list(e) for e in self._recent]}
        due = {
            "latest": final or cycle % self.config.every == 0,
            "best": self.config.best_metric is not None and improves(value, self.best_value, self.config.best_mode),
            "snapshots": self.config.snapshot_every > 0 and cycle % self.config.snapshot_every == 0,
        }
        saved = []
        for kind, is_due in due.items():
            # A resumed run recomputes the cycles after its checkpoint exactly; those already saved stay as they are.
            if is_due and cycle not in self._managers[kind].all_steps():
                lean = kind in self.config.lean
                storable = to_storable(state.without_environments() if lean else state)
                self._quiet = self._quiet or _QuietWriters()
                try:
                    self._managers[kind].save(cycle, args=ocp.args.Composite(
                        state=ocp.args.PyTreeSave(storable), meta=ocp.args.JsonSave(meta | {"environments": not lean})))
                except Exception as error:
                    self._finish(failed=[(kind, cycle, error)])  # raises it, once the saves begun before are done
                self._writing.append((kind, cycle))
                saved.append(kind)
        if "best" in saved:
            self.best_value = value
        if final:
            self.finish()
        return saved

    def finish(self) -> None:
        """Wait until the saves still being written are on disk, then write their manifests; DiskFullError (the
        failed saves' leftovers removed, the checkpoints before them intact) if the disk filled meanwhile."""
        self._finish(failed=[])

    def _finish(self, failed: list[tuple[str, int, BaseException]]) -> None:
        """`finish`, with the saves that already failed when started (`failed`: kind, cycle, error)."""
        writing, self._writing = self._writing, []
        manifests_failed = []
        try:
            for kind, cycle in writing:
                try:
                    self._managers[kind].wait_until_finished()
                except Exception as error:
                    failed.append((kind, cycle, error))
            unsaved = {(kind, cycle) for kind, cycle, _ in failed}
            for kind, cycle in writing:
                if (kind, cycle) in unsaved or not is_main_process():  # Orbax's save waited for every process
                    continue
                try:
                    write_manifest(self._directory / kind / str(cycle))
                except OSError as error:
                    manifests_failed.append((kind, cycle, error))
            errors = [error for *_, error in failed + manifests_failed]
            other = next((error for error in errors if not is_disk_full(error)), None)
            if other is not None:
                raise other
            if errors:
                raise self._disk_full([(kind, cycle) for kind, cycle, _ in failed],
                                      [(kind, cycle) for kind, cycle, _ in manifests_failed], errors[0]) from None
        except BaseException as error:
            self._failed = True
            if self._quiet is not None:
                self._quiet.stop(disk_full=is_disk_full(error) or isinstance(error, DiskFullError))
                self._quiet = None
            raise
        if self._quiet is not None:
            self._quiet.stop(disk_full=False)
            self._quiet = None

    def _disk_full(self, unsaved: list[tuple[str, int]], unlisted: list[tuple[str, int]],
                   error: BaseException) -> DiskFullError:
        """Remove what the failed saves left (Orbax's temporary folders of `unsaved`; the manifests' drafts of
        `unlisted`, saved but without their manifest) and say what is intact."""
        for kind, cycle in unlisted:
            (self._directory / kind / str(cycle) / f"{MANIFEST_FILE}.tmp").unlink(missing_ok=True)
        for kind, cycle in unsaved:
            for leftover in self._temporary(kind, cycle):
                shutil.rmtree(leftover, ignore_errors=True)
            self._managers[kind].reload()
        kept = {k: self.steps(k) for k in KINDS if self.steps(k)}
        free = shutil.disk_usage(self._directory).free
        what = "; ".join(
            [f"the {kind} checkpoint of cycle {cycle} could not be saved" for kind, cycle in unsaved]
            + [f"the {kind} checkpoint of cycle {cycle} was saved, but not its manifest (it reads as unverifiable)"
               for kind, cycle in unlisted])
        run_dir = self._directory.parent
        happened, fix = no_room(error) or NO_ROOM[errno.ENOSPC][1:]
        then = (f"The checkpoints saved before are intact ({describe_saved(kept)}). {fix[0].upper()}{fix[1:]}, then "
                f"continue with `angora-jax resume {run_dir}`" if kept else
                f"No checkpoint was saved before, so the run cannot continue: {fix}, then train it again with "
                f"`angora-jax resume {run_dir} --from-scratch` (the cycles logged so far are kept aside)")
        return DiskFullError(
            f"{happened}: {what} in {self._directory} ({free / 2**20:.1f} MiB free; {type(error).__name__}). "
            f"{then}.")

    def restore(self, template: Any, which: str | int = "latest", partial: bool = False) -> Restored:
        """Read a state shaped like `template` (a TrainState, any tree of arrays, or its `jax.eval_shape`).

        Args:
            template: the tree whose leaves are read, with their shapes and dtypes.
            which: "latest", "best", or a cycle number (found among latest, best and snapshots).
            partial: read only the leaves `template` has (e.g. params and normaliser statistics, stored under the same
                paths as in the TrainState) and ignore the others, whatever their shapes; otherwise the checkpoint must
                hold exactly `template`'s leaves.

        Raises:
            FileNotFoundError: there is no such checkpoint (the message lists what exists).
            CheckpointError: it cannot be read, or a leaf read differs in shape or dtype from `template`'s.
        """
        self.finish()  # a checkpoint this object is still writing is read once whole
        return self._read_newest(which, lambda kind, cycle: self._restore(template, kind, cycle, partial))

    def _restore(self, template: Any, kind: str, cycle: int, partial: bool) -> Restored:
        # Whole arrays onto this process's first device, whatever devices saved them (several devices or hosts):
        # training lays the state out again for the devices it runs on.
        device = jax.sharding.SingleDeviceSharding(jax.local_devices()[0])
        abstract = jax.tree.map(
            lambda x: jax.ShapeDtypeStruct(x.shape, x.dtype, sharding=device), jax.eval_shape(to_storable, template)
        )
        manager = self._managers[kind]
        self.check_intact(kind, cycle)
        failure = None
        try:
            stored = manager.item_metadata(cycle)["state"].tree
            _check_fits(self._directory / kind / str(cycle), stored, abstract, partial)
        except CheckpointError:
            raise
        except Exception as error:  # Orbax and TensorStore raise many types for unreadable files; all mean the same
            failure = _briefly(error)
            _drop_failed_read_reports()
        else:
            restored, failure = _read_quietly(manager, cycle, ocp.args.Composite(
                state=ocp.args.PyTreeRestore(
                    abstract, ocp.checkpoint_utils.construct_restore_args(abstract), partial_restore=partial
                ),
                meta=ocp.args.JsonRestore(),
            ))
        if failure is not None:
            existing = {k: self.steps(k) for k in KINDS}
            raise CheckpointError(
                f"Checkpoint {self._directory / kind / str(cycle)} cannot be read ({failure}). It is corrupt, "
                f"incomplete or from an incompatible version of angora_jax. Use another one (saved: "
                f"{describe_saved(existing)}; pass its cycle to --checkpoint, or to resume's --from), or delete "
                "this one."
            )
        return Restored(from_storable(template, restored["state"]), dict(restored["meta"]))

    def unreadable(self, kind: str, cycle: int) -> str | None:
        """Why checkpoint `kind`/`cycle` cannot be read whole (every array read as it was saved, without a template),
        None when it can: the check left for one without a manifest to verify it by."""
        return _read_quietly(self._managers[kind], cycle, ocp.args.Composite(
            state=ocp.args.PyTreeRestore(), meta=ocp.args.JsonRestore()))[1]

    def holds_environments(self, which: str | int = "latest") -> bool:
        """Whether checkpoint `which` holds the environments' states (not `checkpoint.lean`), so that resuming from
        it continues exactly; FileNotFoundError as `restore` when there is no such checkpoint."""
        return self._read_newest(which, self._read_meta).get("environments", True)

    def _read_newest(self, which: str | int, read: Callable[[str, int], Any]) -> Any:
        """`read(kind, cycle)` of checkpoint `which`. A process training the run replaces its latest and best
        checkpoints (one of each is kept) while others read them; a read that fails because its checkpoint was
        replaced meanwhile reads the one that replaced it ("latest", "best"), or says what happened (a cycle)."""
        which = checkpoint_name(which)
        for attempt in range(_REPLACED_RETRIES):
            kind, cycle = self.locate(which)
            try:
                return read(kind, cycle)
            except (CheckpointError, FileNotFoundError):  # Orbax lists a step's files, then finds one gone
                newer = self._replaced(kind, cycle)
                if newer is None:
                    raise
                if not isinstance(which, str) or attempt == _REPLACED_RETRIES - 1:
                    raise CheckpointError(
                        f"Checkpoint {self._directory / kind / str(cycle)} was removed while it was read: a process "
                        f"training the run replaced it with cycle {newer}, as it keeps only the newest {kind} "
                        f"checkpoint. Read {kind} again, or a snapshot (kept for good).") from None
        raise AssertionError("unreachable")

    def _replaced(self, kind: str, cycle: int) -> int | None:
        """The cycle of the checkpoint that replaced `kind`/`cycle` ("latest" or "best", which keep one) since this
        object listed them, else None."""
        if kind == "snapshots":  # kept for good: a failed read is the checkpoint's own
            return None
        for _ in range(_REPLACED_RETRIES):
            try:
                self._managers[kind].reload()
                break
            except FileNotFoundError:  # a step removed while Orbax listed the steps: list them again
                time.sleep(0.05)
        newer = max(self._managers[kind].all_steps(), default=None)
        return newer if newer is not None and newer > cycle else None

    def close(self) -> None:
        """Finish the saves being written (`finish`), then release Orbax's managers."""
        try:
            self.finish()
        finally:
            for manager in self._managers.values():
                try:
                    manager.close()
                except Exception:
                    # Orbax raises a failed background save's error again when its manager closes; `finish` has
                    # reported it (DiskFullError), and raising it here would replace that message with a bare one.
                    if not self._failed:
                        raise

    def locate(self, which: str | int) -> tuple[str, int]:
        """The kind and cycle of checkpoint `which` ("latest", "best" or a cycle: of the kinds that hold it, the first
        not found damaged); FileNotFoundError listing what exists when there is none."""
        which = checkpoint_name(which)
        if which in ("latest", "best"):
            step = self._managers[which].latest_step()
            if step is not None:
                return which, step
        elif isinstance(which, int):
            holding = [kind for kind in KINDS if which in self._managers[kind].all_steps()]
            # The first sound one, verified in turn: the others of that cycle need not be hashed.
            sound = next((kind for kind in holding if self.damage(kind, which) in (None, "no manifest")), None)
            if holding:
                return sound or holding[0], which
        existing = {kind: self.steps(kind) for kind in KINDS}
        if not any(existing.values()):
            raise FileNotFoundError(
                f"No checkpoints in {self._directory}: the run saved none yet (it saves one every checkpoint.every "
                "cycles and at its end), or they were deleted. `angora-jax check RUN_DIR` says which and what resume "
                "would do (with cycles logged and no checkpoint left: `resume --from-scratch`, in Python "
                "aj.resume(run_dir, from_scratch=True), trains it again and keeps the earlier files)."
            )
        saved = {kind: cycles for kind, cycles in existing.items() if cycles}
        kinds = [repr(kind) for kind in ("latest", "best") if kind in saved]
        cycles = sorted({cycle for found in saved.values() for cycle in found})
        choices = " or ".join([*kinds, cycles_to_offer(cycles, which)])
        raise FileNotFoundError(f"No checkpoint {which!r}. Saved: {describe_saved(saved)}; ask for {choices}.")

    def verified(self) -> dict[tuple[str, int], str | None]:
        """What this reader found of the checkpoints it verified: (kind, cycle) -> damage (None: intact)."""
        return dict(self._damage)

    def damage(self, kind: str, cycle: int) -> str | None:
        """What is wrong with checkpoint `kind`/`cycle` by its manifest (`manifest.verify`), None when intact; "no
        manifest" when it cannot be checked (saved before manifests were written)."""
        self.finish()  # its manifest is written once it is whole
        if (kind, cycle) not in self._damage:
            self._damage[kind, cycle] = verify(self._directory / kind / str(cycle))
        return self._damage[kind, cycle]

    def check_intact(self, kind: str, cycle: int) -> None:
        """Raise CheckpointError naming the damaged file and the newest intact checkpoint, unless the manifest of
        checkpoint `kind`/`cycle` holds (or it has none)."""
        problem = self.damage(kind, cycle)
        if problem in (None, "no manifest"):
            return
        intact = self.newest_intact(skip=(kind, cycle))
        named = intact and (intact[0] if intact[0] != kind and intact[0] in ("latest", "best") else intact[1])
        fallback = (f"The newest intact checkpoint is {intact[0]} of cycle {intact[1]}: read it with --checkpoint "
                    f"{named} (resume: --from {named}); in Python checkpoint={named!r} (resume: start_from={named!r})"
                    if intact else "No other intact checkpoint is left")
        raise CheckpointError(f"Checkpoint {self._directory / kind / str(cycle)} is damaged: {problem}. {fallback}; "
                              "or restore the folder from a copy. `angora-jax check RUN_DIR` lists every checkpoint.")

    def newest_intact(self, skip: tuple[str, int] | None = None) -> tuple[str, int] | None:
        """The kind and cycle of the newest checkpoint not found damaged (its manifest holds, or it has none to check;
        `skip` left out), or None. Newest first, stopping at the first intact one: verifying means hashing every file,
        and a run's older checkpoints (a full one of the cube is 301 MB) need not be read to name it."""
        for cycle, kind in self._newest_first():
            if (kind, cycle) != skip and self.damage(kind, cycle) in (None, "no manifest"):
                return kind, cycle
        return None

    def saved_config(self) -> tuple[str, int, dict[str, Any]] | None:
        """The run's config as saved with its newest intact checkpoint, as (kind, cycle, the config's dict), or None
        when no checkpoint keeps one."""
        for cycle, kind in self._newest_first():
            if self.damage(kind, cycle) not in (None, "no manifest"):
                continue
            try:
                config = self._read_meta(kind, cycle).get("config")
            except CheckpointError:  # unreadable without a manifest to say so, or removed by a live writer meanwhile
                continue
            return (kind, cycle, config) if isinstance(config, dict) and config else None
        return None

    def _newest_first(self) -> list[tuple[int, str]]:
        """Every saved (cycle, kind), newest first; of one cycle's, latest, best, snapshots: the one a caller most
        likely verified, and the one a user knows best."""
        return sorted(((cycle, kind) for kind in KINDS for cycle in self.steps(kind)),
                      key=lambda entry: (-entry[0], KINDS.index(entry[1])))

    def _read_meta(self, kind: str, cycle: int) -> dict[str, Any]:
        self.check_intact(kind, cycle)
        try:
            restored = self._managers[kind].restore(cycle, args=ocp.args.Composite(meta=ocp.args.JsonRestore()))
            return dict(restored["meta"])
        except Exception as error:  # as in `restore`: every unreadable file means the same to the user
            raise CheckpointError(
                f"Checkpoint {self._directory / kind / str(cycle)} cannot be read ({type(error).__name__}: {error}). "
                "It is corrupt or incomplete; `angora-jax check RUN_DIR` lists the intact checkpoints.") from error

    def _best_candidate(self, metrics: dict[str, float]) -> float:
        """This cycle's value of the best metric as `improves` compares it (`compared_value`; NaN without one)."""
        if self.config.best_metric is None:
            return math.nan
        value, self._recent = compared_value(self._recent, metrics, self.config.best_metric, self.config.best_episodes)
        return value


def improves(value: float, best: float | None, mode: str) -> bool:
    """Whether a cycle's `value` of the best metric makes a new best checkpoint against `best` (None: none yet) under
    `mode` ("max" or "min"): NaN never does (e.g. no episode finished in the cycle), nor does a tie."""
    if math.isnan(value):
        return False
    if best is None:
        return True
    return value > best if mode == "max" else value < best


# What Orbax's and TensorStore's writer threads print when a save fails, each thread for itself and some after the save
# has raised (their callbacks find the save's event loop closed): the failure, which the save raises once anyway.
# A process of a multi-process run killed mid-save: the others' writer threads time out at Orbax's commit barrier
# (their echo), and the process stops with the CLI's one message (distributed.lost_process_exit).
_ECHOES = (*(words for words, *_ in NO_ROOM.values()), "Event loop is closed", "RESOURCE_EXHAUSTED",
           "async_write_complete", *LOST_PEER)


def _mid_removal(record: logging.LogRecord) -> bool:
    return not record.getMessage().startswith("Metadata file does not exist")


def _damaged_metadata(record: logging.LogRecord) -> bool:
    return not record.getMessage().startswith(("Failed to json parse Metadata file", "Failed to read Metadata file"))


def _is_echo(text: str) -> bool:
    return any(echo in text for echo in _ECHOES)


def _chain(error: BaseException | None) -> str:
    """The reprs of an error and of those it was raised from or during."""
    seen = []
    while error is not None and error not in seen:
        seen.append(error)
        error = error.__cause__ or error.__context__
    return " ".join(map(repr, seen))


class _EchoFilter(logging.Filter):
    def filter(self, record: logging.LogRecord) -> bool:  # the message, or the error it was logged with
        return not _is_echo(record.getMessage() + (_chain(record.exc_info[1]) if record.exc_info else ""))


class _QuietWriters:
    """While saves are written: drop the writer threads' reports of their failure (asyncio's and absl's log records,
    and the tracebacks that callbacks print through sys.excepthook or sys.unraisablehook); the save's own error says
    it once. After a full disk they go on after the save, so the hooks then stay for the rest of the process."""

    def __init__(self) -> None:
        self._unraisable, self._excepthook = sys.unraisablehook, sys.excepthook
        self._echo = _EchoFilter()
        self._loggers = [logging.getLogger(name) for name in ("asyncio", "absl")]
        unraisable, excepthook = self._unraisable, self._excepthook

        def quiet_unraisable(report) -> None:
            if not _is_echo(f"{_chain(report.exc_value)} {report.err_msg}"):
                unraisable(report)

        def quiet_excepthook(kind, error, traceback) -> None:
            if not _is_echo(_chain(error)):
                excepthook(kind, error, traceback)

        sys.unraisablehook, sys.excepthook = quiet_unraisable, quiet_excepthook
        for logger in self._loggers:
            logger.addFilter(self._echo)

    def stop(self, disk_full: bool) -> None:
        if disk_full:  # and the writes it had scheduled are dropped unawaited
            warnings.filterwarnings("ignore", "coroutine .* was never awaited", RuntimeWarning)
            return
        sys.unraisablehook, sys.excepthook = self._unraisable, self._excepthook
        for logger in self._loggers:
            logger.removeFilter(self._echo)


def _briefly(error: BaseException) -> str:
    """An Orbax or TensorStore error in one line: its type and first sentence, without the TensorStore spec (dozens of
    lines) that some append."""
    text = str(error).split(" See full TensorStore details")[0].strip().splitlines()
    first = text[0].rstrip(". ") if text else ""
    return f"{type(error).__name__}: {first[:300]}"


@contextlib.contextmanager
def _silenced_while_reading() -> Iterator[None]:
    """Standard error (the file descriptor, for TensorStore's threads, and Python's stream) into /dev/null while a
    checkpoint is read: when a read fails, Orbax's and TensorStore's threads and left-over coroutines print a traceback
    per array (thousands of lines, "Event loop is closed") around the one message the user should get."""
    sys.stderr.flush()
    kept_fd, kept_stream, kept_hook = os.dup(2), sys.stderr, sys.unraisablehook
    sink = open(os.devnull, "w")  # noqa: SIM115 (closed below, after the descriptor is put back)
    os.dup2(sink.fileno(), 2)
    sys.stderr, sys.unraisablehook = sink, (lambda unraisable: None)
    try:
        yield
    finally:
        os.dup2(kept_fd, 2)
        os.close(kept_fd)
        sys.stderr, sys.unraisablehook = kept_stream, kept_hook
        sink.close()


def _read_quietly(manager: ocp.CheckpointManager, cycle: int, args: Any) -> tuple[Any, str | None]:
    """`manager.restore(cycle, args)` as (what it read, None), or (None, why it failed in one line, `_briefly`). A
    failed read's Orbax and TensorStore reports go nowhere: those printed while it fails into the sink of
    `_silenced_while_reading`, where its left-over coroutines are collected and its threads given a moment to finish;
    those still held, finalized when the process exits, are dropped by `_drop_failed_read_reports`."""
    with _silenced_while_reading():
        try:
            return manager.restore(cycle, args=args), None
        except Exception as error:  # Orbax and TensorStore raise many types for unreadable files; all mean the same
            failure = _briefly(error)
        gc.collect()
        time.sleep(0.2)
    _drop_failed_read_reports()
    return None, failure


def _drop_failed_read_reports() -> None:
    """From a failed read on, drop the "Exception ignored" reports of Orbax's array-reading coroutines that it left
    behind (and the warning that one was never awaited), and asyncio's "exception was never retrieved" for its
    reading tasks; every other report goes where it went. Installed once."""
    previous = sys.unraisablehook
    if getattr(previous, "drops_failed_reads", False):
        return

    def hook(unraisable: Any) -> None:
        # TensorStore's callbacks that find the failed read's event loop closed report it with no object.
        closed = isinstance(unraisable.exc_value, RuntimeError) and str(unraisable.exc_value) == "Event loop is closed"
        if "_read_array_index_and_device_put" not in repr(unraisable.object) and not closed:
            previous(unraisable)

    hook.drops_failed_reads = True
    sys.unraisablehook = hook
    warnings.filterwarnings("ignore", message="coroutine '_read_array_index_and_device_put' was never awaited")
    logging.getLogger("asyncio").addFilter(lambda record: not (
        "never retrieved" in record.getMessage() and "while reading array index" in record.getMessage()))


def disk_needed(config: CheckpointConfig, state: Any, cycles_left: int) -> int:
    """Bytes the checkpoints of `cycles_left` more cycles take at most, for a state shaped like `state` (arrays or
    `jax.ShapeDtypeStruct`s): latest and best twice each (a new one is written before the old one goes) and every
    snapshot due, each full or lean as `config.lean` says."""

    def size(kind: str) -> int:
        kept = state.without_environments() if kind in config.lean else state
        return sum(x.size * x.dtype.itemsize for x in jax.tree.leaves(kept))

    snapshots = cycles_left // config.snapshot_every if config.snapshot_every else 0
    best = 2 * size("best") if config.best_metric is not None else 0
    return 2 * size("latest") + best + snapshots * size("snapshots")


def misfits(stored: Mapping[str, Any], abstract: Mapping[str, Any], partial: bool = False) -> dict[str, str]:
    """Leaf name -> what is wrong, for the leaves of `abstract` (arrays or `jax.ShapeDtypeStruct`s by dotted path)
    that `stored` lacks or holds with another shape or dtype, and, unless `partial`, the stored leaves `abstract`
    lacks; empty when they fit."""
    differ = {
        name: f"stored {tuple(stored[name].shape)} {stored[name].dtype}, expected {tuple(x.shape)} {x.dtype}"
        for name, x in abstract.items()
        if name in stored and (tuple(stored[name].shape) != tuple(x.shape) or stored[name].dtype != x.dtype)
    }
    return {**differ, **{name: "not stored" for name in sorted(set(abstract) - set(stored))},
            **{name: "stored, not expected" for name in ([] if partial else sorted(set(stored) - set(abstract)))}}


def describe_misfits(found: Mapping[str, str]) -> str:
    """`misfits` in a message: the first five, and how many more."""
    problems = [f"{name}: {what}" for name, what in found.items()]
    return "; ".join(problems[:5]) + (f"; and {len(problems) - 5} more" if len(problems) > 5 else "")


def _check_fits(where: Path, stored: dict[str, Any], abstract: dict[str, jax.ShapeDtypeStruct], partial: bool) -> None:
    """Raise CheckpointError naming the leaves of `abstract` that the checkpoint lacks or stores with another shape or
    dtype (and, unless `partial`, the stored leaves `abstract` lacks), with the likely cause and its fix."""
    found = misfits(stored, abstract, partial)
    if not found:
        return
    listed = describe_misfits(found)
    if any(name.startswith(("params.", "obs_stats.")) for name in found):
        run_dir = where.parents[2]  # RUN_DIR/checkpoints/KIND/CYCLE
        cause = (
            "Its parameters or observation statistics do not fit the network and task of the config: the run's "
            "config.yaml (ppo.network, env) was changed after training. Restore the config the run was trained with: "
            f"`angora-jax check {run_dir} --restore-config` puts back the settings saved with its checkpoints (the "
            "edited file is kept beside it)"
        )
    else:
        cause = (
            "Its training state (environment states, optimizer, carries) does not fit the current task: the task's "
            "physics state layout or the config changed since it was saved. Evaluating and rendering still work "
            "(`load_agent` reads only parameters and statistics); to resume, use the angora_jax version and config "
            "it was saved with, or train again"
        )
    raise CheckpointError(f"Checkpoint {where} does not fit this run ({listed}). {cause}.", misfits=listed)


def _finite(metrics: dict[str, float]) -> dict[str, float | None]:
    """JSON has no NaN: undefined metrics (no finished episode) become null."""
    return {k: None if isinstance(v, float) and not math.isfinite(v) else v for k, v in metrics.items()}
