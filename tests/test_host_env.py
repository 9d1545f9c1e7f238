"""Any Gymnasium environment through the same trainer (`gym:<id>`, simulated on the host): Gymnasium's own
CartPole-v1 learns through `aj.train` as our pure-JAX CartPole does, resumes, evaluates, and bad input is refused.

Measured on 2 CPU cores with the shipped cartpole config (60 cycles, seed 0, about 10 s): the training-mean return
is 352 over cycles 36-40 and 500 from cycle 50 on; the bar (400 over the last 5 cycles) has that margin."""

import numpy as np
import pytest

import angora_jax as aj
from angora_jax.experiment import ConfigError, validate
from angora_jax.ppo import PPOConfig, make_cycle

BAR = 400.0


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    root = tmp_path_factory.mktemp("runs")
    return aj.train("cartpole", ["env.task=gym:CartPole-v1", f"logging.run_root={root}",
                                 "logging.run_name=gym", "logging.progress=none", "logging.report=false"])


def test_gymnasium_cartpole_learns_on_the_host_path(run):
    returns = [m["episode_return"] for m in run.history]
    assert np.nanmean(returns[:4]) < 100, "it starts near random play (about 22)"
    assert np.nanmean(returns[-5:]) > BAR, returns
    assert (run.run_dir / "sessions.jsonl").read_text().count("Gymnasium") >= 1, "the physics line names the host"


def test_a_host_run_evaluates_and_a_stopped_one_resumes(run, tmp_path):
    result = aj.evaluate(run.run_dir, "latest", episodes=8, save=False)
    assert result.meta["path"] == "batched" and result.summary["episode_return"]["mean"] > BAR
    stopped = aj.train("cartpole", ["env.task=gym:CartPole-v1", "ppo.num_cycles=3", f"logging.run_root={tmp_path}",
                                    "logging.run_name=s", "logging.progress=none", "logging.report=false"],
                       minutes=1e-6)
    assert not stopped.finished and len(stopped.history) == 1
    resumed = aj.resume(stopped.run_dir)
    assert resumed.finished and [m["cycle"] for m in resumed.history] == [2, 3]


def test_bad_gymnasium_input_is_refused_with_the_fix():
    with pytest.raises(ConfigError, match="gym:<id>"):
        validate(aj.load_config("cartpole", ["env.task=CartPol"]))
    with pytest.raises(ValueError, match=r"gymnasium.make\('NoSuchEnv-v0'\) failed"):
        aj.make("gym:NoSuchEnv-v0")
    with pytest.raises(ValueError, match="Box observations"):
        aj.make("gym:Blackjack-v1")
    with pytest.raises(ValueError, match="train it on one device"):
        make_cycle(aj.make("gym:CartPole-v1"), None, PPOConfig(num_envs=4, minibatch_size=128), num_devices=2)
