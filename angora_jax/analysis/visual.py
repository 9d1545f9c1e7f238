"""Inside the visual area of an agent that sees camera images (`ppo.network.visual`: `cornet_z` or `impala`), or
of a trained cube `PoseEstimator` (OpenAI's Dactyl route: its encoder, shared by its cameras, is the visual system
of a policy that reads the estimated pose): what its first layer filters for, what each layer's feature maps show of
given frames, which pixels its outputs depend on (gradient saliency; for an estimator also of the pose it reads,
`pose_saliency`) and which images its units prefer (activation maximization with jitter and blur, as Lucid
regularizes it). The question these answer: does the encoder attend to the cube's edges and faces, or to the
fingers? `saliency_share` measures it against a cube mask (`angora_jax.vision.cube_masks`, `mask_edges`).

    images = recording["input_vision"].values[0, :4, 0]               # (4, height, width, 3) uint8, one camera
    filters = first_layer_filters(agent)                               # (filters, kh, kw, 3)
    maps = feature_maps(agent, images)                                  # layer -> (4, h, w, channels)
    where = saliency(agent, images, unit=3)                             # (4, height, width), |d feature 3 / d pixel|
    found, trace = preferred_stimuli(agent, "V4", units=[0, 1])        # (2, height, width, 3) uint8, (2, steps)

    estimator = PoseEstimator.load("encoder.pose.msgpack")             # each function above takes it for agent
    where = pose_saliency(estimator, frames, "orientation")           # (N, cameras, H, W, 3) -> (N, cameras, H, W)
    on_cube = saliency_share(where, masks)                              # (N, cameras); chance: masks' pixel share
"""

from __future__ import annotations

import functools
from typing import Any, Literal

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import optax
import scipy.ndimage
import xarray as xr

from angora_jax.analysis.decoding import plot_path
from angora_jax.analysis.units import as_scalar, checked_units, is_unit, unit_range
from angora_jax.experiment.agent import Agent, check_agent
from angora_jax.experiment.config import ConfigError, check_count, check_number, check_seed
from angora_jax.nets.visual import make_visual_area, make_visual_encoder
from angora_jax.vision.estimator import PoseEstimator
from angora_jax.wording import counted

# What these analyses look inside: an agent with a visual area, or a pose estimator (its encoder).
Seer = Agent | PoseEstimator


def check_seer(seer: object) -> None:
    """TypeError naming what to do when `seer` is neither a PoseEstimator nor what these analyses read of an agent,
    its `config` and `params` (an Agent, or a stand-in holding those two): a run directory, an exported Policy or a
    recording given for it failed with AttributeError ('str' object has no attribute 'config')."""
    if isinstance(seer, PoseEstimator) or (hasattr(seer, "config") and hasattr(seer, "params")):
        return
    try:
        check_agent(seer)
    except TypeError as error:
        raise TypeError(f"{error} A pose estimator's file is read with angora_jax.vision.PoseEstimator.load(FILE), "
                        "which this analysis takes too.") from None


def _visual_system(seer: Seer) -> tuple[nn.Module, Any, tuple[int, int]]:
    """The encoder module that `seer` sees with, its parameters and the (height, width) of the camera images it
    reads (an agent's: 64 x 64 where its config names none); ValueError for an agent without a visual area,
    TypeError for what is neither an agent nor an estimator (`check_seer`)."""
    check_seer(seer)
    if isinstance(seer, PoseEstimator):
        return make_visual_encoder(seer.encoder, **seer.encoder_options), seer.params["encoder"], (seer.size,) * 2
    module = make_visual_area(seer.config.ppo.network.visual)
    if module is None or "visual" not in seer.params:
        raise ValueError(f"The agent ({seer.config.env.task}, network {seer.config.ppo.network.name}) has no visual "
                         "area: these analyses need a run that sees camera images (ppo.network.visual), or a "
                         "PoseEstimator.")
    vision = seer.config.env.options.get("vision") or {}
    return module, seer.params["visual"], (vision.get("height", 64), vision.get("width", 64))


