"""`pretrain-vision`: render hand and cube poses and train a visual encoder that sees the cube's pose."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from angora_jax.cli.arguments import EXIT_OK, EXIT_USAGE, positive_int, refused_existing, seed
from angora_jax.envs.rendering import CAMERAS, RenderError
from angora_jax.vision.orientations import ORIENTATIONS
from angora_jax.whole_files import written_whole
from angora_jax.wording import counted


def add_pretrain_vision(commands: argparse._SubParsersAction) -> None:
    """The `pretrain-vision` verb: its arguments and its handler."""
    vision = commands.add_parser("pretrain-vision", help="render random hand and cube poses and train a visual "
                                                         "encoder to see the cube's pose (angora_jax.vision)")
    vision.add_argument("--out", required=True, help="file for the trained encoder (a component; the whole pose "
                                                     "network goes beside it, suffix .pose.msgpack; never overwritten)")
    vision.add_argument("--samples", type=positive_int, default=20000, help="renders (default: 20000)")
    vision.add_argument("--size", type=positive_int, default=64, help="image width and height in pixels (default: 64)")
    vision.add_argument("--cameras", nargs="+", default=["front", "side", "top"], choices=sorted(CAMERAS),
                        help="the views the encoder sees (default: front side top)")
    vision.add_argument("--renderer", default="cpu", choices=["cpu", "warp"],
                        help="cpu: mujoco.Renderer (OpenGL); warp: MuJoCo Warp's batched ray tracer (GPU)")
    vision.add_argument("--encoder", default="cornet_z", help="cornet_z or impala (default: cornet_z)")
    vision.add_argument("--widths", type=positive_int, nargs="+", default=None,
                        help="channels per stage (default: the encoder's own: cornet_z 32 64 128 256, impala 16 32 32)")
    vision.add_argument("--features", type=positive_int, default=256, help="the encoder's output size (default: 256)")
    vision.add_argument("--steps", type=positive_int, default=5000, help="Adam steps (default: 5000)")
    vision.add_argument("--batch", type=positive_int, default=64, help="samples per Adam step (default: 64)")
    vision.add_argument("--orientation", default="6d", choices=list(ORIENTATIONS),
                        help="how the pose head outputs the cube's orientation (default: 6d, continuous)")
    vision.add_argument("--seed", type=seed, default=0, help="seed of the poses and the weights (default: 0)")
    vision.set_defaults(handler=command_pretrain_vision)


def command_pretrain_vision(args: argparse.Namespace) -> int:
    import json

    import jax

    from angora_jax.experiment.run_dir import unwritable_out
    from angora_jax.nets.components import save_component
    from angora_jax.nets.visual import VISUAL_ENCODERS
    from angora_jax.vision import pretrain_pose_encoder, render_pose_dataset
    from angora_jax.vision.dataset import check_pose_renders
    from angora_jax.vision.pretrain import pose_network

    out = Path(args.out)
    estimator_out, numbers_out = out.with_suffix(".pose.msgpack"), out.with_suffix(".json")
    outputs = ((out, "components"), (estimator_out, "pose estimators"), (numbers_out, "numbers"))
    if any(refused_existing("pretrain-vision", file, what) for file, what in outputs):
        return EXIT_USAGE
    if numbers_out == out:
        print(f"angora-jax pretrain-vision: --out {out}: the numbers (.json) would overwrite the encoder there; give "
              "an --out ending in .msgpack.", file=sys.stderr)
        return EXIT_USAGE
    if args.encoder not in VISUAL_ENCODERS:
        print(f"angora-jax pretrain-vision: unknown encoder {args.encoder!r}; choose one of {sorted(VISUAL_ENCODERS)}.",
              file=sys.stderr)
        return EXIT_USAGE
    # The outputs are written after hours of rendering and training: their folder is checked first (the folders
    # missing under the nearest existing one are made then).
    if (why := unwritable_out(out)) is not None:
        print(f"angora-jax pretrain-vision: --out {out}: {why}; give a file in a folder you can write to.",
              file=sys.stderr)
        return EXIT_USAGE
    options = {"features": args.features} | ({"widths": tuple(args.widths)} if args.widths else {})
    try:
        if args.samples < 2:
            raise ValueError(f"--samples must be at least 2 (a tenth, at least one, is held out to measure the "
                             f"encoder on), got {args.samples}.")
        if args.batch > args.samples:
            raise ValueError(f"--batch ({args.batch}) must be at most --samples ({args.samples}).")
        check_pose_renders(args.samples, tuple(args.cameras), args.size, args.size, args.renderer)
        pose_network(args.encoder, options, args.orientation, (len(args.cameras), args.size, args.size, 3))
    except (ValueError, ModuleNotFoundError) as error:
        print(f"angora-jax pretrain-vision: {error}", file=sys.stderr)
        return EXIT_USAGE
    start = time.perf_counter()
    try:
        dataset = render_pose_dataset(args.samples, tuple(args.cameras), args.size, args.size, seed=args.seed,
                                      renderer=args.renderer)
    except RenderError as error:
        print(f"angora-jax pretrain-vision: {error} Or render with MuJoCo Warp on a GPU: --renderer warp.",
              file=sys.stderr)
        return EXIT_USAGE
    rendered = time.perf_counter() - start
    train, test = dataset.split(0.1)
    result = pretrain_pose_encoder(train, test, args.encoder, options, args.steps, args.batch, seed=args.seed,
                                   orientation=args.orientation)
    save_component(result.params, "encoder", out)  # whole or not at all, never over an existing file
    result.estimator.save(estimator_out)
    report = {"encoder": args.encoder, "options": options, "cameras": args.cameras, "size": args.size,
              "renderer": args.renderer, "samples": args.samples, "device": str(jax.devices()[0].device_kind),
              "render_seconds": rendered, "train_seconds": result.seconds, "steps": args.steps,
              "orientation": args.orientation, "batch": args.batch, "learning_rate": result.learning_rate,
              **result.errors,
              "loss": result.history}
    with written_whole(numbers_out, replace=False) as draft:
        draft.write_text(json.dumps(report, indent=1))
    errors = result.errors
    print(f"Rendered {counted(len(dataset), 'sample')} x {counted(len(args.cameras), 'camera')} in {rendered:.0f} s; "
          f"trained {counted(args.steps, 'step')} in {result.seconds:.0f} s. Held-out ({errors['test_samples']}): "
          f"position {errors['position_mm_median']:.1f} mm median ({errors['position_mm_p90']:.1f} p90), orientation "
          f"{errors['orientation_deg_median']:.1f} deg median ({errors['orientation_deg_p90']:.1f} p90).")
    print(f"Encoder: {out} (load with network.pretrained); the whole pose network: {estimator_out} "
          f"(angora_jax.vision.PoseEstimator.load); numbers: {numbers_out}")
    return EXIT_OK

