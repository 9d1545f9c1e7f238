"""Probe a trained run end to end and time each part: recording N episodes of every layer (compile, then again),
decoding task variables from areas (against noise and against the same network with random weights on the same
inputs), ablations of areas, unit fractions and input modalities (task outcomes with standard errors), fixed points of
the recurrent premotor layer, PCA, timescales and, for the cube, RSA against model RDMs. Written for the brain-area
model (`cortical`) on reach and on the cube; what is decoded and lesioned depends on the task
(`angora_jax.analysis.PROBES`).

    python benchmarks/probe_trained.py runs/reach_cortical --episodes 480     # e.g. after
    angora-jax train shadow_reach_cortical logging.run_name=reach_cortical
    python benchmarks/probe_trained.py runs/cube_cortical --episodes 480 --name cube_cortical_probe   # GPU, after
    angora-jax train shadow_ihom_cortical logging.run_name=cube_cortical
"""

from __future__ import annotations

import argparse
import os

import jax
import numpy as np
from common import RESULTS, markdown_table, timed, write_results

import angora_jax as aj
from angora_jax import analysis as an
from angora_jax.cli import add_env_option


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("run_dir")
    parser.add_argument("--episodes", type=int, default=480)
    parser.add_argument("--decode-episodes", type=int, default=64, help="episodes used for decoding and dynamics")
    parser.add_argument("--name", default="reach_cortical_probe")
    parser.add_argument("--fixed-point-starts", type=int, default=64, help="states the fixed-point search starts from")
    parser.add_argument("--fixed-point-iterations", type=int, default=500, help="optimisation steps of that search")
    parser.add_argument("--steps", type=int, default=None,
                        help="policy steps per episode, recorded and lesioned (default: until every episode ends)")
    add_env_option(parser)  # e.g. 'physics={impl: warp}' on a CPU: Warp compiles the cube far sooner than MJX's JAX
    parser.add_argument("--out-dir", default=RESULTS, help="folder of the plots and the JSON (default: results/)")
    args = parser.parse_args(argv)
    agent = aj.load_agent(args.run_dir, "best", args.env_option)
    task = agent.config.env.task
    if task not in an.PROBES:
        parser.error(f"{task} has no probe here; tasks with one: {sorted(an.PROBES)}.")
    probe = an.PROBES[task]
    layers, variables = list(probe.layers), list(probe.variables)
    seconds: dict[str, float] = {}
    for attempt in ("record_first_with_compile", "record_again"):
        recording = None  # freed before the next: 480 trained cube episodes of every layer hold tens of GB
        recording = timed(seconds, attempt, an.record_activity, agent, episodes=args.episodes, steps=args.steps)
    part = recording.isel(episode=slice(0, args.decode_episodes))
    decoding, control = timed(seconds, "decode_both", lambda: (
        an.decode(part, layers, variables),
        an.decode(an.replay_activity(an.with_random_weights(agent), part), layers, variables)))
    ablation = timed(seconds, "ablation", an.ablation, agent, probe.lesions(agent), episodes=args.episodes,
                     steps=args.steps)
    points = timed(seconds, "fixed_points", an.agent_fixed_points, agent, part, "network.PMC", "network.PMC_in",
                   starts=args.fixed_point_starts, iterations=args.fixed_point_iterations)
    components = timed(seconds, "principal_components", an.principal_components, part, layers)
    scales = timed(seconds, "timescales", an.timescales, part, layers)
    os.makedirs(args.out_dir, exist_ok=True)
    out = os.path.join(args.out_dir, args.name)
    similarity = None
    if probe.rsa_variables:
        similarity = timed(seconds, "similarity", an.similarity, part, probe.rsa_condition, layers,
                           probe.rsa_variables)
        an.plot_similarity(similarity, f"{out}_similarity.png")
    an.plot_decoding(decoding, f"{out}_decoding.png")
    an.plot_ablation(ablation, probe.outcomes[0], f"{out}_ablation.png")
    an.plot_dynamics(components, f"{out}_dynamics.png", points)
    an.plot_timescales(scales, f"{out}_timescales.png")
    rows = [{"lesion": str(name), **{f"{o}_{stat}": float(ablation[stat].sel(lesion=name, outcome=o))
                                     for o in probe.outcomes for stat in ("mean", "sem")}}
            for name in ablation["lesion"].values]
    columns = [("lesion", "lesion", "s")]
    for o in probe.outcomes:
        columns += [(f"{o}_mean", o, ".3f"), (f"{o}_sem", "s.e.m.", ".3f")]
    print(markdown_table(rows, columns))
    summary = {
        "seconds": seconds, "recording_mb": recording.nbytes / 1e6, "run_cycle": agent.cycle,
        "decoding_r2": decoding["r2"].to_pandas().round(3).to_dict(),
        "decoding_noise_baseline": decoding["baseline"].to_pandas().round(3).to_dict(),
        "decoding_r2_random_weights_same_inputs": control["r2"].to_pandas().round(3).to_dict(),
        "fixed_points": {"starts": len(points["fixed"]), "max_speed": float(points["speed"].max()),
                         "largest_eigenvalue_modulus_median": float(np.median(np.abs(points["eigenvalues"][:, 0])))},
        "pca_components_for_90pct": dict(zip(layers, components["dimensionality"].values.tolist(), strict=True)),
        "timescale_median_s": dict(zip(layers, scales["timescale_median"].values.round(4).tolist(), strict=True)),
        "recorded_steps": int(recording.sizes["time"]),
        "episode_length_mean_steps": float(recording["alive"].sum("time").mean()),
    }
    if similarity is not None:
        summary["rsa_condition"] = probe.rsa_condition
        summary["rsa_model_similarity"] = similarity["model_similarity"].to_pandas().round(3).to_dict()
    print({k: v for k, v in summary.items() if not k.startswith("decoding")})
    config = {"run_dir": args.run_dir, "episodes": args.episodes, "steps": args.steps, "env_options": args.env_option,
              "decode_episodes": args.decode_episodes,
              "fixed_point_starts": args.fixed_point_starts, "fixed_point_iterations": args.fixed_point_iterations,
              "summary": summary}
    print(write_results(args.name, config, rows, f"{out}_{jax.devices()[0].platform}.json"))


if __name__ == "__main__":
    main()