def visual_area(seer: Seer) -> tuple[nn.Module, Any]:
    """The visual area module and its parameters: an agent's (`ppo.network.visual`) or a pose estimator's encoder;
    ValueError for an agent without one."""
    module, params, _ = _visual_system(seer)
    return module, params


def conv_layers(seer: Seer) -> list[str]:
    """Names of the visual area's convolutions in the order images pass them (e.g. V1, V2, V4, IT for cornet_z)."""
    return list(_convolutions(seer, jnp.zeros((1, *_visual_system(seer)[2], 3), jnp.uint8)))


def _convolutions(seer: Seer, images: jax.Array) -> dict[str, jax.Array]:
    """Each convolution's output for `images`, in the order of the calls, not of the parameters: a restored
    checkpoint holds them sorted by name (IT before V1). Applied eagerly, since JAX's tree functions would sort the
    captured layers by name too."""
    module, params = visual_area(seer)
    _, captured = module.apply({"params": params}, images, capture_intermediates=True, mutable=["intermediates"])
    return {name: outputs["__call__"][0] for name, outputs in captured["intermediates"].items()
            if np.ndim(params.get(name, {}).get("kernel", 0)) == 4}


def first_layer_filters(seer: Seer) -> np.ndarray:
    """The first convolution's kernels as images, `(filters, kh, kw, 3)` float (weights per colour channel)."""
    _, params = visual_area(seer)
    kernel = np.asarray(params[conv_layers(seer)[0]]["kernel"])  # (kh, kw, 3, filters)
    return np.moveaxis(kernel, -1, 0)


def feature_maps(seer: Seer, images: np.ndarray) -> dict[str, np.ndarray]:
    """Each convolution's output (before its ReLU) for `images` `(N, height, width, 3)` uint8 (one camera's frames,
    or any cameras' stacked: the encoder sees each image alone): layer -> `(N, h, w, channels)`."""
    return {name: np.asarray(output) for name, output in _convolutions(seer, jnp.asarray(images)).items()}


def saliency(seer: Seer, images: np.ndarray, unit: int | None = None,
             readout: np.ndarray | None = None) -> np.ndarray:
    """Gradient saliency: |d output / d pixel| for `images` `(N, height, width, 3)` uint8, the largest over colour
    channels, `(N, height, width)` per pixel value (0-255). output: feature `unit` of the visual area's output
    `(features,)`, or `features @ readout` for a readout vector `(features,)` (e.g. a decoder's weights for a task
    variable). Give exactly one of them: `unit` a whole number from 0 to the output's count of units less 1.
    ConfigError for a unit or readout that is none, before any gradient (unit=1.5 gave a map of zeros)."""
    if (unit is None) == (readout is None):
        raise ConfigError("Give exactly one of unit (a feature of the visual area) or readout (a vector over them).")
    module, params = visual_area(seer)
    features = module.apply({"params": params}, jnp.zeros((1, *np.shape(images)[1:]), jnp.uint8)).shape[-1]
    if readout is None:
        unit = as_scalar(unit)
        if not is_unit(unit, features):
            raise ConfigError(f"unit must be a whole number {unit_range('output', features)}, got {unit!r}.")
        weights = jax.nn.one_hot(unit, features)
    else:
        try:
            weights = jnp.asarray(np.asarray(readout, np.float32))
        except (TypeError, ValueError):  # text, a ragged list
            weights = None
        if weights is None or weights.shape != (features,):
            got = repr(readout) if weights is None else f"shape {weights.shape}"
            raise ConfigError(f"readout must be numbers shaped ({features},), a weight for each of the output's "
                              f"{counted(features, 'unit')}, got {got}.")

    # Float pixels: the encoder scales any dtype the same way, and gradients need floats.
    return gradient_saliency(lambda pixels: module.apply({"params": params}, pixels) @ weights, images)


