"""Checkpoints: a run stopped by SIGTERM saves a loadable checkpoint, and `resume` continues bit-for-bit like
an uninterrupted run; best and snapshot checkpoints are kept; run directories are never overwritten."""

import errno
import json
import os
import re
import shutil
import signal
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import yaml
from episode_pools import pooled_means
from jax_events import jax_events
from tiny import TINY_PPO

import angora_jax as aj
from angora_jax.cli import main
from angora_jax.experiment import (
    Checkpoints,
    RunDirError,
    TrainingInterrupted,
    read_metrics,
    resume,
    snapshot_cycles,
    validate,
)
from angora_jax.experiment.checkpoint import CheckpointError, cycles_to_offer
from angora_jax.experiment.config import CheckpointConfig, ConfigError
from angora_jax.experiment.monitor import set_aside_after
from angora_jax.experiment.programs import cycle_programs
from angora_jax.experiment.run_dir import CHECKPOINTS

# A recurrent network, so that resuming must restore carries and env states mid-episode, not just parameters.
TINY = [
    *TINY_PPO,
    "ppo.num_cycles=4",
    "ppo.network.name=gru",
    "ppo.network.width=16",
    "ppo.network.cell_size=16",
    "logging.progress=none",
    "logging.report=false",
    "checkpoint.every=100",
    "checkpoint.snapshot_every=2",
    "checkpoint.best_episodes=4",  # a few episodes end per cycle: the best metric pools cycles, across the resume too
]
# Wall-clock, memory and compilation-cache readings differ between any two runs; everything else must match exactly.
UNTIMED = {"seconds", "steps_per_second", "compile_seconds", "time", "memory/host_peak_bytes", "compile_cache_hits",
           "compile_cache_misses"}

# Every run here is a few tiny cycles (tests/quick_compile.py).
pytestmark = pytest.mark.usefixtures("quick_file_compiles")


# Before any training in this process: its SIGHUP handler is set for training, then restored.
HANGUP_AS_STARTED = signal.getsignal(signal.SIGHUP)


def config(tmp_path, name):
    return aj.load_config("cartpole", [*TINY, f"logging.run_root={tmp_path}", f"logging.run_name={name}"])


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """An uninterrupted run, and a run that receives SIGTERM after cycle 2 and is then resumed."""
    root = tmp_path_factory.mktemp("runs")
    whole = aj.train(config(root, "whole"))

    def terminate_after_cycle_2(record):
        if record["cycle"] == 2:
            os.kill(os.getpid(), signal.SIGTERM)

    with pytest.raises(TrainingInterrupted, match="SIGTERM after cycle 2.*angora-jax resume") as stopped:
        aj.train(config(root, "split"), on_cycle=terminate_after_cycle_2)
    split_dir = root / "split"
    at_interrupt = Checkpoints(split_dir / CHECKPOINTS, config(root, "split").checkpoint).steps("latest")
    with jax_events("backend_compile_duration") as compiled:  # compiled or read from the persistent cache
        resumed = resume(split_dir)
    return whole, stopped.value, at_interrupt, resumed, compiled


@pytest.mark.slow
def test_a_time_limit_stops_with_a_checkpoint_and_resume_continues_exactly(runs, tmp_path):
    """Training in pieces (`--minutes`): a call past its limit stops after the cycle it is in, saves, and reports the
    run unfinished; resume (with its own limit) goes on, and the pieces end where the uninterrupted run does."""
    whole = runs[0]
    first = aj.train(config(tmp_path, "pieces"), minutes=1e-9)
    assert not first.finished and [r["cycle"] for r in first.history] == [1]
    last = resume(first.run_dir, minutes=60)
    assert last.finished and [r["cycle"] for r in last.history] == [2, 3, 4]
    assert resume(first.run_dir, minutes=1e-9).finished, "a finished run stays finished"
    for a, b in zip(jax.tree.leaves(whole.state.params), jax.tree.leaves(last.state.params), strict=True):
        np.testing.assert_array_equal(a, b)
    assert [r["cycle"] for r in read_metrics(first.run_dir)] == [1, 2, 3, 4]
    with pytest.raises(ValueError, match="minutes"):
        aj.train(config(tmp_path, "no_time"), minutes=0.0)


def test_a_checkpoint_replaced_while_it_is_read_gives_way_to_the_one_that_replaced_it(runs, tmp_path):
    """Evaluating or probing a run while it trains: the training process replaces its latest checkpoint (one is kept)
    after a reader listed it. Reading "latest" then reads the newer one; reading that cycle by number says it was
    replaced, not that it is corrupt."""
    whole = runs[0]
    run = tmp_path / "live"
    shutil.copytree(whole.run_dir, run)
    reader = Checkpoints(run / CHECKPOINTS, config(tmp_path, "live").checkpoint, create=False)
    assert reader.steps("latest") == [4]
    writer = Checkpoints(run / CHECKPOINTS, config(tmp_path, "live").checkpoint)
    writer.save(whole.state.replace(cycle=whole.state.cycle + 1), {"cycle": 5}, {}, final=True)
    writer.close()
    assert not (run / CHECKPOINTS / "latest" / "4").exists()
    read = reader.restore(whole.state, "latest")
    assert read.meta["cycle"] == 5 and int(read.state.cycle) == 5
    reader = Checkpoints(run / CHECKPOINTS, config(tmp_path, "live").checkpoint, create=False)
    writer = Checkpoints(run / CHECKPOINTS, config(tmp_path, "live").checkpoint)
    writer.save(whole.state.replace(cycle=whole.state.cycle + 2), {"cycle": 6}, {}, final=True)
    writer.close()
    with pytest.raises(CheckpointError, match=r"latest/5 was removed while it was read: a process training the run "
                                              r"replaced it with cycle 6.*Read latest again"):
        reader.restore(whole.state, 5)
    # Removed mid-read, Orbax raises FileNotFoundError (a user's export: "a folder on the way does not exist ... check
    # the path"), and listing the steps again may meet the next removal: both are read again.
    reader = Checkpoints(run / CHECKPOINTS, config(tmp_path, "live").checkpoint, create=False)
    writer = Checkpoints(run / CHECKPOINTS, config(tmp_path, "live").checkpoint)
    writer.save(whole.state.replace(cycle=whole.state.cycle + 3), {"cycle": 7}, {}, final=True)
    writer.close()
    restore, reload, failures = reader._restore, reader._managers["latest"].reload, []

    def gone_once(template, kind, cycle, partial):
        if not failures:
            failures.append(cycle)
            raise FileNotFoundError(2, "No such file or directory", str(run / CHECKPOINTS / kind / str(cycle)))
        return restore(template, kind, cycle, partial)

    def listing_meets_a_removal():
        if len(failures) == 1:
            failures.append("reload")
            raise FileNotFoundError(2, "No such file or directory")
        return reload()

    reader._restore, reader._managers["latest"].reload = gone_once, listing_meets_a_removal
    assert reader.restore(whole.state, "latest").meta["cycle"] == 7 and failures == [6, "reload"]


