"""A lower bound on the memory a training run needs on each device, from shapes alone (nothing is compiled or
allocated): sizes that cannot fit are refused before a run starts, with the estimate that rules them out.

Counted: the environment states the run keeps (one per environment: physics, observations, task state) and the
transitions one cycle stores (`rollout_length` per environment: observations, action, log-probability, value,
reward, flags, episode statistics, task metrics). Not counted: parameters and optimizer state (small next to these
at the sizes that fail; `network_too_large` checks a network of more than 4,096 units apart), the physics'
temporaries and XLA's buffers, and on MuJoCo Warp the physics state (Warp's contact and constraint buffers are
shared by the whole batch and sized to it, `Env.sized_for`, so one environment's state does not show what a batch
costs), so a run that passes may still run out of memory, but one that fails cannot fit.
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


# Network sizes up to this many units are not checked (`network_too_large`): the parameters are then small next to
# the environments, and tracing a network's initialisation costs up to seconds on every validation.
CHECKED_ABOVE_UNITS = 4096
# Parameters, their gradients and Adam's two moments: the fewest copies of the parameters an update holds.
_PARAMETER_COPIES = 4


def network_too_large(config: PPOConfig, env: Env) -> str | None:
    """None when the network fits on a device, else a sentence saying why not: the parameter count of a network
    whose `width`, `cell_size` or `memory` is above `CHECKED_ABOVE_UNITS` (from shapes: nothing is allocated), with
    the bytes of its parameters, gradients and optimizer moments, against the device's memory. A mistyped width
    (100000000 for 1000) otherwise passes every other check and stalls while its parameters are allocated."""
    network = config.network
    sizes = {key: getattr(network, key) for key in ("width", "cell_size", "memory")}
    if max((size or 0 for size in sizes.values()), default=0) <= CHECKED_ABOVE_UNITS:
        return None
    import jax.numpy as jnp

    from angora_jax.nets import make_network
    from angora_jax.ppo.cycle import build_head, build_model

    module = make_network(network)
    model = build_model(module, build_head(env, config), config)
    observations = env.observation_shapes()

    def parameters(key: jax.Array):
        obs = jax.tree.map(lambda shape: jnp.zeros((1, *shape.shape), shape.dtype), observations)
        return model.init(key, module.initial_carry(1), obs)["params"]

    # `.size` is a Python int, exact at any size (an int64 product of shapes wraps around past 2**63).
    leaves = jax.tree.leaves(jax.eval_shape(parameters, jax.random.key(0)))
    count = sum(x.size for x in leaves)
    needed = _PARAMETER_COPIES * sum(x.size * x.dtype.itemsize for x in leaves)
    device = jax.local_devices()[0]
    available = device_memory(device)
    if available is None or needed <= available:
        return None
    given = [f"ppo.network.{key}={size:,}" for key, size in sizes.items() if size]
    return (f"{', '.join(given)} make{'s' if len(given) == 1 else ''} a network of {count:,} parameters: with their "
            f"gradients and the optimizer's two moments at least {needed / GIB:,.1f} GiB, against "
            f"{available / GIB:,.1f} GiB on {device.platform} device {device.id} ({device.device_kind}). Use fewer "
            "units (the shipped configs use 32 to 512).")


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
