"""Data-parallel training over local devices: one `jax.jit` of a `jax.shard_map` over a one-axis `Mesh`.

Why `shard_map` and not `pmap`: `pmap` is in maintenance mode and compiles its own way (one program per device,
arrays with a leading device axis), while `jit` + `shard_map` is the path JAX develops: the TrainState stays one
global array per leaf with a `NamedSharding` (no device axis to add or strip, so checkpoints and `eval_shape` see
the shapes of one device, but for MuJoCo Warp's per-device buffers, below), the same mesh spans several hosts
under `jax.distributed`, and the per-device body is exactly the single-device cycle with collectives switched on by
an axis name.

Layout: the N environments (their states, recurrent carries, accumulators, `discounted_return`) are split over
the mesh axis `AXIS` in contiguous blocks, N / D per device; parameters, optimizer state, normaliser statistics,
PRNG key and cycle count are replicated. With `axis_name=None` every helper here is the identity, which makes one
device the D = 1 case of the same code, compiled without collectives.
Each device makes its own environments: `init` runs data-parallel too, so an environment's state is whatever its
device's share of the batch makes it. That matters for MuJoCo Warp, whose physics state holds, besides the
per-environment leaves, buffers that one batch shares (the contact pool `contact__*`, sized for the batch the
environment was sized for, and its counters `nacon`, `ncollision`, shape `(1,)`): each device's share is sized for
N / D environments (`Env.sized_for`) and owns such a pool, so the global state holds D pools laid end to end on the
same axis (`nacon` is `(D,)`), as `pmap` would stack them. Those buffers are scratch that every physics step
refills, so they carry nothing from one step to the next.

Equivalence: D devices compute what one device computes, up to floating-point summation order.

- Random numbers depend on the environment, not on the device: the rollout key is split into one key per global
  environment and each device takes its block (`local_share`); environment states (and their auto-reset keys)
  come from the global environment keys the same way.
- Minibatches are drawn from the replicated key over the global (trajectory, chunk) grid, the same for any D, and
  each device computes the gradient of its equal share of every global minibatch; gradients are averaged
  (`pmean`), advantages normalised by the whole minibatch's mean and std, normaliser statistics pooled exactly.
  The share needs no data movement because the sampling is stratified (`tbptt.minibatch_indices`): the N
  trajectories form n contiguous blocks (n = trajectories per minibatch tile), each minibatch takes one
  trajectory of every block, and a device holds n / D whole blocks, so its share of every minibatch is already in
  its memory. The alternative, an `all_gather` of the rollout's training batch (observations, resets, actions,
  log-probabilities, values, advantages, targets, chunk-start carries) so that every device can pick any
  trajectory, would send every device the (D - 1) / D of the batch it lacks, every cycle, and hold all of it on
  every device: the batch is 28 MB per cycle at configs/shadow_reach.yaml's size (4,096 envs x 16 steps, `simple`:
  432 bytes per transition), 1.45 GB at configs/shadow_ihom_paper.yaml's (16,384 x 48, `wide`: 1,848 bytes). The price
  of stratification is a constraint: D must divide the tile's n (`per_device` says so).
Traffic that stays: one gradient all-reduce per minibatch (reach: 0.70 MB x 64 updates = 45 MB per cycle; IHOM:
52 MB x 192 = 10 GB per cycle), one per rollout step for the normaliser (every modality's moments together), one
per epoch for the advantage statistics of all its minibatches, and the metrics once per cycle. Small all-reduces
cost their latency, not their bytes, so each pools everything it can in one (`normalization.pooled_moments`).
MuJoCo Warp on 4 H100s (32-step fast cube, weak scaling, 16,384 envs per GPU): one process per GPU 1.97x on 2 and 3.94x
on 4; one process driving all GPUs 1.87x on 2 and 3.87x on 4 (10 cycles). That layout once hung after 3 cycles on 4
GPUs, when Warp's cache of captured CUDA graphs, 32 per call by default, began evicting (one process needs a set per
GPU; `mjx_env.size_warp_graph_cache` keeps 32 per device;
benchmarks/results/scaling/scaling_ShadowHandCube_weak_one_4xh100.json).
Only one process per GPU is measured over whole runs, so it is the layout to use there.
Measured on two H200s (reach, weak scaling, 4,096 envs per GPU; benchmarks/results/scaling/scaling_*): 1.76x one
GPU's rate with one process driving both, 1.81x with one process per GPU. Communication is not what is lost: the
same program on one GPU (this `shard_map` over a one-device mesh) runs at 0.91 of the plain `jax.jit` cycle, and two
GPUs run it at 1.97x that. Under the Shardy partitioner it runs at 0.96 on one GPU, but Shardy cannot compile it for
two (see `DataParallel`). Two independent single-GPU runs side by side keep 0.98-1.0 each, and removing the per-step
all-reduce (the normaliser updated once per rollout) did not change the ratio, so neither the host nor the lockstep
costs more. The compiled programs show why: the reach env step's position stage has 264 gathers in the data-parallel
program against 119 in the plain one, 117 of them indexed through `jnp.take` index arithmetic on constants of the
MJX model that XLA did not fold, because shard_map took the 827 closed-over constants as operands and XLA carried
them through the rollout's loops. `data_parallel` now keeps them inside the per-device body (an inner jit); whether
that recovers the 9% is not yet measured on GPUs.
Observed on CPU (tests/test_parallel.py, CartPole, 4 forced devices against 1, 8 cycles): parameters within 2e-7
(largest parameter 0.59), identical episode returns, all other metrics within 1.1e-6; the test allows 1e-5.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding
from jax.sharding import PartitionSpec as P

from angora_jax.ppo.config import PPOConfig, tile_shape
from angora_jax.wording import counted

AXIS = "devices"


def resolve_num_devices(setting: int | str) -> int:
    """The device count a `distribution.num_devices` setting asks for: a positive int, or "all" for every device
    JAX sees (`jax.device_count()`). Raises ValueError naming the key when it cannot be met."""
    available = jax.device_count()
    if setting == "all":
        return available
    if isinstance(setting, bool) or not isinstance(setting, int) or setting < 1:
        raise ValueError(f"distribution.num_devices must be a positive integer or 'all', got {setting!r}.")
    if jax.process_count() > 1 and setting != available:
        # Under jax.distributed each process would otherwise train alone on its first devices and write the same run
        # directory: the others' devices are not in its mesh, and the first checkpoint fails to save their arrays.
        raise ValueError(
            f"distribution.num_devices={setting} in a jax.distributed job of {jax.process_count()} processes, which "
            f"has {available} devices: every process trains on all of them, so set distribution.num_devices=all (a "
            "run being resumed: that line of RUN_DIR/config.yaml), or train without --distributed."
        )
    if setting > available:
        raise ValueError(
            f"distribution.num_devices={setting} but JAX sees only {counted(available, 'device')} ({jax.devices()}); "
            f"use num_devices<={available} or 'all' (on CPU, XLA_FLAGS=--xla_force_host_platform_device_count=K "
            "makes K)."
        )
    return setting


def per_device(config: PPOConfig, num_devices: int) -> PPOConfig:
    """The config one device runs: `num_envs` and `minibatch_size` are run totals, divided over the devices.

    Raises ValueError naming the keys when a total is not a multiple of `num_devices`, or when the devices cannot
    take equal shares of every minibatch tile (its trajectory count n must be a multiple of `num_devices`, see the
    module docstring).
    """
    if num_devices == 1:
        return config
    for name in ("num_envs", "minibatch_size"):
        total = getattr(config, name)
        if total % num_devices:
            raise ValueError(
                f"ppo.{name}={total} is a run total split over distribution.num_devices={num_devices} devices, so it "
                f"must be a multiple of {num_devices}; {_fix(config, name, num_devices)}."
            )
    trajectories, chunks = tile_shape(config.validate())
    if trajectories % num_devices:
        suggestion = _shareable_minibatch_size(config, num_devices)
        fix = f"use e.g. ppo.minibatch_size={suggestion}" if suggestion else "use more ppo.num_envs"
        raise ValueError(
            f"ppo.minibatch_size={config.minibatch_size} makes minibatch tiles of n="
            f"{counted(trajectories, 'trajectory', 'trajectories')} x m={counted(chunks, 'chunk')} (of ppo.num_envs="
            f"{config.num_envs} trajectories); distribution.num_devices={num_devices} devices each take an equal "
            f"share of a tile's trajectories, so their count must be a multiple of {num_devices}; {fix}."
        )
    return config.replace(num_envs=config.num_envs // num_devices, minibatch_size=config.minibatch_size // num_devices)


def _fix(config: PPOConfig, name: str, num_devices: int) -> str:
    """Settings that make `config` fit `num_devices` devices, starting from the multiple of `num_devices` nearest to
    its `name` (num_envs or minibatch_size), with a shareable minibatch size beside it where that alone does not do:
    a suggestion that fails on the next rule helps nobody."""

    def fits(**settings: int) -> bool:
        # per_device's rules without its messages: building them suggests settings in turn, which for every
        # candidate here took seconds (4,095 envs) to minutes on the way to one refusal.
        candidate = config.replace(**settings)
        if (candidate.num_envs % num_devices or candidate.minibatch_size % num_devices
                or candidate.minibatch_size % candidate.chunk_length):
            return False
        tile = tile_shape(candidate)  # n x m whole chunks make the minibatch, so it divides the rollout's batch
        return tile is not None and tile[0] % num_devices == 0

    total = getattr(config, name)
    nearest = sorted(range(num_devices, 4 * total + num_devices, num_devices), key=lambda n: (abs(n - total), -n))
    single = next((n for n in nearest if fits(**{name: n})), None)
    if single is not None:
        return f"use e.g. ppo.{name}={single}"
    if name == "num_envs":
        minibatch = _shareable_minibatch_size(config.replace(num_envs=nearest[0]), num_devices)
        if minibatch and fits(num_envs=nearest[0], minibatch_size=minibatch):
            return f"use e.g. ppo.num_envs={nearest[0]} ppo.minibatch_size={minibatch}"
    return f"use a multiple of {num_devices} that also fits the minibatch rules"


def _shareable_minibatch_size(config: PPOConfig, num_devices: int) -> int | None:
    """The valid minibatch size closest to the configured one whose tile `num_devices` devices can share, if any."""
    batch = config.num_envs * config.rollout_length
    candidates = []
    for size in range(config.chunk_length, batch + 1, config.chunk_length):
        if batch % size == 0:
            tile = tile_shape(config.replace(minibatch_size=size))
            if tile is not None and tile[0] % num_devices == 0:
                candidates.append(size)
    return min(candidates, key=lambda size: abs(size - config.minibatch_size), default=None)


def axis_name(num_devices: int) -> str | None:
    """The mesh axis the collectives reduce over, or None on one device (no collectives at all)."""
    return None if num_devices == 1 else AXIS


def pmean(x: Any, axis: str | None) -> Any:
    """Mean over devices (identity when `axis` is None)."""
    return x if axis is None else jax.lax.pmean(x, axis)


def psum(x: Any, axis: str | None) -> Any:
    """Sum over devices (identity when `axis` is None)."""
    return x if axis is None else jax.lax.psum(x, axis)


def local_share(x: jax.Array, axis: str | None) -> jax.Array:
    """This device's block of the leading axis of a replicated `x` (length a multiple of D): block d of D equal
    contiguous blocks on device d, the layout of `P(AXIS)`; all of `x` when `axis` is None."""
    if axis is None:
        return x
    size = x.shape[0] // jax.lax.axis_size(axis)
    return jax.lax.dynamic_slice_in_dim(x, jax.lax.axis_index(axis) * size, size)


def host_copy(tree: Any) -> Any:
    """This process's copy of a tree of replicated arrays, as NumPy arrays read from its first device. No program
    runs: under jax.distributed an operation on the global arrays would be a program over every process's devices,
    which all processes must run (one process computing alone waits for the others)."""
    return jax.tree.map(lambda x: np.asarray(x.addressable_data(0)), tree)


def environment_keys(key: jax.Array, num_envs: int, axis: str | None) -> jax.Array:
    """`(N / D,)` keys for this device's environments: the replicated `key` split into one key per environment of
    the run's `num_envs`, so an environment's random stream does not depend on the device count."""
    return local_share(jax.random.split(key, num_envs), axis)


@dataclass(frozen=True)
class DataParallel:
    """A per-device function of one argument compiled over a device mesh (built by `data_parallel`); called,
    lowered and shape-evaluated like a `jax.jit` function, on an argument in any layout (each call first lays it
    out, see `place`)."""

    compiled: Any  # jit of the shard_map
    shardings: Any  # NamedSharding per leaf of the argument (a prefix tree of it)
    platform: str

    def __call__(self, arg: Any) -> Any:
        with self._partitioner():
            return self.compiled(self.place(arg))

    def lower(self, arg: Any) -> jax.stages.Lowered:
        """The lowered program (for `.compile()`, its HLO text, or an ahead-of-time compiled executable)."""
        with self._partitioner():
            return self.compiled.lower(self.place(arg))

    def place(self, arg: Any) -> Any:
        """A global value (fresh, or restored from a checkpoint onto one device) in the data-parallel layout; traced
        values (under `jax.eval_shape`) pass as they are."""
        return jax.tree.map(
            lambda sharding, part: jax.tree.map(lambda leaf: _put(leaf, sharding), part),
            self.shardings,
            arg,
            is_leaf=lambda x: isinstance(x, NamedSharding),
        )

    @contextlib.contextmanager
    def _partitioner(self) -> Iterator[None]:
        if self.platform != "gpu":
            yield
            return
        # XLA's GPU compiler segfaults on this program under the Shardy partitioner (jax 0.11.2, two H200s: a
        # plain shard_map psum compiles, the cycle crashes in backend_compile_and_load, CartPole as well as reach);
        # GSPMD compiles and runs it. The flag is part of jit's cache key, so setting it around the call suffices.
        previous = jax.config.jax_use_shardy_partitioner
        jax.config.update("jax_use_shardy_partitioner", False)
        try:
            yield
        finally:
            jax.config.update("jax_use_shardy_partitioner", previous)


def data_parallel(body: Callable[[Any], Any], in_specs: Any, out_specs: Any, num_devices: int) -> DataParallel:
    """Compile the per-device `body(arg)` over the first `num_devices` devices.

    The result's `place(arg)` lays a global argument out.

    Args:
        body: the computation of one device.
        in_specs: PartitionSpecs (a prefix tree) of the argument: `P(AXIS)` for leaves whose leading axis is split over
            the devices (environments: each device holds N / D of them, and whatever else its share owns, such as
            MuJoCo Warp's contact pool), `P()` for replicated ones.
        out_specs: PartitionSpecs of the result, as for `in_specs`; outputs specified `P()` must be equal on every
            device (the collectives ensure it).
        num_devices: the devices to run on.
    """
    mesh = Mesh(np.array(jax.devices()[:num_devices]), (AXIS,))
    shardings = jax.tree.map(lambda spec: NamedSharding(mesh, spec), in_specs, is_leaf=lambda x: isinstance(x, P))
    # The inner jit keeps the constants `body` closes over (the MJX model) inside the per-device body, where XLA
    # folds them as in the plain cycle; shard_map alone would take them as operands (module docstring).
    # Environments build some state from constants (e.g. empty modalities), which the varying-manual-axes check
    # would reject as a scan carry changing type; replication of the P() outputs is ensured by the collectives.
    compiled = jax.jit(jax.shard_map(jax.jit(body), mesh=mesh, in_specs=(in_specs,), out_specs=out_specs,
                                     check_vma=False))
    return DataParallel(compiled, shardings, mesh.devices.flat[0].platform)


def _put(leaf: Any, sharding: NamedSharding) -> jax.Array:
    """`leaf` laid out by `sharding`; across hosts every process holds the same global value (same seed, same
    checkpoint) and contributes the slices of its own devices, since `device_put` reaches only local devices."""
    if isinstance(leaf, jax.core.Tracer) or (isinstance(leaf, jax.Array) and leaf.sharding == sharding):
        return leaf
    if jax.process_count() == 1:
        return jax.device_put(leaf, sharding)
    if jax.dtypes.issubdtype(leaf.dtype, jax.dtypes.prng_key):
        return jax.random.wrap_key_data(_put(jax.random.key_data(leaf), sharding), impl=jax.random.key_impl(leaf))
    value = np.asarray(leaf)
    return jax.make_array_from_callback(value.shape, sharding, lambda index: value[index])