def gradient_saliency(output, images: np.ndarray) -> np.ndarray:
    """|d output / d pixel|, the largest over colour channels, `(N, ..., height, width)`, for `images`
    `(N, ..., height, width, 3)` (e.g. several cameras per sample) differentiated as float pixel values and
    `output(pixels)` `(N,)`, each sample's own output, or `(N, K)`, K outputs of each sample, of which the largest
    gradient counts."""
    pixels = jnp.asarray(images, jnp.float32)
    # Summed over samples: each sample's outputs depend on its own pixels alone, so one backward pass per output
    # gives every sample's gradient.
    gradient = jax.jacrev(lambda pixels: output(pixels).sum(axis=0))(pixels)  # ((K,) N, ..., 3)
    return np.asarray(jnp.abs(gradient).max(axis=-1).reshape(-1, *pixels.shape[:-1]).max(axis=0))


def pose_saliency(estimator: PoseEstimator, frames: np.ndarray,
                  output: Literal["orientation", "position"] = "orientation") -> np.ndarray:
    """Which pixels the pose an estimator reads depends on: |d output / d pixel| for `frames`
    `(N, cameras, height, width, 3)` uint8 (its cameras, in its order), the largest over colour channels and over the
    output's components, `(N, cameras, height, width)` per pixel value (0-255). output "position": the network's 3
    standardised position outputs (metres over the training set's spread, about 12 mm here). "orientation": the 9
    entries of the rotation matrix the head's outputs map to, not the outputs themselves: the map normalises them
    (Gram-Schmidt for "6d", a unit quaternion), so a change of their length, or of the second 3-vector along the
    first, changes no orientation; the matrix's entries move only with the orientation read, on the same scale (-1
    to 1) whichever representation the head was trained in."""
    if output not in ("orientation", "position"):
        raise ValueError(f"output must be 'orientation' or 'position', got {output!r}.")
    if not isinstance(estimator, PoseEstimator):
        raise TypeError(f"pose_saliency takes a PoseEstimator (angora_jax.vision.PoseEstimator.load(FILE)), got "
                        f"{type(estimator).__name__}; for an agent's visual area: saliency(agent, images, unit=...).")
    frames = np.asarray(frames)
    estimator.check_frames(frames)
    network, which = estimator.network(), ("position", "orientation").index(output)

    def pose(pixels: jax.Array) -> jax.Array:
        return network.apply({"params": estimator.params}, pixels)[which].reshape(len(pixels), -1)

    return gradient_saliency(pose, frames)


