"""Our measured IHOM training samples/s on one GPU against AngoraPy's reported cost, as a ratio.

AngoraPy (Weidler, Goebel and Senden, 2023) reports training in-hand object manipulation (IHOM) on about 1.19
billion samples in 96 hours on 384 CPU cores and 32 P100 GPUs. A sample is one environment (policy) step; both
control the hand every 0.08 s, so samples/s compare directly, and sim-s/s = samples/s x 0.08 s.

    python benchmarks/angorapy_ratio.py                      # reads results/env_train_throughput/
                                                             # train_throughput_ShadowHandCube_gpu.json
    python benchmarks/angorapy_ratio.py --results PATH.json  # any train_throughput JSON of the cube task
"""

from __future__ import annotations

import argparse
import json
import os

ANGORAPY_SAMPLES = 1.19e9
ANGORAPY_HOURS = 96.0
ANGORAPY_HARDWARE = "384 CPU cores + 32 P100 GPUs"
DEFAULT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "results", "env_train_throughput",
                       "train_throughput_ShadowHandCube_gpu.json")


def angorapy_samples_per_s() -> float:
    """AngoraPy's IHOM training rate: reported samples over reported wall time."""
    return ANGORAPY_SAMPLES / (ANGORAPY_HOURS * 3600.0)


def ratios(record: dict) -> list[dict]:
    """One row per measured configuration of a `train_throughput` record: our samples/s, sim-s/s and the ratio
    to AngoraPy's rate."""
    if record.get("benchmark") != "train_throughput" or record["config"]["args"]["task"] != "ShadowHandCube":
        raise ValueError("Expected a train_throughput record of ShadowHandCube (benchmarks/train_throughput.py "
                         f"--task ShadowHandCube), got {record.get('benchmark')!r}.")
    theirs = angorapy_samples_per_s()
    dt = record["config"]["control_dt_s"]
    device = f"{record['device']['count']} x {record['device']['kind']}"
    return [{"device": device, "model": row["model"], "num_envs": row["num_envs"],
             "samples_per_s": row["train_env_steps_per_s"], "sim_s_per_s": row["train_env_steps_per_s"] * dt,
             "angorapy_samples_per_s": theirs, "angorapy_sim_s_per_s": theirs * dt,
             "ratio": row["train_env_steps_per_s"] / theirs} for row in record["results"]]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--results", default=DEFAULT, help="a train_throughput JSON of ShadowHandCube")
    args = parser.parse_args()
    with open(args.results) as f:
        rows = ratios(json.load(f))
    print(f"AngoraPy: {ANGORAPY_SAMPLES:.3g} samples in {ANGORAPY_HOURS:.0f} h on {ANGORAPY_HARDWARE} = "
          f"{angorapy_samples_per_s():,.0f} samples/s ({rows[0]['angorapy_sim_s_per_s']:,.0f} sim-s/s)")
    print("| ours on | model | envs | samples/s | sim-s/s | ours / AngoraPy |")
    print("|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['device']} | {r['model']} | {r['num_envs']:,} | {r['samples_per_s']:,.0f} | "
              f"{r['sim_s_per_s']:,.0f} | {r['ratio']:.1f} |")


if __name__ == "__main__":
    main()
