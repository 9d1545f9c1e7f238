"""Pretrain a visual encoder to see the cube's pose: position and orientation from the cameras' images.

Trains a `PoseNet` (`angora_jax.vision.estimator`: one encoder over every camera's image, a head for the standardised
position and the orientation in one of `ORIENTATIONS`). Loss: mean squared error of the standardised position plus
|R_pred - R|^2 / 8 (Frobenius), which equals 1 - <q_pred, q>^2 for quaternions: it ignores the quaternion's sign.
Adam (optax), its learning rate decaying to zero on a cosine over the steps by default (the small errors that the
orientation bar asks for come in the last, small steps). Reported on held-out episodes: median and 90th-percentile
errors of the position in mm and of the orientation in degrees (the angle of the rotation between prediction and
truth).

The result is a `PoseEstimator` (the whole network, ready to read frames) whose encoder is also a component
(`angora_jax.nets.components`): `save_component(result.params, "encoder", file)` writes it, and a policy's visual
area of the same encoder and sizes loads it with `network.pretrained` and keeps it fixed with `network.frozen`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import optax

from angora_jax.nets.visual import VISUAL_ENCODERS, make_visual_encoder
from angora_jax.ppo.memory import device_memory
from angora_jax.vision.dataset import PoseDataset
from angora_jax.vision.estimator import (
    ORIENTATIONS,
    PoseEstimator,
    PoseNet,
    orientation_error_degrees,
    rotation_matrices,
)
from angora_jax.wording import counted


@dataclass
class PretrainResult:
    """What `pretrain_pose_encoder` returns.

    Attributes:
        estimator: the trained network as a `PoseEstimator`.
        errors: held-out position (mm) and orientation (deg) medians and 90th percentiles.
        history: (step, training loss) every `log_every` steps.
        seconds: wall time of the training.
        learning_rate: the schedule it trained with, in words.
    """

    estimator: PoseEstimator
    errors: dict[str, float]
    history: list[tuple[int, float]] = field(default_factory=list)
    seconds: float = 0.0
    learning_rate: str = ""

    @property
    def params(self) -> Any:
        """The PoseNet's parameters (its encoder under "encoder")."""
        return self.estimator.params


def pose_network(encoder: str = "cornet_z", encoder_options: dict | None = None, orientation: str = "6d",
                 frames: tuple[int, ...] = (1, 64, 64, 3)) -> PoseNet:
    """The `PoseNet` of `encoder` with `encoder_options` (widths, features) and `orientation`, checked on a sample's
    `frames` (cameras, height, width, 3) by tracing its initialisation (nothing is computed): ValueError naming the
    encoder, the options, its defaults and the fix when they do not fit it."""
    if orientation not in ORIENTATIONS:
        raise ValueError(f"Unknown orientation {orientation!r}; choose one of {tuple(ORIENTATIONS)}.")
    options = encoder_options or {}
    model = PoseNet(make_visual_encoder(encoder, **options), orientation=orientation)
    try:
        shapes = jax.eval_shape(model.init, jax.random.key(0), jax.ShapeDtypeStruct((1, *frames), jnp.uint8))
    except (TypeError, ValueError) as error:
        defaults = VISUAL_ENCODERS[encoder]
        given = " and ".join(f"{name} {value}" for name, value in options.items())
        raise ValueError(f"The visual encoder {encoder} does not take {given} ({error}): its default widths are "
                         f"{defaults.widths} (channels of each stage, one number per stage; --widths) and its "
                         f"features {defaults.features} (--features).") from None
    size = sum(leaf.size * leaf.dtype.itemsize for leaf in jax.tree.leaves(shapes))
    device = jax.devices()[0]
    memory = device_memory(device)
    if memory is not None and 4 * size > memory:  # parameters, gradients and Adam's two moments
        raise ValueError(f"The pose network's parameters take {size / 1e9:,.1f} GB, four times that with their "
                         f"gradients and Adam's moments, more than the {device.platform} device's "
                         f"{memory / 1e9:,.0f} GB: give fewer features (--features) or smaller widths (--widths).")
    return model


def pretrain_pose_encoder(train: PoseDataset, test: PoseDataset, encoder: str = "cornet_z",
                          encoder_options: dict | None = None, steps: int = 2000, batch_size: int = 64,
                          learning_rate: float = 1e-3, seed: int = 0, log_every: int = 100,
                          orientation: str = "6d", decay: bool = True) -> PretrainResult:
    """Train `PoseNet(make_visual_encoder(encoder, **encoder_options), orientation=orientation)` on `train` for
    `steps` Adam steps of `batch_size` samples and measure it on `test` (module docstring).

    Args:
        decay: the learning rate falls from `learning_rate` to zero on a cosine (False: it stays constant).
    """
    model = pose_network(encoder, encoder_options, orientation, train.images.shape[1:])
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
    estimator = PoseEstimator(jax.device_get(params), encoder, dict(encoder_options or {}), orientation,
                              train.cameras, train.images.shape[-2], mean.astype(np.float32),
                              spread.astype(np.float32), train.renderer)
    predict = jax.jit(estimator.__call__)
    predicted = [jax.device_get(predict(jnp.asarray(test.images[i:i + 256]))) for i in range(0, len(test), 256)]
    predicted_position = np.concatenate([p[0] for p in predicted])
    predicted_quaternion = np.concatenate([p[1] for p in predicted])
    position_mm = 1000.0 * np.linalg.norm(predicted_position - test.cube_position, axis=-1)
    orientation_deg = orientation_error_degrees(predicted_quaternion, test.cube_quaternion)
    errors = {"position_mm_median": float(np.median(position_mm)),
              "position_mm_p90": float(np.percentile(position_mm, 90)),
              "orientation_deg_median": float(np.median(orientation_deg)),
              "orientation_deg_p90": float(np.percentile(orientation_deg, 90)),
              "test_samples": len(test), "train_samples": len(train)}
    schedule = (f"{learning_rate:g}, cosine decay to 0 over {counted(steps, 'step')}" if decay else
                f"{learning_rate:g}, constant")
    return PretrainResult(estimator, errors, history, seconds, schedule)
