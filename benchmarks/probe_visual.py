"""Probe a trained pixel agent (one that sees camera images through a visual area, `ppo.network.visual`) and time
each part: recording N episodes with their frames (compile, then again); inside the visual area, the first layer's
filters, feature maps, gradient saliency of the output features and preferred stimuli by activation maximization
(`analysis.visual_analysis`, compile, then again); and lagged decoding of task variables at t + k from each dense
layer's activity at t, against the noise baseline and against the same network with random weights given the same
frames and inputs (`analysis.with_random_weights` + `replay_activity`). The question for the cube: which layers
predict its future rotation beyond what an untrained network's response to the same frames holds?

    angora-jax train shadow_reach_pixels logging.run_name=reach_pixels        # e.g., on a GPU, then
    python benchmarks/probe_visual.py runs/reach_pixels --name reach_pixels_probe
    angora-jax train shadow_ihom_pixels env.options.vision.width=32 env.options.vision.height=32 \\
        logging.run_name=cube_pixels
    python benchmarks/probe_visual.py runs/cube_pixels --name cube_pixels_probe
"""

from __future__ import annotations

import argparse
import os

import jax
from common import RESULTS, lagged_decoding_rows, markdown_table, timed, write_results

import angora_jax as aj
from angora_jax import analysis as an
from angora_jax.cli.arguments import add_env_option

# What to decode over lags, per task (Env.task_variables): the cube's orientation (rotation matrix, sign-free),
# angular velocity (rad/s) and rotation to the goal (matrix); reach's fingertips (m).
VARIABLES = {
    "ShadowHandCube": ("task_cube_rotation", "task_cube_angular_velocity", "task_rotation_to_goal"),
    "ShadowHandReach": ("task_fingertips",),
    "ShadowHandFreeReach": ("task_fingertips",),
}


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("run_dir")
    parser.add_argument("--checkpoint", default="best")
    parser.add_argument("--episodes", type=int, default=64, help="episodes recorded, with their frames")
    parser.add_argument("--steps", type=int, default=None,
                        help="policy steps per recorded episode (default: until every episode has ended)")
    parser.add_argument("--frames", type=int, default=4, help="frames (of the first episode) the visual analysis sees")
    parser.add_argument("--camera", type=int, default=0)
    parser.add_argument("--units", type=int, default=4, help="output features and channels per layer analysed")
    parser.add_argument("--ascent-steps", type=int, default=256, help="gradient steps of activation maximization")
    parser.add_argument("--lags", type=int, nargs="+", default=[0, 1, 2, 4, 8, 16], help="policy steps k")
    add_env_option(parser)  # e.g. 'physics={impl: warp}' on a CPU: Warp compiles the cube far sooner than MJX's JAX
    parser.add_argument("--name", default="pixels_probe")
    parser.add_argument("--out-dir", default=os.path.join(RESULTS, "probing"),
                        help="folder of the plots and the JSON (default: results/probing/)")
    args = parser.parse_args(argv)
    agent = aj.load_agent(args.run_dir, args.checkpoint, args.env_option)
    task = agent.config.env.task
    variables = list(VARIABLES.get(task.removesuffix("Sequential"), ()))
    if not variables:
        parser.error(f"{task} has no variables to decode here; tasks with some: {sorted(VARIABLES)}.")
    seconds: dict[str, float] = {}
    recording = timed(seconds, "record_first_with_compile", an.record_activity, agent, args.episodes, args.steps,
                      images=True)
    recording = timed(seconds, "record_again", an.record_activity, agent, args.episodes, args.steps, images=True)
    images = recording["input_vision"].values[0, : args.frames, args.camera]
    analyse = (an.visual_analysis, agent, images, args.units, args.ascent_steps)
    timed(seconds, "visual_first_with_compile", *analyse)
    visual = timed(seconds, "visual_again", *analyse)
    # The dense layers the policy computes (the visual area's features and the policy's layers): the value path
    # sees privileged inputs (the cube's pose), which would make decoding the pose from it trivial.
    layers = [name for name in an.dense_layers(agent) if "value" not in name and f"activity_{name}" in recording]
    lags = [k for k in args.lags if abs(k) < recording.sizes["time"]]
    decoding = timed(seconds, "lagged_decode", an.decode, recording, layers, variables, lags=lags)
    random_weights = an.replay_activity(an.with_random_weights(agent), recording)
    control = timed(seconds, "lagged_decode_random_weights", an.decode, random_weights, layers, variables, lags=lags,
                    baseline=False)
    os.makedirs(args.out_dir, exist_ok=True)
    out = os.path.join(args.out_dir, args.name)
    an.plot_visual(visual, f"{out}_visual.png")
    an.plot_decoding(decoding, f"{out}_lagged_decoding.png")
    an.plot_decoding(control, f"{out}_lagged_decoding_random_weights.png")
    rows, columns = lagged_decoding_rows(decoding, control, lags, layers, variables)
    print(markdown_table(rows, columns))
    future = [row for row in rows if row["lag"] > 0 and row["above_random_weights"]]
    summary = {
        "seconds": seconds, "run_cycle": agent.cycle, "task": task, "recording_mb": recording.nbytes / 1e6,
        "recorded_steps": int(recording.sizes["time"]),
        "episode_length_mean_steps": float(recording["alive"].sum("time").mean()),
        "visual_layers": [str(name) for name in visual["layer"].values],
        "saliency_max": float(visual["saliency"].max()),
        "preferred_activation": visual["preferred_activation"].to_pandas().round(4).to_dict(),
        "future_decoded_above_random_weights": sorted({(row["layer"], row["variable"]) for row in future}),
    }
    print({k: v for k, v in summary.items() if k != "preferred_activation"})
    config = {"run_dir": args.run_dir, "checkpoint": args.checkpoint, "env_options": args.env_option,
              "episodes": args.episodes, "frames": args.frames,
              "camera": args.camera, "units": args.units, "ascent_steps": args.ascent_steps, "lags": lags,
              "variables": variables, "layers": layers, "summary": summary}
    print(write_results(args.name, config, rows, f"{out}_{jax.devices()[0].platform}.json", study="probing"))


if __name__ == "__main__":
    main()
