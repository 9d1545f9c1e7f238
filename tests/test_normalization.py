"""Running normalisation: batched merges equal whole-data statistics, per-modality stats with empty modalities,
reward scaling by the discounted return."""

import jax
import jax.numpy as jnp
import numpy as np

from angora_jax.envs.core import Sensation
from angora_jax.ppo.normalization import (
    RunningMeanStd,
    discounted_returns,
    normalize_observation,
    observation_stats,
    update_observation_stats,
)


def test_parallel_merge_equals_statistics_of_all_data():
    rng = np.random.default_rng(0)
    batches = [rng.normal(3.0, 2.0, (n, 4)).astype(np.float32) for n in (5, 17, 1, 40)]
    stats = RunningMeanStd.create((4,))
    for batch in batches:
        stats = stats.update(jnp.asarray(batch))
    everything = np.concatenate(batches)
    np.testing.assert_allclose(stats.mean, everything.mean(0), rtol=1e-4, atol=1e-4)
    np.testing.assert_allclose(stats.var, everything.var(0), rtol=1e-3)
    np.testing.assert_allclose(stats.count, len(everything), rtol=1e-5)


def test_a_merge_over_a_device_axis_equals_one_merge_of_the_whole_batch():
    """The fast tier's check of the pooled merge (tests/test_parallel.py checks it on four devices): shares of a
    batch on a vmapped axis merge as the whole batch does, count included, from a start that has seen data."""
    rng = np.random.default_rng(1)
    start = RunningMeanStd.create((3,)).update(jnp.asarray(rng.normal(-1.0, 0.5, (8, 3)), jnp.float32))
    shares = jnp.asarray(rng.normal(2.0, 3.0, (4, 10, 3)), jnp.float32)
    pooled = jax.vmap(lambda share: start.update(share, axis_name="devices"), axis_name="devices")(shares)
    whole = start.update(shares.reshape(40, 3))
    for device in range(4):
        np.testing.assert_allclose(pooled.count[device], whole.count, rtol=1e-6)
        np.testing.assert_allclose(pooled.mean[device], whole.mean, rtol=1e-5, atol=1e-6)
        np.testing.assert_allclose(pooled.var[device], whole.var, rtol=1e-5)


def test_update_treats_all_leading_axes_as_samples():
    x = jax.random.normal(jax.random.key(0), (6, 7, 3)) * 4.0 + 1.0
    a = RunningMeanStd.create((3,)).update(x)
    b = RunningMeanStd.create((3,)).update(x.reshape(42, 3))
    np.testing.assert_allclose(a.mean, b.mean, rtol=1e-6)
    np.testing.assert_allclose(a.var, b.var, rtol=1e-6)


def test_normalize_centres_scales_and_clips():
    stats = RunningMeanStd(jnp.array([1.0, -2.0]), jnp.array([4.0, 0.25]), jnp.asarray(10.0))
    out = stats.normalize(jnp.array([[3.0, -2.5], [1.0, 100.0]]), clip=5.0)
    np.testing.assert_allclose(out, [[1.0, -1.0], [0.0, 5.0]], rtol=1e-5)
    np.testing.assert_allclose(stats.scale(jnp.array([4.0]), clip=10.0), [2.0, 8.0], rtol=1e-5)


def test_observation_stats_per_modality_with_empty_modalities():
    obs = Sensation.make(
        proprioception=jax.random.normal(jax.random.key(0), (8, 5)) * 3.0 + 2.0,
        goal=jax.random.normal(jax.random.key(1), (8, 2)) - 7.0,
    )
    stats = observation_stats(jax.tree.map(lambda x: x[0], obs))
    assert stats.touch.mean.shape == (0,) and stats.proprioception.mean.shape == (5,)
    stats = update_observation_stats(stats, obs)
    normalized = normalize_observation(stats, obs, clip=10.0)
    np.testing.assert_allclose(normalized.proprioception.mean(0), 0.0, atol=1e-4)
    np.testing.assert_allclose(normalized.goal.std(0), 1.0, rtol=1e-2)
    assert normalized.vision.shape == (8, 0)


def test_discounted_returns_follow_the_recursion_and_reset_at_episode_ends():
    rewards = jnp.array([[1.0, 2.0], [1.0, 2.0], [1.0, 2.0]])
    dones = jnp.array([[0.0, 0.0], [1.0, 0.0], [0.0, 0.0]])
    seen, carried = discounted_returns(jnp.array([10.0, 0.0]), rewards, dones, gamma=0.5)
    np.testing.assert_allclose(seen[:, 0], [6.0, 4.0, 1.0])
    np.testing.assert_allclose(seen[:, 1], [2.0, 3.0, 3.5])
    np.testing.assert_allclose(carried, [1.0, 3.5])
