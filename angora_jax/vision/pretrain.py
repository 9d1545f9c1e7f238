"""Pretrain a visual encoder to see the cube's pose: position and orientation from the cameras' images.

`PoseNet` runs one encoder (shared weights) over each camera's image, concatenates the features and maps them to the
cube's position (standardised by the training set's mean and spread) and orientation, as a rotation matrix made from
the head's outputs in one of `ORIENTATIONS`: "quaternion" (4 numbers, normalised) or "6d" (two 3-vectors made
orthonormal by Gram-Schmidt, the third their cross product; Zhou et al. 2019, "On the continuity of rotation
representations": every orientation has its quaternion pair q, -q, so a network that outputs quaternions must jump
somewhere between them, while the 6D map is continuous). Loss: mean squared error of the standardised position plus
|R_pred - R|^2 / 8 (Frobenius), which equals 1 - <q_pred, q>^2 for quaternions: it ignores the quaternion's sign.
Adam (optax), its learning rate decaying to zero on a cosine over the steps by default (the small errors that the
orientation bar asks for come in the last, small steps). Reported on held-out episodes: median and 90th-percentile
errors of the position in mm and of the orientation in degrees (the angle of the rotation between prediction and
truth).

The trained encoder is a component (`angora_jax.nets.components`): `save_component(result.params, "encoder", file)`
writes it, and a policy's visual area of the same encoder and sizes loads it with `network.pretrained` and keeps it
fixed with `network.frozen`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import optax
from jax.scipy.spatial.transform import Rotation

from angora_jax.nets.visual import make_visual_encoder
from angora_jax.vision.dataset import PoseDataset

ORIENTATIONS = {"quaternion": 4, "6d": 6}  # the head's outputs per orientation representation


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


@dataclass
class PretrainResult:
    """params: the PoseNet's (its encoder under "encoder"); errors: held-out position (mm) and orientation (deg)
    medians and 90th percentiles; history: (step, training loss) every `log_every` steps."""

    params: Any
    errors: dict[str, float]
    history: list[tuple[int, float]] = field(default_factory=list)
    seconds: float = 0.0


def orientation_error_degrees(predicted: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Angle (deg) of the rotation between unit quaternions, per row: 2 arccos |<p, q>|."""
    dot = np.clip(np.abs(np.sum(predicted * truth, axis=-1)), 0.0, 1.0)
    return np.degrees(2.0 * np.arccos(dot))


def pretrain_pose_encoder(train: PoseDataset, test: PoseDataset, encoder: str = "cornet_z",
                          encoder_options: dict | None = None, steps: int = 2000, batch_size: int = 64,
                          learning_rate: float = 1e-3, seed: int = 0, log_every: int = 100,
                          orientation: str = "6d", decay: bool = True) -> PretrainResult:
    """Train `PoseNet(make_visual_encoder(encoder, **encoder_options), orientation=orientation)` on `train` for
    `steps` Adam steps of `batch_size` samples and measure it on `test` (module docstring). decay: the learning
    rate falls from `learning_rate` to zero on a cosine (False: it stays constant)."""
    if orientation not in ORIENTATIONS:
        raise ValueError(f"Unknown orientation {orientation!r}; choose one of {tuple(ORIENTATIONS)}.")
    model = PoseNet(make_visual_encoder(encoder, **(encoder_options or {})), orientation=orientation)
    mean, spread = train.cube_position.mean(0), train.cube_position.std(0) + 1e-6
    # The images stay on the host and each step sends its batch: a data set of more than 2^31 pixels (e.g. 54,000
    # samples of three 96 x 96 views) fails as one device array inside a gather (CUDA_ERROR_INVALID_VALUE, measured).
    position = ((train.cube_position - mean) / spread).astype(np.float32)
    rng = np.random.default_rng(seed)
    params = model.init(jax.random.key(seed), jnp.asarray(train.images[:1]))["params"]
    optimizer = optax.adam(optax.cosine_decay_schedule(learning_rate, steps) if decay else learning_rate)
    opt_state = optimizer.init(params)

    def loss_fn(params, images, position, quaternion):
        predicted_position, predicted_rotation = model.apply({"params": params}, images)
        position_loss = jnp.mean((predicted_position - position) ** 2)
        rotation = rotation_matrices(quaternion, "quaternion")
        orientation_loss = jnp.mean(jnp.sum((predicted_rotation - rotation) ** 2, axis=(-2, -1))) / 8.0
        return position_loss + orientation_loss

    @jax.jit
    def update(params, opt_state, images, position, quaternion):
        loss, grads = jax.value_and_grad(loss_fn)(params, images, position, quaternion)
        updates, opt_state = optimizer.update(grads, opt_state, params)
        return optax.apply_updates(params, updates), opt_state, loss

    history, start = [], time.perf_counter()
    for step in range(1, steps + 1):
        rows = np.sort(rng.integers(0, len(train), batch_size))
        params, opt_state, loss = update(params, opt_state, train.images[rows], position[rows],
                                         train.cube_quaternion[rows])
        if step % log_every == 0 or step == steps:
            history.append((step, float(loss)))
    seconds = time.perf_counter() - start
    predict = jax.jit(lambda p, x: model.apply({"params": p}, x))
    predicted = [jax.device_get(predict(params, jnp.asarray(test.images[i:i + 256])))
                 for i in range(0, len(test), 256)]
    predicted_position = np.concatenate([p[0] for p in predicted]) * spread + mean
    predicted_quaternion = np.asarray(quaternions(jnp.asarray(np.concatenate([p[1] for p in predicted]))))
    position_mm = 1000.0 * np.linalg.norm(predicted_position - test.cube_position, axis=-1)
    orientation_deg = orientation_error_degrees(predicted_quaternion, test.cube_quaternion)
    errors = {"position_mm_median": float(np.median(position_mm)),
              "position_mm_p90": float(np.percentile(position_mm, 90)),
              "orientation_deg_median": float(np.median(orientation_deg)),
              "orientation_deg_p90": float(np.percentile(orientation_deg, 90)),
              "test_samples": len(test), "train_samples": len(train)}
    return PretrainResult(jax.device_get(params), errors, history, seconds)
