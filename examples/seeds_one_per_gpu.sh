#!/bin/bash
# Seeds of one config, one single-GPU run per GPU at once: how the headline numbers get their seed statistics
# (benchmarks/ihom_curve.py --seeds N reads the runs back). Seed i trains on GPU i mod GPUS, as
# runs/<RUN_NAME>-seed<i>; with more seeds than GPUs the later ones start as GPUs free up. Each run is an ordinary
# single-device run: resume, evaluate or analyze it on its own.
#
#   examples/seeds_one_per_gpu.sh shadow_ihom 4                 # a 4-GPU host: seeds 0-3 at once
#   SEEDS_FROM=4 examples/seeds_one_per_gpu.sh shadow_ihom 1    # a fifth seed later (seed 4)
#   python benchmarks/ihom_curve.py fast=runs/shadow_ihom-seed0 fast=runs/shadow_ihom-seed1 ... --seeds 5 \
#       --device "NVIDIA H200" --name fast_seeds_h200
#
# Ctrl-C stops every run after its cycle with a checkpoint; continue each with angora-jax resume runs/<name>-seed<i>.
set -euo pipefail

CONFIG=${1:?usage: examples/seeds_one_per_gpu.sh CONFIG SEEDS [KEY=VALUE ...]}
SEEDS=${2:?usage: examples/seeds_one_per_gpu.sh CONFIG SEEDS [KEY=VALUE ...]}
shift 2
GPUS=${GPUS:-$(nvidia-smi -L | wc -l)}
FIRST=${SEEDS_FROM:-0}
NAME=${RUN_NAME:-${CONFIG##*/}}
NAME=${NAME%.yaml}

declare -A running=()  # GPU -> pid
pids=()
trap 'kill -INT "${pids[@]}" 2>/dev/null' INT TERM
status=0
for ((seed = FIRST; seed < FIRST + SEEDS; seed++)); do
    gpu=$(((seed - FIRST) % GPUS))
    if [ -n "${running[$gpu]:-}" ]; then wait "${running[$gpu]}" || status=$?; fi
    CUDA_VISIBLE_DEVICES=$gpu angora-jax train "$CONFIG" "ppo.seed=$seed" "logging.run_name=$NAME-seed$seed" "$@" &
    running[$gpu]=$!
    pids+=($!)
done
for pid in "${running[@]}"; do wait "$pid" || status=$?; done
exit "$status"