def test_a_finished_run_trained_longer_ends_as_the_longer_run_and_records_its_new_length(runs, tmp_path, capsys):
    """`resume --num-cycles N` trains a finished run on to N cycles, bit for bit the run that was asked for N from the
    start, and records N in its config.yaml and session record; fewer cycles than it has done, or a run whose
    schedule spans its length, are refused with the reason before anything changes."""
    whole = runs[0]
    # The same settings at another length reuse the programs that `runs` traced: nothing compiled depends on the
    # count without a schedule that ends at the last cycle (cycle_programs' key).
    with jax_events("jaxpr_trace_duration") as traced:
        short = aj.train(aj.load_config("cartpole", [*TINY, "ppo.num_cycles=2", f"logging.run_root={tmp_path}",
                                                     "logging.run_name=short", "logging.progress=lines"]))
        capsys.readouterr()
        assert main(["resume", str(short.run_dir)]) == 0
        said = capsys.readouterr().out
        assert "nothing to train (cycle 2 of 2: already complete)" in said and "compiling" not in said, said
        assert "already complete; to train it longer: angora-jax resume" in said
        assert main(["check", str(short.run_dir)]) == 0
        assert "the run is complete (2 of 2 cycles): `angora-jax resume" in capsys.readouterr().out
        assert main(["resume", str(short.run_dir), "--num-cycles", "4"]) == 0
    assert not {"init", "cycle"} & set(traced), traced
    assert "ppo.num_cycles 2 -> 4, recorded in its config.yaml" in capsys.readouterr().err
    for a, b in zip(jax.tree.leaves(whole.state.params), jax.tree.leaves(aj.load_agent(short.run_dir, "latest").params),
                    strict=True):
        np.testing.assert_array_equal(a, b)
    untimed = [[{k: v for k, v in r.items() if k not in UNTIMED} for r in read_metrics(d)]
               for d in (whole.run_dir, short.run_dir)]
    assert untimed[0] == untimed[1]
    assert yaml.safe_load((short.run_dir / "config.yaml").read_text())["ppo"]["num_cycles"] == 4
    assert json.loads((short.run_dir / "hyperparameters.json").read_text())["ppo.num_cycles"] == 4
    sessions = [json.loads(line) for line in (short.run_dir / "sessions.jsonl").read_text().splitlines()]
    assert [(s["start_cycle"], s["num_cycles"]) for s in sessions] == [(0, 2), (2, 2), (2, 4)]

    before = (short.run_dir / "config.yaml").read_text()
    assert main(["resume", str(short.run_dir), "--num-cycles", "3"]) == 2
    assert "--num-cycles 3 is below cycle 4, where" in capsys.readouterr().err
    (short.run_dir / "config.yaml").write_text(before.replace("lr_decay: false", "lr_decay: true"))
    assert main(["resume", str(short.run_dir), "--num-cycles", "6"]) == 2
    err = capsys.readouterr().err
    assert "anneals over its ppo.num_cycles (ppo.lr_decay)" in err and "ppo.init_from=" in err
    assert "num_cycles: 4" in (short.run_dir / "config.yaml").read_text()


def test_a_run_stopped_at_its_target_trains_on_past_it_when_asked(runs, tmp_path, capsys, monkeypatch):
    """A run that `ppo.stop_at` ended is complete: `resume` leaves it as it is, reads its checkpoint without the
    environments (nothing continues them) and says how to go on; `resume --no-stop-at` trains it to its
    `ppo.num_cycles`, bit for bit the run without a target, and removes the target from its config.yaml. `--num-cycles`
    alone is refused before it records anything: it would train nothing."""
    whole = runs[0]
    target = "ppo.stop_at={metric: episode_return, value: -1.0e9, episodes: 1}"  # the first cycle's own return
    early = aj.train(aj.load_config("cartpole", [*TINY, target, f"logging.run_root={tmp_path}",
                                                 "logging.run_name=early"]))
    assert early.stopped_at is not None and int(early.state.cycle) == 1
    restores, restore = [], Checkpoints.restore
    monkeypatch.setattr(Checkpoints, "restore", lambda self, template, which="latest", partial=False: (
        restores.append((which, partial, template.actor is None)), restore(self, template, which, partial))[1])
    assert main(["resume", str(early.run_dir)]) == 0  # ended by its target, it is complete: left as it is
    assert restores == [(1, True, True)], "a full checkpoint read whole for a run that does not go on"
    monkeypatch.undo()
    out = capsys.readouterr().out
    assert "1 cycle done (0 in this session)" in out and "Stopped early at cycle 1, as ppo.stop_at asks" in out
    assert f"To train on past it: angora-jax resume {early.run_dir} --no-stop-at" in out
    assert main(["check", str(early.run_dir)]) == 0
    assert "ppo.stop_at ended it (episode_return" in capsys.readouterr().out
    recorded = (early.run_dir / "config.yaml").read_text()
    assert main(["resume", str(early.run_dir), "--num-cycles", "6"]) == 2, "a longer length alone trains nothing"
    assert "add --no-stop-at to train it on to 6 cycles" in capsys.readouterr().err
    assert (early.run_dir / "config.yaml").read_text() == recorded, "a refused length must not be recorded"
    assert main(["resume", str(early.run_dir), "--no-stop-at"]) == 0
    captured = capsys.readouterr()
    assert "ppo.stop_at removed, recorded in its config.yaml" in captured.err and "4 cycles done (3" in captured.out
    assert yaml.safe_load((early.run_dir / "config.yaml").read_text())["ppo"]["stop_at"] is None
    for a, b in zip(jax.tree.leaves(whole.state.params), jax.tree.leaves(aj.load_agent(early.run_dir, "latest").params),
                    strict=True):
        np.testing.assert_array_equal(a, b)


