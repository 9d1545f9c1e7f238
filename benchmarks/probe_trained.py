"""Probe a trained run end to end and time each part: recording episodes of every layer (compile, then again),
decoding task variables from areas (against noise and against the same network with random weights on the same
inputs; with --lags also of the future, and the areas' cross-correlation), ablations of areas, unit fractions and
input modalities (task outcomes with standard errors), fixed points of the recurrent premotor layer, PCA, timescales
and, for the cube, RSA against model RDMs. Lesions run --episodes episodes (480, the paper's count, for their
standard errors); the analyses of activity read --decode-episodes recorded ones (480 whole trained cube episodes of
every layer would hold over 10 GB on the host). Written for the brain-area model (`cortical`) on reach and on the cube;
what is decoded and lesioned depends on the task
(`angora_jax.analysis.PROBES`). Each part's plot and the JSON are written as the part ends, so a run cut short keeps
what it finished (the JSON's `stages_done`).

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
from common import RESULTS, lagged_decoding_rows, markdown_table, timed, write_results

import angora_jax as aj
from angora_jax import analysis as an
from angora_jax.cli.arguments import add_env_option


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("run_dir")
    parser.add_argument("--episodes", type=int, default=480, help="episodes of each lesion and of the intact agent")
    parser.add_argument("--decode-episodes", type=int, default=64,
                        help="recorded episodes that decoding, dynamics, timescales and RSA read")
    parser.add_argument("--record-episodes", type=int, default=None,
                        help="episodes recorded with every layer's activity (default: --decode-episodes; more only "
                             "times a larger recording)")
    parser.add_argument("--name", default="reach_cortical_probe")
    parser.add_argument("--fixed-point-starts", type=int, default=64, help="states the fixed-point search starts from")
    parser.add_argument("--fixed-point-iterations", type=int, default=500, help="optimisation steps of that search")
    parser.add_argument("--steps", type=int, default=None,
                        help="policy steps per episode, recorded and lesioned (default: until every episode ends)")
    parser.add_argument("--lags", type=int, nargs="*", default=[],
                        help="policy steps k: also decode the task's variables at t + k from each area at t (e.g. "
                             "0 1 2 4 8 16: which areas predict the cube's future rotation), and cross-correlate "
                             "the areas' leading components")
    add_env_option(parser)  # e.g. 'physics={impl: warp}' on a CPU: Warp compiles the cube far sooner than MJX's JAX
    parser.add_argument("--out-dir", default=os.path.join(RESULTS, "probing"),
                        help="folder of the plots and the JSON (default: results/probing/)")
    args = parser.parse_args(argv)
    agent = aj.load_agent(args.run_dir, "best", args.env_option)
    task = agent.config.env.task
    if task not in an.PROBES:
        parser.error(f"{task} has no probe here; tasks with one: {sorted(an.PROBES)}.")
    probe = an.PROBES[task]
    layers, variables = list(probe.layers), list(probe.variables)
    os.makedirs(args.out_dir, exist_ok=True)
    out = os.path.join(args.out_dir, args.name)
    path = f"{out}_{jax.devices()[0].platform}.json"
    seconds: dict[str, float] = {}
    summary: dict = {"seconds": seconds, "run_cycle": agent.cycle}
    rows: list[dict] = []
    config = {"run_dir": args.run_dir, "episodes": args.episodes, "steps": args.steps, "env_options": args.env_option,
              "decode_episodes": args.decode_episodes,
              "record_episodes": args.record_episodes or args.decode_episodes, "lags": args.lags,
              "fixed_point_starts": args.fixed_point_starts, "fixed_point_iterations": args.fixed_point_iterations,
              "summary": summary}

    def save(stage: str) -> None:
        """The JSON after each part, so a run cut short keeps what it finished (`stages_done`)."""
        summary["stages_done"] = [*summary.get("stages_done", []), stage]
        write_results(args.name, config, rows, path, study="probing")

    for attempt in ("record_first_with_compile", "record_again"):
        recording = None  # 480 whole cube episodes of every layer hold about 10 GB: never two at once
        recording = timed(seconds, attempt, an.record_activity, agent, episodes=args.record_episodes or
                          args.decode_episodes, steps=args.steps)
    summary["recording_mb"] = recording.nbytes / 1e6
    part = recording.isel(episode=slice(0, args.decode_episodes)).copy(deep=True)
    del recording
    summary["recorded_steps"] = int(part.sizes["time"])
    summary["episode_length_mean_steps"] = float(part["alive"].sum("time").mean())
    save("record")
    # The control: the same network with random weights, replayed once on the recorded inputs for every comparison.
    random_part = timed(seconds, "replay_random_weights", an.replay_activity, an.with_random_weights(agent), part)
    decoding, control = timed(seconds, "decode_both", lambda: (
        an.decode(part, layers, variables), an.decode(random_part, layers, variables, baseline=False)))
    an.plot_decoding(decoding, f"{out}_decoding.png")
    summary["decoding_r2"] = decoding["r2"].to_pandas().round(3).to_dict()
    summary["decoding_noise_baseline"] = decoding["baseline"].to_pandas().round(3).to_dict()
    summary["decoding_r2_random_weights_same_inputs"] = control["r2"].to_pandas().round(3).to_dict()
    save("decode")
    if args.lags:
        summary["future"] = predicted_future(part, random_part, layers, variables, args.lags, seconds, out)
        save("lagged_decode")
    ablation = timed(seconds, "ablation", an.ablation, agent, probe.lesions(agent), episodes=args.episodes,
                     steps=args.steps)
    an.plot_ablation(ablation, probe.outcomes[0], f"{out}_ablation.png")
    rows += [{"lesion": str(name), **{f"{o}_{stat}": float(ablation[stat].sel(lesion=name, outcome=o))
                                      for o in probe.outcomes for stat in ("mean", "sem")}}
             for name in ablation["lesion"].values]
    columns = [("lesion", "lesion", "s")]
    for o in probe.outcomes:
        columns += [(f"{o}_mean", o, ".3f"), (f"{o}_sem", "s.e.m.", ".3f")]
    print(markdown_table(rows, columns))
    save("ablation")
    scales = timed(seconds, "timescales", an.timescales, part, layers)
    an.plot_timescales(scales, f"{out}_timescales.png")
    summary["timescale_median_s"] = dict(zip(layers, scales["timescale_median"].values.round(4).tolist(), strict=True))
    save("timescales")
    if probe.rsa_variables:
        similarity = timed(seconds, "similarity", an.similarity, part, probe.rsa_condition, layers,
                           probe.rsa_variables)
        an.plot_similarity(similarity, f"{out}_similarity.png")
        summary["rsa_condition"] = probe.rsa_condition
        summary["rsa_model_similarity"] = similarity["model_similarity"].to_pandas().round(3).to_dict()
        save("similarity")
    components = timed(seconds, "principal_components", an.principal_components, part, layers)
    summary["pca_components_for_90pct"] = dict(zip(layers, components["dimensionality"].values.tolist(), strict=True))
    points = timed(seconds, "fixed_points", an.agent_fixed_points, agent, part, "network.PMC", "network.PMC_in",
                   starts=args.fixed_point_starts, iterations=args.fixed_point_iterations)
    an.plot_dynamics(components, f"{out}_dynamics.png", points)
    summary["fixed_points"] = {"starts": len(points["fixed"]), "max_speed": float(points["speed"].max()),
                               "largest_eigenvalue_modulus_median": float(
                                   np.median(np.abs(points["eigenvalues"][:, 0])))}
    save("fixed_points")
    print({k: v for k, v in summary.items() if not k.startswith("decoding") and k != "future"})
    print(path)


def predicted_future(part, random_part, layers: list[str], variables: list[str], lags: list[int],
                     seconds: dict[str, float], out: str) -> dict:
    """Lagged decoding, from each area, of the probe's variables that are not inputs (what the world does, not what
    the network is fed), trained (`part`) against random weights on the same inputs (`random_part`), and the areas'
    cross-correlation; plots beside `out`. Returns the rows, the (area, variable) pairs that predict the future
    (lag > 0) above the control, and the lead of each pair of areas (s)."""
    variables = [name for name in variables if not name.startswith("input_")]
    lags = [k for k in lags if abs(k) < part.sizes["time"]]
    decoding = timed(seconds, "lagged_decode", an.decode, part, layers, variables, lags=lags)
    control = timed(seconds, "lagged_decode_random_weights", an.decode, random_part, layers, variables, lags=lags,
                    baseline=False)
    correlation = timed(seconds, "cross_correlation", an.cross_correlation, part, layers)
    an.plot_decoding(decoding, f"{out}_lagged_decoding.png")
    an.plot_decoding(control, f"{out}_lagged_decoding_random_weights.png")
    an.plot_cross_correlation(correlation, f"{out}_cross_correlation.png")
    rows, columns = lagged_decoding_rows(decoding, control, lags, layers, variables)
    print(markdown_table(rows, columns))
    return {"lagged_decoding": rows,
            "future_decoded_above_random_weights": sorted({(row["layer"], row["variable"]) for row in rows
                                                            if row["lag"] > 0 and row["above_random_weights"]}),
            "cross_correlation_peak_lag_s": correlation["peak_lag"].to_pandas().round(3).to_dict()}


if __name__ == "__main__":
    main()
