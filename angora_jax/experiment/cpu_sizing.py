"""A GPU-sized run started without a GPU: what one cycle would cost on the CPU, said before compiling, with a CPU-sized
override to use instead."""

from __future__ import annotations

from angora_jax.experiment.config import Config
from angora_jax.wording import counted

# Env steps per second of MJX's JAX implementation on 2 CPU cores (batch 16, the tasks' own physics settings;
# benchmarks/results/physics_throughput/physics_throughput_cpu.json, configs "reach-tuned" and "cube-tuned"). More
# cores run faster, roughly in proportion.
CPU_ENV_STEPS_PER_S = {"ShadowHandReach": 1715.0, "ShadowHandFreeReach": 1715.0, "ShadowHandCube": 44.0,
                       "ShadowHandReachSequential": 1715.0, "ShadowHandFreeReachSequential": 1715.0}
# Past this many env steps per cycle, a task without a measured rate is called GPU-sized.
GPU_SIZED_STEPS = 65536
# At most 32 environments for a CPU run: a hand task's cycle stays within seconds to a minute on 2 cores. (More once
# deadlocked XLA's CPU thread pool on 2 cores; angora_jax/cpu_threads.py has the cause and sizes the pool against it.)
CPU_ENVS = 32


def cpu_note(config: Config, physics: dict, on_gpu: bool) -> str | None:
    """A warning for a run on MJX (`physics`: `Env.physics_info()`) without a GPU whose cycle would take more than
    5 minutes, or whose cycles more than an hour with more than `CPU_ENVS` environments, at the measured CPU rate
    (or, for tasks without one, more than `GPU_SIZED_STEPS` env steps): the env steps per cycle, the estimated time
    per cycle and in all, and a CPU-sized override (`ppo.num_envs`, `ppo.minibatch_size`).
    None on a GPU, on the eager C MuJoCo path, or for a run small enough."""
    if on_gpu or not physics.get("engine", "").startswith("MuJoCo MJX"):
        return None
    ppo = config.ppo
    steps = ppo.num_envs * ppo.rollout_length
    rate = CPU_ENV_STEPS_PER_S.get(config.env.task)
    long = ppo.num_cycles * steps / rate >= 3600 and ppo.num_envs > CPU_ENVS if rate else False  # the override helps
    if (steps / rate < 300 and not long) if rate else steps <= GPU_SIZED_STEPS:
        return None
    envs = min(CPU_ENVS, ppo.num_envs)
    minibatch = envs // (4 if envs % 4 == 0 else 1) * ppo.rollout_length  # 4 minibatches of whole trajectories
    override = f"ppo.num_envs={envs} ppo.minibatch_size={minibatch}"
    cost = "" if rate is None else (
        f", about {_duration(steps / rate)} per cycle ({_duration(ppo.num_cycles * steps / rate)} for its "
        f"{counted(ppo.num_cycles, 'cycle')}) at the {rate:,.0f} env steps/s that 2 CPU cores ran "
        "(benchmarks/results/physics_throughput/physics_throughput_cpu.json; "
        f"{_duration(envs * ppo.rollout_length / rate)} with the override; compiling the first cycle adds about a "
        "minute, 53 s for the cube from an empty compilation cache)")
    return (f"Note: no GPU found, and this config is sized for one: {ppo.num_envs:,} envs x {ppo.rollout_length} steps "
            f"= {steps:,} env steps per cycle on {physics['engine']} on the CPU{cost}. For a CPU run, add: {override}; "
            "for the GPU, install JAX's CUDA build and warp-lang (README, `angora-jax doctor`).")


def _duration(seconds: float) -> str:
    """`seconds` in the largest fitting unit, e.g. '276 days', '3.3 hours', '47 s', '0.3 s'."""
    if seconds >= 3 * 86400:
        return f"{seconds / 86400:,.0f} days"
    if seconds >= 5400:
        return f"{seconds / 3600:.1f} hours"
    if seconds >= 90:
        return f"{seconds / 60:.0f} minutes"
    return f"{seconds:.0f} s" if seconds >= 10 else f"{seconds:.1f} s"
