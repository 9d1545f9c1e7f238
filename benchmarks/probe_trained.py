"""Probe a trained run end to end and time each part: recording N episodes of every layer (compile, then again),
decoding task variables from areas (against noise and against the same network with random weights on the same
inputs), ablations of areas, unit fractions and input modalities (success and goal distance with standard errors),
fixed points of the recurrent premotor layer, PCA and timescales. Written for the brain-area model on reach.

    python benchmarks/probe_trained.py runs/reach_cortical --episodes 480     # e.g. after
    angora-jax train shadow_reach_cortical logging.run_name=reach_cortical
"""

from __future__ import annotations

import argparse
import os
import time

import jax
import numpy as np
from common import RESULTS, markdown_table, write_results

import angora_jax as aj
from angora_jax import analysis as an

LAYERS = ["network.SSC_2", "network.SPL", "network.IPS", "network.MCC", "network.LPFC", "network.PMC.1", "network.M1"]
VARIABLES = ["input_goal", "input_asymmetric", "input_proprioception", "metric_goal_distance"]


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("run_dir")
    parser.add_argument("--episodes", type=int, default=480)
    parser.add_argument("--decode-episodes", type=int, default=64, help="episodes used for decoding and dynamics")
    parser.add_argument("--name", default="reach_cortical_probe")
    parser.add_argument("--fixed-point-starts", type=int, default=64, help="states the fixed-point search starts from")
    parser.add_argument("--fixed-point-iterations", type=int, default=500, help="optimisation steps of that search")
    parser.add_argument("--out-dir", default=RESULTS, help="folder of the plots and the JSON (default: results/)")
    args = parser.parse_args(argv)
    agent = aj.load_agent(args.run_dir, "best")
    seconds = {}
    for attempt in ("record_first_with_compile", "record_again"):
        start = time.perf_counter()
        recording = an.record_activity(agent, episodes=args.episodes)
        seconds[attempt] = time.perf_counter() - start
    part = recording.isel(episode=slice(0, args.decode_episodes))
    start = time.perf_counter()
    decoding = an.decode(part, LAYERS, VARIABLES)
    control = an.decode(an.replay_activity(an.with_random_weights(agent), part), LAYERS, VARIABLES)
    seconds["decode_both"] = time.perf_counter() - start
    lesions = {"-SSC_2": an.lesion_area(agent, "network.SSC_2"), "-IPS": an.lesion_area(agent, "network.IPS"),
               "-MCC": an.lesion_area(agent, "network.MCC"), "-50% M1": an.lesion_fraction(agent, "network.M1", 0.5),
               "-10% M1": an.lesion_fraction(agent, "network.M1", 0.1),
               "-goal input": an.silence_modality(agent, "goal"),
               "-proprioception": an.silence_modality(agent, "proprioception"),
               "-none": an.lesion(agent, "network.M1", [])}
    start = time.perf_counter()
    ablation = an.ablation(agent, lesions, episodes=args.episodes)
    seconds["ablation"] = time.perf_counter() - start
    start = time.perf_counter()
    points = an.agent_fixed_points(agent, part, "network.PMC", "network.PMC_in", starts=args.fixed_point_starts,
                                   iterations=args.fixed_point_iterations)
    components = an.principal_components(part, LAYERS)
    scales = an.timescales(part, LAYERS)
    seconds["dynamics"] = time.perf_counter() - start
    os.makedirs(args.out_dir, exist_ok=True)
    out = os.path.join(args.out_dir, args.name)
    an.plot_decoding(decoding, f"{out}_decoding.png")
    an.plot_ablation(ablation, "success", f"{out}_ablation.png")
    an.plot_dynamics(components, f"{out}_dynamics.png", points)
    an.plot_timescales(scales, f"{out}_timescales.png")
    rows = [{"lesion": str(name), **{f"{o}_{stat}": float(ablation[stat].sel(lesion=name, outcome=o))
                                     for o in ("success", "goal_distance") for stat in ("mean", "sem")}}
            for name in ablation["lesion"].values]
    print(markdown_table(rows, [("lesion", "lesion", "s"), ("success_mean", "success", ".3f"),
                                ("success_sem", "s.e.m.", ".3f"), ("goal_distance_mean", "goal distance (m)", ".4f"),
                                ("goal_distance_sem", "s.e.m.", ".4f")]))
    summary = {
        "seconds": seconds, "recording_mb": recording.nbytes / 1e6, "run_cycle": agent.cycle,
        "decoding_r2": decoding["r2"].to_pandas().round(3).to_dict(),
        "decoding_noise_baseline": decoding["baseline"].to_pandas().round(3).to_dict(),
        "decoding_r2_random_weights_same_inputs": control["r2"].to_pandas().round(3).to_dict(),
        "fixed_points": {"starts": len(points["fixed"]), "max_speed": float(points["speed"].max()),
                         "largest_eigenvalue_modulus_median": float(np.median(np.abs(points["eigenvalues"][:, 0])))},
        "pca_components_for_90pct": dict(zip(LAYERS, components["dimensionality"].values.tolist(), strict=True)),
        "timescale_median_s": dict(zip(LAYERS, scales["timescale_median"].values.round(4).tolist(), strict=True)),
    }
    print({k: v for k, v in summary.items() if not k.startswith("decoding")})
    config = {"run_dir": args.run_dir, "episodes": args.episodes, "decode_episodes": args.decode_episodes,
              "fixed_point_starts": args.fixed_point_starts, "fixed_point_iterations": args.fixed_point_iterations,
              "summary": summary}
    print(write_results(args.name, config, rows, f"{out}_{jax.devices()[0].platform}.json"))


if __name__ == "__main__":
    main()