@pytest.mark.slow
def test_a_second_run_of_the_same_settings_reuses_the_traced_programs_and_its_own_seed(runs, tmp_path):
    """A run of the same task and PPO settings in the same process (here a second seed, and the same seed again)
    traces neither `init` nor `cycle` again; the seed still picks the run: the same seed ends as the first run did,
    another one elsewhere. Settings that change the program (another width) trace it anew."""
    whole = runs[0]
    with jax_events("jaxpr_trace_duration") as traced:
        again = aj.train(config(tmp_path, "again"))
        other_seed = aj.train(aj.load_config("cartpole", [*TINY, "ppo.seed=7", f"logging.run_root={tmp_path}",
                                                         "logging.run_name=seed7"]))
        assert not {"init", "cycle"} & set(traced), traced
        aj.train(aj.load_config("cartpole", [*TINY, "ppo.network.width=8", f"logging.run_root={tmp_path}",
                                             "logging.run_name=narrow"]))
        assert {"init", "cycle"} <= set(traced), traced
    for a, b in zip(whole.history, again.history, strict=True):
        assert {k: v for k, v in a.items() if k not in UNTIMED} == {k: v for k, v in b.items() if k not in UNTIMED}
    assert other_seed.history[-1]["loss"] != whole.history[-1]["loss"]
    assert not np.array_equal(jax.tree.leaves(other_seed.state.params)[0], jax.tree.leaves(whole.state.params)[0])


def test_other_env_options_get_programs_of_their_own():
    """The programs a process keeps for reuse (`cycle_programs`) belong to the task's settings as well as the PPO
    settings: the traced step closes over the environment, so the same PPO settings on CartPole with another
    `env.options` value (the episode limit) must be traced anew, while the same options with another seed reuse them.
    Nothing is traced or compiled here: `make_cycle` only wraps the functions."""

    def programs(*overrides):
        config = aj.load_config("cartpole", [*TINY, *overrides])
        return cycle_programs(config, validate(config, new_run=False))

    short = programs("env.options.max_episode_steps=50")
    assert programs("env.options.max_episode_steps=50", "ppo.seed=3") is short
    longer = programs("env.options.max_episode_steps=80")
    assert longer[0] is not short[0] and longer[1] is not short[1]



def test_a_longer_run_of_the_same_settings_reuses_the_programs_unless_a_schedule_ends_at_its_last_cycle():
    """`resume --num-cycles N` (or the same config asked for more cycles) in the same process reuses the programs:
    the cycle count reaches them only through the learning-rate decay and the entropy schedule, which end at the
    last cycle, so with either of those on, another count gets programs of its own."""

    def programs(*overrides):
        config = aj.load_config("cartpole", [*TINY, *overrides])
        return cycle_programs(config, validate(config, new_run=False))

    assert programs("ppo.num_cycles=9") is programs("ppo.num_cycles=4")
    for schedule in ("ppo.lr_decay=true", "ppo.entropy_coef_final=0.0"):
        assert programs(schedule, "ppo.num_cycles=9")[1] is not programs(schedule, "ppo.num_cycles=4")[1], schedule


def test_a_decaying_learning_rate_follows_its_own_runs_length_where_another_lengths_programs_were_made(tmp_path):
    """With `ppo.lr_decay` the rate falls linearly to 0 over `ppo.num_cycles`, so programs made for a 4-cycle run must
    not serve a 2-cycle run of the same settings: its rate halves at its second cycle, not falls by a quarter."""
    decaying = [*TINY_PPO, "ppo.lr_decay=true", "ppo.learning_rate=1e-3", "logging.progress=none",
                "logging.report=false", f"logging.run_root={tmp_path}"]
    longer = aj.load_config("cartpole", [*decaying, "ppo.num_cycles=4"])
    cycle_programs(longer, validate(longer, new_run=False))  # made, not traced: the 2-cycle run compiles its own
    short = aj.train(aj.load_config("cartpole", [*decaying, "ppo.num_cycles=2", "logging.run_name=short"]))
    np.testing.assert_allclose([r["learning_rate"] for r in short.history], [1e-3, 5e-4], rtol=1e-6)


@pytest.mark.slow
def test_sigterm_saves_a_loadable_checkpoint_and_restores_the_handler(runs):
    _, stopped, at_interrupt, *_ = runs
    assert stopped.signum == signal.SIGTERM and stopped.cycle == 2
    assert at_interrupt == [2]  # checkpoint.every=100: only the interruption made it save
    assert signal.getsignal(signal.SIGTERM) is signal.SIG_DFL
    assert signal.getsignal(signal.SIGHUP) is HANGUP_AS_STARTED  # SIG_DFL, or SIG_IGN under nohup
    agent = aj.load_agent(stopped.run_dir, checkpoint=2)
    assert agent.cycle == 2 and int(agent.state.cycle) == 2


def test_resume_equals_uninterrupted(runs):
    """The resumed run ends as the uninterrupted one, and its state, read from the checkpoint, ran the programs that
    the same process compiled for the fresh run (the state's placement on the device is part of a program's key)."""
    whole, _, _, resumed, compiled = runs
    assert not {"jit(init)", "jit(cycle)"} & set(compiled), compiled
    assert [r["cycle"] for r in resumed.history] == [3, 4]
    for a, b in zip(whole.history[2:], resumed.history, strict=True):
        assert {k: v for k, v in a.items() if k not in UNTIMED} == {k: v for k, v in b.items() if k not in UNTIMED}
    # The whole final state, parameters, optimizer, normalisers, env states, carries and keys, bit for bit.
    for a, b in zip(jax.tree.leaves(whole.state), jax.tree.leaves(resumed.state), strict=True):
        if jax.dtypes.issubdtype(a.dtype, jax.dtypes.prng_key):
            a, b = jax.random.key_data(a), jax.random.key_data(b)
        np.testing.assert_array_equal(a, b)
    # The split run's log holds each cycle once, like the whole run's.
    assert [r["cycle"] for r in read_metrics(resumed.run_dir)] == [1, 2, 3, 4]


def test_an_on_cycle_that_fails_keeps_its_cycle_and_resume_ends_as_the_whole_run(runs, tmp_path):
    """A notebook's live plot raising at cycle 2 ended the run with the cycles since its last checkpoint unsaved (here
    all: checkpoint.every=100), and resume then refused without from_scratch. That cycle is now saved, the error says
    so, and resume ends as the run that was not stopped."""
    whole = runs[0]

    def plot(record):
        if record["cycle"] == 2:
            raise ValueError("the plot failed")

    with pytest.raises(ValueError, match="the plot failed") as failed:
        aj.train(config(tmp_path, "plotted"), on_cycle=plot)
    run = tmp_path / "plotted"
    assert f"the run stopped after cycle 2, whose checkpoint is saved; fix on_cycle, then continue with " \
           f"aj.resume({str(run)!r}, on_cycle=...)" in "".join(failed.value.__notes__)
    resumed = resume(run)
    assert resumed.finished and [r["cycle"] for r in resumed.history] == [3, 4]
    for a, b in zip(jax.tree.leaves(whole.state.params), jax.tree.leaves(resumed.state.params), strict=True):
        np.testing.assert_array_equal(a, b)


