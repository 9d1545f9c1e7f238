"""Visual encoders: camera images to a feature vector, for a visual cortical area, pose estimation or a policy.

Images enter as uint8 `(B, height, width, 3)` (as rendered and stored); the encoder scales them to [-0.5, 0.5]
itself, so rollouts and datasets keep pixels in uint8. Both encoders work at any resolution from 32 x 32 on.

- `cornet_z`: CORnet-Z (Kubilius et al. 2018), the feed-forward core of AngoraPy's visual component: areas V1, V2,
  V4 and IT, each a convolution, ReLU and max-pooling; global average pooling and a dense map to `features`.
- `impala`: the IMPALA ResNet (Espeholt et al. 2018) used by RL agents that see pixels: per stack a convolution,
  max-pooling and two residual blocks; a dense map to `features`.
"""

from __future__ import annotations

from collections.abc import Callable

import flax.linen as nn
import jax
import jax.numpy as jnp


def _pixels(images: jax.Array) -> jax.Array:
    return images.astype(jnp.float32) / 255.0 - 0.5


class CorNetZ(nn.Module):
    """CORnet-Z: V1 (7x7 stride 2), V2, V4, IT (3x3), each ReLU + 3x3/2 max-pool; `(B, H, W, 3)` -> `(B, features)`."""

    widths: tuple[int, int, int, int] = (32, 64, 128, 256)
    features: int = 256

    @nn.compact
    def __call__(self, images: jax.Array) -> jax.Array:
        x = _pixels(images)
        for name, width, kernel, stride in zip(("V1", "V2", "V4", "IT"), self.widths, (7, 3, 3, 3), (2, 1, 1, 1),
                                               strict=True):
            x = nn.relu(nn.Conv(width, (kernel, kernel), strides=stride, name=name)(x))
            x = nn.max_pool(x, (3, 3), strides=(2, 2), padding="SAME")
        return nn.Dense(self.features, name="decoder")(x.mean(axis=(-3, -2)))


class Impala(nn.Module):
    """IMPALA ResNet: stacks of conv 3x3, max-pool 3x3/2, two residual blocks; `(B, H, W, 3)` -> `(B, features)`."""

    widths: tuple[int, ...] = (16, 32, 32)
    features: int = 256

    @nn.compact
    def __call__(self, images: jax.Array) -> jax.Array:
        x = _pixels(images)
        for width in self.widths:
            x = nn.max_pool(nn.Conv(width, (3, 3))(x), (3, 3), strides=(2, 2), padding="SAME")
            for _ in range(2):
                x = x + nn.Conv(width, (3, 3))(nn.relu(nn.Conv(width, (3, 3))(nn.relu(x))))
        return nn.relu(nn.Dense(self.features)(nn.relu(x).reshape(x.shape[:-3] + (-1,))))


VISUAL_ENCODERS: dict[str, Callable[..., nn.Module]] = {"cornet_z": CorNetZ, "impala": Impala}


def make_visual_area(config) -> nn.Module | None:
    """The visual encoder a `VisualConfig` describes (None for None); ValueError for an unknown encoder or sizes."""
    if config is None:
        return None
    if config.features < 1 or any(width < 1 for width in config.widths):
        raise ValueError(f"network.visual sizes must be >= 1, got widths {config.widths}, features {config.features}.")
    return make_visual_encoder(config.encoder, features=config.features,
                               **({"widths": tuple(config.widths)} if config.widths else {}))


def make_visual_encoder(name: str, **options) -> nn.Module:
    """The visual encoder `name` ("cornet_z" or "impala") with its `options` (widths, features)."""
    if name not in VISUAL_ENCODERS:
        raise ValueError(f"Unknown visual encoder {name!r}; choose one of {sorted(VISUAL_ENCODERS)}.")
    return VISUAL_ENCODERS[name](**options)
