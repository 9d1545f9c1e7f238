"""Off-screen rendering of MuJoCo tasks with `mujoco.Renderer`: named cameras that follow the task's `camera_body`.

Rendering needs an OpenGL backend chosen by `MUJOCO_GL` before MuJoCo is imported: `egl` (Debian/Ubuntu packages
`libegl1` and `libegl-mesa0`; a GPU driver's EGL works too) or `osmesa` (package `libosmesa6`, slower).
"""

from __future__ import annotations

import copy
import numbers
import os
import warnings
from dataclasses import dataclass

import mujoco
import numpy as np

from angora_jax.opengl_backend import GL_HINT, changed_since_import


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


VISION_PREFIX = "vision_"


def camera_pose(lookat: np.ndarray, camera: Camera) -> tuple[np.ndarray, np.ndarray]:
    """Position and `xyaxes` (right, up) of a fixed MuJoCo camera that sees what the free `camera` sees when it looks
    at `lookat`: MuJoCo places a free camera at lookat - distance x forward, forward = (cos el cos az, cos el sin az,
    sin el), and a camera looks along its -z axis with +y up."""
    azimuth, elevation = np.radians(camera.azimuth), np.radians(camera.elevation)
    forward = np.array([np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth), np.sin(elevation)])
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    return np.asarray(lookat) - camera.distance * forward, np.concatenate([right, np.cross(right, forward)])


def add_cameras(spec: mujoco.MjSpec, lookat: np.ndarray, names: tuple[str, ...], fovy: float = 45.0) -> list[str]:
    """Add fixed cameras `vision_<name>` to the world of `spec`, one per `CAMERAS` name, placed as that free camera
    looking at `lookat`, with MuJoCo's default free-camera field of view. Model cameras are what MuJoCo Warp renders
    in batches, and `mujoco.Renderer` renders them by name: both paths see the same views."""
    added = []
    for name in names:
        position, xyaxes = camera_pose(lookat, camera_named(name))
        spec.worldbody.add_camera(name=VISION_PREFIX + name, pos=position, xyaxes=xyaxes, fovy=fovy)
        added.append(VISION_PREFIX + name)
    return added


def camera_named(name: str) -> Camera:
    """The camera called `name` in `CAMERAS`; ValueError listing the names otherwise."""
    if name not in CAMERAS:
        raise ValueError(f"Unknown camera {name!r}; choose one of {sorted(CAMERAS)}.")
    return CAMERAS[name]


class SceneRenderer:
    """Renders `(height, width, 3)` uint8 frames of a `mujoco.MjData` of `model` through `camera`: a free `Camera`
    that looks at `camera_body`, or the name of one of the model's own cameras (e.g. `vision_front`)."""

    def __init__(self, model: mujoco.MjModel, camera_body: str | None, camera: Camera | str, width: int = 320,
                 height: int = 240):
        framebuffer = model.vis.global_
        if width > framebuffer.offwidth or height > framebuffer.offheight:
            # MuJoCo draws into an offscreen framebuffer of the model's size (640 x 480 unless its XML says otherwise)
            # and refused larger frames with "specify a larger offscreen framebuffer in the model XML", which the
            # user of `render --width` cannot do: this renderer's copy of the model gets one that fits instead.
            model = copy.copy(model)
            model.vis.global_.offwidth = max(width, framebuffer.offwidth)
            model.vis.global_.offheight = max(height, framebuffer.offheight)
        try:
            # GLFW warns (on stderr, before the message below) of each step that fails without a display: its first
            # warning, the cause, goes into the message instead.
            with warnings.catch_warnings(record=True) as warned:
                warnings.simplefilter("always")
                self._renderer = mujoco.Renderer(model, height, width)
        except Exception as error:  # MuJoCo raises different types per backend when no GL context can be made
            changed = changed_since_import()
            if changed:
                raise RenderError(f"MuJoCo cannot render: {changed}.") from error
            backend = os.environ.get("MUJOCO_GL", "unset (GLFW, needs a display)")
            cause = f" (first, {warned[0].message})" if warned else ""
            raise RenderError(f"MuJoCo cannot render with MUJOCO_GL={backend}: {error}{cause}. {GL_HINT}") from error
        self._model = model
        self._body = camera_body
        self._camera = camera

    def render(self, data: mujoco.MjData) -> np.ndarray:
        """The current frame of `data`, shape `(height, width, 3)`, uint8."""
        self._update(data)
        return self._renderer.render()

    def render_depth(self, data: mujoco.MjData) -> np.ndarray:
        """The current depth image of `data` (m from the camera's plane), shape `(height, width)`, float32."""
        self._update(data)
        self._renderer.enable_depth_rendering()
        try:
            return self._renderer.render()
        finally:
            self._renderer.disable_depth_rendering()

    def _update(self, data: mujoco.MjData) -> None:
        if isinstance(self._camera, str):
            self._renderer.update_scene(data, self._camera)
            return
        camera = mujoco.MjvCamera()
        mujoco.mjv_defaultFreeCamera(self._model, camera)
        camera.distance, camera.azimuth, camera.elevation = (
            self._camera.distance, self._camera.azimuth, self._camera.elevation)
        if self._body is not None:
            camera.lookat[:] = data.body(self._body).xpos
        self._renderer.update_scene(data, camera)

    def close(self) -> None:
        self._renderer.close()


def check_pixels(width: object, height: object) -> None:
    """ValueError unless `width` and `height` are whole numbers of at least 1 (not bools): text ("320" from a widget)
    or a fraction failed deep in a comparison or a format once the task was made."""
    if any(isinstance(size, bool) or not isinstance(size, numbers.Integral) or size < 1 for size in (width, height)):
        raise ValueError(f"Frames are whole numbers of pixels, at least 1 x 1: width and height, got {width!r} x "
                         f"{height!r}.")
