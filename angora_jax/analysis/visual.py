"""Inside the visual area of an agent that sees camera images (`ppo.network.visual`: `cornet_z` or `impala`):
what its first layer filters for, what each layer's feature maps show of given frames, which pixels its outputs
depend on (gradient saliency) and which images its units prefer (activation maximization with jitter and blur, as
Lucid regularizes it). The question these answer: does the encoder attend to the cube's edges and faces, or to the
fingers?

    images = recording["input_vision"].values[0, :4, 0]               # (4, height, width, 3) uint8, one camera
    filters = first_layer_filters(agent)                               # (filters, kh, kw, 3)
    maps = feature_maps(agent, images)                                  # layer -> (4, h, w, channels)
    where = saliency(agent, images, unit=3)                             # (4, height, width), |d feature 3 / d pixel|
    found, trace = preferred_stimuli(agent, "V4", units=[0, 1])        # (2, height, width, 3) uint8, (2, steps)
"""

from __future__ import annotations

from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import optax
import xarray as xr

from angora_jax.experiment.agent import Agent
from angora_jax.nets.visual import make_visual_area


def visual_area(agent: Agent) -> tuple[nn.Module, Any]:
    """The agent's visual area module and its parameters; ValueError for an agent without one."""
    module = make_visual_area(agent.config.ppo.network.visual)
    if module is None or "visual" not in agent.params:
        raise ValueError(f"The agent ({agent.config.env.task}, network {agent.config.ppo.network.name}) has no visual "
                         "area: these analyses need a run that sees camera images (ppo.network.visual).")
    return module, agent.params["visual"]


def conv_layers(agent: Agent) -> list[str]:
    """Names of the visual area's convolutions in the order images pass them (e.g. V1, V2, V4, IT for cornet_z)."""
    return list(_convolutions(agent, jnp.zeros((1, *_camera_size(agent), 3), jnp.uint8)))


def _convolutions(agent: Agent, images: jax.Array) -> dict[str, jax.Array]:
    """Each convolution's output for `images`, in the order of the calls, not of the parameters: a restored
    checkpoint holds them sorted by name (IT before V1). Applied eagerly, since JAX's tree functions would sort the
    captured layers by name too."""
    module, params = visual_area(agent)
    _, captured = module.apply({"params": params}, images, capture_intermediates=True, mutable=["intermediates"])
    return {name: outputs["__call__"][0] for name, outputs in captured["intermediates"].items()
            if np.ndim(params.get(name, {}).get("kernel", 0)) == 4}


def _camera_size(agent: Agent) -> tuple[int, int]:
    """(height, width) of the agent's camera images (64 x 64 where its config names none)."""
    vision = agent.config.env.options.get("vision") or {}
    return vision.get("height", 64), vision.get("width", 64)


def first_layer_filters(agent: Agent) -> np.ndarray:
    """The first convolution's kernels as images, `(filters, kh, kw, 3)` float (weights per colour channel)."""
    _, params = visual_area(agent)
    kernel = np.asarray(params[conv_layers(agent)[0]]["kernel"])  # (kh, kw, 3, filters)
    return np.moveaxis(kernel, -1, 0)


def feature_maps(agent: Agent, images: np.ndarray) -> dict[str, np.ndarray]:
    """Each convolution's output (before its ReLU) for `images` `(N, height, width, 3)` uint8: layer ->
    `(N, h, w, channels)`."""
    return {name: np.asarray(output) for name, output in _convolutions(agent, jnp.asarray(images)).items()}


