"""JAX's persistent compilation cache for runs: a second run of the same config reads its compiled programs from disk.

Compiling is a large part of a short run (reach: about 30 of its 55 s to solve on one GPU; the cube's cycle over a
minute), and the same config compiles to the same programs. `enable` points JAX's persistent cache at a directory,
`~/.cache/angora_jax` unless the environment variable `ANGORA_JAX_CACHE` names another (a shared filesystem for a
cluster, a scratch disk) or is `off`. A cache directory set for JAX itself (`JAX_COMPILATION_CACHE_DIR` or
`jax.config.update("jax_compilation_cache_dir", ...)`) is left as it is. `train`, `resume` and the `angora-jax`
command enable it; `counts()` says how many programs were read from it and how many compiled.

Under `jax.distributed` (several processes) the default is off. Every process must compile the same programs: on
GPUs, XLA shares the autotuning of a program between the processes compiling it, so a process that read the program
from the cache while another compiled it would leave that one waiting. (The first-cycle hang of a 4-GPU run first
blamed on the cache was process 0's monitor running programs alone, since fixed; with the cache on, multi-process GPU
runs are not yet measured.) Naming a directory (`ANGORA_JAX_CACHE=DIR`, or `enable(DIR)`) turns it on there too.

Entries are keyed by the program, the JAX and XLA versions and the device, so a stale entry is never read; delete the
directory to reclaim its space. Programs that call back into Python (host-rendered camera vision on the CPU) are
compiled every time.
"""

from __future__ import annotations

import os
from pathlib import Path

import jax
from jax.experimental.compilation_cache import compilation_cache

ENV_VAR = "ANGORA_JAX_CACHE"
DEFAULT = Path("~/.cache/angora_jax")
_EVENTS = {"/jax/compilation_cache/cache_hits": "hits", "/jax/compilation_cache/cache_misses": "misses"}
_counts = {"hits": 0, "misses": 0}
_listening = False


def enable(directory: str | Path | None = None) -> Path | None:
    """Use the persistent compilation cache in `directory` (default: `$ANGORA_JAX_CACHE`, else
    `~/.cache/angora_jax`, but off under jax.distributed unless named); "off" leaves it off. Returns the directory
    in use (JAX's own setting if one was made), or None when off. Takes effect for programs compiled after the call,
    also when others were compiled before."""
    if jax.config.jax_compilation_cache_dir:
        _listen()
        return Path(jax.config.jax_compilation_cache_dir)
    named = directory if directory is not None else os.environ.get(ENV_VAR)
    if named is None and jax.process_count() > 1:
        return None  # off by default under jax.distributed (module docstring)
    setting = str(named if named is not None else DEFAULT)
    if setting.lower() == "off":
        return None
    path = Path(setting).expanduser()
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise OSError(f"The compilation cache directory {path} cannot be made ({error}); set {ENV_VAR} to a "
                      f"writable directory, or {ENV_VAR}=off.") from None
    jax.config.update("jax_compilation_cache_dir", str(path))
    # JAX decides whether to use its cache once, at the first compile: a notebook may have compiled before.
    compilation_cache.reset_cache()
    _listen()
    return path


def counts() -> dict[str, int]:
    """Programs read from the cache ("hits") and compiled because they were not in it ("misses") so far in this
    process, while the cache was on."""
    return dict(_counts)


def _listen() -> None:
    global _listening
    if not _listening:
        jax.monitoring.register_event_listener(_count)
        _listening = True


def _count(event: str, **_: object) -> None:
    if event in _EVENTS:
        _counts[_EVENTS[event]] += 1
