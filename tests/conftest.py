"""Test-wide settings."""

import os

# Headless rendering: MuJoCo's default GLFW backend needs a display; EGL (Mesa's on CPUs) does not.
os.environ.setdefault("MUJOCO_GL", "egl")

# XLA's CPU runtime can deadlock when an operation running on its intra-op thread pool splits work back into the same
# pool and waits (a known XLA CPU issue; seen here as a test with every thread idle, forever, when MJX factored 44 or
# more hand environments' mass matrices on 2 cores). Single-threaded Eigen keeps work off that pool. Subprocesses that
# tests start inherit it.
if "xla_cpu_multi_thread_eigen" not in os.environ.get("XLA_FLAGS", ""):
    os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} --xla_cpu_multi_thread_eigen=false".strip()
