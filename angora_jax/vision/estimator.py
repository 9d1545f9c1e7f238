"""The cube's pose seen from camera frames: `PoseNet`, the network that `pretrain_pose_encoder` trains, and
`PoseEstimator`, a trained one ready to use (frames in, position in m and orientation as a quaternion out).

`PoseNet` runs one encoder (shared weights) over each camera's image, concatenates the features and maps them to the
cube's position (standardised by the training set's mean and spread) and orientation, as a rotation matrix made from
the head's outputs in one of `ORIENTATIONS`: "quaternion" (4 numbers, normalised) or "6d" (two 3-vectors made
orthonormal by Gram-Schmidt, the third their cross product; Zhou et al. 2019, "On the continuity of rotation
representations": every orientation has its quaternion pair q, -q, so a network that outputs quaternions must jump
somewhere between them, while the 6D map is continuous).

A `PoseEstimator` holds the whole trained network (the encoder and the pose head), the training set's position
scaling and what it was trained on (encoder and sizes, cameras, image size); `angora-jax pretrain-vision` saves one
beside the encoder component (`<out>.pose.msgpack`), `PoseEstimator.load` reads it back. It is how OpenAI's Dactyl
fed its policy: a vision model trained separately on renders, estimating the pose the policy was trained on.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
from flax import serialization
from jax.scipy.spatial.transform import Rotation

from angora_jax.envs.shadow_hand import register_pose_estimator_reader
from angora_jax.nets.visual import make_visual_encoder
from angora_jax.saved_files import POSE_ESTIMATOR, content_kind
from angora_jax.vision.orientations import ORIENTATIONS
from angora_jax.whole_files import written_whole


def _unit(x: jax.Array) -> jax.Array:
    return x / (jnp.linalg.norm(x, axis=-1, keepdims=True) + 1e-8)


def rotation_matrices(out: jax.Array, orientation: str) -> jax.Array:
    """`(B, ORIENTATIONS[orientation])` head outputs -> `(B, 3, 3)` rotation matrices (module docstring)."""
    if orientation == "quaternion":
        w, xyz = out[:, :1], out[:, 1:]  # MuJoCo's order: w first; SciPy's Rotation takes it last
        return Rotation.from_quat(_unit(jnp.concatenate([xyz, w], axis=-1))).as_matrix()
    first = _unit(out[:, :3])
    second = _unit(out[:, 3:] - jnp.sum(first * out[:, 3:], axis=-1, keepdims=True) * first)
    return jnp.stack([first, second, jnp.cross(first, second)], axis=-1)


def quaternions(rotations: jax.Array) -> jax.Array:
    """`(B, 3, 3)` rotation matrices -> `(B, 4)` unit quaternions in MuJoCo's order (w, x, y, z)."""
    xyzw = Rotation.from_matrix(rotations).as_quat()
    return jnp.concatenate([xyzw[:, 3:], xyzw[:, :3]], axis=-1)


class PoseNet(nn.Module):
    """`(B, cameras, H, W, 3)` uint8 -> (standardised position `(B, 3)`, rotation matrix `(B, 3, 3)`); the head
    outputs the orientation as `orientation` (`ORIENTATIONS`)."""

    encoder: nn.Module
    hidden: int = 256
    orientation: str = "6d"

    @nn.compact
    def __call__(self, images: jax.Array) -> tuple[jax.Array, jax.Array]:
        batch, cameras = images.shape[:2]
        features = self.encoder(images.reshape((batch * cameras, *images.shape[2:])))
        x = nn.relu(nn.Dense(self.hidden, name="head_hidden")(features.reshape(batch, -1)))
        out = nn.Dense(3 + ORIENTATIONS[self.orientation], name="head_out")(x)
        return out[:, :3], rotation_matrices(out[:, 3:], self.orientation)


