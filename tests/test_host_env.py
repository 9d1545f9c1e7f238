"""Any Gymnasium environment through the same trainer (`gym:<id>`, simulated on the host): Gymnasium's own
CartPole-v1 learns through `aj.train` as our pure-JAX CartPole does, resumes, evaluates, and bad input is refused.

Measured on 2 CPU cores with the shipped cartpole config (60 cycles, seed 0, about 10 s): the training-mean return
is 352 over cycles 36-40 and 500 from cycle 50 on; the bar (400 over the last 5 cycles) has that margin."""

import gymnasium
import jax
import numpy as np
import pytest
from gymnasium import spaces

import angora_jax as aj
from angora_jax.experiment import ConfigError, validate
from angora_jax.ppo import PPOConfig, make_cycle

BAR = 400.0


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    root = tmp_path_factory.mktemp("runs")
    return aj.train("cartpole", ["env.task=gym:CartPole-v1", f"logging.run_root={root}",
                                 "logging.run_name=gym", "logging.progress=none", "logging.report=false"])


@pytest.mark.slow
def test_gymnasium_cartpole_learns_on_the_host_path(run):
    returns = [m["episode_return"] for m in run.history]
    assert np.nanmean(returns[:4]) < 100, "it starts near random play (about 22)"
    assert np.nanmean(returns[-5:]) > BAR, returns
    assert (run.run_dir / "sessions.jsonl").read_text().count("Gymnasium") >= 1, "the physics line names the host"


@pytest.mark.slow
def test_a_host_run_evaluates_and_a_stopped_one_resumes(run, tmp_path, quick_compiles):
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
    with pytest.raises(ValueError, match="has no fixed-size encoding.*flatten_space"):
        aj.make("gym:angora_test/SequenceObservation-v0")
    with pytest.raises(ValueError, match="train it on one device"):
        make_cycle(aj.make("gym:CartPole-v1"), None, PPOConfig(num_envs=4, minibatch_size=128), num_devices=2)


class ToyObservations(gymnasium.Env):
    """Observations of every kind the host path encodes, set by the step count t, so their encoding is known."""

    observation_space = spaces.Dict({"cell": spaces.Discrete(3), "speed": spaces.Box(-1.0, 1.0, (2,)),
                                     "flags": spaces.MultiDiscrete([2, 3])})
    action_space = spaces.Discrete(2)

    def reset(self, seed=None, options=None):
        super().reset(seed=seed)
        self.t = 0
        return self.observe(), {}

    def step(self, action):
        self.t += 1
        return self.observe(), float(action), self.t == 3, False, {}

    def observe(self):
        return {"cell": self.t % 3, "speed": np.array([self.t / 10, -self.t / 10], np.float32),
                "flags": np.array([self.t % 2, self.t % 3])}


class SequenceObservation(ToyObservations):
    observation_space = spaces.Sequence(spaces.Discrete(2))


gymnasium.register("angora_test/ToyObservations-v0", entry_point=ToyObservations, max_episode_steps=10)
gymnasium.register("angora_test/SequenceObservation-v0", entry_point=SequenceObservation)


def test_dict_discrete_and_multidiscrete_observations_are_encoded_as_gymnasium_flattens_them():
    env = aj.make("gym:angora_test/ToyObservations-v0").sized_for(2)
    encoded = {t: gymnasium.spaces.flatten(ToyObservations.observation_space, ToyObservations.observe(
        type("At", (), {"t": t})())) for t in range(4)}
    # t = 1: cell 1 of 3, flags (1 of 2, 1 of 3), speed (0.1, -0.1); Dict's parts in its sorted key order
    np.testing.assert_allclose(encoded[1], [0, 1, 0, 0, 1, 0, 1, 0, 0.1, -0.1], atol=1e-6)
    assert env.observation_size == 10
    states = jax.vmap(env.reset)(jax.random.split(jax.random.key(0), 2))
    np.testing.assert_allclose(states.obs.proprioception, [encoded[0]] * 2, atol=1e-6)
    step = jax.vmap(env.step)
    for t in (1, 2, 3):
        states = step(states, np.ones(2, np.int32))
        np.testing.assert_allclose(states.final_obs.proprioception, [encoded[t]] * 2, atol=1e-6)
    np.testing.assert_allclose(states.obs.proprioception, [encoded[0]] * 2, atol=1e-6)  # t = 3 ended: t = 0 again
    assert states.done.tolist() == [1.0, 1.0]


@pytest.mark.slow
def test_a_task_with_discrete_observations_trains_on_the_host_path(tmp_path, quick_compiles):
    run = aj.train("cartpole", ["env.task=gym:Blackjack-v1", "ppo.num_envs=4", "ppo.rollout_length=16",
                                "ppo.chunk_length=8", "ppo.minibatch_size=32", "ppo.num_epochs=1", "ppo.num_cycles=2",
                                f"logging.run_root={tmp_path}", "logging.run_name=b", "logging.progress=none",
                                "logging.report=false"])
    assert [m["cycle"] for m in run.history] == [1, 2]
    assert all(-1.5 <= m["episode_return"] <= 1.5 for m in run.history), "Blackjack pays -1, 0, 1 or 1.5 a hand"
