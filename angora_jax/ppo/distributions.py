"""Policy heads: how network features become an action distribution, on distrax.

A head has two halves. `module()` is the Flax layer that maps the policy trunk's features `(B, F)` to a flat
parameter array `(B, num_params)`; the remaining methods read that array. Actions as stored in the rollout (and
scored by `log_prob`) are in the head's own space; `env_action` turns them into what `Env.step` takes.

To add a distribution, subclass `PolicyHead`, implement `num_params` and `distribution`, override `env_action` or
`module` if needed, and `register_head("name", YourHead)`; the config's `head` field then selects it.
"""

from __future__ import annotations

import abc
from collections.abc import Callable

import distrax
import flax.linen as nn
import jax
import jax.numpy as jnp

from angora_jax.envs.core import ActionSpec
from angora_jax.registry import Registry

# Small policy-output weights make the initial policy nearly uniform / centred ("Implementation matters").
_HEAD_INIT = nn.initializers.orthogonal(0.01)


class PolicyHead(abc.ABC):
    """A parametrised action distribution for one action space; stateless apart from the spec."""

    def __init__(self, action_spec: ActionSpec):
        self.action_spec = action_spec

    @property
    @abc.abstractmethod
    def num_params(self) -> int:
        """Length of the parameter vector the network emits for one state."""

    @abc.abstractmethod
    def distribution(self, params: jax.Array) -> distrax.Distribution:
        """The distribution over stored actions for parameters `(..., num_params)`; batch shape `(...)`."""

    def module(self) -> nn.Module:
        """Flax layer from trunk features `(..., F)` to parameters `(..., num_params)`."""
        return nn.Dense(self.num_params, kernel_init=_HEAD_INIT, name="policy_head")

    def sample(self, params: jax.Array, key: jax.Array) -> jax.Array:
        """One action per parameter row, in the stored (head) space."""
        return self.distribution(params).sample(seed=key)

    def log_prob(self, params: jax.Array, action: jax.Array) -> jax.Array:
        """Log density (or mass) of stored actions, summed over action dimensions; shape `(...)`."""
        return self.distribution(params).log_prob(action)

    def entropy(self, params: jax.Array) -> jax.Array:
        """Entropy in nats, summed over action dimensions; shape `(...)`."""
        return self.distribution(params).entropy()

    def mode(self, params: jax.Array) -> jax.Array:
        """The most likely action (deterministic evaluation), in the stored space."""
        return self.distribution(params).mode()

    def env_action(self, action: jax.Array) -> jax.Array:
        """Map a stored action to the environment's action (within `action_spec` bounds)."""
        return action


class Categorical(PolicyHead):
    """Discrete actions: one logit per action; actions are int32 in `[0, num_actions)`."""

    @property
    def num_params(self) -> int:
        return self.action_spec.num_actions

    def distribution(self, params: jax.Array) -> distrax.Distribution:
        return distrax.Categorical(logits=params)


class MultiCategorical(PolicyHead):
    """Continuous actions, each dimension binned into `bins` evenly spaced values from `low` to `high`.

    Stored actions are int32 bin indices of shape `(..., size)`; `env_action` maps them to values.
    """

    def __init__(self, action_spec: ActionSpec, bins: int = 11):
        super().__init__(action_spec)
        self.bins = bins

    @property
    def num_params(self) -> int:
        return self.action_spec.size * self.bins

    def distribution(self, params: jax.Array) -> distrax.Distribution:
        logits = params.reshape(params.shape[:-1] + (self.action_spec.size, self.bins))
        return distrax.Independent(distrax.Categorical(logits=logits), 1)

    def env_action(self, action: jax.Array) -> jax.Array:
        low, high = self.action_spec.low, self.action_spec.high
        return low + action.astype(jnp.float32) * (high - low) / (self.bins - 1)


class _GaussianParams(nn.Module):
    """Means from the features; one learned log std per dimension, independent of the state."""

    size: int
    init_log_std: float

    @nn.compact
    def __call__(self, features: jax.Array) -> jax.Array:
        mean = nn.Dense(self.size, kernel_init=_HEAD_INIT)(features)
        log_std = self.param("log_std", nn.initializers.constant(self.init_log_std), (self.size,))
        return jnp.concatenate([mean, jnp.broadcast_to(log_std, mean.shape)], axis=-1)


