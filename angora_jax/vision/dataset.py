"""Rendered datasets of random hand and cube poses for pretraining a visual encoder (OpenAI's Dactyl trained its
vision model separately, on renders).

Each sample is independent: the hand's joints drawn uniformly within (the middle of) their ranges, the cube placed
around where it rests on the palm (uniformly within +-`spread` m of `CUBE_REST` along each axis) in a uniformly
random orientation, positions computed by `mj_forward` (no dynamics: a pose need not be physically reachable to
teach what a pose looks like), then one frame per camera: fixed model cameras `vision_<name>` placed as the
`angora_jax.envs.rendering.CAMERAS` views of the palm (`add_cameras`), which MuJoCo Warp renders too. The cube's
faces carry distinct letters and colours, so its orientation is fully visible. Needs an OpenGL backend
(MUJOCO_GL=egl or osmesa).
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import mujoco
import numpy as np

from angora_jax.envs.mjx_env import require_warp
from angora_jax.envs.rendering import VISION_PREFIX, SceneRenderer
from angora_jax.envs.shadow_hand.cube import CUBE_JOINT, load_cube_scene
from angora_jax.ppo.memory import device_memory
from angora_jax.wording import counted

DEFAULT_CAMERAS = ("front", "side", "top")
CUBE_REST = np.array([1.0, 0.875, 0.165])  # m, world frame: where a settled cube lies on the palm (measured)
CUBE_AWAY = np.array([0.0, 0.0, 5.0])  # m: a shift that takes the cube out of every camera's view (`cube_masks`)


@dataclass(frozen=True)
class PoseDataset:
    """Rendered images of the cube with its pose, for pretraining a pose estimator.

    Attributes:
        images: `(N, cameras, height, width, 3)` uint8.
        cube_position: `(N, 3)` m, in the world frame.
        cube_quaternion: `(N, 4)` (w, x, y, z with w >= 0), in the world frame.
        hand_qpos: `(N, 24)` the hand's joint angles (rad).
        cameras: the cameras' names (`rendering.CAMERAS`), in the order of the images' camera axis.
        renderer: what drew the images, "cpu" (OpenGL) or "warp".
    """

    images: np.ndarray
    cube_position: np.ndarray
    cube_quaternion: np.ndarray
    hand_qpos: np.ndarray
    cameras: tuple[str, ...]
    renderer: str = "cpu"

    def __len__(self) -> int:
        return len(self.images)

    def split(self, held_out: float = 0.1) -> tuple[PoseDataset, PoseDataset]:
        """(train, test): the last `held_out` share of the (independent) samples is the test set."""
        cut = len(self) - max(1, int(round(len(self) * held_out)))
        if cut < 1:
            raise ValueError(f"{counted(len(self), 'sample')} cannot be split into train and test; render more.")
        return self._rows(slice(0, cut)), self._rows(slice(cut, None))

    def _rows(self, rows: slice) -> PoseDataset:
        return PoseDataset(self.images[rows], self.cube_position[rows], self.cube_quaternion[rows],
                           self.hand_qpos[rows], self.cameras, self.renderer)


def random_quaternions(rng: np.random.Generator, count: int) -> np.ndarray:
    """`count` orientations uniform over SO(3) as unit quaternions (w, x, y, z) with w >= 0 (normalised Gaussians)."""
    q = rng.standard_normal((count, 4))
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    return q * np.where(q[:, :1] < 0, -1.0, 1.0)


class PoseRenderer:
    """Frames of the cube scene in a given hand and cube pose, one per camera: `render(hand_qpos (24,), position (3,),
    quaternion (4,)) -> (cameras, height, width, 3)` uint8. Use as a context manager (it holds GL contexts)."""

    def __init__(self, cameras: tuple[str, ...] = DEFAULT_CAMERAS, width: int = 64, height: int = 64):
        self.model = load_cube_scene(touch=False, cameras=cameras)
        self.data = mujoco.MjData(self.model)
        self.cube = int(self.model.joint(CUBE_JOINT).qposadr[0])  # the free joint after the hand's 24 hinges
        self.joint_range = self.model.jnt_range[: self.model.njnt - 1]  # one hinge per hand joint, in qpos order
        self._renderers = [SceneRenderer(self.model, None, VISION_PREFIX + name, width, height) for name in cameras]

    def render(self, hand_qpos: np.ndarray, position: np.ndarray, quaternion: np.ndarray) -> np.ndarray:
        self.data.qpos[: self.cube] = hand_qpos
        self.data.qpos[self.cube:self.cube + 3] = position
        self.data.qpos[self.cube + 3:self.cube + 7] = quaternion
        mujoco.mj_forward(self.model, self.data)
        return np.stack([renderer.render(self.data) for renderer in self._renderers])

    def __enter__(self) -> PoseRenderer:
        return self

    def __exit__(self, *exc) -> None:
        for renderer in self._renderers:
            renderer.close()


def render_pose_dataset(samples: int, cameras: tuple[str, ...] = DEFAULT_CAMERAS, width: int = 64, height: int = 64,
                        spread: float = 0.02, hand_spread: float = 0.5, seed: int = 0,
                        renderer: str = "cpu", batch: int = 1024) -> PoseDataset:
    """`samples` independent renders of random hand and cube poses (module docstring); each hand joint is drawn
    within the middle `hand_spread` share of its range (1: the whole range, where fingers often hide the cube).

    Args:
        renderer: "cpu" (`mujoco.Renderer`, one frame at a time) or "warp" (MuJoCo Warp's batched ray tracer on a GPU,
            `batch` poses per call; its lighting differs from OpenGL's, see benchmarks/render_throughput.py).
    """
    rng = np.random.default_rng(seed)
    model = load_cube_scene(touch=False, cameras=cameras)
    cube = int(model.joint(CUBE_JOINT).qposadr[0])
    low, high = model.jnt_range[: model.njnt - 1].T
    centre, half = (low + high) / 2, hand_spread * (high - low) / 2
    hand_qpos = rng.uniform(centre - half, centre + half, (samples, cube))
    position = CUBE_REST + rng.uniform(-spread, spread, (samples, 3))
    quaternion = random_quaternions(rng, samples)
    images = render_poses(hand_qpos, position, quaternion, cameras, width, height, renderer, batch)
    return PoseDataset(images, position.astype(np.float32), quaternion.astype(np.float32),
                       hand_qpos.astype(np.float32), tuple(cameras), renderer)


def check_pose_renders(samples: int, cameras: tuple[str, ...], width: int, height: int, renderer: str = "cpu") -> None:
    """Refuse, before rendering anything, `samples` frames of each of `cameras` at `width` x `height` pixels that
    `renderer` cannot draw here: ValueError naming the cause and the fix for an unknown renderer, frames larger than
    the cube scene's offscreen framebuffer (which OpenGL draws into; MuJoCo Warp has none), or images that do not fit
    in this machine's memory; ModuleNotFoundError naming the package when MuJoCo Warp is missing."""
    if renderer not in ("cpu", "warp"):
        raise ValueError(f"renderer must be 'cpu' or 'warp', got {renderer!r}.")
    if renderer == "warp":
        require_warp()
    else:
        framebuffer = load_cube_scene(touch=False, cameras=cameras).vis.global_
        if width > framebuffer.offwidth or height > framebuffer.offheight:
            raise ValueError(f"Frames of {width} x {height} pixels do not fit the cube scene's offscreen framebuffer "
                             f"of {framebuffer.offwidth} x {framebuffer.offheight}, which OpenGL draws into: render "
                             f"at most {min(framebuffer.offwidth, framebuffer.offheight)} pixels square (--size), or "
                             "with MuJoCo Warp on a GPU (--renderer warp).")
    images = samples * len(cameras) * width * height * 3
    memory = device_memory(jax.devices("cpu")[0])
    if memory is not None and 2 * images > memory:  # the frames, and the array they are stacked into at the end
        raise ValueError(f"{counted(samples, 'sample')} x {counted(len(cameras), 'camera')} x {width} x {height} "
                         f"pixels take {images / 1e9:,.1f} GB, twice that while rendering, more than this machine's "
                         f"{memory / 1e9:,.0f} GB of memory: render fewer samples (--samples) or smaller frames "
                         "(--size).")


def render_poses(hand_qpos: np.ndarray, position: np.ndarray, quaternion: np.ndarray,
                 cameras: tuple[str, ...] = DEFAULT_CAMERAS, width: int = 64, height: int = 64,
                 renderer: str = "cpu", batch: int = 1024) -> np.ndarray:
    """Frames `(N, cameras, height, width, 3)` uint8 of given poses: the hand's joint angles `(N, 24)` rad, the cube's
    position `(N, 3)` m and orientation `(N, 4)` (w, x, y, z) in the world frame; renderer and batch as for
    `render_pose_dataset`; `check_pose_renders` says what it refuses."""
    check_pose_renders(len(hand_qpos), cameras, width, height, renderer)
    if renderer == "warp":
        model = load_cube_scene(touch=False, cameras=cameras)
        qpos = np.concatenate([hand_qpos, position, quaternion], axis=1)
        return _render_warp(model, qpos, len(cameras), width, height, batch)
    with PoseRenderer(cameras, width, height) as cpu:
        return np.stack([cpu.render(hand_qpos[i], position[i], quaternion[i]) for i in range(len(hand_qpos))])


def cube_masks(dataset: PoseDataset, threshold: int = 8, without_cube: np.ndarray | None = None) -> np.ndarray:
    """Where the cube is in each of `dataset`'s images: `(N, cameras, height, width)` bool, the pixels whose colour
    (any channel, 0-255) changes by more than `threshold` when the same poses are rendered, with the dataset's own
    renderer, with the cube moved `CUBE_AWAY` out of every camera's view (`without_cube`: those frames, where they
    were rendered already). The scene's light casts no shadows, so these are the cube's pixels and, with OpenGL's
    antialiasing, a rim of at most one pixel into which its edges blend."""
    if without_cube is None:
        height, width = dataset.images.shape[2:4]
        without_cube = render_poses(dataset.hand_qpos, dataset.cube_position + CUBE_AWAY, dataset.cube_quaternion,
                                    dataset.cameras, width, height, dataset.renderer)
    return np.abs(dataset.images.astype(np.int16) - without_cube).max(axis=-1) > threshold


def _render_warp(model: mujoco.MjModel, qpos: np.ndarray, cameras: int, width: int, height: int,
                 batch: int) -> np.ndarray:
    """Frames `(N, cameras, height, width, 3)` uint8 of the poses `qpos` `(N, nq)`, `batch` at a time on Warp."""
    import jax.numpy as jnp
    from mujoco import mjx

    from angora_jax.envs.mjx_env import quiet_iteration_caps, warp_sizes

    mx = quiet_iteration_caps(mjx.put_model(model, impl="warp"))
    start = mjx.make_data(model, impl="warp", **warp_sizes(model, batch))
    context = mjx.create_render_context(mjm=model, nworld=batch, cam_res=(width, height), use_textures=True,
                                        use_shadows=False, render_rgb=[True] * cameras,
                                        render_depth=[False] * cameras, enabled_geom_groups=[0, 1, 2])
    handle = context.pytree()

    @jax.jit
    def frames(qpos):
        data = jax.vmap(lambda q: start.replace(qpos=q))(qpos)
        data = jax.vmap(mjx.forward, in_axes=(None, 0))(mx, data)
        data = jax.vmap(mjx.refit_bvh, in_axes=(None, 0, None))(mx, data, handle)
        rgb, _, _ = jax.vmap(mjx.render, in_axes=(None, 0, None))(mx, data, handle)
        images = jnp.stack([mjx.get_rgb(handle, camera, rgb) for camera in range(cameras)], axis=1)
        return (images * 255.0 + 0.5).astype(jnp.uint8)

    out = []
    for first in range(0, len(qpos), batch):
        chunk = qpos[first:first + batch]
        padded = np.concatenate([chunk, np.repeat(chunk[-1:], batch - len(chunk), axis=0)])  # one compiled size
        out.append(np.asarray(frames(jnp.asarray(padded, jnp.float32)))[: len(chunk)])
    return np.concatenate(out)
