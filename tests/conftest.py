"""Test-wide settings."""

import os

# Headless rendering: MuJoCo's default GLFW backend needs a display; EGL (Mesa's on CPUs) does not.
os.environ.setdefault("MUJOCO_GL", "egl")
