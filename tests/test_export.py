"""`angora-jax export` and `aj.load_policy`: a trained recurrent policy in one file acts, without its run directory,
exactly as the run's own agent does; bad files and an existing output are refused."""

import shutil

import jax
import numpy as np
import pytest
from tiny import TINY_PPO

import angora_jax as aj
from angora_jax.cli import main
from angora_jax.experiment import RunDirError


@pytest.fixture(scope="module")
def lstm_run(tmp_path_factory):
    root = tmp_path_factory.mktemp("runs")
    return aj.train("cartpole", [*TINY_PPO, "ppo.num_cycles=2", "ppo.network.name=lstm", "logging.progress=none",
                                 "logging.report=false", f"logging.run_root={root}", "logging.run_name=lstm"]).run_dir


def rollout(act, carry, env, steps=6, batch=3):
    """Actions of `act(carry, obs) -> (carry, actions)` over `steps` steps of `batch` CartPoles, stepping them."""
    states = jax.vmap(env.reset)(jax.random.split(jax.random.key(7), batch))
    actions = []
    for _ in range(steps):
        carry, action = act(carry, states.obs)
        states = jax.vmap(env.step)(states, action)
        actions.append(np.asarray(action))
    return np.stack(actions)


def test_an_exported_policy_acts_as_the_run_does_without_the_run(lstm_run, tmp_path, capsys):
    agent = aj.load_agent(lstm_run)
    expected = rollout(lambda c, o: agent.act(c, o)[:2], agent.initial_carry(3), agent.env)
    out = tmp_path / "policy.msgpack"
    assert main(["export", str(lstm_run), "--out", str(out)]) == 0
    assert f"Policy: {out}" in capsys.readouterr().out
    moved = shutil.move(lstm_run, tmp_path / "elsewhere")  # loading reads the file alone
    try:
        policy = aj.load_policy(out)
        assert policy.agent.cycle == agent.cycle == 2
        np.testing.assert_array_equal(rollout(jax.jit(policy.act), policy.initial_carry(3), policy.agent.env), expected)
        assert len(np.unique(expected)) == 2, "both actions occur: the comparison sees the policy, not a constant"
    finally:
        shutil.move(moved, lstm_run)


def test_export_never_overwrites_and_load_policy_refuses_other_files(lstm_run, tmp_path, capsys):
    taken = tmp_path / "taken.msgpack"
    taken.write_bytes(b"keep me")
    assert main(["export", str(lstm_run), "--out", str(taken)]) == 2
    assert "never overwrites" in capsys.readouterr().err and taken.read_bytes() == b"keep me"
    with pytest.raises(RunDirError, match="is not an exported policy"):
        aj.load_policy(taken)
    with pytest.raises(FileNotFoundError, match="angora-jax export RUN_DIR --out FILE"):
        aj.load_policy(tmp_path / "missing.msgpack")
