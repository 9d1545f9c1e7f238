"""Camera images as a sensation: `CameraVision` settings and the renderers that fill `Sensation.vision` with them.

A task with vision renders one frame per camera after every step and reset: `(cameras, height, width, channels)`
uint8, RGB (3 channels) and/or depth (1 channel, 0 at the camera to 255 at `depth_range` m and beyond). The cameras are
fixed model cameras `vision_<name>` placed as the `rendering.CAMERAS` views of the task's `camera_body`
(`rendering.add_cameras`), so every path renders the same views:

- the batched MJX path with MuJoCo Warp (GPU): `WarpCameras`, MuJoCo Warp's ray tracer inside the compiled step. Its
  render context holds one buffer per environment, so the step must be vmapped over exactly the batch the environment
  was sized for (`Env.sized_for`; trainers and evaluators do it);
- the batched MJX path with MJX's JAX implementation (CPU; tests): `HostCameras` through `jax.pure_callback`, one
  `mujoco.Renderer` (OpenGL) frame per environment;
- the eager C MuJoCo twin (evaluation, rendering, gymnasium view): `HostCameras` directly.

OpenGL and Warp see the same views (same camera poses, field of view and geometry) but shade differently: Warp has
no skybox and draws the hand untextured, so most pixels differ (benchmarks/render_throughput.py --compare measured
89-91% differing at 64 x 64). A policy trained on one renderer should be evaluated on the same one.
"""

from __future__ import annotations

import collections
import dataclasses
import functools
import weakref
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from angora_jax.envs.rendering import CAMERAS, VISION_PREFIX, SceneRenderer, camera_named

# The renderers a camera frame can come from, as `vision.render_pose_dataset` names them.
RENDERERS = {"cpu": "OpenGL (mujoco.Renderer)", "warp": "MuJoCo Warp"}


@dataclass(frozen=True)
class CameraVision:
    """Which cameras a task sees through and how: the task option `vision`.

    Attributes:
        cameras: names from `rendering.CAMERAS` ("front", "side", "top", "wide").
        width: image width in pixels.
        height: image height in pixels.
        rgb: render the colour channels.
        depth: render the depth channel (at least one of rgb and depth).
        depth_range: m, the depth that maps to 255.
        renderer: the renderer whose images what reads the frames was trained on, "cpu" (OpenGL, `mujoco.Renderer`) or
            "warp" (MuJoCo Warp), or None (any): the two draw the same views differently (Warp has no skybox and no
            textures), so a path that renders with the other refuses to run.
    """

    cameras: tuple[str, ...] = ("front",)
    width: int = 64
    height: int = 64
    rgb: bool = True
    depth: bool = False
    depth_range: float = 1.0
    renderer: str | None = None

    @classmethod
    def from_options(cls, options: dict[str, Any] | None) -> CameraVision | None:
        """Settings from a task's `vision` option (a mapping of these fields, or None for no vision); ValueError
        naming the field and the choices when one does not fit."""
        if options is None:
            return None
        if not isinstance(options, dict):
            raise ValueError(f"vision must be a mapping like {{cameras: [front], width: 64, height: 64}}, got "
                             f"{options!r}.")
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = set(options) - known
        if unknown:
            raise ValueError(f"Unknown vision settings {sorted(unknown)}; known: {sorted(known)}.")
        values = dict(options)
        if "cameras" in values:
            cameras = values["cameras"]
            values["cameras"] = (cameras,) if isinstance(cameras, str) else tuple(cameras)
        vision = cls(**values)
        for name in vision.cameras:
            camera_named(name)
        if not vision.cameras or len(set(vision.cameras)) != len(vision.cameras):
            raise ValueError(f"vision.cameras must name distinct cameras of {sorted(CAMERAS)}, got {vision.cameras}.")
        if min(vision.width, vision.height) < 8:
            raise ValueError(f"vision.width and vision.height must be at least 8 pixels, got {vision.width} x "
                             f"{vision.height}.")
        if not (vision.rgb or vision.depth):
            raise ValueError("vision needs rgb: true, depth: true or both.")
        if vision.depth_range <= 0:
            raise ValueError(f"vision.depth_range must be > 0 m, got {vision.depth_range}.")
        if vision.renderer not in (None, *RENDERERS):
            raise ValueError(f"vision.renderer must be one of {list(RENDERERS)} or null, got {vision.renderer!r}.")
        return vision

    def refuse_when_run(self, renderer: str) -> None:
        """Inside a JAX program: when these frames must come from another renderer than `renderer`, a host callback
        that raises `check_renderer`'s error when the program runs (not when it is traced: a shape evaluation, as
        loading a run does, still works); nothing otherwise."""
        if self.renderer not in (None, renderer):
            jax.debug.callback(functools.partial(self.check_renderer, renderer))

    def check_renderer(self, renderer: str) -> None:
        """A ValueError naming the fix when these frames must come from another renderer than `renderer`."""
        if self.renderer not in (None, renderer):
            raise ValueError(
                f"These camera frames are read by something trained on {RENDERERS[self.renderer]}'s images, but this "
                f"path renders with {RENDERERS[renderer]}, which draws them differently: "
                + ("run it with MuJoCo Warp (evaluate: --path batched --env-option physics.impl=warp; record and "
                   "analyze: --env-option physics.impl=warp; train: env.options.physics.impl=warp), on a GPU (the CPU "
                   "renders with it too, slowly)."
                   if self.renderer == "warp" else "run it on the CPU paths or MJX's JAX implementation (OpenGL)."))

    @property
    def channels(self) -> int:
        return 3 * self.rgb + self.depth

    @property
    def frame_shape(self) -> tuple[int, int, int, int]:
        """`(cameras, height, width, channels)` of one environment's frames."""
        return len(self.cameras), self.height, self.width, self.channels

    def camera_ids(self, model: mujoco.MjModel) -> list[int]:
        """The model's camera ids of `cameras`; ValueError when the scene was compiled without them."""
        ids = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, VISION_PREFIX + name) for name in self.cameras]
        missing = [name for name, i in zip(self.cameras, ids, strict=True) if i < 0]
        if missing:
            raise ValueError(f"The scene has no cameras {[VISION_PREFIX + n for n in missing]}: compile it with "
                             "them (e.g. load_cube_scene(cameras=...)).")
        return ids

    def depth_to_uint8(self, depth: Any) -> Any:
        """Depth in m to uint8 (0 at the camera, 255 at `depth_range` and beyond); numpy or JAX arrays."""
        xp = jnp if isinstance(depth, jax.Array) else np
        return (xp.clip(depth / self.depth_range, 0.0, 1.0) * 255.0 + 0.5).astype(xp.uint8)