@pytest.mark.slow
def test_acting_reads_only_parameters_and_statistics(runs, tmp_path, capsys):
    """A checkpoint whose stored environment states no longer fit the task (as reach's did after its scene dropped
    contacts) still loads for acting, with the same parameters and actions; resuming it exactly, or loading it under a
    config whose network differs, stops with the cause and the fix; resuming it otherwise goes on with fresh
    environments and says so."""
    whole = runs[0]
    changed_dir = tmp_path / "changed"
    shutil.copytree(whole.run_dir, changed_dir, ignore=shutil.ignore_patterns(CHECKPOINTS))
    actor = whole.state.actor
    physics = jax.tree.map(lambda x: jnp.concatenate([x, x], axis=-1), actor.env_state.physics)
    changed = whole.state.replace(actor=actor.replace(env_state=actor.env_state.replace(physics=physics)))
    saver = Checkpoints(changed_dir / CHECKPOINTS, config(tmp_path, "changed").checkpoint)
    assert saver.save(changed, {}, {}, final=True)[0] == "latest"
    saver.close()

    agent = aj.load_agent(changed_dir, "latest")
    assert agent.cycle == 4
    for a, b in zip(jax.tree.leaves((agent.params, agent.state.obs_stats)),
                    jax.tree.leaves((whole.state.params, whole.state.obs_stats)), strict=True):
        np.testing.assert_array_equal(a, b)
    obs = actor.env_state.obs
    carry = actor.carry
    np.testing.assert_array_equal(agent.act(carry, obs)[1], aj.load_agent(whole.run_dir, "latest").act(carry, obs)[1])

    # A cycle left to train: the environments would continue (a finished run's are not read, so nothing misfits).
    saved = yaml.safe_load((changed_dir / "config.yaml").read_text())
    saved["ppo"]["num_cycles"] = 5
    (changed_dir / "config.yaml").write_text(yaml.safe_dump(saved))
    with pytest.raises(CheckpointError, match=r"actor\.env_state\.physics.*stored \(4, 8\).*expected \(4, 4\).*"
                                              r"Evaluating and rendering still work"):
        resume(changed_dir, exact=True)
    # Without --exact the run goes on from the checkpoint's parameters, optimizer and key, with fresh environments.
    continued = resume(changed_dir)
    assert "from cycle 4 with fresh environments, not bit for bit" in capsys.readouterr().err
    assert int(continued.state.cycle) == 5 and [r["cycle"] for r in continued.history] == [5]
    assert continued.state.actor.env_state.physics.shape == (4, 4)
    saved["ppo"]["network"]["width"] = 32
    (changed_dir / "config.yaml").write_text(yaml.safe_dump(saved))
    with pytest.raises(CheckpointError, match=r"params\..*stored \(.*16\).*expected \(.*32\).*do not fit the "
                                              r"network.*Restore the config the run was trained with: `angora-jax "
                                              rf"check {re.escape(str(changed_dir))} --restore-config` puts back"):
        aj.load_agent(changed_dir, "latest")
    # The fix the message names works: the network's width is put back, and the policy loads again.
    assert main(["check", str(changed_dir), "--restore-config"]) == 0
    assert aj.load_agent(changed_dir, "latest").config.ppo.network.width == 16


def test_a_lean_checkpoint_resumes_with_fresh_environments_only_when_not_asked_for_exactness(runs, tmp_path, capsys):
    """checkpoint.lean=[latest, best, snapshots]: a run stopped by SIGTERM after cycle 2 saves its parameters,
    optimizer, normalisers, key and cycle but no environments (its size: tests/test_warp.py, checkpoint_size.py);
    `resume --exact` refuses it naming the option, `resume` goes on with fresh environments and says so."""
    whole = runs[0]
    lean = aj.load_config("cartpole", [*TINY, f"logging.run_root={tmp_path}", "logging.run_name=lean",
                                       "checkpoint.lean=[latest, best, snapshots]"])

    def terminate_after_cycle_2(record):
        if record["cycle"] == 2:
            os.kill(os.getpid(), signal.SIGTERM)

    with pytest.raises(TrainingInterrupted):
        aj.train(lean, on_cycle=terminate_after_cycle_2)
    checkpoints = Checkpoints(tmp_path / "lean" / CHECKPOINTS, lean.checkpoint, create=False)
    assert not checkpoints.holds_environments("latest") and not checkpoints.holds_environments(2)
    checkpoints.close()
    whole_checkpoints = Checkpoints(whole.run_dir / CHECKPOINTS, config(tmp_path, "whole").checkpoint, create=False)
    # The whole run keeps environments in latest, not in its snapshots (the default lean kind), at the same cycle 4.
    assert whole_checkpoints.holds_environments("latest") and not whole_checkpoints.holds_environments(2)
    whole_checkpoints.close()
    # Lean on disk: the snapshot at cycle 2 stores no environment leaves, which a whole state asks for.
    whole_checkpoints = Checkpoints(whole.run_dir / CHECKPOINTS, config(tmp_path, "whole").checkpoint, create=False)
    with pytest.raises(CheckpointError, match=r"actor\.env_state\..*not stored"):
        whole_checkpoints.restore(whole.state, 2)
    whole_checkpoints.close()
    # The same training up to the stop: the lean checkpoint holds the parameters the whole run had at cycle 2.
    for a, b in zip(jax.tree.leaves(aj.load_agent(tmp_path / "lean", "latest").params),
                    jax.tree.leaves(aj.load_agent(whole.run_dir, 2).params), strict=True):
        np.testing.assert_array_equal(a, b)

    with pytest.raises(CheckpointError, match=r"exactly from cycle 2: it is lean .*Resume without --exact"):
        resume(tmp_path / "lean", exact=True)
    continued = resume(tmp_path / "lean")
    assert "from cycle 2 with fresh environments, not bit for bit: it is lean" in capsys.readouterr().err
    assert int(continued.state.cycle) == 4 and [r["cycle"] for r in read_metrics(tmp_path / "lean")] == [1, 2, 3, 4]
    assert all(record["finite"] == 1.0 for record in continued.history)
    # Finished, it has nothing to continue: returned as it is, without the note, also when asked to be exact.
    again = resume(tmp_path / "lean", exact=True)
    assert int(again.state.cycle) == 4 and again.history == [] and "fresh environments" not in capsys.readouterr().err