class Gaussian(PolicyHead):
    """Diagonal Gaussian with state-independent learned log std. Samples are unbounded and stored as drawn (so
    their log_prob is exact); `env_action` clips them to the bounds."""

    def __init__(self, action_spec: ActionSpec, init_log_std: float = 0.0):
        super().__init__(action_spec)
        self.init_log_std = init_log_std

    @property
    def num_params(self) -> int:
        return 2 * self.action_spec.size

    def module(self) -> nn.Module:
        return _GaussianParams(self.action_spec.size, self.init_log_std, name="policy_head")

    def distribution(self, params: jax.Array) -> distrax.Distribution:
        mean, log_std = jnp.split(params, 2, axis=-1)
        return distrax.MultivariateNormalDiag(mean, jnp.exp(log_std))

    def env_action(self, action: jax.Array) -> jax.Array:
        return jnp.clip(action, self.action_spec.low, self.action_spec.high)


class Beta(PolicyHead):
    """Beta distribution per dimension with alpha, beta = softplus(.) + 1 > 1 (unimodal), scaled affinely from
    [0, 1] to [low, high]. Stored actions are in the bounds; they are kept a hair inside them so that the log
    density stays finite.

    `init_mean` in (0, 1) is the initial policy's mean action as a fraction of each dimension's range (0.5: the
    middle). The output layer's bias starts where alpha and beta have that mean, the nearer side's parameter at
    1 + log 2 (its value at 0.5), so a mean away from the middle is also a narrower start: a muscle hand whose 39
    excitations all start at 0.5 co-contracts and drives the pose away before it learns to relax
    (benchmarks/results/myohand/README.md)."""

    _EDGE = 1e-6

    def __init__(self, action_spec: ActionSpec, init_mean: float = 0.5):
        super().__init__(action_spec)
        self.init_mean = init_mean

    @property
    def num_params(self) -> int:
        return 2 * self.action_spec.size

    def module(self) -> nn.Module:
        return nn.Dense(self.num_params, kernel_init=_HEAD_INIT, bias_init=self._bias_init, name="policy_head")

    def _bias_init(self, key: jax.Array, shape: tuple[int, ...], dtype=jnp.float32) -> jax.Array:
        m = self.init_mean
        if m == 0.5:  # alpha = beta = softplus(0) + 1: a zero bias, as the other heads start
            return jnp.zeros(shape, dtype)
        near = 1.0 + jnp.log(2.0)
        alpha, beta = (near, near * (1 - m) / m) if m <= 0.5 else (near * m / (1 - m), near)
        # The inverse of softplus(x) + 1: x = log(exp(p - 1) - 1), written to stay finite for large p.
        inverse = [p - 1 + jnp.log(-jnp.expm1(-(p - 1))) for p in (alpha, beta)]
        size = self.action_spec.size
        return jnp.concatenate([jnp.full(size, inverse[0]), jnp.full(size, inverse[1])]).astype(dtype).reshape(shape)

    def distribution(self, params: jax.Array) -> distrax.Distribution:
        alpha, beta = jnp.split(jax.nn.softplus(params) + 1.0, 2, axis=-1)
        low, high = self.action_spec.low, self.action_spec.high
        unit = distrax.Beta(alpha, beta)
        return distrax.Independent(distrax.Transformed(unit, distrax.ScalarAffine(shift=low, scale=high - low)), 1)

    def _inside(self, action: jax.Array) -> jax.Array:
        low, high = self.action_spec.low, self.action_spec.high
        margin = self._EDGE * (high - low)
        return jnp.clip(action, low + margin, high - margin)

    def sample(self, params: jax.Array, key: jax.Array) -> jax.Array:
        return self._inside(super().sample(params, key))

    def log_prob(self, params: jax.Array, action: jax.Array) -> jax.Array:
        return super().log_prob(params, self._inside(action))


HEADS: Registry[Callable[..., PolicyHead]] = Registry("policy head", "heads")
for _name, _head in (("categorical", Categorical), ("multicategorical", MultiCategorical), ("gaussian", Gaussian),
                     ("beta", Beta)):
    HEADS.register(_name, _head)


def register_head(name: str, factory: Callable[..., PolicyHead]) -> None:
    """Make `factory(action_spec, **options) -> PolicyHead` selectable as `PPOConfig.head = name`."""
    HEADS.register(name, factory)


def list_heads() -> list[str]:
    """Names of the registered heads, sorted."""
    return HEADS.names()


def make_head(name: str, action_spec: ActionSpec, **options) -> PolicyHead:
    """Build the head `name` for `action_spec`; `options` (e.g. `bins`, `init_log_std`) go to its constructor."""
    return HEADS.get(name)(action_spec, **options)
