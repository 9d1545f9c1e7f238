"""The PPO loss against a hand-computed minibatch: both sides of the ratio clip, the clipped and unclipped value
loss, the entropy bonus, the coefficients, and advantage normalisation; and the cycle's logged statistics of a
rollout (explained variance, the means over ended episodes) against their formulas."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from angora_jax.envs.core import ActionSpec
from angora_jax.ppo import make_head
from angora_jax.ppo.cycle import episode_metrics, explained_variance
from angora_jax.ppo.losses import LossInputs, advantage_moments, normalized_advantages, ppo_loss

HEAD = make_head("categorical", ActionSpec(low=jnp.zeros((0,)), high=jnp.zeros((0,)), num_actions=3))
LOGITS = jnp.array([[0.5, -1.0, 2.0], [0.0, 0.0, 0.0], [1.0, 3.0, -2.0], [-0.5, 0.2, 0.1]])
ACTIONS = jnp.array([2, 0, 1, 1])
RATIOS = np.array([1.5, 0.5, 1.1, 0.7])  # new / old probability of the action taken
ADVANTAGES = np.array([1.0, 1.0, -2.0, -2.0])
VALUES = np.array([1.0, 2.0, 0.0, -1.0])  # the current value function
OLD_VALUES = np.array([0.5, 2.5, 0.0, 0.0])  # the rollout's
TARGETS = np.array([2.0, 1.0, 0.3, -1.0])
EPSILON = 0.2


def batch() -> LossInputs:
    log_probs = HEAD.log_prob(LOGITS, ACTIONS) - jnp.log(jnp.asarray(RATIOS, jnp.float32))
    return LossInputs(ACTIONS, log_probs, jnp.asarray(OLD_VALUES, jnp.float32), jnp.asarray(ADVANTAGES, jnp.float32),
                      jnp.asarray(TARGETS, jnp.float32))


def loss(value_clip: bool, value_coef: float = 0.5, entropy_coef: float = 0.01, logits=LOGITS):
    return ppo_loss(HEAD, logits, jnp.asarray(VALUES, jnp.float32), batch(), EPSILON, value_coef, entropy_coef,
                    value_clip)


def test_the_clipped_objective_by_hand():
    # min(r A, clip(r, 0.8, 1.2) A) per sample:
    #   r 1.5, A +1: 1.2 (clipped above: no gain from pushing further)   r 0.5, A +1: 0.5 (the pessimistic side)
    #   r 1.1, A -2: -2.2 (inside the clip)                               r 0.7, A -2: -1.6 (clipped below)
    _, parts = loss(value_clip=True)
    assert float(parts["policy_loss"]) == pytest.approx(-(1.2 + 0.5 - 2.2 - 1.6) / 4, abs=1e-6)
    assert float(parts["clip_fraction"]) == 0.75  # |r - 1| > 0.2 for 1.5, 0.5 and 0.7
    assert float(parts["approx_kl"]) == pytest.approx(np.mean(RATIOS - 1 - np.log(RATIOS)), rel=1e-5)
    # Where the clip binds (samples 1 and 4) the policy gets no gradient; elsewhere it does.
    grads = jax.grad(lambda logits: loss(True, logits=logits)[1]["policy_loss"])(LOGITS)
    moved = np.abs(np.asarray(grads)).sum(axis=1)
    assert moved[0] == moved[3] == 0.0 and moved[1] > 0 and moved[2] > 0


def test_the_value_loss_by_hand_clipped_and_not():
    # Unclipped: (V - target)^2 = 1, 1, 0.09, 0. The clipped value moves at most 0.2 from the rollout's:
    # 0.7, 2.3, 0.0, -0.2, errors 1.69, 1.69, 0.09, 0.64; the loss takes the larger error of each.
    _, clipped = loss(value_clip=True)
    _, plain = loss(value_clip=False)
    assert float(clipped["value_loss"]) == pytest.approx(0.5 * (1.69 + 1.69 + 0.09 + 0.64) / 4, rel=1e-5)
    assert float(plain["value_loss"]) == pytest.approx(0.5 * (1 + 1 + 0.09 + 0) / 4, rel=1e-5)


@pytest.mark.parametrize("value_coef, entropy_coef", [(0.5, 0.01), (1.0, 0.0), (0.25, 0.1)])
def test_the_total_weighs_its_parts_by_the_coefficients(value_coef, entropy_coef):
    total, parts = loss(value_clip=False, value_coef=value_coef, entropy_coef=entropy_coef)
    probabilities = jax.nn.softmax(LOGITS)
    entropy = float(-(probabilities * jnp.log(probabilities)).sum(-1).mean())
    assert float(parts["entropy"]) == pytest.approx(entropy, rel=1e-5)
    expected = float(parts["policy_loss"]) + value_coef * float(parts["value_loss"]) - entropy_coef * entropy
    assert float(total) == pytest.approx(expected, rel=1e-6)


def test_advantages_are_normalised_per_minibatch_and_a_constant_one_stays_finite():
    advantages = jnp.array([[1.0, 3.0, 5.0, 7.0], [2.0, 2.0, 2.0, 2.0]])  # two minibatches
    mean, std = advantage_moments(advantages)
    np.testing.assert_allclose(mean, [4.0, 2.0])
    np.testing.assert_allclose(std, [np.sqrt(5.0), 0.0], atol=1e-6)
    first = normalized_advantages(advantages[0], mean[0], std[0])
    np.testing.assert_allclose(first, (np.array([1, 3, 5, 7]) - 4) / np.sqrt(5), rtol=1e-5)
    np.testing.assert_array_equal(normalized_advantages(advantages[1], mean[1], std[1]), np.zeros(4))


def test_explained_variance_is_one_minus_the_residual_over_the_targets_variance():
    targets = np.array([[2.0, 1.0], [4.0, 6.0], [0.5, -1.0]])  # (T, N)
    values = np.array([[1.0, 2.0], [3.0, 4.0], [0.0, 0.5]])
    expected = 1.0 - np.var(targets - values) / np.var(targets)  # 0.73 here; over var(values) it would be 0.26
    assert float(explained_variance(jnp.asarray(targets), jnp.asarray(values))) == pytest.approx(expected, abs=1e-5)
    assert float(explained_variance(jnp.asarray(targets), jnp.asarray(targets))) == pytest.approx(1.0, abs=1e-6)
    assert float(explained_variance(jnp.asarray(targets), jnp.full((3, 2), 9.0))) == pytest.approx(0.0, abs=1e-5)
    # Pooled over devices: vmap with an axis name stands in for 3 devices holding a step each.
    pooled = jax.vmap(lambda t, v: explained_variance(t, v, "devices"), axis_name="devices")(targets, values)
    np.testing.assert_allclose(pooled, expected, atol=1e-5)


def test_task_metrics_are_means_over_the_episodes_that_ended_not_over_all_steps():
    # Two environments, four steps; episodes end at step 1 and 3 of the first, step 2 of the second.
    dones = np.array([[0, 0], [1, 0], [0, 1], [1, 0]], np.float32)
    returns = np.array([[0, 0], [5, 0], [0, 2], [3, 0]], np.float32)  # 0 except where an episode ended
    lengths = np.array([[0, 0], [2, 0], [0, 3], [2, 0]], np.float32)
    success = np.array([[1, 1], [1, 1], [1, 0], [0, 1]], np.float32)  # the task's, every step: 1 at the first end
    metrics = episode_metrics(*map(jnp.asarray, (dones, returns, lengths)), {"success": jnp.asarray(success)})
    assert float(metrics["episodes"]) == 3.0
    assert float(metrics["episode_return"]) == pytest.approx(10 / 3)
    assert float(metrics["episode_length"]) == pytest.approx(7 / 3)
    assert float(metrics["metric/success"]) == pytest.approx(1 / 3), "over all steps it would be 6 / 8"
    pooled = jax.vmap(lambda *x: episode_metrics(*x[:3], {"success": x[3]}, "devices"), in_axes=1,
                      axis_name="devices")(dones, returns, lengths, success)  # one environment per device
    np.testing.assert_allclose(pooled["metric/success"], [1 / 3, 1 / 3], rtol=1e-6)
    none_ended = episode_metrics(*map(jnp.zeros_like, map(jnp.asarray, (dones, returns, lengths))),
                                 {"success": jnp.asarray(success)})
    assert all(np.isnan(float(none_ended[k])) for k in ("episode_return", "episode_length", "metric/success"))
