"""Policy heads: log_prob against scipy / direct formulas, bounds, entropy, mode; the head registry; config checks."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import special, stats

from angora_jax.envs.classic import CartPole, Pendulum
from angora_jax.envs.core import ActionSpec
from angora_jax.ppo import PolicyHead, PPOConfig, list_heads, make_head, register_head

LOW = jnp.array([-1.0, 0.0, -2.0])
HIGH = jnp.array([1.0, 3.0, 0.5])
BOX = ActionSpec(low=LOW, high=HIGH)
DISCRETE = ActionSpec(low=jnp.zeros((0,)), high=jnp.zeros((0,)), num_actions=5)
BATCH = 64

# Every program here runs once on a small batch (tests/quick_compile.py).
pytestmark = pytest.mark.usefixtures("quick_file_compiles")


def random_params(head: PolicyHead, seed: int = 0) -> jax.Array:
    return jax.random.normal(jax.random.key(seed), (BATCH, head.num_params)) * 1.5


def all_heads():
    return [
        make_head("categorical", DISCRETE),
        make_head("multicategorical", BOX, bins=7),
        make_head("gaussian", BOX, init_log_std=-0.5),
        make_head("beta", BOX),
    ]


def test_categorical_log_prob_is_log_softmax():
    head = make_head("categorical", DISCRETE)
    params = random_params(head)
    actions = head.sample(params, jax.random.key(1))
    expected = np.take_along_axis(special.log_softmax(np.asarray(params), axis=-1), np.asarray(actions)[:, None], 1)
    np.testing.assert_allclose(head.log_prob(params, actions), expected[:, 0], rtol=1e-5, atol=1e-5)


def test_multicategorical_log_prob_sums_per_dimension_log_softmax_and_maps_bins_to_bounds():
    head = make_head("multicategorical", BOX, bins=7)
    params = random_params(head)
    actions = head.sample(params, jax.random.key(1))
    logits = special.log_softmax(np.asarray(params).reshape(BATCH, 3, 7), axis=-1)
    expected = np.take_along_axis(logits, np.asarray(actions)[..., None], -1)[..., 0].sum(-1)
    np.testing.assert_allclose(head.log_prob(params, actions), expected, rtol=1e-5, atol=1e-5)
    extremes = head.env_action(jnp.array([[0, 0, 0], [6, 6, 6], [3, 3, 3]]))
    np.testing.assert_allclose(extremes, np.stack([LOW, HIGH, (LOW + HIGH) / 2]), rtol=1e-6, atol=1e-6)


def test_multicategorical_entropy_is_the_sum_over_dimensions_of_each_dimensions_entropy():
    head = make_head("multicategorical", BOX, bins=7)
    params = random_params(head, seed=2)
    p = special.softmax(np.asarray(params, np.float64).reshape(BATCH, 3, 7), axis=-1)
    per_dimension = -(p * np.log(p)).sum(-1)
    np.testing.assert_allclose(head.entropy(params), per_dimension.sum(-1), rtol=1e-5, atol=1e-5)
    # The joint log-probability, too, adds the dimensions' log-probabilities of the action's bins.
    actions = head.sample(params, jax.random.key(3))
    chosen = np.take_along_axis(np.log(p), np.asarray(actions)[..., None], -1)[..., 0]
    np.testing.assert_allclose(head.log_prob(params, actions), chosen.sum(-1), rtol=1e-5, atol=1e-5)


def test_gaussian_log_prob_matches_scipy_and_std_is_state_independent():
    head = make_head("gaussian", BOX)
    params = random_params(head)
    actions = head.sample(params, jax.random.key(1))
    mean, log_std = np.split(np.asarray(params), 2, axis=-1)
    expected = stats.norm.logpdf(np.asarray(actions), mean, np.exp(log_std)).sum(-1)
    np.testing.assert_allclose(head.log_prob(params, actions), expected, rtol=1e-4, atol=1e-4)

    module = make_head("gaussian", BOX, init_log_std=-0.5).module()
    variables = module.init(jax.random.key(0), jnp.zeros((2, 4)))
    out = module.apply(variables, jax.random.normal(jax.random.key(2), (2, 4)))
    np.testing.assert_allclose(out[0, 3:], out[1, 3:])  # log std: the same for different states
    np.testing.assert_allclose(out[0, 3:], np.full(3, -0.5))


@pytest.mark.parametrize("init_mean", [0.5, 0.1, 0.02, 0.9])
def test_the_beta_heads_initial_policy_has_the_mean_asked_for_and_stays_unimodal(init_mean):
    """`ppo.beta_init_mean`: the output layer's bias puts the untrained policy's mean action at that fraction of each
    range (a muscle hand started at 0.5 on every excitation co-contracts), with alpha and beta above 1."""
    head = make_head("beta", BOX, init_mean=init_mean)
    module = head.module()
    variables = module.init(jax.random.key(0), jnp.zeros((2, 16)))
    params = module.apply(variables, jax.random.normal(jax.random.key(1), (BATCH, 16)))
    alpha, beta = np.split(np.logaddexp(0.0, np.asarray(params, np.float64)) + 1.0, 2, axis=-1)
    assert (alpha > 1).all() and (beta > 1).all()
    # The kernel starts at 0.01 scale, so the features move the mean by well under a percent of the range.
    np.testing.assert_allclose(alpha / (alpha + beta), init_mean, rtol=0.02)
    low, high = np.asarray(LOW), np.asarray(HIGH)
    samples = jax.vmap(lambda key: head.sample(params, key))(jax.random.split(jax.random.key(2), 64))
    np.testing.assert_allclose(((np.asarray(samples) - low) / (high - low)).mean(), init_mean, atol=0.01)
    if init_mean == 0.5:  # the middle is the zero bias that the head always had
        np.testing.assert_array_equal(variables["params"]["bias"], 0.0)


def test_the_configs_beta_init_mean_reaches_the_head():
    from angora_jax.ppo.cycle import build_head

    assert build_head(Pendulum(), PPOConfig(head="beta", beta_init_mean=0.1)).init_mean == 0.1


def test_beta_log_prob_and_entropy_match_scipy_scaled_to_bounds():
    head = make_head("beta", BOX)
    params = random_params(head)
    actions = head.sample(params, jax.random.key(1))
    alpha, beta = np.split(np.logaddexp(0.0, np.asarray(params, np.float64)) + 1.0, 2, axis=-1)
    low, high = np.asarray(LOW), np.asarray(HIGH)
    unit = (np.asarray(actions, np.float64) - low) / (high - low)
    expected = (stats.beta.logpdf(unit, alpha, beta) - np.log(high - low)).sum(-1)
    np.testing.assert_allclose(head.log_prob(params, actions), expected, rtol=1e-3, atol=1e-3)
    expected_entropy = (stats.beta.entropy(alpha, beta) + np.log(high - low)).sum(-1)
    np.testing.assert_allclose(head.entropy(params), expected_entropy, rtol=1e-3, atol=1e-3)
    assert np.all(alpha > 1) and np.all(beta > 1)


def test_beta_log_prob_is_finite_on_the_bounds():
    head = make_head("beta", BOX)
    params = random_params(head)[:2]
    assert np.all(np.isfinite(head.log_prob(params, jnp.stack([LOW, HIGH]))))


@pytest.mark.parametrize("index", range(4), ids=["categorical", "multicategorical", "gaussian", "beta"])
def test_samples_in_bounds_entropy_finite_and_no_likelier_than_the_mode(index):
    head = all_heads()[index]
    params = random_params(head, seed=3)
    samples = jnp.stack([head.env_action(head.sample(params, jax.random.key(k))) for k in range(5)])
    if head.action_spec.discrete:
        assert samples.dtype == jnp.int32
        assert np.all((samples >= 0) & (samples < DISCRETE.num_actions))
    else:
        assert np.all((samples >= LOW) & (samples <= HIGH))
    assert np.all(np.isfinite(head.entropy(params)))
    assert head.entropy(params).shape == (BATCH,)
    assert not np.array_equal(samples[0], samples[1])  # sampling is random
    # The mode is at least as likely as any sample (unimodal or discrete distributions).
    mode, other = head.mode(params), head.sample(params, jax.random.key(9))
    assert np.all(head.log_prob(params, mode) >= head.log_prob(params, other) - 1e-4)


def test_each_heads_mode_is_its_definition():
    """What deterministic evaluation plays: the most likely action by each head's formula, in the stored space."""
    categorical, binned, gaussian, beta = all_heads()
    params = random_params(categorical, seed=4)
    np.testing.assert_array_equal(categorical.mode(params), np.argmax(np.asarray(params), axis=-1))
    params = random_params(binned, seed=5)
    bins = np.argmax(np.asarray(params).reshape(BATCH, 3, 7), axis=-1)
    np.testing.assert_array_equal(binned.mode(params), bins)
    np.testing.assert_allclose(binned.env_action(binned.mode(params)), LOW + bins * (HIGH - LOW) / 6, rtol=1e-6)
    params = random_params(gaussian, seed=6)
    np.testing.assert_allclose(gaussian.mode(params), np.asarray(params)[:, :3], rtol=1e-6)  # the mean
    params = random_params(beta, seed=7)
    a, b = np.split(np.logaddexp(0.0, np.asarray(params, np.float64)) + 1.0, 2, axis=-1)
    unit = (a - 1) / (a + b - 2)  # the Beta's mode for a, b > 1
    np.testing.assert_allclose(beta.mode(params), LOW + unit * (HIGH - LOW), rtol=1e-4, atol=1e-5)