def test_a_missing_cycle_is_answered_with_the_saved_cycles_nearest_it():
    """A run keeping snapshots every 20 cycles up to 280, asked for cycle 50, was offered "a cycle (160, 180, ...,
    280, 289)", as if nothing before 160 were kept."""
    saved = [*range(20, 281, 20), 289]
    assert cycles_to_offer(saved, 50) == "a cycle near 50 (20, 40, 60, 80, 100, 120, 140, 160)"
    assert cycles_to_offer(saved, 285) == "a cycle near 285 (160, 180, 200, 220, 240, 260, 280, 289)"
    assert cycles_to_offer(saved, "bset") == "a cycle (160, 180, 200, 220, 240, 260, 280, 289)"


def test_checkpoint_kinds_and_monitor_records(runs, tmp_path):
    whole = runs[0]
    checkpoints = Checkpoints(whole.run_dir / CHECKPOINTS, config(tmp_path, "whole").checkpoint, create=False)
    assert checkpoints.steps("latest") == [4] and checkpoints.steps("snapshots") == [2, 4]
    # The best cycle's return pooled over the latest 4 episodes (the cycle's own, then the cycles before it, the
    # oldest in part) beats every earlier cycle's.
    pooled = pooled_means(whole.history, "episode_return", 4)
    finite = [cycle for cycle, value in pooled.items() if np.isfinite(value)]
    assert finite and len(finite) < len(pooled), f"the first cycle ends under 4 episodes, so this run pools: {pooled}"
    assert checkpoints.steps("best") == [max(finite, key=lambda c: (pooled[c], -c))], pooled
    resumed = Checkpoints(runs[3].run_dir / CHECKPOINTS, config(tmp_path, "split").checkpoint, create=False)
    assert resumed.steps("best") == checkpoints.steps("best"), "the resumed run's pool went on where it stopped"
    resumed.close()
    with pytest.raises(FileNotFoundError, match=r"No checkpoint 3. Saved: .*snapshots of cycles 2, 4; ask for .*"
                                                r"or a cycle near 3 \(2, 4\)\.$"):
        checkpoints.restore(whole.state, 3)
    checkpoints.close()
    record = whole.history[0]
    for key in ("episode_return", "policy_loss", "entropy", "approx_kl", "norm/reward_std", "memory/host_peak_bytes"):
        assert key in record, key
    assert record["compile_seconds"] > 0 and "compile_seconds" not in whole.history[1]


def test_a_run_directory_is_never_overwritten(runs, tmp_path):
    whole = runs[0]
    before = {p: p.stat().st_mtime_ns for p in whole.run_dir.rglob("*")}
    with pytest.raises(RunDirError, match="already exists and is left untouched.*angora-jax resume"):
        aj.train(config(whole.run_dir.parent, "whole"))
    assert {p: p.stat().st_mtime_ns for p in whole.run_dir.rglob("*")} == before
    # A name taken by something that is no run gets no advice to resume it (resume would refuse it).
    (tmp_path / "afile").write_text("notes")
    (tmp_path / "empty").mkdir()
    (tmp_path / "starting").mkdir()
    (tmp_path / "starting" / "writer.lock").write_text("{}")
    for name, said in (("afile", "is a file, not a run directory"), ("empty", "exists and is not a run"),
                       ("starting", "Another process is starting a run in")):
        with pytest.raises(RunDirError, match=said) as refused:
            aj.train(config(tmp_path, name))
        assert "resume" not in str(refused.value) and "another logging.run_name" in str(refused.value)
    assert (tmp_path / "afile").read_text() == "notes" and not any((tmp_path / "empty").iterdir())


def test_records_after_the_checkpoint_are_set_aside_not_lost(tmp_path):
    """A run killed hard (no chance to save) has logged cycles after its latest checkpoint; resuming recomputes them,
    so they move to a side file and metrics.jsonl holds each cycle once."""
    lines = [json.dumps({"cycle": c, "episode_return": float(c)}) for c in range(1, 6)]
    (tmp_path / "metrics.jsonl").write_text("\n".join(lines) + "\n")
    side = set_aside_after(tmp_path, 3)
    assert [r["cycle"] for r in read_metrics(tmp_path)] == [1, 2, 3]
    assert side.name == "metrics.after-cycle-3.jsonl" and side.read_text().splitlines() == lines[3:]
    assert set_aside_after(tmp_path, 3) is None  # nothing later than cycle 3 any more


def test_a_set_aside_that_fails_leaves_the_log_and_no_side_file_or_draft(tmp_path, monkeypatch):
    """A resume on a full disk wrote the side file, failed to rewrite metrics.jsonl and left its draft; each retry then
    set the same records aside again (metrics.after-cycle-8-2 ... -9.jsonl). The lock's draft stayed behind too."""
    from angora_jax.experiment.run_lock import RunLock

    lines = [json.dumps({"cycle": c}) for c in range(1, 6)]
    (tmp_path / "metrics.jsonl").write_text("\n".join(lines) + "\n")
    write_text = Path.write_text

    def full_disk_for_the_log_and_lock(path, text, *args, **kwargs):
        log_draft = path.name.startswith(".metrics.") and not path.name.startswith(".metrics.after")
        if not (log_draft or path.suffix == ".tmp"):  # the side file is written, the log's and the lock's drafts not
            return write_text(path, text, *args, **kwargs)
        write_text(path, text[:3], *args, **kwargs)
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(Path, "write_text", full_disk_for_the_log_and_lock)
    for _ in range(2):
        with pytest.raises(OSError, match="No space left"):
            set_aside_after(tmp_path, 3)
    with pytest.raises(OSError, match="No space left"):
        RunLock(tmp_path).acquire()
    monkeypatch.undo()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["metrics.jsonl"]
    assert (tmp_path / "metrics.jsonl").read_text().splitlines() == lines


