"""The operating system's errors (a full disk, a read-only mount, permissions) as one sentence with the fix."""

from __future__ import annotations

import errno
import os
import traceback

_NOT_YOURS = ("you may not write or read there: choose a place of your own (a new run: logging.run_root; what "
              "evaluate, record, render, export and report write: --out FOLDER) or fix its permissions")

# What to do about the errors the operating system reports, by errno.
OS_ERROR_FIXES = {
    errno.ENOSPC: "free space on that disk (or move the run root to a larger one)",
    errno.EDQUOT: "free space within your disk quota (or move the run root)",
    errno.EFBIG: "a file reached this process's file-size limit: raise it (`ulimit -f unlimited`, or the job's limit)",
    errno.EROFS: "the file system is read-only: choose a writable place (logging.run_root, --out; evaluating a run "
                 "there: evaluate --out FOLDER)",
    errno.EACCES: _NOT_YOURS,
    errno.EPERM: _NOT_YOURS,
    errno.ENAMETOOLONG: "shorten the path or name",
    errno.EIO: "the disk or network file system failed: check the mount, then retry",
    errno.ENOTDIR: "a part of the path is a file, not a folder: fix the path",
    errno.EISDIR: "a folder is where a file belongs: give a file's path (or, where it is a run's own file, such as "
                  "RUN_DIR/metrics.jsonl, move the folder away)",
    errno.EEXIST: "a file is in the way where a folder must be made: choose another path (logging.run_root, --out)",
    errno.ENOENT: "a folder on the way does not exist or cannot be made there: check the path",
}


# The verbs that train: a run they stop is continued by `resume`. Other verbs (render, export, report, ...) stop no
# run, and told that "a run stopped by it keeps every checkpoint" a user looked for harm to their training run.
TRAINING_VERBS = ("train", "resume")


def os_error_message(error: OSError, command: str = "train") -> str:
    """An OSError as one sentence: what failed, on which file, and the fix; under a verb that trains (`command` in
    TRAINING_VERBS), that a run interrupted this way keeps what it saved before (`angora-jax check RUN_DIR`, then
    `resume`)."""
    where = f" ({error.filename})" if error.filename else ""
    fix = OS_ERROR_FIXES.get(error.errno, "fix the cause and retry")
    if command == "resume" and error.errno in (errno.EACCES, errno.EPERM):
        # resume writes into the run itself, so no other place will do.
        fix = ("resume writes into the run: fix its permissions, or copy the run to a folder of your own "
               "and make it yours (cp -r RUN_DIR MY_RUN; chmod -R u+w MY_RUN), then resume the copy")
    during_a_run = command in TRAINING_VERBS and error.errno in (errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EIO)
    return f"{error.strerror or error}{where}: {fix}." + (
        " A run stopped by it keeps every checkpoint saved before: `angora-jax check RUN_DIR` shows them, "
        "`angora-jax resume RUN_DIR` continues." if during_a_run else "")


# How XLA (its status code) and MuJoCo Warp (a kernel load that fails, after Warp has printed the CUDA error) say that
# a device's memory ran out.
_OUT_OF_MEMORY = ("RESOURCE_EXHAUSTED", "out of memory", "Out of memory")
_WARP_KERNEL_LOAD = "Failed to load CUDA module"


def device_memory_message(error: BaseException, command: str = "train") -> str | None:
    """The sentence for a JAX runtime error (or one it was raised from) that says a device's memory ran out, naming
    the usual causes and their fixes (on a GPU: another process holding its share; on the CPU: only the batch) and,
    under a verb that trains (`command` in TRAINING_VERBS), that the run keeps what it saved before; None for every
    other error. A full disk, which TensorStore also reports as RESOURCE_EXHAUSTED, is not taken for it."""
    import jax

    from angora_jax.experiment.run_dir import NO_ROOM

    on_gpu = jax.default_backend() == "gpu"
    while error is not None:
        text = str(error)
        if type(error).__name__ in ("JaxRuntimeError", "XlaRuntimeError") and not any(
                words in text for words, *_ in NO_ROOM.values()):
            if any(sign in text for sign in _OUT_OF_MEMORY):
                line = next(line for line in text.splitlines() if any(sign in line for sign in _OUT_OF_MEMORY))
                what = f"the {'GPU' if on_gpu else 'machine'} ran out of memory ({line.strip()[:200]})"
                break
            if _WARP_KERNEL_LOAD in text:
                what = ("MuJoCo Warp could not load its CUDA kernels onto the GPU (Warp printed the CUDA error above; "
                        "'out of memory' is the usual one)")
                on_gpu = True
                break
        error = error.__cause__ or error.__context__
    else:
        return None
    fewer = ("fewer environments (train: ppo.num_envs and ppo.minibatch_size; evaluate: a smaller --batch; record: "
             "fewer --episodes; run: fewer --num-envs)")
    advice = (f"Use {fewer}. " if not on_gpu else
              "Each JAX process takes 75% of a GPU's memory when it starts, so a second process on the same GPU "
              "(nvidia-smi lists them) leaves too little: run them one after another, or give each a share before "
              f"starting it (XLA_PYTHON_CLIENT_MEM_FRACTION=0.45 for two). Alone on the GPU, use {fewer}. ")
    kept = ("A run stopped by it keeps every checkpoint saved before: `angora-jax check RUN_DIR` shows them, "
            "`angora-jax resume RUN_DIR` continues." if command in TRAINING_VERBS else "")
    return f"{what}. {advice}{kept}".rstrip()


def platform_message(error: BaseException) -> str | None:
    """The sentence for JAX failing to start the platform that `JAX_PLATFORMS` names (a GPU platform on a machine or
    an installation without one: `JAX_PLATFORMS=cuda` copied from a cluster's job script), None for every other
    error. JAX raises it where it starts its backends (xla_bridge), as RuntimeError "Unable to initialize backend" for
    some names and as a bare AssertionError for others (`cuda` without JAX's CUDA plugin, jax 0.10): both ended even
    `angora-jax doctor` in a traceback."""
    chosen = os.environ.get("JAX_PLATFORMS")
    frames = traceback.extract_tb(error.__traceback__)
    if not chosen or not frames or os.path.basename(frames[-1].filename) != "xla_bridge.py":
        return None
    from angora_jax.experiment.doctor import CUDA_INSTALL  # JAX: only for this message

    cause = str(error).split(" (set JAX_PLATFORMS")[0] or f"JAX raised {type(error).__name__}"
    return (f"JAX cannot start the platform that JAX_PLATFORMS={chosen} names on this machine ({cause[:300]}): unset "
            "JAX_PLATFORMS to let JAX use what this machine has (`angora-jax doctor` then lists its devices); for an "
            f"NVIDIA GPU, JAX needs its CUDA build: {CUDA_INSTALL}.")