# The GL threads and renderers of cameras the garbage collector dropped, closed at the next safe point (when cameras
# are made again). A finalizer runs wherever collection strikes, even inside a lock its thread holds: closing there
# (a submit to the GL thread takes concurrent.futures' global lock) hung a test process while Orbax's thread pool,
# holding that lock, started a thread. Appending to a deque takes no lock.
_dropped: collections.deque[tuple[ThreadPoolExecutor, list[SceneRenderer]]] = collections.deque()


class HostCameras:
    """Frames of a `mujoco.MjData` of `model` through `vision`'s cameras with `mujoco.Renderer` (OpenGL; needs
    MUJOCO_GL=egl or osmesa without a display). `frames(data) -> (cameras, height, width, channels)` uint8."""

    def __init__(self, model: mujoco.MjModel, vision: CameraVision):
        vision.camera_ids(model)
        while _dropped:
            _close_in(*_dropped.popleft())
        self.model, self.vision = model, vision
        # A GL context is current in one thread only, and JAX runs host callbacks in threads of its own (a new one
        # almost every call): all GL work runs in this one thread, which owns the renderers.
        self._gl = ThreadPoolExecutor(1, thread_name_prefix="angora_jax_gl")
        # Fails here, naming the fix, when no GL context can be made.
        self._renderers = self._gl.submit(lambda: [
            SceneRenderer(model, None, VISION_PREFIX + name, vision.width, vision.height)
            for name in vision.cameras]).result()
        self._data = mujoco.MjData(model)
        # A renderer must be closed in the thread whose GL context it uses, never by the garbage collector's thread.
        self._closer = weakref.finalize(self, _dropped.append, (self._gl, self._renderers))
        self._closer.atexit = False  # at exit the GL thread is already stopped, and the process frees its contexts

    def frames(self, data: mujoco.MjData) -> np.ndarray:
        self.vision.check_renderer("cpu")
        return self._gl.submit(self._frames, data).result()

    def _frames(self, data: mujoco.MjData) -> np.ndarray:
        out = []
        for renderer in self._renderers:
            channels = []
            if self.vision.rgb:
                channels.append(renderer.render(data))
            if self.vision.depth:
                channels.append(self.vision.depth_to_uint8(renderer.render_depth(data))[..., None])
            out.append(np.concatenate(channels, axis=-1))
        return np.stack(out)

    def frames_of_poses(self, qpos: np.ndarray, mocap_pos: np.ndarray, mocap_quat: np.ndarray) -> np.ndarray:
        """Frames `(N, cameras, height, width, channels)` of N poses given by `qpos` `(N, nq)` and the mocap bodies'
        `(N, nmocap, 3)` positions and `(N, nmocap, 4)` orientations (what places every body of the scene)."""
        out = np.empty((len(qpos), *self.vision.frame_shape), np.uint8)
        for i in range(len(qpos)):
            self._data.qpos[:] = qpos[i]
            self._data.mocap_pos[:] = mocap_pos[i]
            self._data.mocap_quat[:] = mocap_quat[i]
            mujoco.mj_kinematics(self.model, self._data)
            mujoco.mj_camlight(self.model, self._data)
            out[i] = self._frames(self._data)
        return out

    def traced_frames(self, qpos: jax.Array, mocap_pos: jax.Array, mocap_quat: jax.Array) -> jax.Array:
        """`frames_of_poses` for one environment inside a JAX program (`jax.pure_callback`, batched under vmap)."""
        self.vision.refuse_when_run("cpu")

        def render(qpos, mocap_pos, mocap_quat):
            batch = qpos.shape[:-1]
            count = int(np.prod(batch))
            flat = [np.asarray(x, np.float64).reshape((count,) + x.shape[len(batch):])
                    for x in (qpos, mocap_pos, mocap_quat)]
            frames = self._gl.submit(self.frames_of_poses, *flat).result()
            return frames.reshape(batch + self.vision.frame_shape)

        shape = jax.ShapeDtypeStruct(self.vision.frame_shape, jnp.uint8)
        return jax.pure_callback(render, shape, qpos, mocap_pos, mocap_quat, vmap_method="broadcast_all")

    def close(self) -> None:
        if self._closer.detach() is not None:
            _close_in(self._gl, self._renderers)


