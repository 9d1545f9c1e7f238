"""Settings that no other test changes reach what they govern: each PPO setting changes the trained parameters (an
ignored one leaves them bit for bit the same, all else being equal), `checkpoint.best_mode: min` keeps the lowest
cycle, and `logging.tensorboard` writes every cycle's scalars. (`value_clip` binds only once the value function has
moved by clip_epsilon, which one tiny cycle does not reach: tests/test_losses.py computes both of its value losses.)"""

import struct
from pathlib import Path

import jax
import numpy as np
import pytest
from episode_pools import pooled_means
from quick_compile import compile_quickly
from tensorboardX.proto import event_pb2
from tiny import TINY_PPO

import angora_jax as aj
from angora_jax.experiment.config import load_config, validate
from angora_jax.experiment.held_out import is_due
from angora_jax.ppo.cycle import make_cycle

# Every program here runs a cycle or two (tests/quick_compile.py).
pytestmark = pytest.mark.usefixtures("quick_file_compiles")


def one_cycle(overrides: list[str]):
    """The parameters after one cycle, its programs compiled quickly (tests/quick_compile.py): every setting makes
    programs of its own, each run once."""
    config = load_config("cartpole", [*TINY_PPO, *overrides])
    init, cycle = make_cycle(validate(config), None, config.ppo)
    key = jax.random.key(0)
    state = compile_quickly(init, key)(key)
    state, _ = compile_quickly(cycle, state)(state)
    return state.params


@pytest.fixture(scope="module")
def default_params():
    return one_cycle([])


@pytest.mark.slow
@pytest.mark.parametrize("setting", [
    "ppo.normalize_advantages=false", "ppo.max_grad_norm=0.001", "ppo.value_coef=0.1", "ppo.gae_lambda=0.5",
    "ppo.normalization.clip=0.5",
])
def test_each_ppo_setting_changes_the_update(default_params, setting):
    assert load_config("cartpole", [setting]) != load_config("cartpole"), "not the default already"
    changed = one_cycle([setting])
    differences = jax.tree.leaves(jax.tree.map(lambda a, b: float(np.abs(a - b).max()), changed, default_params))
    assert max(differences) > 0, f"{setting} left the parameters as the default run's"


def tensorboard_scalars(folder: Path) -> dict[str, dict[int, float]]:
    """tag -> {step: value} from the TFRecord event files in `folder` (length, crc, Event proto, crc)."""
    scalars: dict[str, dict[int, float]] = {}
    for path in folder.glob("events.out.tfevents.*"):
        data, offset = path.read_bytes(), 0
        while offset < len(data):
            (length,) = struct.unpack("<Q", data[offset:offset + 8])
            event = event_pb2.Event.FromString(data[offset + 12:offset + 12 + length])
            offset += 12 + length + 4
            for value in event.summary.value:
                scalars.setdefault(value.tag, {})[event.step] = value.simple_value
    return scalars


def test_best_mode_min_keeps_the_lowest_cycle_and_tensorboard_gets_every_cycles_scalars(tmp_path):
    run = aj.train("cartpole", [*TINY_PPO, "ppo.num_cycles=4", "checkpoint.best_metric=episode_return",
                                "checkpoint.best_mode=min", "checkpoint.best_episodes=1",  # each cycle's own value
                                "logging.tensorboard=true", "logging.progress=none", "logging.report=false",
                                f"logging.run_root={tmp_path}", "logging.run_name=r"])
    returns = [record["episode_return"] for record in run.history]
    assert len(set(returns)) > 1, "the cycles differ, so best and latest can too"
    assert aj.load_agent(run.run_dir, "best").cycle == 1 + int(np.argmin(returns))
    scalars = tensorboard_scalars(run.run_dir / "tensorboard")
    steps = [record["env_steps"] for record in run.history]
    assert sorted(scalars["episode_return"]) == steps
    np.testing.assert_allclose([scalars["episode_return"][s] for s in steps], returns, rtol=1e-6)
    assert {"loss", "entropy", "norm/reward_std"} <= set(scalars)


