#!/bin/bash
# Data-parallel training on every GPU of one host, one angora-jax process per GPU: the layout a cluster job uses
# (examples/slurm_train.sh), here without a scheduler. Each process joins a jax.distributed job on this host and takes
# the GPU of its index (--local-devices); process 0 logs and all write the checkpoint. Measured on 4 H100s: the fast
# cube (its 32-step recipe) on MuJoCo Warp at 16,384 envs per GPU trains at 3.94x one GPU's rate in this layout
# (benchmarks/results/scaling/scaling_ShadowHandCube_weak_processes_4xh100.json); configs/shadow_ihom_4gpu.yaml is the fast cube
# sized and tuned for 4 GPUs (benchmarks/results/cube_multi_gpu/ihom_curve_4gpu_processes_h100.json), shadow_ihom_2gpu the same per GPU on 2
# (benchmarks/results/cube_multi_gpu/ihom_curve_2gpu_h100.json).
# ppo.num_envs and ppo.minibatch_size are run totals: multiples of the GPU count.
#
#   examples/multi_gpu_host.sh shadow_ihom_2gpu      # on a 2-GPU host; shadow_ihom_4gpu on a 4-GPU host
#   GPUS=2 RUN_NAME=my-run examples/multi_gpu_host.sh shadow_reach
#
# Ctrl-C (SIGINT to every process) stops all after the same cycle with a checkpoint; continue with
#   COMMAND=resume examples/multi_gpu_host.sh runs/<run_name>
set -euo pipefail

TARGET=${1:?usage: examples/multi_gpu_host.sh CONFIG [KEY=VALUE ...]  (COMMAND=resume: RUN_DIR)}
shift
COMMAND=${COMMAND:-train}
if ! command -v angora-jax > /dev/null; then
    echo "multi_gpu_host.sh: angora-jax is not on PATH: activate the environment it is installed in (in a clone:" \
         "source .venv/bin/activate, after make gpu)." >&2
    exit 2
fi
if [ -z "${GPUS:-}" ]; then
    if ! GPUS=$(nvidia-smi -L 2> /dev/null | grep -c '^GPU'); then
        echo "multi_gpu_host.sh: no NVIDIA GPU found (nvidia-smi lists none): this script starts one process per GPU." \
             "Set GPUS=N to start N processes anyway (on the CPU they share its cores; for trying the layout)." >&2
        exit 2
    fi
fi
PORT=${PORT:-12355}
extra=()
if [ "$COMMAND" = train ]; then
    # All processes must name the same run directory.
    extra=(distribution.num_devices=all "logging.run_name=${RUN_NAME:-${TARGET##*/}-$(date +%Y%m%d-%H%M%S)}")
fi

pids=()
trap 'kill -INT "${pids[@]}" 2>/dev/null' INT TERM
for ((i = 0; i < GPUS; i++)); do
    angora-jax "$COMMAND" "$TARGET" --distributed --coordinator "localhost:$PORT" --num-processes "$GPUS" \
        --process-id "$i" --local-devices "$i" "${extra[@]}" "$@" &
    pids+=($!)
done
status=0
for pid in "${pids[@]}"; do wait "$pid" || status=$?; done
exit "$status"
