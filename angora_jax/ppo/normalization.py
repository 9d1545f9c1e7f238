"""Running normalisation as pure functional state: observations per modality, rewards by the return's scale.

`RunningMeanStd` merges batches with the parallel (Chan et al.) form of Welford's algorithm, so one update per
batch gives the same result as feeding the samples one at a time. Under data parallelism (`axis_name` set) the
devices' equal-sized batches are pooled exactly before the merge, so every device holds the stats of the whole batch.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
from flax import struct

from angora_jax.envs.core import Sensation, is_image

_EPS = 1e-8


@struct.dataclass
class RunningMeanStd:
    """Mean and (population) variance of everything seen so far, per feature; `count` is a float32 scalar."""

    mean: jax.Array
    var: jax.Array
    count: jax.Array

    @classmethod
    def create(cls, shape: tuple[int, ...] = ()) -> RunningMeanStd:
        """Start with mean 0, variance 1 and a tiny count, so the first batch dominates at once."""
        return cls(jnp.zeros(shape, jnp.float32), jnp.ones(shape, jnp.float32), jnp.asarray(1e-4, jnp.float32))

    def update(self, batch: jax.Array, axis_name: str | None = None) -> RunningMeanStd:
        """Merge `batch` of shape `(..., *mean.shape)`; all leading axes are samples. With `axis_name`, the batches
        of all devices on that mapped axis are merged as one (each device passes its own, all of equal size)."""
        samples = math.prod(batch.shape[: batch.ndim - self.mean.ndim])
        x = batch.reshape((samples,) + self.mean.shape).astype(jnp.float32)
        n = jnp.asarray(samples, jnp.float32)
        batch_mean, batch_var = x.mean(0), x.var(0)
        if axis_name is not None:
            batch_mean, batch_var = pooled_moments(batch_mean, batch_var, axis_name, shift=self.mean)
            n = n * jax.lax.psum(1, axis_name)
        total = self.count + n
        delta = batch_mean - self.mean
        mean = self.mean + delta * n / total
        m2 = self.var * self.count + batch_var * n + delta**2 * self.count * n / total
        return RunningMeanStd(mean, m2 / total, total)

    def normalize(self, x: jax.Array, clip: float) -> jax.Array:
        """`(x - mean) / std`, clipped to +-clip."""
        return jnp.clip((x - self.mean) / jnp.sqrt(self.var + _EPS), -clip, clip)

    def scale(self, x: jax.Array, clip: float) -> jax.Array:
        """`x / std` (no centring, as for rewards), clipped to +-clip."""
        return jnp.clip(x / jnp.sqrt(self.var + _EPS), -clip, clip)


def pooled_moments(
    mean: jax.Array, var: jax.Array, axis_name: str, shift: jax.Array | float = 0.0
) -> tuple[jax.Array, jax.Array]:
    """Mean and (population) variance of the union of the devices' equal-sized batches on `axis_name`, from each
    batch's own `mean` and `var`: Chan's merge of D batches in closed form, E[var_d + (mean_d - m)^2], in a single
    all-reduce (its latency, not its bytes, is what a rollout step or minibatch pays for it).

    `shift`, the same on every device (e.g. the running mean), conditions the one-pass form: the offsets from it
    are small, so E[(mean_d - shift)^2] - (m - shift)^2 loses no precision to cancellation.
    """
    offset = mean - shift
    pooled_offset, second_moment = jax.lax.pmean((offset, var + offset**2), axis_name)
    return shift + pooled_offset, jnp.maximum(second_moment - pooled_offset**2, 0.0)


def observation_stats(obs: Sensation) -> Sensation:
    """One `RunningMeanStd` per modality, shaped like a single observation `obs` (no batch axis).

    `obs` may hold arrays or `jax.ShapeDtypeStruct`s (e.g. `env.observation_shapes()`). Camera images get empty
    stats (shape `(0,)`): pixels keep their uint8 scale, which the visual encoder maps to [-0.5, 0.5] itself.
    """
    return jax.tree.map(lambda leaf: RunningMeanStd.create((0,) if is_image(leaf) else leaf.shape[-1:]), obs)


def update_observation_stats(stats: Sensation, obs: Sensation, axis_name: str | None = None) -> Sensation:
    """Merge a batch of observations (leaves `(..., size)`) into the per-modality stats (pooled over the devices
    on `axis_name` when given, see `RunningMeanStd.update`); images pass by."""
    return jax.tree.map(lambda s, x: s if is_image(x) else s.update(x, axis_name), stats, obs, is_leaf=_is_stats)


def normalize_observation(stats: Sensation, obs: Sensation, clip: float) -> Sensation:
    """Normalise every modality of `obs` (leaves `(..., size)`) by its running stats; images stay as they are."""
    return jax.tree.map(lambda s, x: x if is_image(x) else s.normalize(x, clip), stats, obs, is_leaf=_is_stats)


def discounted_returns(
    returns: jax.Array, rewards: jax.Array, dones: jax.Array, gamma: float
) -> tuple[jax.Array, jax.Array]:
    """Per-env running discounted return, whose std sets the reward scale.

    Args:
        returns: `(N,)` carried over from the previous cycle.
        rewards: `(T, N)` raw rewards.
        dones: `(T, N)` 1 where an episode ended at the step.
        gamma: the discount factor.

    Returns:
        The return after each step's reward `(T, N)` and the `(N,)` value to carry on (reset to 0 where the last step
        ended an episode).
    """

    def step(ret, x):
        reward, done = x
        ret = ret * gamma + reward
        return ret * (1.0 - done), ret

    carried, seen = jax.lax.scan(step, returns, (rewards, dones))
    return seen, carried


def _is_stats(node) -> bool:
    return isinstance(node, RunningMeanStd)