def saliency(agent: Agent, images: np.ndarray, unit: int | None = None,
             readout: np.ndarray | None = None) -> np.ndarray:
    """Gradient saliency: |d output / d pixel| for `images` `(N, height, width, 3)` uint8, the largest over colour
    channels, `(N, height, width)` per pixel value (0-255). output: feature `unit` of the visual area's output
    `(features,)`, or `features @ readout` for a readout vector `(features,)` (e.g. a decoder's weights for a task
    variable). Give exactly one of them."""
    if (unit is None) == (readout is None):
        raise ValueError("Give exactly one of unit (a feature of the visual area) or readout (a vector over them).")
    module, params = visual_area(agent)
    features = module.apply({"params": params}, jnp.zeros((1, *np.shape(images)[1:]), jnp.uint8)).shape[-1]
    weights = jax.nn.one_hot(unit, features) if readout is None else jnp.asarray(readout, jnp.float32)
    if weights.shape != (features,) or (unit is not None and not 0 <= unit < features):
        shape = None if readout is None else weights.shape
        raise ValueError(f"The visual area has {features} features: unit must be in [0, {features}) and readout "
                         f"shaped ({features},), got unit {unit}, readout {shape}.")

    # Float pixels: the encoder scales any dtype the same way, and gradients need floats.
    return gradient_saliency(lambda pixels: module.apply({"params": params}, pixels) @ weights, images)


def gradient_saliency(output, images: np.ndarray) -> np.ndarray:
    """|d output / d pixel|, the largest over colour channels, `(N, height, width)`, for `output(pixels) -> (N,)`
    (each image's own output) and `images` `(N, height, width, 3)`, differentiated as float pixel values."""
    gradient = jax.grad(lambda pixels: output(pixels).sum())(jnp.asarray(images, jnp.float32))
    return np.asarray(jnp.abs(gradient).max(axis=-1))


