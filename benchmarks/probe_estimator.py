"""Inside the visual system of a trained cube pose estimator (OpenAI's Dactyl route: the estimator reads the cube's
pose from camera frames and a policy acts on that pose, so its encoder, shared by its cameras, is the visual system
of a pixel agent). Does the encoder attend to the cube's edges and faces, or to the fingers? On frames of held-out
poses with their cube masks, it times and reports: the visual analysis of the encoder (first-layer filters, feature
maps, preferred stimuli of the first units of each convolution; `analysis.visual_analysis`, compile, then again);
the saliency of the pose read (`analysis.pose_saliency`, orientation and position, compile, then again) and, per
camera, the share of that saliency on the cube and on its edges against the share of pixels they cover (chance, for
saliency spread evenly), and the same share of the last convolution's mean feature map (after its ReLU, each cell
spread over the pixels it covers).

Frames come from an NPZ (`images` `(N, cameras, H, W, 3)` uint8 in the estimator's camera order and `no_cube`, the
same poses rendered with the cube out of view; `cube_position`, `cube_quaternion`, `hand_qpos` are kept if there) or
are rendered here with the estimator's renderer (`vision.render_pose_dataset` and `vision.cube_masks`; OpenGL on a
CPU, Warp needs a GPU):

    python benchmarks/probe_estimator.py encoder.pose.msgpack --frames frames.npz --name cube_estimator_visual
    python benchmarks/probe_estimator.py encoder.pose.msgpack --samples 64 --seed 12345
"""

from __future__ import annotations

import argparse
import os

import jax
import numpy as np
from common import RESULTS, markdown_table, timed, write_results

from angora_jax import analysis as an
from angora_jax.vision import PoseDataset, PoseEstimator, cube_masks, render_pose_dataset


def load_frames(args: argparse.Namespace, estimator: PoseEstimator, seconds: dict[str, float]) -> tuple[
        np.ndarray, np.ndarray]:
    """Frames `(N, cameras, H, W, 3)` uint8 and their cube masks `(N, cameras, H, W)`, from `--frames` or rendered."""
    if args.frames is None:
        dataset = timed(seconds, "render_frames", render_pose_dataset, args.samples, estimator.cameras,
                        estimator.size, estimator.size, seed=args.seed, renderer=estimator.renderer or "cpu")
        return dataset.images, timed(seconds, "cube_masks", cube_masks, dataset, args.threshold)
    saved = np.load(args.frames)
    rows = slice(0, args.samples)
    images = saved["images"][rows]
    dataset = PoseDataset(images, *(saved[key][rows] if key in saved else None
                                    for key in ("cube_position", "cube_quaternion", "hand_qpos")),
                          estimator.cameras, estimator.renderer or "cpu")
    return images, cube_masks(dataset, args.threshold, without_cube=saved["no_cube"][rows])


def last_map(estimator: PoseEstimator, images: np.ndarray) -> np.ndarray:
    """The last convolution's mean over channels after its ReLU (what the next stage reads), each cell spread over
    the pixels it covers: `(N, cameras, H, W, 3)` -> `(N, cameras, H, W)`."""
    flat = images.reshape(-1, *images.shape[2:])
    maps = np.maximum(an.feature_maps(estimator, flat)[an.visual.conv_layers(estimator)[-1]], 0.0).mean(axis=-1)
    return np.asarray(jax.image.resize(maps, (len(flat), *images.shape[2:4]), "nearest")).reshape(images.shape[:4])