def test_a_save_is_written_behind_the_next_cycle_and_whole_when_it_is_final(runs, tmp_path):
    """`save` returns while Orbax writes in the background; the manifest, written once the files are whole, marks
    when: not after the save itself, but after the next cycle's save, and at once after a `final` save (a run that
    stops must leave its checkpoints whole before it says how to resume)."""
    whole = runs[0]
    saver = Checkpoints(tmp_path / "c", CheckpointConfig(every=2, best_metric=None, snapshot_every=0))

    def at(cycle):
        return whole.state.replace(cycle=jnp.asarray(cycle, whole.state.cycle.dtype))

    assert saver.save(at(2), {}, {}) == ["latest"]
    assert not (tmp_path / "c/latest/2/manifest.json").exists()
    assert saver.save(at(3), {}, {}) == []
    assert (tmp_path / "c/latest/2/manifest.json").is_file() and saver.damage("latest", 2) is None
    assert saver.save(at(5), {}, {}, final=True) == ["latest"]
    assert (tmp_path / "c/latest/5/manifest.json").is_file() and saver.steps("latest") == [5]
    saver.close()


def test_a_lucky_cycle_of_one_episode_does_not_hold_the_best_for_good(runs, tmp_path):
    """With few environments a cycle ends an episode or two: one that succeeded by chance (success 1.0, which nothing
    can beat) used to stay the best for good, and `evaluate` read that untrained policy. The metric is now compared
    over the latest `best_episodes` episodes, pooled across cycles; `eval/` values, held out, as they are."""
    whole = runs[0]
    cycles = [(1.0, 1), (0.0, 3), (0.5, 30), (0.25, 4), (0.9, 40), (0.8, 40)]
    # Cycle 3 pools its 30 episodes with two of cycle 2's failures; cycle 4's 4 with 28 of cycle 3's ties it.
    for metric, expected in [("metric/success", {3: 0.5 * 30 / 32, 5: 0.9}),
                             ("eval/metric/success", {1: 1.0})]:
        saver = Checkpoints(tmp_path / metric.replace("/", "_"), CheckpointConfig(every=100, best_metric=metric))
        best = {}
        for cycle, (success, episodes) in enumerate(cycles, 1):
            state = whole.state.replace(cycle=jnp.asarray(cycle, whole.state.cycle.dtype))
            if "best" in saver.save(state, {metric: success, "episodes": episodes}, {}):
                best[cycle] = saver.best_value
        saver.close()
        assert best.keys() == expected.keys(), (metric, best)
        for cycle, value in expected.items():
            assert best[cycle] == pytest.approx(value), (metric, cycle)


def test_a_resumed_run_pools_the_best_metric_with_the_episodes_before_its_checkpoint(runs, tmp_path):
    """The episodes that the best metric pools are kept in each checkpoint: a run resumed from one compares its next
    cycle as the run that had not stopped would."""
    whole = runs[0]
    settings = CheckpointConfig(every=1, best_metric="metric/success", lean=("latest", "best"))

    def at(cycle):
        return whole.state.replace(cycle=jnp.asarray(cycle, whole.state.cycle.dtype))

    first = Checkpoints(tmp_path / "c", settings)
    assert first.save(at(1), {"metric/success": 0.0, "episodes": 20}, {}) == ["latest"]
    assert first.save(at(2), {"metric/success": 0.5, "episodes": 20}, {}) == ["latest", "best"]
    first.close()
    again = Checkpoints(tmp_path / "c", settings)
    again.continue_from(2)
    assert again.save(at(3), {"metric/success": 1.0, "episodes": 8}, {}, final=True) == ["latest", "best"]
    assert again.best_value == pytest.approx((8 * 1.0 + 20 * 0.5 + 4 * 0.0) / 32)
    again.close()


def test_the_best_state_is_written_in_the_cycle_that_reaches_it(runs, tmp_path):
    """No state is held for a later save: holding the best cycle's device arrays churned XLA's buffer addresses, and
    with them MuJoCo Warp's captured CUDA graphs, until the GPUs ran out of memory (`Checkpoints`)."""
    whole = runs[0]
    saver = Checkpoints(tmp_path / "best", CheckpointConfig(every=4, best_metric="episode_return", best_episodes=1,
                                                            lean=("best",)))
    returns = {1: 1.0, 2: 2.0, 3: 1.5, 4: 2.5}
    saved = {}
    for cycle, value in returns.items():
        state = whole.state.replace(cycle=jnp.asarray(cycle, whole.state.cycle.dtype))
        saved[cycle] = saver.save(state, {"episode_return": value}, {})
    assert saved == {1: ["best"], 2: ["best"], 3: [], 4: ["latest", "best"]}
    assert saver.steps("best") == [4] and saver.steps("latest") == [4]
    restored = saver.restore(jax.eval_shape(lambda: whole.state.without_environments()), "best")
    assert restored.meta["cycle"] == 4 and not restored.meta["environments"]
    saver.close()


def test_after_a_failed_read_the_closed_event_loop_reports_are_dropped_and_others_kept(monkeypatch):
    """TensorStore's callbacks that outlive a failed read (a checkpoint removed by the run's writer mid-read) report
    "Event loop is closed" with no object: 60 tracebacks around one exported policy."""
    import sys
    import types

    from angora_jax.experiment import checkpoint

    reported = []
    monkeypatch.setattr(sys, "unraisablehook", lambda unraisable: reported.append(str(unraisable.exc_value)))
    checkpoint._drop_failed_read_reports()
    for error, obj in ((RuntimeError("Event loop is closed"), None), (RuntimeError("another failure"), "something")):
        sys.unraisablehook(types.SimpleNamespace(exc_type=type(error), exc_value=error, exc_traceback=None,
                                                 err_msg=None, object=obj))
    assert reported == ["another failure"]


def early_best_run(source: Path, run: Path) -> Path:
    """A copy of the 4-cycle run `source` whose best checkpoint is cycle 2 (its snapshot), as a best metric that
    never rose keeps an early cycle."""
    shutil.copytree(source, run)
    shutil.rmtree(run / CHECKPOINTS / "best")
    (run / CHECKPOINTS / "best").mkdir()
    shutil.copytree(run / CHECKPOINTS / "snapshots" / "2", run / CHECKPOINTS / "best" / "2")
    return run


def test_a_best_checkpoint_from_the_first_half_of_the_run_is_named_when_an_agent_is_loaded(runs, tmp_path, capsys):
    """A best metric that never rose (a success rate of 0 in a short CPU run) keeps cycle 1 as best: record, ablate and
    dynamics then probed the untrained network, saying nothing (a user's trial of the probing page)."""
    run = early_best_run(runs[0].run_dir, tmp_path / "early")
    assert aj.load_agent(run).cycle == 2
    err = capsys.readouterr().err
    assert f"Note: the best checkpoint of {run} is cycle 2, from the first half of its 4 cycles" in err, err
    assert "--checkpoint latest; in Python checkpoint='latest') holds cycle 4" in err
    assert aj.load_agent(run, "latest").cycle == 4 and capsys.readouterr().err == ""