def preferred_stimuli(agent: Agent, layer: str, units: list[int] | np.ndarray, size: tuple[int, int] | None = None,
                      steps: int = 256, learning_rate: float = 0.05, jitter: int = 2, blur: float = 0.5,
                      seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """The image that most activates each of `units` (channels) of convolution `layer` (the channel's mean over
    positions), or of the visual area's output when `layer` is "output": gradient ascent from faint noise on an
    unconstrained image mapped to 0-255 by a sigmoid, each step seeing it shifted by up to `jitter` pixels and then
    blurred by `blur` (the share of each pixel replaced by its 3 x 3 neighbourhood's mean), the regularizers Lucid
    uses against high-frequency patterns. All units are optimized at once, in one compiled program. size: (height,
    width), default the agent's camera images. Returns the images `(units, height, width, 3)` uint8 and the
    activation at each step `(units, steps)`."""
    module, params = visual_area(agent)
    if layer != "output" and layer not in conv_layers(agent):
        raise ValueError(f"No convolution {layer!r} in the visual area; choose one of {conv_layers(agent)} or "
                         "'output'.")
    height, width = size or _camera_size(agent)
    units = np.asarray(units, int)

    def activations(pixels: jax.Array) -> jax.Array:
        out, captured = module.apply({"params": params}, pixels[None], capture_intermediates=True,
                                     mutable=["intermediates"])
        return out[0] if layer == "output" else captured["intermediates"][layer]["__call__"][0][0].mean(axis=(0, 1))

    count = jax.eval_shape(activations, jnp.zeros((height, width, 3))).shape[-1]
    if units.ndim != 1 or not ((units >= 0) & (units < count)).all():
        raise ValueError(f"{layer} has {count} units; units must be a list of indices in [0, {count}), got "
                         f"{units.tolist()}.")
    optimizer = optax.adam(learning_rate)
    kernel = jnp.full((3, 3), 1.0 / 9.0)
    smooth = jax.vmap(lambda c: jax.scipy.signal.convolve2d(c, kernel, mode="same"), in_axes=2, out_axes=2)

    def ascend(unit: jax.Array, key: jax.Array) -> tuple[jax.Array, jax.Array]:
        def activation(logits, shift):
            return activations(jnp.roll(255.0 * jax.nn.sigmoid(logits), shift, axis=(0, 1)))[unit]

        def step(carry, key):
            logits, state = carry
            value, gradient = jax.value_and_grad(activation)(logits, jax.random.randint(key, (2,), -jitter, jitter + 1))
            updates, state = optimizer.update(-gradient, state)  # ascent
            logits = optax.apply_updates(logits, updates)
            return ((1.0 - blur) * logits + blur * smooth(logits), state), value

        start, key = jax.random.split(key)
        logits = 0.1 * jax.random.normal(start, (height, width, 3))
        (logits, _), trace = jax.lax.scan(step, (logits, optimizer.init(logits)), jax.random.split(key, steps))
        return 255.0 * jax.nn.sigmoid(logits), trace

    keys = jax.random.split(jax.random.key(seed), len(units))
    images, traces = jax.jit(jax.vmap(ascend))(jnp.asarray(units), keys)
    return np.asarray(images).round().astype(np.uint8), np.asarray(traces)


def visual_analysis(agent: Agent, images: np.ndarray, units: int = 4, steps: int = 256,
                    layers: list[str] | None = None) -> xr.Dataset:
    """All of the above for `images` `(N, height, width, 3)` uint8 as one Dataset: `filters`, the last
    convolution's mean feature map per image (`last_map`), the saliency of each of the first `units` output features
    (`saliency`, image x unit x y x x) and the preferred stimulus of each of the first `units` channels of each of
    `layers` (default: every convolution; `preferred`, layer x unit x y x x x rgb) with its final activation
    (`preferred_activation`); images (`preferred`, `frames`) hold 0-255 as int16."""
    images = np.asarray(images)
    if images.ndim != 4 or images.shape[-1] != 3 or images.dtype != np.uint8:
        raise ValueError(f"images must be (N, height, width, 3) uint8 camera frames, got {images.shape} "
                         f"{images.dtype}; take them from a recording made with angora-jax record --images.")
    convolutions = conv_layers(agent)
    layers = list(layers or convolutions)
    maps = feature_maps(agent, images)
    filters = first_layer_filters(agent)
    where = np.stack([saliency(agent, images, unit=u) for u in range(units)], axis=1)
    preferred = [preferred_stimuli(agent, layer, range(units), images.shape[1:3], steps) for layer in layers]
    last = maps[convolutions[-1]].mean(axis=-1)
    # Images as int16 (values 0-255): NetCDF 3, which `angora-jax analyze` writes, has no unsigned bytes.
    return xr.Dataset(
        {
            "filters": (("filter", "ky", "kx", "rgb"), filters),
            "last_map": (("image", "my", "mx"), last),
            "saliency": (("image", "unit", "y", "x"), where),
            "preferred": (("layer", "unit", "y", "x", "rgb"),
                          np.stack([found for found, _ in preferred]).astype(np.int16)),
            "preferred_activation": (("layer", "unit"), np.stack([trace[:, -1] for _, trace in preferred])),
            "frames": (("image", "y", "x", "rgb"), images.astype(np.int16)),
        },
        coords={"layer": layers, "unit": np.arange(units)},
        attrs={"last_layer": convolutions[-1]},
    )


def plot_visual(result: xr.Dataset, path: str) -> None:
    """One figure: the first layer's filters, each frame with its saliency (the first unit) and its last feature
    map, and each layer's preferred stimuli."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    filters = result["filters"].values
    frames = result["frames"].values
    preferred = result["preferred"].values
    rows = 1 + len(frames) + len(result["layer"])
    columns = max(3, min(len(filters), 8), preferred.shape[1])
    figure, axes = plt.subplots(rows, columns, figsize=(1.8 * columns, 1.8 * rows), squeeze=False)
    for ax in axes.flat:
        ax.axis("off")
    for i, kernel in enumerate(filters[:columns]):
        low, high = kernel.min(), kernel.max()
        axes[0, i].imshow((kernel - low) / (high - low + 1e-12))
        axes[0, i].set_title(f"filter {i}", fontsize=7)
    for r, frame in enumerate(frames, start=1):
        axes[r, 0].imshow(frame)
        axes[r, 0].set_title("frame", fontsize=7)
        axes[r, 1].imshow(result["saliency"].values[r - 1, 0], cmap="magma")
        axes[r, 1].set_title("saliency, unit 0", fontsize=7)
        axes[r, 2].imshow(result["last_map"].values[r - 1], cmap="viridis")
        axes[r, 2].set_title(f"{result.attrs['last_layer']} mean map", fontsize=7)
    for r, layer in enumerate(result["layer"].values, start=1 + len(frames)):
        for u in range(preferred.shape[1]):
            axes[r, u].imshow(preferred[r - 1 - len(frames), u])
            axes[r, u].set_title(f"{layer} unit {u}", fontsize=7)
    figure.tight_layout()
    figure.savefig(path, dpi=100)
    plt.close(figure)