def _close_in(gl: ThreadPoolExecutor, renderers: list[SceneRenderer]) -> None:
    gl.submit(lambda: [renderer.close() for renderer in renderers]).result()
    gl.shutdown()


class WarpCameras:
    """Frames of batches of `num_envs` MJX-on-Warp `Data` through `vision`'s cameras with MuJoCo Warp's ray tracer,
    on any of this process's GPUs (each has its own render context; data-parallel training renders each device's
    share of `num_envs` environments on it).

    `frames(mjx_model, data)` renders one environment and must run under a vmap over exactly `num_envs` environments
    (the render context's buffers have that many worlds). Each instance holds its own context (its own BVH): a step
    that renders two states (the ended episode's and the fresh one's) uses two instances, so their renders cannot
    interleave."""

    def __init__(self, model: mujoco.MjModel, vision: CameraVision, num_envs: int):
        from mujoco import mjx

        ids = vision.camera_ids(model)
        wanted = set(ids)
        self.vision, self.ids = vision, ids
        # One context on each of this process's GPUs (Warp's FFI picks the one of the device a call runs on), so that
        # data-parallel training renders each device's share on that device; Warp's default device otherwise.
        gpus = [f"cuda:{device.local_hardware_id}" for device in jax.local_devices() if device.platform == "gpu"]
        self._context = mjx.create_render_context(
            mjm=model, nworld=num_envs, devices=gpus or None, cam_res=(vision.width, vision.height), use_textures=True,
            use_shadows=False,
            render_rgb=[vision.rgb and i in wanted for i in range(model.ncam)],
            render_depth=[vision.depth and i in wanted for i in range(model.ncam)], enabled_geom_groups=[0, 1, 2])
        self._handle = self._context.pytree()

    def frames(self, mjx_model: Any, data: Any) -> jax.Array:
        from mujoco import mjx

        self.vision.refuse_when_run("warp")

        data = mjx.refit_bvh(mjx_model, data, self._handle)
        rgb, depth, _ = mjx.render(mjx_model, data, self._handle)
        if rgb.ndim > 1:
            # Data that no vmap batches (a fixed start, the same in every env; a shape evaluation of one env) reaches
            # Warp unbatched: every world then renders that one state, and the first world's frames are its frames.
            rgb, depth = rgb[0], depth[0]
        out = []
        for camera in self.ids:
            channels = []
            if self.vision.rgb:
                channels.append((mjx.get_rgb(self._handle, camera, rgb) * 255.0 + 0.5).astype(jnp.uint8))
            if self.vision.depth:
                metres = mjx.get_depth(self._handle, camera, depth, self.vision.depth_range) * self.vision.depth_range
                channels.append(self.vision.depth_to_uint8(metres))
            out.append(jnp.concatenate(channels, axis=-1))
        return jnp.stack(out)


def check_path_renderer(env: Any, batched: bool) -> None:
    """`CameraVision.check_renderer` for the frames that `env`'s task (if it sees through cameras) renders on the
    batched path (MuJoCo Warp's renderer when it runs on Warp, else OpenGL) or the eager CPU path (OpenGL): for the
    commands that run episodes to call before they compile, where inside a program the same error surfaces from a
    host callback."""
    vision = getattr(getattr(env, "task", None), "vision", None)
    if vision is not None:
        vision.check_renderer("warp" if batched and getattr(env, "impl", None) == "warp" else "cpu")