def test_a_run_started_from_an_early_best_is_told_once_how_to_start_from_the_latest(runs, tmp_path, capsys):
    """`ppo.init_from=RUN` reads RUN's best checkpoint. A MyoHandPose curriculum on a GPU handed stage 2 stage 1's
    cycle 1 of 227 (no episode had succeeded, so best stayed at cycle 1): the note said `--checkpoint latest`, which
    `init_from` has no use for, and came twice (the check before compiling, then the start)."""
    from angora_jax.experiment.agent import saved_policy

    run = early_best_run(runs[0].run_dir, tmp_path / "early")
    saved_policy(str(run))
    saved_policy(str(run))
    err = capsys.readouterr().err
    assert err.count(f"Note: the best checkpoint of {run} is cycle 2, from the first half of its 4 cycles") == 1, err
    assert f"The latest checkpoint (name it as {run}:latest, e.g. ppo.init_from={run}:latest) holds cycle 4" in err
    saved_policy(f"{run}:latest")
    assert capsys.readouterr().err == ""


def test_a_reader_opens_a_run_whose_writer_removes_a_step_while_orbax_lists_them(runs, monkeypatch):
    """Opening Orbax's managers lists each kind's steps and reads their times: export of a run saving every cycle
    failed in 1 of 8 tries with "No such file or directory (.../latest/172) ... check the path"."""
    import orbax.checkpoint as ocp

    real, failures = ocp.CheckpointManager, []

    def removed_once(directory, *args, **kwargs):
        if not failures:
            failures.append(directory)
            raise FileNotFoundError(2, "No such file or directory", str(directory / "172"))
        return real(directory, *args, **kwargs)

    monkeypatch.setattr(ocp, "CheckpointManager", removed_once)
    reader = Checkpoints(runs[0].run_dir / CHECKPOINTS, CheckpointConfig(), create=False)
    try:
        assert reader.steps("latest") == [4] and len(failures) == 1
    finally:
        reader.close()


def test_a_cycle_given_as_digits_or_a_numpy_integer_names_that_checkpoint(runs, tmp_path):
    """A notebook's cycle often comes as text ("2", typed into a widget) or as a numpy integer (read from an array of
    `read_metrics` or a DataFrame): each names the snapshot of that cycle, for loading and resuming, as the int does.
    They were answered "No checkpoint '2'. ... ask for ... a cycle (2)" (and np.int64(2) likewise)."""
    whole = runs[0]
    for cycle in ("2", np.int64(2), np.int32(2)):
        assert aj.load_agent(whole.run_dir, cycle).cycle == 2
    run = tmp_path / "from_text"
    shutil.copytree(whole.run_dir, run)
    assert [r["cycle"] for r in resume(run, start_from="2").history] == [3, 4]


@pytest.mark.parametrize("flag", ["from_scratch", "exact", "force", "no_stop_at"])
def test_a_flag_given_as_text_is_refused_before_the_run_is_touched(runs, tmp_path, flag):
    """`resume(run, from_scratch="no")` (a widget's or a file's text) is a true value: it trained the run again from
    cycle 0, its outputs moved to previous-1; `force="no"` would take over a live writer's lock."""
    run = tmp_path / "run"
    shutil.copytree(runs[0].run_dir, run)
    before = sorted(path.name for path in run.iterdir())
    with pytest.raises(TypeError, match=rf"^{flag} must be True or False, got 'no' \(str\): a non-empty string counts "
                                        r"as True\.$"):
        resume(run, **{flag: "no"})
    assert sorted(path.name for path in run.iterdir()) == before


@pytest.mark.parametrize("given", [True, 2.0, None, [2]])
def test_a_checkpoint_that_is_no_name_or_whole_number_is_refused_as_such(runs, given):
    """`checkpoint=True` (a widget's checkbox) read as cycle 1 and failed on a folder named "True": "Checkpoint
    .../latest/True is damaged"; 2.0 (a cycle from a DataFrame's float column) and None were "No checkpoint 2.0",
    though the run holds cycle 2."""
    with pytest.raises(TypeError, match=rf"^A checkpoint is 'best', 'latest' or a cycle \(a whole number, e\.g\. 2\), "
                                        rf"got {re.escape(repr(given))} \({type(given).__name__}\)\.$"):
        aj.load_agent(runs[0].run_dir, given)


@pytest.mark.parametrize("options, error, message", [
    ({"on_cycle": "print"}, TypeError, r"^on_cycle is called with each cycle's record \(a dict\), e.g. on_cycle=print "
                                       r"or on_cycle=records.append; got 'print' \(str\)\.$"),
    ({"minutes": "5"}, ValueError, r"^minutes \(the call's time limit\) must be > 0, got '5'\.$"),
    ({"minutes": 0}, ValueError, r"^minutes \(the call's time limit\) must be > 0, got 0\.$"),
    ({"on_cycle": lambda: None}, TypeError, r"^on_cycle is called with each cycle's record \(a dict\), e.g. on_cycle="
                                            r"print or on_cycle=records.append; <lambda> takes \(\)\.$"),
    ({"on_cycle": lambda record, axes: None}, TypeError, r"^on_cycle is called with each cycle's record .*; <lambda> "
                                                         r"takes \(record, axes\)\.$"),
])
def test_an_on_cycle_or_time_limit_that_cannot_be_used_is_refused_before_a_run_directory_is_made(runs, tmp_path,
                                                                                                 options, error,
                                                                                                 message):
    """on_cycle="print" (a notebook slip) was found only after the first cycle had compiled and run: "'str' object is
    not callable", leaving a run with that cycle logged and no checkpoint, which resume refuses to start over (it
    needs from_scratch=True); minutes="5" failed comparing text with a number once the run directory was made. An
    on_cycle that takes no record, or two arguments, failed the same way after the first cycle."""
    with pytest.raises(error, match=message):
        aj.train(config(tmp_path, "refused"), **options)
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(error, match=message):
        resume(runs[0].run_dir, **options)