def plot_saliency(images: np.ndarray, masks: np.ndarray, saliency: dict[str, np.ndarray], cameras: tuple[str, ...],
                  path: str) -> None:
    """One row per pose, per camera its frame, its cube mask and each saliency map with the mask's outline."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = 2 + len(saliency)
    figure, axes = plt.subplots(len(images), panels * len(cameras), squeeze=False,
                                figsize=(1.6 * panels * len(cameras), 1.7 * len(images)))
    for ax in axes.flat:
        ax.axis("off")
    for i in range(len(images)):
        for c, camera in enumerate(cameras):
            row = axes[i, panels * c:panels * (c + 1)]
            row[0].imshow(images[i, c])
            row[0].set_title(f"{camera}", fontsize=7)
            row[1].imshow(masks[i, c], cmap="gray")
            row[1].set_title("cube mask", fontsize=7)
            for ax, (name, where) in zip(row[2:], saliency.items(), strict=True):
                ax.imshow(where[i, c], cmap="magma")
                ax.contour(masks[i, c], levels=[0.5], colors="cyan", linewidths=0.5)
                ax.set_title(f"{name} saliency", fontsize=7)
    figure.tight_layout()
    figure.savefig(path, dpi=100)
    plt.close(figure)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("estimator", help="a pose estimator file (pretrain-vision's <out>.pose.msgpack)")
    parser.add_argument("--frames", default=None, help="an NPZ of frames with images and no_cube (default: render)")
    parser.add_argument("--samples", type=int, default=64, help="poses: the NPZ's first N, or N rendered")
    parser.add_argument("--seed", type=int, default=12345, help="of the rendered poses")
    parser.add_argument("--threshold", type=int, default=8, help="colour change (0-255) that marks a cube pixel")
    parser.add_argument("--analysis-frames", type=int, default=2,
                        help="poses whose frames (every camera's) the visual analysis and the figures show")
    parser.add_argument("--units", type=int, default=4, help="output features and channels per layer analysed")
    parser.add_argument("--ascent-steps", type=int, default=256, help="gradient steps of activation maximization")
    parser.add_argument("--note", default="", help="recorded in the JSON's config")
    parser.add_argument("--name", default="estimator_visual")
    parser.add_argument("--out-dir", default=os.path.join(RESULTS, "probing"),
                        help="folder of the plots and the JSON (default: results/probing/)")
    args = parser.parse_args(argv)
    estimator = PoseEstimator.load(args.estimator)
    seconds: dict[str, float] = {}
    images, masks = load_frames(args, estimator, seconds)
    estimator.check_frames(images)
    edges = an.mask_edges(masks)
    shown = images[: args.analysis_frames]
    analyse = (an.visual_analysis, estimator, shown.reshape(-1, *images.shape[2:]), args.units, args.ascent_steps)
    timed(seconds, "visual_first_with_compile", *analyse)
    visual = timed(seconds, "visual_again", *analyse)
    measures = {}
    for output in ("orientation", "position"):
        timed(seconds, f"{output}_saliency_first_with_compile", an.pose_saliency, estimator, images, output)
        measures[f"{output} saliency"] = timed(seconds, f"{output}_saliency_again", an.pose_saliency, estimator,
                                               images, output)
    layer = visual.attrs["last_layer"]
    measures[f"{layer} mean map"] = timed(seconds, "last_map", last_map, estimator, images)

    rows = []
    cube_pixels, edge_pixels = masks.mean(axis=(-2, -1)), edges.mean(axis=(-2, -1))  # chance, whatever the measure
    for measure, where in measures.items():
        on_cube, on_edges = an.saliency_share(where, masks), an.saliency_share(where, edges)
        for c, camera in enumerate(estimator.cameras):
            row = {"camera": camera, "measure": measure, "cube_share": float(np.nanmean(on_cube[:, c])),
                   "cube_pixels": float(cube_pixels[:, c].mean()), "edge_share": float(np.nanmean(on_edges[:, c])),
                   "edge_pixels": float(edge_pixels[:, c].mean()),
                   "images_above_chance": float(np.mean(on_cube[:, c] > cube_pixels[:, c]))}
            row["cube_over_chance"] = row["cube_share"] / row["cube_pixels"]
            row["edge_over_chance"] = row["edge_share"] / row["edge_pixels"]
            rows.append(row)
    columns = [("camera", "camera", "s"), ("measure", "measure", "s"), ("cube_share", "on cube", ".3f"),
               ("cube_pixels", "cube pixels", ".3f"), ("cube_over_chance", "x chance", ".2f"),
               ("edge_share", "on edges", ".3f"), ("edge_pixels", "edge pixels", ".3f"),
               ("edge_over_chance", "x chance", ".2f"), ("images_above_chance", "images above chance", ".2f")]
    print(markdown_table(rows, columns))

    os.makedirs(args.out_dir, exist_ok=True)
    out = os.path.join(args.out_dir, args.name)
    an.plot_visual(visual, f"{out}_visual.png")
    plot_saliency(shown, masks[: args.analysis_frames], {name.split()[0]: measures[name] for name in
                  ("orientation saliency", "position saliency")}, estimator.cameras, f"{out}_saliency.png")
    summary = {"seconds": seconds, "poses": len(images),
               "visual_layers": [str(name) for name in visual["layer"].values],
               "preferred_activation": visual["preferred_activation"].to_pandas().round(4).to_dict()}
    print({"seconds": {key: round(value, 2) for key, value in seconds.items()}})
    config = {"estimator": args.estimator, "frames": args.frames, "samples": args.samples, "seed": args.seed,
              "threshold": args.threshold, "analysis_frames": args.analysis_frames, "units": args.units,
              "ascent_steps": args.ascent_steps, "note": args.note,
              "estimator_config": {"encoder": estimator.encoder, "encoder_options": estimator.encoder_options,
                                   "orientation": estimator.orientation, "cameras": list(estimator.cameras),
                                   "size": estimator.size, "renderer": estimator.renderer},
              "summary": summary}
    print(write_results(args.name, config, rows, f"{out}_{jax.devices()[0].platform}.json", study="probing"))


if __name__ == "__main__":
    main()
