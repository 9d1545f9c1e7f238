"""Test-wide settings."""

import atexit
import os
import shutil
import tempfile

# Headless rendering: MuJoCo's default GLFW backend needs a display; EGL (Mesa's on CPUs) does not.
os.environ.setdefault("MUJOCO_GL", "egl")

# XLA's CPU runtime can deadlock when an operation running on its intra-op thread pool splits work back into the same
# pool and waits (a known XLA CPU issue; seen here as a test with every thread idle, forever, when MJX factored 44 or
# more hand environments' mass matrices on 2 cores). Single-threaded Eigen keeps work off that pool. Subprocesses that
# tests start inherit it.
if "xla_cpu_multi_thread_eigen" not in os.environ.get("XLA_FLAGS", ""):
    os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} --xla_cpu_multi_thread_eigen=false".strip()

# Many tests train the same tiny configs, and each run builds its cycle afresh, so XLA compiles identical programs
# again and again. JAX's persistent compilation cache, in a folder of this session only (nothing carries over between
# sessions, so no test depends on an earlier one), turns the repeats into cache reads. Subprocesses inherit it.
if "JAX_COMPILATION_CACHE_DIR" not in os.environ:
    os.environ["JAX_COMPILATION_CACHE_DIR"] = tempfile.mkdtemp(prefix="angora_jax_xla_cache_")
    atexit.register(shutil.rmtree, os.environ["JAX_COMPILATION_CACHE_DIR"], ignore_errors=True)
os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0")
os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES", "0")
