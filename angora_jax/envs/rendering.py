"""Off-screen rendering of MuJoCo tasks with `mujoco.Renderer`: named cameras that follow the task's `camera_body`.

Rendering needs an OpenGL backend chosen by `MUJOCO_GL` before MuJoCo is imported: `egl` (Debian/Ubuntu packages
`libegl1` and `libegl-mesa0`; a GPU driver's EGL works too) or `osmesa` (package `libosmesa6`, slower).
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import mujoco
import numpy as np

GL_HINT = (
    "Rendering needs an OpenGL backend: on a machine without a display install `libegl1 libegl-mesa0` and set "
    "MUJOCO_GL=egl, or install `libosmesa6` and set MUJOCO_GL=osmesa, before starting Python."
)


class RenderError(RuntimeError):
    """No frame can be rendered on this machine (no GL backend) or for this task (no MuJoCo scene)."""


@dataclass(frozen=True)
class Camera:
    """A free camera looking at the task's `camera_body` from `distance` m, `azimuth` and `elevation` degrees."""

    distance: float
    azimuth: float
    elevation: float


# Views of the hand (the palm is the look-at point); "front" is the default of the gymnasium view and of render.
CAMERAS = {
    "front": Camera(0.4, 90.0, -40.0),
    "side": Camera(0.4, 180.0, -25.0),
    "top": Camera(0.45, 90.0, -85.0),
    "wide": Camera(0.8, 120.0, -30.0),
}


def camera_named(name: str) -> Camera:
    """The camera called `name` in `CAMERAS`; ValueError listing the names otherwise."""
    if name not in CAMERAS:
        raise ValueError(f"Unknown camera {name!r}; choose one of {sorted(CAMERAS)}.")
    return CAMERAS[name]


class SceneRenderer:
    """Renders `(height, width, 3)` uint8 frames of a `mujoco.MjData` of `model` through `camera`."""

    def __init__(self, model: mujoco.MjModel, camera_body: str | None, camera: Camera, width: int = 320,
                 height: int = 240):
        try:
            self._renderer = mujoco.Renderer(model, height, width)
        except Exception as error:  # MuJoCo raises different types per backend when no GL context can be made
            backend = os.environ.get("MUJOCO_GL", "unset (GLFW, needs a display)")
            raise RenderError(f"MuJoCo cannot render with MUJOCO_GL={backend}: {error}. {GL_HINT}") from error
        self._model = model
        self._body = camera_body
        self._camera = camera

    def render(self, data: mujoco.MjData) -> np.ndarray:
        """The current frame of `data`, shape `(height, width, 3)`, uint8."""
        camera = mujoco.MjvCamera()
        mujoco.mjv_defaultFreeCamera(self._model, camera)
        camera.distance, camera.azimuth, camera.elevation = (
            self._camera.distance, self._camera.azimuth, self._camera.elevation)
        if self._body is not None:
            camera.lookat[:] = data.body(self._body).xpos
        self._renderer.update_scene(data, camera)
        return self._renderer.render()

    def close(self) -> None:
        self._renderer.close()
