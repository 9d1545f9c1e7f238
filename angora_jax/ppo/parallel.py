"""Data-parallel training over local devices: one `jax.jit` of a `jax.shard_map` over a one-axis `Mesh`.

Why `shard_map` and not `pmap`: `pmap` is in maintenance mode and compiles its own way (one program per device,
arrays with a leading device axis), while `jit` + `shard_map` is the path JAX develops: the TrainState stays one
global array per leaf with a `NamedSharding` (no device axis to add or strip, so checkpoints and `eval_shape` see
the same shapes as on one device), the same mesh spans several hosts under `jax.distributed`, and the per-device
body is exactly the single-device cycle with collectives switched on by an axis name.

Layout: the N environments (their states, recurrent carries, accumulators, `discounted_return`) are split over
the mesh axis `AXIS`, N / D per device; parameters, optimizer state, normaliser statistics, PRNG key and cycle
count are replicated. Each device rolls out its own environments with its own key (`device_key`), computes the
gradients of its share of every minibatch, and the gradients (`pmean`), normaliser updates (exact pooled merge in
`RunningMeanStd.update`) and metrics are combined across devices, so the replicated values stay identical.
With `axis_name=None` every helper here is the identity, which makes one device the D = 1 case of the same code.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding
from jax.sharding import PartitionSpec as P

from angora_jax.ppo.config import PPOConfig

AXIS = "devices"


def resolve_num_devices(setting: int | str) -> int:
    """The device count a `distribution.num_devices` setting asks for: a positive int, or "all" for every device
    JAX sees (`jax.device_count()`). Raises ValueError naming the key when it cannot be met."""
    available = jax.device_count()
    if setting == "all":
        return available
    if isinstance(setting, bool) or not isinstance(setting, int) or setting < 1:
        raise ValueError(f"distribution.num_devices must be a positive integer or 'all', got {setting!r}.")
    if setting > available:
        raise ValueError(
            f"distribution.num_devices={setting} but JAX sees only {available} device(s) ({jax.devices()}); use "
            f"num_devices<={available} or 'all' (on CPU, XLA_FLAGS=--xla_force_host_platform_device_count=K makes K)."
        )
    return setting


def per_device(config: PPOConfig, num_devices: int) -> PPOConfig:
    """The config one device runs: `num_envs` and `minibatch_size` are run totals, divided over the devices.

    Raises ValueError naming the keys when a total is not a multiple of `num_devices` or the per-device share
    admits no minibatch tile.
    """
    if num_devices == 1:
        return config
    for name in ("num_envs", "minibatch_size"):
        total = getattr(config, name)
        if total % num_devices:
            raise ValueError(
                f"ppo.{name}={total} is a run total split over distribution.num_devices={num_devices} devices, so it "
                f"must be a multiple of {num_devices}; use e.g. ppo.{name}={(total // num_devices + 1) * num_devices}."
            )
    local = config.replace(num_envs=config.num_envs // num_devices, minibatch_size=config.minibatch_size // num_devices)
    try:
        return local.validate()
    except ValueError as error:
        raise ValueError(
            f"per device (ppo.num_envs={local.num_envs}, ppo.minibatch_size={local.minibatch_size} of "
            f"distribution.num_devices={num_devices}): {error}"
        ) from None


def axis_name(num_devices: int) -> str | None:
    """The mesh axis the collectives reduce over, or None on one device (no collectives at all)."""
    return None if num_devices == 1 else AXIS


def pmean(x: Any, axis: str | None) -> Any:
    """Mean over devices (identity when `axis` is None)."""
    return x if axis is None else jax.lax.pmean(x, axis)


def psum(x: Any, axis: str | None) -> Any:
    """Sum over devices (identity when `axis` is None)."""
    return x if axis is None else jax.lax.psum(x, axis)


def device_key(key: jax.Array, axis: str | None) -> jax.Array:
    """A key of this device's own: the replicated `key` folded with the device index (unchanged on one device)."""
    return key if axis is None else jax.random.fold_in(key, jax.lax.axis_index(axis))


def state_specs(state: Any) -> Any:
    """PartitionSpecs for a TrainState: environments split over `AXIS` (leading axis N), everything else replicated."""
    return state.replace(
        params=P(),
        opt_state=P(),
        obs_stats=P(),
        reward_stats=P(),
        discounted_return=P(AXIS),
        actor=P(AXIS),
        key=P(),
        cycle=P(),
    )


def data_parallel(
    cycle: Callable[[Any], tuple[Any, dict[str, jax.Array]]], state_shape: Any, num_devices: int
) -> tuple[Callable[[Any], Any], Callable[[Any], tuple[Any, dict[str, jax.Array]]]]:
    """Compile the per-device `cycle(state) -> (state, metrics)` over the first `num_devices` devices.

    state_shape: the global TrainState (or its `jax.eval_shape`), to lay out the state. Returns `place(state)`,
    which puts a global state (fresh, or restored from a checkpoint onto one device) into the data-parallel layout,
    and the compiled `cycle` on placed states; metrics come back replicated (already reduced over devices).
    """
    mesh = Mesh(np.array(jax.devices()[:num_devices]), (AXIS,))
    specs = state_specs(state_shape)
    shardings = jax.tree.map(lambda spec: NamedSharding(mesh, spec), specs, is_leaf=lambda x: isinstance(x, P))
    # Environments build some state from constants (e.g. empty modalities), which the varying-manual-axes check
    # would reject as a scan carry changing type; replication of the P() outputs is ensured by the collectives.
    mapped = jax.jit(jax.shard_map(cycle, mesh=mesh, in_specs=(specs,), out_specs=(specs, P()), check_vma=False))

    def place(state: Any) -> Any:
        return jax.tree.map(
            lambda sharding, part: jax.tree.map(lambda leaf: _put(leaf, sharding), part),
            shardings,
            state,
            is_leaf=lambda x: isinstance(x, NamedSharding),
        )

    return place, mapped


def _put(leaf: Any, sharding: NamedSharding) -> jax.Array:
    """`leaf` laid out by `sharding`; across hosts every process holds the same global value (same seed, same
    checkpoint) and contributes the slices of its own devices, since `device_put` reaches only local devices."""
    if isinstance(leaf, jax.Array) and leaf.sharding == sharding:
        return leaf
    if jax.process_count() == 1:
        return jax.device_put(leaf, sharding)
    if jax.dtypes.issubdtype(leaf.dtype, jax.dtypes.prng_key):
        return jax.random.wrap_key_data(_put(jax.random.key_data(leaf), sharding), impl=jax.random.key_impl(leaf))
    value = np.asarray(leaf)
    return jax.make_array_from_callback(value.shape, sharding, lambda index: value[index])
