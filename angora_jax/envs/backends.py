"""Where a MuJoCo task runs: "mjx" (batched and jit-able: training, batched evaluation) or "cpu" (its eager C MuJoCo
twin: evaluation, rendering, the gymnasium view, parity checks against other implementations)."""

from __future__ import annotations

from angora_jax.envs.core import Env
from angora_jax.envs.cpu_env import CpuEnv
from angora_jax.envs.mjx_env import MjxEnv
from angora_jax.envs.mujoco_task import MujocoTask

BACKENDS = ("mjx", "cpu")


def on_backend(backend: str, task: MujocoTask, frame_skip: int, max_episode_steps: int,
               warp_max_envs: int | None = None) -> Env:
    """`task` with `frame_skip` physics steps per policy step on `backend`; ValueError naming the choices otherwise.

    Args:
        warp_max_envs: the batch MuJoCo Warp's buffers hold (None: sized by the trainer, `Env.sized_for`).
    """
    if backend not in BACKENDS:
        raise ValueError(f"Unknown backend {backend!r}; choose one of {BACKENDS}.")
    if backend == "cpu":
        return CpuEnv(task, frame_skip=frame_skip, max_episode_steps=max_episode_steps)
    return MjxEnv(task, frame_skip, max_episode_steps, warp_max_envs=warp_max_envs)
