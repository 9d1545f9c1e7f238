"""A saved run carried into one whose value function reads more: `asymmetric` grown at its end.

Fine-tuning with `ppo.init_from` a run trained without `env.options.value_sees_physics` under that option, the value
function's inputs gain the drawn physics at the end of `asymmetric`. Everything else carries over as it is. The
weights that read the new entries start at zero, so the value function starts out as the source's, and learns to read
them. The `asymmetric` statistics keep the source's mean and variance for the entries it had, but their count starts
afresh, so the first cycle's samples set them all, the new entries included.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from angora_jax.envs.core import Sensation, is_image
from angora_jax.nets.components import shape_misfits
from angora_jax.ppo.normalization import RunningMeanStd

_PROBE_ROWS = 8


def asymmetric_growth(current: Sensation, saved: Sensation) -> int:
    """Entries that `asymmetric` gained at its end in the observation statistics `current` against `saved`, 0 when
    it did not grow or another modality differs."""
    ours, theirs = np.shape(current.asymmetric.mean), np.shape(saved.asymmetric.mean)
    if shape_misfits(current.replace(asymmetric=None), saved.replace(asymmetric=None)):
        return 0
    if len(ours) != 1 or len(theirs) != 1 or ours[0] <= theirs[0]:
        return 0
    return ours[0] - theirs[0]


def grows_inputs_only(current: Any, saved: Any, growth: int) -> bool:
    """Whether the parameter trees differ only in leaves with `growth` more rows (a dense layer's kernel, `(inputs,
    ...)`) here than in `saved`."""
    ours = dict(jax.tree_util.tree_leaves_with_path(current))
    theirs = dict(jax.tree_util.tree_leaves_with_path(saved))
    if ours.keys() != theirs.keys():
        return False
    for path, leaf in ours.items():
        mine, old = np.shape(leaf), np.shape(theirs[path])
        if mine != old and (len(mine) < 2 or mine[1:] != old[1:] or mine[0] - old[0] != growth):
            return False
    return True


def rows_reading_new_inputs(value_of: Callable[[Any, Sensation], jax.Array], params: Any, shapes: Sensation,
                            old_size: int, key: jax.Array) -> Any:
    """Per parameter leaf, a boolean mask of its first axis: the rows that read `asymmetric`'s entries from
    `old_size` on (all False for a leaf that reads none of them).

    Found by their gradients: with those entries at 0 and every other input random, a row that reads them has a
    zero gradient; with them random too, a nonzero one. Rows fed by anything else are nonzero both times. Works for
    any network that reads `asymmetric` through dense layers, wherever the entries lie in what it concatenates.

    Args:
        value_of: `(params, obs) -> values (B,)`, the model's value for a batch of observations.
        params: this run's parameters (the new shapes).
        shapes: one observation's `ShapeDtypeStruct`s (`env.observation_shapes()`).
        old_size: how many entries `asymmetric` had before.
        key: for the random probe inputs.
    """
    leaves, treedef = jax.tree.flatten(shapes)
    keys = jax.random.split(key, len(leaves))

    def batch(leaf: jax.ShapeDtypeStruct, leaf_key: jax.Array) -> jax.Array:
        shape = (_PROBE_ROWS, *leaf.shape)
        return jnp.zeros(shape, leaf.dtype) if is_image(leaf) else jax.random.normal(leaf_key, shape, leaf.dtype)

    probe = jax.tree.unflatten(treedef, [batch(leaf, k) for leaf, k in zip(leaves, keys, strict=True)])
    without = probe.replace(asymmetric=probe.asymmetric.at[:, old_size:].set(0.0))

    def row_gradients(obs: Sensation) -> Any:
        grads = jax.grad(lambda p: jnp.sum(value_of(p, obs)))(params)
        return jax.tree.map(lambda g: np.abs(np.asarray(g)).reshape(g.shape[0], -1).sum(1) if g.ndim else g, grads)

    with_new, zeroed = row_gradients(probe), row_gradients(without)
    return jax.tree.map(lambda a, b: (a > 0) & (b == 0) if np.ndim(a) else np.zeros((), bool), with_new, zeroed)


def grown_params(current: Any, saved: Any, reads_new: Any) -> Any | None:
    """`saved` in `current`'s shapes and dtypes: each grown leaf with zeros in the rows `reads_new` marks and the
    saved rows, in order, in the others. None when a grown leaf's marked rows do not number its growth."""
    ours, treedef = jax.tree.flatten(current)
    grown = []
    for mine, theirs, mask in zip(ours, treedef.flatten_up_to(saved), treedef.flatten_up_to(reads_new), strict=True):
        if np.shape(mine) == np.shape(theirs):
            grown.append(jnp.asarray(theirs, dtype=mine.dtype))
            continue
        if int(np.sum(mask)) != np.shape(mine)[0] - np.shape(theirs)[0]:
            return None
        values = np.zeros(np.shape(mine), np.asarray(theirs).dtype)
        values[~mask] = np.asarray(theirs)
        grown.append(jnp.asarray(values, dtype=mine.dtype))
    return jax.tree.unflatten(treedef, grown)


def grown_stats(current: Sensation, saved: Sensation) -> Sensation:
    """`saved` observation statistics in `current`'s shapes: `asymmetric` keeps the saved mean and variance of the
    entries it had, the new entries `current`'s (mean 0, variance 1), and the count `current`'s, so that the first
    update sets every entry from its samples."""
    fresh, old = current.asymmetric, saved.asymmetric
    size = np.shape(old.mean)[0]
    asymmetric = RunningMeanStd(jnp.asarray(fresh.mean).at[:size].set(old.mean),
                                jnp.asarray(fresh.var).at[:size].set(old.var), jnp.asarray(fresh.count))
    carried = jax.tree.map(lambda ours, theirs: jnp.asarray(theirs, dtype=ours.dtype), current.replace(asymmetric=None),
                           saved.replace(asymmetric=None))
    return carried.replace(asymmetric=asymmetric)