def test_custom_head_can_be_registered_and_made():
    class Deterministicish(PolicyHead):
        @property
        def num_params(self):
            return self.action_spec.size

        def distribution(self, params):
            import distrax

            return distrax.MultivariateNormalDiag(params, jnp.full(params.shape, 0.01))

    register_head("test_narrow_gaussian", Deterministicish)
    assert "test_narrow_gaussian" in list_heads()
    head = make_head("test_narrow_gaussian", BOX)
    assert head.sample(jnp.zeros((2, 3)), jax.random.key(0)).shape == (2, 3)
    PPOConfig(head="test_narrow_gaussian").validate_for(Pendulum())
    register_head("test_narrow_gaussian", Deterministicish)  # the same definition again (a cell run twice): replaced
    with pytest.raises(ValueError, match=r"already registered \(by test_heads\..*Deterministicish\): choose another"):
        register_head("test_narrow_gaussian", type("Other", (Deterministicish,), {}))
    with pytest.raises(ValueError, match="Unknown policy head 'nope'"):
        make_head("nope", BOX)


def test_config_rejects_bad_heads_and_minibatch_shapes():
    with pytest.raises(ValueError, match="head='beta' needs continuous actions"):
        PPOConfig(head="beta").validate_for(CartPole())
    with pytest.raises(ValueError, match="head='categorical' needs discrete actions"):
        PPOConfig(head="categorical").validate_for(Pendulum())
    with pytest.raises(ValueError, match="ppo.minibatch_size"):
        PPOConfig(num_envs=4, rollout_length=32, chunk_length=16, minibatch_size=48).validate()
    with pytest.raises(ValueError, match="ppo.chunk_length"):
        PPOConfig(rollout_length=100, chunk_length=16).validate()
    with pytest.raises(ValueError, match="ppo.head must be"):
        PPOConfig(head="poisson").validate()
    with pytest.raises(ValueError, match="PPOConfig.gamma"):
        PPOConfig(gamma=1.5).validate()
    assert PPOConfig().validate_for(CartPole()).head_for(CartPole()) == "categorical"
    assert PPOConfig().head_for(Pendulum()) == "gaussian"