def saliency_share(saliency: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """The share of each image's saliency (or any non-negative map, e.g. a feature map resized to the image) that
    lies in `mask`: `saliency` `(N, ..., height, width)` and a bool `mask` of the same shape (or one that broadcasts)
    -> `(N, ...)`, between 0 and 1; NaN for an image without saliency. Chance, for saliency spread evenly, is the
    mask's share of pixels, `mask.mean(axis=(-2, -1))`."""
    saliency = np.asarray(saliency, np.float64)
    total = saliency.sum(axis=(-2, -1))
    with np.errstate(invalid="ignore", divide="ignore"):
        return (saliency * mask).sum(axis=(-2, -1)) / total


def mask_edges(mask: np.ndarray) -> np.ndarray:
    """The edge pixels of each image's mask, `(..., height, width)` bool: the mask less its binary erosion (3 x 3)
    within the image; the image's border is not an edge (a cube cut off by the frame has no edge there)."""
    mask = np.asarray(mask, bool)
    structure = np.ones((1,) * (mask.ndim - 2) + (3, 3), bool)
    return mask & ~scipy.ndimage.binary_erosion(mask, structure, border_value=1)


def preferred_stimuli(seer: Seer, layer: str, units: list[int] | np.ndarray, size: tuple[int, int] | None = None,
                      steps: int = 256, learning_rate: float = 0.05, jitter: int = 2, blur: float = 0.5,
                      seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """The image that most activates each of `units` (channels) of convolution `layer` (the channel's mean over
    positions), or of the visual area's output when `layer` is "output": gradient ascent from faint noise on an
    unconstrained image mapped to 0-255 by a sigmoid, each step seeing it shifted by up to `jitter` pixels and then
    blurred by `blur` (the share of each pixel replaced by its 3 x 3 neighbourhood's mean), the regularizers Lucid
    uses against high-frequency patterns. All units are optimized at once, in one compiled program.

    Args:
        units: channel indices of `layer` (features of the output), one or more whole numbers from 0 to its count
            less 1; a unit given twice ascends from two starts.
        size: (height, width), default that of the camera images `seer` reads.
        steps: ascent steps, at least 1.
        learning_rate: Adam's step size, above 0.
        jitter: the largest shift, whole pixels (0: none).
        blur: 0 to 1.
        seed: a whole number from 0 to 2**32 - 1.

    Returns:
        The images `(units, height, width, 3)` uint8 and the activation at each step `(units, steps)`.
    """
    images, traces = _preferred_stimuli(seer, [layer], units, size, steps, learning_rate, jitter, blur, seed)
    return images[0], traces[0]


def _preferred_stimuli(seer: Seer, layers: list[str], units: Any, size: tuple[int, int] | None = None,
                       steps: int = 256, learning_rate: float = 0.05, jitter: int = 2, blur: float = 0.5,
                       seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """`preferred_stimuli` (its defaults) of the same `units` of each of `layers`, from the same starts, in one
    compiled program: the images `(layers, units, height, width, 3)` uint8 and the traces `(layers, units, steps)`,
    each layer's as `preferred_stimuli` finds them alone. `visual_analysis` asks for every layer's: one program for
    them all, rather than one a layer, cut its CPU time by a quarter to a third (CORnet-Z's 4 layers, 2 cores)."""
    if size is not None:
        if not isinstance(size, tuple | list | np.ndarray) or len(size) != 2:
            raise ConfigError(f"size must be (height, width) in pixels, e.g. (64, 64), got {size!r}.")
        size = (check_count("size[0] (height)", size[0]), check_count("size[1] (width)", size[1]))
    steps, jitter = check_count("steps", steps), check_count("jitter", jitter, least=0)
    learning_rate = check_number("learning_rate", learning_rate, 0.0, open_low=True)
    blur, seed = check_number("blur", blur, 0.0, 1.0), check_seed("seed", seed)
    module, params, camera = _visual_system(seer)
    convolutions = conv_layers(seer)
    for layer in layers:
        _check_layer(layer, convolutions)
    height, width = size or camera

    def activations(pixels: jax.Array, layer: str) -> jax.Array:
        out, captured = module.apply({"params": params}, pixels[None], capture_intermediates=True,
                                     mutable=["intermediates"])
        return out[0] if layer == "output" else captured["intermediates"][layer]["__call__"][0][0].mean(axis=(0, 1))

    for layer in layers:
        count = jax.eval_shape(functools.partial(activations, layer=layer), jnp.zeros((height, width, 3))).shape[-1]
        units = checked_units(units, layer, count)
    optimizer = optax.adam(learning_rate)
    kernel = jnp.full((3, 3), 1.0 / 9.0)
    smooth = jax.vmap(lambda c: jax.scipy.signal.convolve2d(c, kernel, mode="same"), in_axes=2, out_axes=2)

    def ascend(layer: str, unit: jax.Array, key: jax.Array) -> tuple[jax.Array, jax.Array]:
        def activation(logits, shift):
            return activations(jnp.roll(255.0 * jax.nn.sigmoid(logits), shift, axis=(0, 1)), layer)[unit]

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

    @jax.jit
    def every_layer(units: jax.Array, keys: jax.Array) -> tuple[jax.Array, jax.Array]:
        found = [jax.vmap(functools.partial(ascend, layer))(units, keys) for layer in layers]
        return jnp.stack([images for images, _ in found]), jnp.stack([trace for _, trace in found])

    images, traces = every_layer(jnp.asarray(units), jax.random.split(jax.random.key(seed), len(units)))
    return np.asarray(images).round().astype(np.uint8), np.asarray(traces)


def _check_layer(layer: object, convolutions: list[str]) -> None:
    """ConfigError unless `layer` is one of `convolutions` (the visual area's, in order) or "output": the words of
    every analysis that takes a layer."""
    if layer != "output" and layer not in convolutions:
        raise ConfigError(f"No convolution {layer!r} in the visual area; choose one of {convolutions} or 'output'.")


def _unit_counts(seer: Seer, layers: list[str], size: tuple[int, int]) -> dict[str, int]:
    """The units of the visual area's output (its features, as "output") and of each of `layers` (a convolution's
    channels, from its kernel's shape), for images of `size` (height, width): from shapes alone, nothing runs."""
    module, params = visual_area(seer)
    output = jax.eval_shape(lambda pixels: module.apply({"params": params}, pixels),
                            jax.ShapeDtypeStruct((1, *size, 3), jnp.uint8)).shape[-1]
    return {"output": output, **{layer: output if layer == "output" else int(np.shape(params[layer]["kernel"])[-1])
                                 for layer in layers}}


def visual_analysis(seer: Seer, images: np.ndarray, units: int = 4, steps: int = 256,
                    layers: list[str] | None = None) -> xr.Dataset:
    """All of the above but `pose_saliency` for `images` `(N, height, width, 3)` uint8 (for several cameras, their
    frames stacked) as one Dataset: `filters`, the last
    convolution's mean feature map per image (`last_map`), the saliency of each of the first `units` output features
    (`saliency`, image x unit x y x x) and the preferred stimulus of each of the first `units` channels of each of
    `layers` (default: every convolution; `preferred`, layer x unit x y x x x rgb) with its final activation
    (`preferred_activation`); images (`preferred`, `frames`) hold 0-255 as int16.

    `units` is a whole number from 1 to the fewest units of the output and of `layers`, `steps` (of each preferred
    stimulus's ascent) one of at least 1: checked, with `layers`, before anything is computed (ConfigError)."""
    units, steps = check_count("units", units), check_count("steps", steps)
    images = np.asarray(images)
    if images.ndim != 4 or images.shape[-1] != 3 or images.dtype != np.uint8:
        raise ValueError(f"images must be (N, height, width, 3) uint8 camera frames, got {images.shape} "
                         f"{images.dtype}; take them from a recording made with angora-jax record --images.")
    convolutions = conv_layers(seer)
    layers = [layers] if isinstance(layers, str) else list(layers or convolutions)
    for layer in layers:
        _check_layer(layer, convolutions)
    counts = _unit_counts(seer, layers, images.shape[1:3])
    if units > min(counts.values()):
        shown = ", ".join(f"{layer} {count}" for layer, count in counts.items())
        raise ConfigError(f"units must be a whole number from 1 to {min(counts.values())}, got {units}: the analysis "
                          f"shows that many units of the output and of each layer (their units: {shown}).")
    maps = feature_maps(seer, images)
    filters = first_layer_filters(seer)
    where = np.stack([saliency(seer, images, unit=u) for u in range(units)], axis=1)
    found, traces = _preferred_stimuli(seer, layers, range(units), images.shape[1:3], steps)
    last = maps[convolutions[-1]].mean(axis=-1)
    # Images as int16 (values 0-255): NetCDF 3, which `angora-jax analyze` writes, has no unsigned bytes.
    return xr.Dataset(
        {
            "filters": (("filter", "ky", "kx", "rgb"), filters),
            "last_map": (("image", "my", "mx"), last),
            "saliency": (("image", "unit", "y", "x"), where),
            "preferred": (("layer", "unit", "y", "x", "rgb"), found.astype(np.int16)),
            "preferred_activation": (("layer", "unit"), traces[:, :, -1]),
            "frames": (("image", "y", "x", "rgb"), images.astype(np.int16)),
        },
        coords={"layer": layers, "unit": np.arange(units)},
        attrs={"last_layer": convolutions[-1]},
    )


def plot_visual(result: xr.Dataset, path: str) -> None:
    """One figure: the first layer's filters, each frame with its saliency (the first unit) and its last feature
    map, and each layer's preferred stimuli."""
    plot_path("plot_visual", result, "layer", "visual_analysis", path)
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
