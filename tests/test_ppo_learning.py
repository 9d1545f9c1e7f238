"""PPO learns: with fixed seeds, classic tasks are solved past stated return bars with feed-forward and recurrent
models and discrete and continuous heads; divergence is reported clearly."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from angora_jax.envs.classic import CartPole
from angora_jax.envs.registry import make
from angora_jax.ppo import NetworkConfig, PPOConfig, TrainingDivergedError, make_evaluate, train
from angora_jax.ppo.config import BlocksConfig

# Random policies score about 22 on CartPole (max 500), about -1200 on Pendulum (best about -150) and -500 on Acrobot
# (the episode's limit; gymnasium's reward threshold is -100).
CARTPOLE = PPOConfig(
    num_envs=16, rollout_length=128, chunk_length=16, minibatch_size=512, num_epochs=4, gamma=0.99
)
PENDULUM = CARTPOLE.replace(gamma=0.95, num_cycles=150)

CASES = {
    "cartpole-simple-categorical": ("CartPole", CARTPOLE.replace(num_cycles=50), 400.0),
    # 40 cycles ended at 397.7 on an AMD EPYC (seed 0; 500 with seeds 1 and 2), past 400 on the machines before:
    # float rounding differs by CPU and 40 cycles left no margin. At 50 cycles seeds 0-2 all end at 500 there.
    "cartpole-lstm-categorical": (
        "CartPole",
        CARTPOLE.replace(num_cycles=50, network=NetworkConfig(name="lstm")),
        400.0,
    ),
    # Two SAPG policy blocks (ppo.blocks), judged by the leader's return: 500 from cycle 25 on (seed 0, AMD EPYC).
    "cartpole-simple-categorical-blocks": ("CartPole", CARTPOLE.replace(num_cycles=50, blocks=BlocksConfig(count=2)),
                                           400.0),
    "acrobot-simple-categorical": ("Acrobot", CARTPOLE.replace(num_cycles=40), -120.0),
    "pendulum-simple-gaussian": ("Pendulum", PENDULUM, -400.0),
    "pendulum-gru-beta": ("Pendulum", PENDULUM.replace(head="beta", network=NetworkConfig(name="gru")), -400.0),
    "pendulum-shared-multicategorical-lrdecay": (
        "Pendulum",
        PENDULUM.replace(head="multicategorical", lr_decay=True, network=NetworkConfig(shared_trunk=True)),
        -400.0,
    ),
}


def final_return(history: list[dict[str, float]]) -> float:
    """Mean return of the episodes finished in the last 10% of cycles (cycles without a finished episode skipped)."""
    tail = history[-max(1, len(history) // 10) :]
    return float(np.nanmean([m["episode_return"] for m in tail]))


@pytest.mark.slow
@pytest.mark.parametrize("case", CASES)
def test_ppo_solves_classic_task(case):
    task, config, bar = CASES[case]
    lines = []
    state, history = train(config, make(task), log=lines.append)
    assert len(lines) == config.num_cycles and "episode_return=" in lines[-1] and "sps=" in lines[-1]
    first = float(np.nanmean([m["episode_return"] for m in history[: len(history) // 10]]))
    reached = final_return(history)
    assert reached > bar, f"{case}: final return {reached:.1f} did not pass the bar {bar} (started at {first:.1f})"
    last = history[-1]
    for name in ("episode_length", "policy_loss", "value_loss", "entropy", "approx_kl", "clip_fraction"):
        assert np.isfinite(last[name]), name
    # Explained variance is meaningless once returns barely vary (CartPole at 500 steps): ask for it while learning.
    assert max(m["explained_variance"] for m in history) > 0.5
    assert last["env_steps"] == config.num_cycles * config.num_envs * config.rollout_length
    print(f"{case}: return {first:.1f} -> {reached:.1f} (bar {bar}), deterministic", end=" ")
    assert last["steps_per_second"] > 0 and history[0]["compile_seconds"] > 0
    # Normalisation is on by default: the stats have seen every observation and every step's return.
    np.testing.assert_allclose(state.obs_stats.proprioception.count, last["env_steps"], rtol=1e-3)
    np.testing.assert_allclose(state.reward_stats.count, last["env_steps"], rtol=1e-3)
    # The deterministic policy (the head's mode) does at least as well as the bar too.
    evaluation = make_evaluate(make(task), None, config, num_envs=8)(state, jax.random.key(123))
    print(f"{float(evaluation['episode_return']):.1f}")
    assert float(evaluation["episode_return"]) > bar, evaluation
    if config.lr_decay:
        assert history[0]["learning_rate"] == pytest.approx(config.learning_rate)
        assert history[-1]["learning_rate"] < 0.02 * config.learning_rate


class NaNRewardCartPole(CartPole):
    def _step(self, physics, info, action, key):
        physics, obs, reward, terminated, info, metrics = super()._step(physics, info, action, key)
        return physics, obs, jnp.float32(jnp.nan), terminated, info, metrics


@pytest.mark.slow
def test_divergence_raises_a_clear_error(quick_compiles):
    config = CARTPOLE.replace(num_envs=4, rollout_length=16, minibatch_size=64, num_cycles=3)
    with pytest.raises(TrainingDivergedError, match="cycle 1.*Lower learning_rate"):
        train(config, NaNRewardCartPole(), log=None)