def orientation_error_degrees(predicted: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Angle (deg) of the rotation between unit quaternions, per row: 2 arccos |<p, q>|."""
    dot = np.clip(np.abs(np.sum(predicted * truth, axis=-1)), 0.0, 1.0)
    return np.degrees(2.0 * np.arccos(dot))


@dataclass(frozen=True)
class PoseEstimator:
    """A trained `PoseNet` with what it needs to read frames: `params` (the whole network's), `encoder` and
    `encoder_options` (as `make_visual_encoder` takes them), `orientation` (`ORIENTATIONS`), `cameras` (names, in the
    order of the frames' camera axis), `size` (frame width and height in pixels), and the training set's cube
    position `position_mean` and `position_spread` (`(3,)` m) that the network's position output is scaled by;
    `renderer`, what drew its training images ("cpu": OpenGL, "warp"; None: not recorded), the renderer it must read
    (tasks refuse to feed it another's frames)."""

    params: Any
    encoder: str
    encoder_options: dict
    orientation: str
    cameras: tuple[str, ...]
    size: int
    position_mean: np.ndarray
    position_spread: np.ndarray
    renderer: str | None = None

    def network(self) -> PoseNet:
        """The untrained `PoseNet` that `params` belong to."""
        return PoseNet(make_visual_encoder(self.encoder, **self.encoder_options), orientation=self.orientation)

    def __call__(self, frames: jax.Array) -> tuple[jax.Array, jax.Array]:
        """`(B, cameras, size, size, 3)` uint8 frames -> the cube's position `(B, 3)` (m, world frame) and
        orientation `(B, 4)` (unit quaternion w, x, y, z with w >= 0). Pure: it may be jitted, or called inside a
        jitted function."""
        self.check_frames(frames)
        position, rotation = self.network().apply({"params": self.params}, frames)
        quaternion = quaternions(rotation)
        return position * self.position_spread + self.position_mean, quaternion * jnp.where(
            quaternion[:, :1] < 0, -1.0, 1.0)

    def check_frames(self, frames: jax.Array | np.ndarray) -> None:
        """ValueError unless `frames` are shaped as the estimator reads them: `(B, cameras, size, size, 3)`."""
        expected = (len(self.cameras), self.size, self.size, 3)
        if tuple(frames.shape[1:]) != expected:
            raise ValueError(f"PoseEstimator expects frames (batch, {', '.join(map(str, expected))}) from cameras "
                             f"{list(self.cameras)}; got {tuple(frames.shape)}. Render what it was trained on.")

    def save(self, file: str | Path) -> Path:
        """Write the estimator to `file` (msgpack); refuses to overwrite."""
        file = Path(file)
        if file.exists():
            raise FileExistsError(f"{file} exists; pose estimators are never overwritten: give another file.")
        file.parent.mkdir(parents=True, exist_ok=True)
        state = {"params": jax.device_get(self.params), "encoder": self.encoder,
                 "encoder_options": {k: list(v) if isinstance(v, tuple) else v  # msgpack packs no tuples
                                     for k, v in self.encoder_options.items()}, "orientation": self.orientation,
                 "cameras": list(self.cameras), "size": self.size,
                 "position_mean": np.asarray(self.position_mean, np.float32),
                 "position_spread": np.asarray(self.position_spread, np.float32), "renderer": self.renderer or ""}
        with written_whole(file, replace=False) as draft:
            draft.write_bytes(serialization.msgpack_serialize(state))
        return file

    @classmethod
    def load(cls, file: str | Path) -> PoseEstimator:
        """The estimator that `save` (or `angora-jax pretrain-vision`, as `<out>.pose.msgpack`) wrote to `file`."""
        file = Path(file)
        if not file.is_file():
            relative = ("" if file.is_absolute() else f" (a relative path, read from the current directory "
                        f"{Path.cwd()}: a run keeps the path as it was given, so run from where it was trained, or "
                        "give the file's full path, e.g. --env-option pose_estimator=/full/path)")
            raise FileNotFoundError(f"No pose estimator at {file}{relative}: angora-jax pretrain-vision --out ENCODER "
                                    "writes one beside the encoder, as ENCODER with the suffix .pose.msgpack.")
        try:
            state = serialization.msgpack_restore(file.read_bytes())
        except (ValueError, TypeError):  # what msgpack and flax raise on bytes that are no msgpack
            state = None
        if (kind := content_kind(state)) != POSE_ESTIMATOR:
            raise ValueError(f"{file} is {kind or 'no file of angora_jax (not msgpack, or damaged or cut short)'}, "
                             "not a pose estimator: give the OUT.pose.msgpack that `angora-jax pretrain-vision --out "
                             "OUT` writes beside its encoder OUT.")
        # msgpack returns sequences as lists; the encoders' sizes are tuples
        options = {k: tuple(v) if isinstance(v, list) else v for k, v in state["encoder_options"].items()}
        return cls(state["params"], state["encoder"], options, state["orientation"], tuple(state["cameras"]),
                   int(state["size"]), np.asarray(state["position_mean"]), np.asarray(state["position_spread"]),
                   state.get("renderer") or None)


register_pose_estimator_reader(PoseEstimator.load)