@pytest.mark.slow
def test_stop_at_ends_the_run_with_a_checkpoint_after_the_first_cycle_that_reaches_the_value(tmp_path):
    """The target is compared over the latest `episodes` episodes (here 8, pooled across cycles: a cycle ends a few),
    also by a run resumed before it: one lucky episode does not end a run."""
    common = [*TINY_PPO, "ppo.num_cycles=8", "logging.progress=none", "logging.report=false",
              f"logging.run_root={tmp_path}"]
    history = aj.train("cartpole", [*common, "logging.run_name=all"]).history
    returns = [r["episode_return"] for r in history]
    pooled = pooled_means(history, "episode_return", 8)
    # A target that the pooled return first reaches at a cycle `first` before the last, which an earlier cycle's own
    # return reached already: compared cycle by cycle, the run would stop there.
    first = next((c for c, v in pooled.items() if c < len(returns) and np.isfinite(v) and max(returns[:c - 1]) >= v
                  and all(not u >= v for d, u in pooled.items() if d < c)), None)
    assert first is not None, f"this test needs such a target: {returns}, {pooled}"
    value = pooled[first]
    target = f"ppo.stop_at={{metric: episode_return, value: {value!r}, episodes: 8}}"
    run = aj.train("cartpole", [*common, "logging.run_name=stop", target])
    assert run.finished and int(run.state.cycle) == first
    assert run.stopped_at == f"episode_return {value:.4g} >= {value:g}"
    assert [r["episode_return"] for r in run.history] == returns[:first], "the same run, cut short"
    assert aj.experiment.Checkpoints(run.run_dir / "checkpoints", load_config("cartpole").checkpoint,
                                     create=False).steps("latest") == [first]
    # Trained to the cycle before, then on: that stop needs the episodes of the cycles before the resume.
    pieces = aj.train("cartpole", [*common, "logging.run_name=pieces", target, f"ppo.num_cycles={first - 1}"])
    assert int(pieces.state.cycle) == first - 1 and pieces.stopped_at is None
    resumed = aj.resume(pieces.run_dir, num_cycles=len(returns))
    assert int(resumed.state.cycle) == first and resumed.stopped_at == run.stopped_at


def test_held_out_work_is_due_every_n_cycles_and_after_the_last():
    """Evaluations and videos run on every `every`-th cycle and after the run's last, a multiple or not (the fast
    tier's check: the run below ends on a multiple, and only the slow training-video test ends off one)."""
    assert [cycle for cycle in range(1, 8) if is_due(cycle, 3, 7)] == [3, 6, 7]
    assert [cycle for cycle in range(1, 7) if is_due(cycle, 3, 6)] == [3, 6]


def test_held_out_evaluations_are_logged_on_their_cycles_and_can_choose_the_best(tmp_path):
    run = aj.train("cartpole", [*TINY_PPO, "ppo.num_cycles=4", "evaluation.every=2", "evaluation.episodes=4",
                                "evaluation.seed=3", "checkpoint.best_metric=eval/episode_return",
                                "logging.progress=none", "logging.report=false", f"logging.run_root={tmp_path}",
                                "logging.run_name=r"])
    evaluated = {r["cycle"]: r for r in run.history if "eval/episode_return" in r}
    assert sorted(evaluated) == [2, 4]
    assert {"eval/episode_length", "eval/episode_return"} <= set(evaluated[4])
    latest = aj.load_agent(run.run_dir, "latest")
    assert latest.cycle == 4 and latest.evaluate(num_envs=4, seed=3) == {
        k.removeprefix("eval/"): v for k, v in evaluated[4].items() if k.startswith("eval/")}, "the same 4 episodes"
    best = max(evaluated, key=lambda c: evaluated[c]["eval/episode_return"])
    assert aj.load_agent(run.run_dir, "best").cycle == best
