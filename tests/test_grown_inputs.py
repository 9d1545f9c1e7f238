"""`ppo.grown_inputs` on a small value network, without an environment: the fast counterpart of
`test_randomization::test_init_from_a_run_without_value_sees_physics_carries_its_value_function_over`, which runs the
same code through `ppo.init_from` on the reach task and four networks (slow tier but for none)."""

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from angora_jax.envs.core import Sensation
from angora_jax.ppo.grown_inputs import (
    asymmetric_growth,
    grown_params,
    grown_stats,
    grows_inputs_only,
    rows_reading_new_inputs,
)
from angora_jax.ppo.normalization import RunningMeanStd

# Every program here runs once or a few times on a small network (tests/quick_compile.py).
pytestmark = pytest.mark.usefixtures("quick_file_compiles")

OLD, NEW, GOAL = 5, 8, 3


class _Value(nn.Module):
    """A value function that reads `goal` and `asymmetric` as the shipped networks do: concatenated into a dense
    layer, after a second input stream (`proprioception`) through its own."""

    @nn.compact
    def __call__(self, obs: Sensation) -> jax.Array:
        body = nn.tanh(nn.Dense(4, name="body")(obs.proprioception))
        trunk = nn.tanh(nn.Dense(6, name="trunk")(jnp.concatenate([obs.goal, body, obs.asymmetric], axis=-1)))
        return nn.Dense(1, name="out")(trunk)[..., 0]


def _obs(key: jax.Array, asymmetric: int, batch: int = 16) -> Sensation:
    a, b, c = jax.random.split(key, 3)
    return Sensation.make(proprioception=jax.random.normal(a, (batch, 2)), goal=jax.random.normal(b, (batch, GOAL)),
                          asymmetric=jax.random.normal(c, (batch, asymmetric)))


def _stats(asymmetric: int, shift: float = 0.0, count: float = 1e-4) -> Sensation:
    def stats(size: int) -> RunningMeanStd:
        return RunningMeanStd(jnp.full((size,), shift), jnp.full((size,), 1.0 + shift), jnp.asarray(count))
    return Sensation(proprioception=stats(2), touch=stats(0), muscle=stats(0), vision=stats(0), goal=stats(GOAL),
                     asymmetric=stats(asymmetric))


@pytest.fixture(scope="module")
def saved_and_current():
    model = _Value()
    init = jax.jit(model.init)
    saved = init(jax.random.key(0), _obs(jax.random.key(1), OLD))["params"]
    current = init(jax.random.key(2), _obs(jax.random.key(1), NEW))["params"]
    return model, saved, current


def test_the_growth_is_counted_only_when_asymmetric_alone_grew_at_its_end():
    assert asymmetric_growth(_stats(NEW), _stats(OLD)) == NEW - OLD
    assert asymmetric_growth(_stats(OLD), _stats(OLD)) == 0
    assert asymmetric_growth(_stats(OLD), _stats(NEW)) == 0, "fewer inputs is not growth"
    other = _stats(NEW).replace(goal=RunningMeanStd.create((GOAL + 1,)))
    assert asymmetric_growth(other, _stats(OLD)) == 0, "another modality differs"


def test_only_kernels_with_the_growth_in_their_rows_count_as_grown(saved_and_current):
    _, saved, current = saved_and_current
    assert grows_inputs_only(current, saved, NEW - OLD)
    assert not grows_inputs_only(current, saved, NEW - OLD + 1)
    wider = jax.tree.map(lambda x: x, saved)
    wider["out"]["kernel"] = jnp.zeros((7, 1))
    assert not grows_inputs_only(current, wider, NEW - OLD), "a layer grown by another count"
    assert not grows_inputs_only({**current, "extra": {"bias": jnp.zeros(1)}}, saved, NEW - OLD)


def test_the_rows_reading_the_new_entries_are_found_and_start_at_zero(saved_and_current):
    """The trunk's kernel reads [goal (3), body (4), asymmetric (8)]: rows 12-14 read the new entries, nothing else
    does. With them at zero the grown model's value equals the saved model's for any inputs, the new entries
    whatever they are."""
    model, saved, current = saved_and_current

    @jax.jit
    def value_of(params, obs):
        return model.apply({"params": params}, obs)

    shapes = jax.tree.map(lambda x: jax.ShapeDtypeStruct(x.shape[1:], x.dtype), _obs(jax.random.key(3), NEW))
    rows = rows_reading_new_inputs(value_of, current, shapes, OLD, jax.random.key(4))
    expected = np.zeros(GOAL + 4 + NEW, bool)
    expected[GOAL + 4 + OLD:] = True
    np.testing.assert_array_equal(rows["trunk"]["kernel"], expected)
    assert not any(np.any(mask) for path, mask in jax.tree_util.tree_leaves_with_path(rows)
                   if jax.tree_util.keystr(path) != "['trunk']['kernel']")

    grown = grown_params(current, saved, rows)
    np.testing.assert_array_equal(grown["trunk"]["kernel"][GOAL + 4 + OLD:], 0.0)
    np.testing.assert_array_equal(grown["trunk"]["kernel"][:GOAL + 4 + OLD], saved["trunk"]["kernel"])
    obs = _obs(jax.random.key(5), NEW)
    old_view = obs.replace(asymmetric=obs.asymmetric[:, :OLD])
    np.testing.assert_allclose(value_of(grown, obs), value_of(saved, old_view), rtol=1e-6, atol=1e-6)

    too_few = jax.tree.map(lambda mask: mask.at[-1].set(False) if np.ndim(mask) else mask,
                           jax.tree.map(jnp.asarray, rows))
    assert grown_params(current, saved, too_few) is None, "marked rows that do not number the growth"


def test_the_statistics_keep_the_old_entries_and_start_the_count_afresh():
    fresh, saved = _stats(NEW), _stats(OLD, shift=0.5, count=9.0)
    stats = grown_stats(fresh, saved)
    np.testing.assert_array_equal(stats.asymmetric.mean[:OLD], 0.5)
    np.testing.assert_array_equal(stats.asymmetric.var[:OLD], 1.5)
    np.testing.assert_array_equal(stats.asymmetric.mean[OLD:], 0.0)
    np.testing.assert_array_equal(stats.asymmetric.var[OLD:], 1.0)
    assert float(stats.asymmetric.count) == pytest.approx(1e-4), "the first batch must set the new entries"
    assert float(stats.goal.count) == 9.0 and float(stats.goal.mean[0]) == 0.5, "other modalities as saved"
