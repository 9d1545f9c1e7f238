#!/bin/bash
# Data-parallel training over several hosts with SLURM: one angora-jax process per GPU. `--distributed` calls
# jax.distributed.initialize, which reads the coordinator, the process count and this process's id from SLURM's
# environment (SLURM_STEP_NODELIST, SLURM_NTASKS, SLURM_PROCID) and gives each process the one GPU whose index on
# its node is SLURM_LOCALID. So launch one task per GPU, each task seeing all of its node's GPUs (no per-task GPU
# binding such as --gpus-per-task, which would renumber them): with one task per node JAX would use only GPU 0 of
# each node. One process per GPU is also the faster layout: two H200s trained reach 1.79-1.81x one GPU's rate this
# way, 1.76x with one process driving both (benchmarks/results/scaling/scaling_ShadowHandReach_weak*_gpu.json).
# Only process 0 logs; every process takes part in writing checkpoints, so logging.run_root must be on a filesystem
# all nodes share. ppo.num_envs and ppo.minibatch_size are run totals: multiples of the total GPU count.
# A SIGTERM to any process (here from --signal, 10 minutes before the time limit: time for the current cycle and a
# checkpoint) stops every process after the same cycle, each saving its part of the checkpoint; exit code 143.
#
#   sbatch examples/slurm_train.sh shadow_reach ppo.num_cycles=500
#SBATCH --job-name=angora-jax
#SBATCH --nodes=2
#SBATCH --ntasks-per-node=4
#SBATCH --gpus-per-node=4
#SBATCH --cpus-per-task=4
#SBATCH --time=04:00:00
#SBATCH --signal=TERM@600
set -euo pipefail

CONFIG=${1:?usage: sbatch examples/slurm_train.sh CONFIG [KEY=VALUE ...]}
shift

# All processes must name the same run directory; the job id makes it unique.
srun angora-jax train "$CONFIG" --distributed distribution.num_devices=all \
    logging.run_name="${CONFIG##*/}-$SLURM_JOB_ID" "$@"
# Continue an interrupted job with:  srun angora-jax resume runs/<run_name> --distributed