def test_read_metrics_of_what_is_no_run_directory_says_so_rather_than_return_no_records(runs, tmp_path):
    """A mistyped run path gave read_metrics' empty list, a run without records (an empty plot, no word why), and the
    run's config.yaml given for it NotADirectoryError; a run that has not finished a cycle still reads as []."""
    whole = runs[0].run_dir
    with pytest.raises(RunDirError, match=rf"^{tmp_path / 'whol'} is not a run directory: it does not exist\."):
        read_metrics(tmp_path / "whol")
    with pytest.raises(RunDirError, match=rf"is a file, not a run directory\. It is inside the run directory {whole}"):
        read_metrics(whole / "config.yaml")
    with pytest.raises(RunDirError, match=r"has no config.yaml\. It holds run directories \(.*whole\): give one"):
        read_metrics(whole.parent)
    started = tmp_path / "started"
    started.mkdir()
    assert read_metrics(started) == [], "a directory that train is making into a run"
    shutil.copy(whole / "config.yaml", started)
    assert read_metrics(started) == [] and len(read_metrics(whole)) == 4


def test_resumes_refusals_name_the_python_arguments_beside_the_command_line_options(runs, tmp_path):
    """aj.resume's refusals named only the command's options: a notebook user whose run lost its latest checkpoint (a
    second interrupt before the first save) was told "`--from 4` continues ..., or `--from-scratch` trains again",
    and resume(start_from=7) and resume(num_cycles=3) answered "--from 7: ..." and "--num-cycles 3 is below ..."."""
    run = tmp_path / "nolatest"
    shutil.copytree(runs[0].run_dir, run)
    shutil.rmtree(run / CHECKPOINTS / "latest")
    with pytest.raises(RunDirError, match=rf"`--from 4` continues .*`--from-scratch` trains again .* \(in Python: "
                                          rf"aj.resume\('{run}', start_from=4\) or aj.resume\('{run}', "
                                          r"from_scratch=True\)\)\."):
        resume(run)
    with pytest.raises(RunDirError, match=r"^--from 7 \(in Python start_from=7\): No checkpoint 7\."):
        resume(run, start_from=7)
    with pytest.raises(RunDirError, match=r"cannot be combined with --from \(in Python: from_scratch=True without "
                                          r"start_from\)\.$"):
        resume(run, start_from=4, from_scratch=True)
    with pytest.raises(ConfigError, match=r"--num-cycles 3 is below cycle 4, .*: ask for at least that many "
                                          r"\(num_cycles in Python\)\.$"):
        resume(run, start_from=4, num_cycles=3)


def test_a_run_given_as_what_train_returned_or_as_none_is_refused_naming_the_run_directory(runs, tmp_path):
    """`aj.load_agent(run)` with the TrainingRun that train returned (the notebook's `run = aj.train(...)`), and None
    for a run directory, failed deep in pathlib: "expected str, bytes or os.PathLike object, not TrainingRun"."""
    whole = runs[0]
    calls = (lambda value: resume(value), lambda value: aj.load_agent(value),
             lambda value: aj.evaluate(value, episodes=1, save=False), lambda value: read_metrics(value),
             lambda value: aj.export_policy(value, tmp_path / "p.msgpack"), lambda value: snapshot_cycles(value))
    for call in calls:
        with pytest.raises(TypeError, match=rf"^run_dir is a run directory \(a str or Path\): give run.run_dir "
                                            rf"\('{whole.run_dir}'\), not the TrainingRun that train returned\.$"):
            call(whole)
        with pytest.raises(TypeError, match=r"^run_dir is a run directory \(a str or Path, e.g. 'runs/my-run'\), got "
                                            r"None \(NoneType\)\.$"):
            call(None)
    assert not (tmp_path / "p.msgpack").exists()


def test_a_damaged_checkpoint_names_the_python_arguments_that_read_the_intact_one(runs, tmp_path):
    """A notebook's load_agent of a damaged checkpoint was told only the command's options: "read it with
    --checkpoint best (resume: --from best)"."""
    run = tmp_path / "damaged"
    shutil.copytree(runs[0].run_dir, run)
    meta = run / CHECKPOINTS / "latest" / "4" / "meta" / "metadata"
    meta.write_bytes(meta.read_bytes()[:5])
    with pytest.raises(CheckpointError, match=r"The newest intact checkpoint is best of cycle 4: read it with "
                                              r"--checkpoint best \(resume: --from best\); in Python checkpoint='best' "
                                              r"\(resume: start_from='best'\); or restore the folder"):
        aj.load_agent(run, "latest")


def test_a_run_config_edited_into_one_that_does_not_validate_names_the_edit_and_the_copy_to_restore(runs, tmp_path):
    """A run's config.yaml cut short mid-word (or mistyped by hand) to `task: CartPol` was answered "Unknown value
    'CartPol' for env.task. Did you mean 'CartPole'?", as if the user had asked for that task, with no word that the
    run's own file changed or that its checkpoints keep the config it was trained with."""
    run = tmp_path / "edited"
    shutil.copytree(runs[0].run_dir, run)
    config_file = run / "config.yaml"
    config_file.write_text(config_file.read_text().replace("task: CartPole", "task: CartPol"))
    before = sorted(p.relative_to(run) for p in run.rglob("*"))
    edit = (f"{config_file} was edited after the latest checkpoint of cycle 4 was saved: env.task: 'CartPole' -> "
            "'CartPol', and it no longer loads: Unknown value 'CartPol' for env.task.")
    restore = (f"`angora-jax check {run} --restore-config` writes back the config it was trained with (the edited "
               "file is kept beside it).")
    wanted = "^" + re.escape(edit) + ".* " + re.escape(restore) + "$"
    for call in (lambda: aj.load_agent(run), lambda: resume(run), lambda: aj.evaluate(run, episodes=1, save=False)):
        with pytest.raises(ConfigError, match=wanted):
            call()
    assert sorted(p.relative_to(run) for p in run.rglob("*")) == before


def test_a_run_directory_written_with_a_leading_tilde_is_named_in_the_home_folder(runs, tmp_path, monkeypatch):
    """aj.load_agent("~/runs/x") said "~/runs/x is not a run directory: it does not exist", of a run that exists in
    the home folder: Python reads the ~ as a folder's name, as a shell does not."""
    monkeypatch.setenv("HOME", str(tmp_path))
    shutil.copytree(runs[0].run_dir, tmp_path / "runs" / "x")
    wanted = (r"^~/runs/x is not a run directory: it does not exist\. A leading ~ is the home folder to a shell, not "
              rf"in Python: give '{tmp_path / 'runs' / 'x'}' \(os.path.expanduser\('~/runs/x'\)\)\.$")
    for call in (aj.load_agent, resume, read_metrics):
        with pytest.raises(RunDirError, match=wanted):
            call("~/runs/x")
