"""Step-size control (`ppo.step_size`): the KL-adaptive learning rate's rule and bounds, the entropy weight's
annealing, the settings refused together, and both through a run that is stopped and resumed."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from tiny import TINY_PPO

import angora_jax as aj
from angora_jax.experiment import validate
from angora_jax.experiment.config import load_config
from angora_jax.experiment.programs import cycle_programs
from angora_jax.ppo import PPOConfig
from angora_jax.ppo.step_size import adapt_learning_rate, entropy_coef, learning_rate, make_optimizer

ADAPTIVE = PPOConfig(learning_rate=1e-3, target_kl=0.01, lr_min=1e-4, lr_max=2e-3)


def adapted(rate: float, kl: float, config: PPOConfig = ADAPTIVE) -> float:
    state = make_optimizer(config.replace(learning_rate=rate), 1).init({"w": jnp.zeros(3)})
    return float(learning_rate(adapt_learning_rate(state, jnp.float32(kl), config), config, 0, 1))


def test_the_rate_falls_when_the_kl_is_above_twice_the_target_and_rises_below_half_of_it_within_its_bounds():
    assert adapted(1e-3, 0.021) == pytest.approx(1e-3 / 1.5)
    assert adapted(1e-3, 0.0049) == pytest.approx(1.5e-3)
    for kl in (0.005, 0.01, 0.02):
        assert adapted(1e-3, kl) == pytest.approx(1e-3), f"KL {kl} is within [target/2, 2 target]"
    assert adapted(1.9e-3, 0.0) == pytest.approx(2e-3), "held at lr_max"
    assert adapted(1.2e-4, 1.0) == pytest.approx(1e-4), "held at lr_min"


def test_without_a_target_the_optimizer_state_holds_no_rate_and_follows_the_schedule():
    """Runs saved before step-size control have this optimizer state layout, so their checkpoints still restore."""
    plain = PPOConfig(learning_rate=1e-3, num_cycles=10)
    state = make_optimizer(plain, 4).init({"w": jnp.zeros(3)})
    assert not hyperparameter_states(state)
    assert float(learning_rate(state, plain, 20, 4)) == pytest.approx(1e-3)
    assert float(learning_rate(state, plain.replace(lr_decay=True), 20, 4)) == pytest.approx(5e-4)


def hyperparameter_states(state) -> list:
    """The `optax.inject_hyperparams` states anywhere in an optimizer state (optax has two such classes, both with
    `hyperparams`)."""
    return [s for s in jax.tree.leaves(state, is_leaf=lambda s: hasattr(s, "hyperparams")) if hasattr(s, "hyperparams")]


def test_the_entropy_weight_anneals_linearly_from_the_first_cycle_to_the_last():
    config = PPOConfig(num_cycles=5, entropy_coef=0.02, entropy_coef_final=0.0)
    weights = [float(entropy_coef(config, jnp.int32(c))) for c in range(7)]
    np.testing.assert_allclose(weights, [0.02, 0.015, 0.01, 0.005, 0.0, 0.0, 0.0], atol=1e-9)
    assert float(entropy_coef(config.replace(entropy_coef_final=None), jnp.int32(3))) == pytest.approx(0.02)


@pytest.mark.parametrize("overrides, message", [
    (["ppo.target_kl=0.01", "ppo.lr_decay=true"], "set one of them"),
    (["ppo.target_kl=0.01", "ppo.learning_rate=0.1"], r"must lie within \[lr_min, lr_max\]"),
    (["ppo.target_kl=0"], "ppo.target_kl must be > 0"),
])
def test_step_size_settings_that_contradict_each_other_are_refused(overrides, message):
    with pytest.raises(ValueError, match=message):
        load_config("cartpole", overrides).ppo.validate()


def test_an_adapted_rate_and_an_annealed_entropy_weight_continue_exactly_after_a_resume(tmp_path, quick_compiles):
    """A KL target far above what tiny updates reach raises the rate by 1.5 at each of the cycle's 2 minibatch
    updates; the rate lives in the optimizer state, so the resumed second cycle starts from the first's."""
    overrides = [*TINY_PPO, "ppo.num_cycles=3", "ppo.learning_rate=1e-4", "ppo.target_kl=10.0", "ppo.lr_max=1e-2",
                 "ppo.entropy_coef=0.02", "ppo.entropy_coef_final=0.0", "logging.progress=none",
                 "logging.report=false", f"logging.run_root={tmp_path}"]
    # Programs made in this process for a 5-cycle run of the same settings must not serve this one: its entropy
    # weight anneals over its own 3 cycles (cycle_programs keeps the count in their key). Made, not traced here.
    longer = load_config("cartpole", [*overrides, "ppo.num_cycles=5"])
    cycle_programs(longer, validate(longer, new_run=False))
    whole = aj.train("cartpole", [*overrides, "logging.run_name=whole"])
    np.testing.assert_allclose([r["learning_rate"] for r in whole.history], [1e-4 * 1.5 ** (2 * c) for c in (1, 2, 3)],
                               rtol=1e-5)
    np.testing.assert_allclose([r["entropy_coef"] for r in whole.history], [0.02, 0.01, 0.0], atol=1e-9)
    first = aj.train("cartpole", [*overrides, "logging.run_name=pieces"], minutes=1e-9)
    rest = aj.resume(first.run_dir)
    assert [r["cycle"] for r in first.history + rest.history] == [1, 2, 3]
    for a, b in zip(whole.history, first.history + rest.history, strict=True):
        for key in ("learning_rate", "entropy_coef", "loss", "approx_kl"):
            assert a[key] == b[key], key
