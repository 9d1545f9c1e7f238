"""A lower bound on the memory a training run needs on each device, from shapes alone (nothing is compiled or
allocated): sizes that cannot fit are refused before a run starts, with the estimate that rules them out.

Counted: the environment states the run keeps (one per environment: physics, observations, task state) and the
transitions one cycle stores (`rollout_length` per environment: observations, action, log-probability, value,
reward, flags, episode statistics, task metrics). Not counted: parameters and optimizer state (small next to these
at the sizes that fail), the physics' temporaries and XLA's buffers, and on MuJoCo Warp the physics state (Warp's
contact and constraint buffers are shared by the whole batch and sized to it, `Env.sized_for`, so one environment's
state does not show what a batch costs), so a run that passes may still run out of memory, but one that fails cannot
fit.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

import jax
import numpy as np

from angora_jax.envs.core import Env
from angora_jax.ppo.config import PPOConfig

# Per transition besides the observation and the action: log-probability, value, reward, done, truncated, final
# value, reset, episode return and length (float32 each).
_SCALARS_PER_TRANSITION = 9
GIB = 2**30


@dataclass(frozen=True)
class MemoryEstimate:
    """The memory a run needs at least on each device, in bytes, and what the device offers.

    Attributes:
        env_state: bytes of one environment's state.
        transition: bytes of one stored transition.
        num_envs: environments on each device.
        rollout_length: transitions stored per environment in a cycle.
        available: what the device offers (GPU: XLA's memory limit; CPU: the host's physical memory), None when
            unknown.
        device: the device's kind, for messages.
    """

    env_state: int
    transition: int
    num_envs: int
    rollout_length: int
    available: int | None
    device: str

    @property
    def per_env(self) -> int:
        """Bytes each environment costs: its state plus its transitions of one cycle."""
        return self.env_state + self.rollout_length * self.transition

    @property
    def total(self) -> int:
        return self.num_envs * self.per_env

    @property
    def max_envs(self) -> int | None:
        """The most environments per device under the bound (None when the device's memory is unknown)."""
        return None if self.available is None else self.available // self.per_env

    def fits(self) -> bool:
        return self.available is None or self.total <= self.available

    def describe(self) -> str:
        """One sentence: what is needed, of what, against what is there."""
        states, rollout = self.num_envs * self.env_state, self.num_envs * self.rollout_length * self.transition
        there = "an unknown amount" if self.available is None else f"{self.available / GIB:,.1f} GiB"
        return (
            f"at least {self.total / GIB:,.1f} GiB per device ({self.num_envs:,} environment states of "
            f"{self.env_state:,} bytes: {states / GIB:,.1f} GiB; {self.rollout_length} x {self.num_envs:,} stored "
            f"transitions of {self.transition:,} bytes: {rollout / GIB:,.1f} GiB), against {there} on {self.device}"
        )


def estimate_memory(config: PPOConfig, env: Env, num_devices: int = 1) -> MemoryEstimate:
    """The lower bound for training `env` with `config` on `num_devices` devices (environments split evenly)."""
    state = env.state_shapes()
    if env.physics_info().get("impl") == "warp":
        state = state.replace(physics=())  # Warp's physics state is not counted (see above)
    obs_bytes = _nbytes(state.obs)
    action_bytes = max(1, env.action_spec.size) * 4
    transition = obs_bytes + action_bytes + 4 * (_SCALARS_PER_TRANSITION + len(env.metric_names))
    device = jax.local_devices()[0]
    return MemoryEstimate(
        env_state=_nbytes(state),
        transition=transition,
        num_envs=math.ceil(config.num_envs / num_devices),
        rollout_length=config.rollout_length,
        available=device_memory(device),
        device=f"{device.platform} device {device.id} ({device.device_kind})",
    )


def device_memory(device: jax.Device) -> int | None:
    """Bytes `device` can hold: XLA's limit on accelerators, the host's physical memory on the CPU."""
    stats = device.memory_stats() or {}
    if "bytes_limit" in stats:
        return int(stats["bytes_limit"])
    if device.platform == "cpu" and hasattr(os, "sysconf"):
        try:
            return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
        except (ValueError, OSError):
            return None
    return None


def _nbytes(tree) -> int:
    return sum(int(np.prod(x.shape, dtype=np.int64)) * x.dtype.itemsize for x in jax.tree.leaves(tree))
