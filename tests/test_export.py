"""`angora-jax export` and `aj.load_policy`: a trained recurrent policy in one file acts, without its run directory,
exactly as the run's own agent does; bad files and an existing output are refused."""

import json
import shutil
import sys

import jax
import numpy as np
import pytest
from benchmark_results import BENCHMARKS, results
from flax import serialization
from quick_compile import quick_compilation
from tiny import TINY_PPO

import angora_jax as aj
from angora_jax.analysis import record_activity
from angora_jax.cli import main
from angora_jax.experiment import RunDirError
from angora_jax.experiment.export import export_policy
from angora_jax.experiment.run_dir import CHECKPOINTS

sys.path.insert(0, str(BENCHMARKS))
import exported_policy  # noqa: E402


@pytest.fixture(scope="module")
def lstm_run(tmp_path_factory):
    """A recurrent CartPole run of 2 cycles, compiled quickly (tests/quick_compile.py); its policy compiles as usual."""
    root = tmp_path_factory.mktemp("runs")
    with quick_compilation():
        return aj.train("cartpole", [*TINY_PPO, "ppo.num_cycles=2", "ppo.network.name=lstm", "logging.progress=none",
                                     "logging.report=false", f"logging.run_root={root}",
                                     "logging.run_name=lstm"]).run_dir


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
    assert not any((lstm_run / CHECKPOINTS / "best").glob("[0-9]*")), "2 cycles: too few episodes for a best"
    assert main(["export", str(lstm_run), "--out", str(out)]) == 0  # --checkpoint best, the default
    assert "Policy of the latest checkpoint (the run keeps no best checkpoint: its checkpoint.best_metric is null, " \
           f"or too few episodes had ended when it saved): {out} (load it with" in capsys.readouterr().out, \
        "not silently another checkpoint than the one asked for"
    assert main(["export", str(lstm_run), "--out", str(tmp_path / "latest.msgpack"), "--checkpoint", "latest"]) == 0
    assert f"Policy of the latest checkpoint: {tmp_path / 'latest.msgpack'} (load it" in capsys.readouterr().out
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
    with pytest.raises(FileNotFoundError, match=r"aj.export_policy\(RUN_DIR, FILE\) or angora-jax export RUN_DIR"):
        aj.load_policy(tmp_path / "missing.msgpack")
    # A run directory given for a policy file: the notebook trial was told only of the command.
    with pytest.raises(FileNotFoundError, match=rf"{lstm_run} is a run directory, not an exported policy: "
                                                rf"aj.load_agent\('{lstm_run}'\) loads its policy"):
        aj.load_policy(lstm_run)


def test_export_into_a_folder_writes_the_runs_name_there_and_another_suffix_is_refused(lstm_run, tmp_path, capsys,
                                                                                       monkeypatch):
    """`--out newdir/` wrote a file named newdir, `--out` an existing folder failed as an existing file, and `--out
    x.txt` was accepted: a folder (existing, or a name ending in '/') gets RUN_NAME.msgpack inside it, and a name not
    ending in .msgpack is refused before the run is read, with the name to give; nothing is written for it."""
    (tmp_path / "existing").mkdir()
    for out, written in [(f"{tmp_path / 'newdir'}/", tmp_path / "newdir" / "lstm.msgpack"),
                         (str(tmp_path / "existing"), tmp_path / "existing" / "lstm.msgpack")]:
        assert main(["export", str(lstm_run), "--out", out, "--checkpoint", "latest"]) == 0, capsys.readouterr().err
        assert f"Policy of the latest checkpoint: {written} (load it" in capsys.readouterr().out
        assert aj.load_policy(written).agent.cycle == 2
    assert main(["export", str(lstm_run), "--out", str(tmp_path / "existing")]) == 2, "its lstm.msgpack is kept"
    assert f"{tmp_path / 'existing' / 'lstm.msgpack'} exists" in capsys.readouterr().err
    before = sorted(tmp_path.rglob("*"))
    for out, said in [("x.txt", "give --out a name ending in .msgpack (e.g. x.msgpack), not x.txt."),
                      ("policy", "(e.g. policy.msgpack), or policy/ to write policy/lstm.msgpack, not policy.")]:
        monkeypatch.chdir(tmp_path)
        assert main(["export", str(lstm_run), "--out", out]) == 2
        assert said in capsys.readouterr().err
    with pytest.raises(ValueError, match="an exported policy is a msgpack file"):
        export_policy(lstm_run, tmp_path / "x.txt")
    assert sorted(tmp_path.rglob("*")) == before


@pytest.mark.parametrize("out", ["notes.txt/policy.msgpack", "notes.txt/sub/", "notes.txt"])
def test_export_into_a_file_or_a_folder_it_cannot_write_is_refused_naming_the_folder(out, tmp_path, capsys,
                                                                                     monkeypatch):
    """`--out notes.txt/policy.msgpack` (a file where a folder goes) loaded the run, then said only "[Errno 17] File
    exists: 'notes.txt'", as if the policy existed; refused now before the run is read (none here), naming the file
    in the way; a folder one may not write to likewise."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "notes.txt").write_text("mine")
    if out == "notes.txt":  # a writable file's folder, made read-only (root writes anywhere: os.access says)
        out = "policy.msgpack"
        monkeypatch.setattr("os.access", lambda path, mode: False)
    assert main(["export", "no-run", "--out", out]) == 2
    err = capsys.readouterr().err
    in_the_way = f"{tmp_path} is not writable" if out == "policy.msgpack" else f"{tmp_path / 'notes.txt'} is a file"
    assert f"--out {out}: {in_the_way}" in err and "give a path in a folder you can write to" in err, err
    assert sorted(tmp_path.iterdir()) == [tmp_path / "notes.txt"] and (tmp_path / "notes.txt").read_text() == "mine"


@pytest.mark.slow
def test_the_exported_policy_benchmark_reproduces_evaluates_episodes_in_a_loop_of_its_own(lstm_run, tmp_path):
    policy_file = tmp_path / "policy.msgpack"
    export_policy(lstm_run, policy_file)
    cpu = aj.evaluate(lstm_run, episodes=12, save=True)
    with pytest.raises(SystemExit, match="not a deterministic batched evaluation"):
        exported_policy.main([str(policy_file), str(cpu.json_path), "--out", str(tmp_path / "refused.json")])
    batched = aj.evaluate(lstm_run, episodes=12, path="batched", save=True)
    out = tmp_path / "exported.json"
    exported_policy.main([str(policy_file), str(batched.json_path), "--out", str(out)])
    record = results(out, "exported_policy")
    assert record["config"]["episodes"] == 12 and record["config"]["cycle"] == 2
    rows = {row["quantity"]: row for row in record["results"]}
    assert set(rows) == {"episode_return", "episode_length"}
    for row in rows.values():  # CartPole on the CPU: the plain loop rounds as evaluate's program does
        assert row["equal_episodes"] == 1.0 and row["agree"] and row["exported"] == row["evaluate"]
    assert np.ptp(batched.episodes["episode_length"]) > 0, "episodes differ: the comparison is not of constants"


@pytest.mark.parametrize("section, key, value, said", [
    ("ppo", "network", {"name": "lstm", "width": 8}, r"'lstm' network and CartPole task .*params\.network\."
                                                     r"policy_cell\..*: stored \(64, 64\) float32, expected \(8, 64\) "
                                                     r"float32"),
    ("env", "task", "Pendulum", r"'lstm' network and Pendulum task .*obs_stats.proprioception.mean: stored \(4,\) "
                                r"float32, expected \(3,\) float32"),
])
def test_a_policy_whose_parameters_do_not_fit_what_its_config_builds_is_refused_on_loading(lstm_run, tmp_path,
                                                                                           section, key, value, said):
    """An exported file whose network or task is built otherwise where it is loaded (a network of one's own edited
    since, another angora_jax version; here its config is edited in the file) loaded without a word and then failed
    in `act` with flax's ScopeParamShapeError, or on loading with flax's "The target dict keys and state dict keys do
    not match"; it is refused by load_policy now, naming the leaves and the cause."""
    out = export_policy(lstm_run, tmp_path / "policy.msgpack")
    content = serialization.msgpack_restore(out.read_bytes())
    config = json.loads(content["config"])
    config[section][key] = value
    content["config"] = json.dumps(config)
    changed = tmp_path / "changed.msgpack"
    changed.write_bytes(serialization.msgpack_serialize(content))
    with pytest.raises(RunDirError, match=rf"^{changed} holds parameters that do not fit the {said}.*: their code "
                                          r"changed since the export"):
        aj.load_policy(changed)


def test_act_names_an_observation_or_carry_that_does_not_fit(lstm_run):
    """A NumPy array, an unbatched observation, another task's widths or a carry for another batch size failed deep
    inside JAX (or, on a feed-forward model, gave a scalar action silently)."""
    agent = aj.load_agent(lstm_run)
    obs = jax.vmap(agent.env.reset)(jax.random.split(jax.random.key(0), 4)).obs
    carry = agent.initial_carry(4)
    assert agent.act(carry, obs)[1].shape == (4,)
    with pytest.raises(TypeError, match=r"obs must be a Sensation .* got ndarray"):
        agent.act(carry, np.zeros((4, 4), np.float32))
    one = agent.env.reset(jax.random.key(0)).obs
    with pytest.raises(ValueError, match=r"obs.proprioception has shape \(4,\); this agent \(CartPole\) reads \(B, 4\) "
                                         r"for a batch of B environments: make one observation a batch of 1 with "
                                         r"jax.tree.map\(lambda x: x\[None\], obs\)"):
        agent.act(agent.initial_carry(1), one)
    # What the message says works (it said obs[None], which a Sensation does not take).
    assert agent.act(agent.initial_carry(1), jax.tree.map(lambda x: x[None], one))[1].shape == (1,)
    wide = obs.replace(proprioception=np.zeros((4, 7), np.float32))
    with pytest.raises(ValueError, match=r"obs.proprioception has shape \(4, 7\).*observations of another task\?"):
        agent.act(carry, wide)
    with pytest.raises(ValueError, match=r"The carry is for a batch of 2 environments and obs for 4: start it with "
                                         r"agent.initial_carry\(4\)"):
        agent.act(agent.initial_carry(2), obs)


def test_act_samples_from_one_key_or_a_seed_and_names_what_to_pass_for_anything_else(lstm_run):
    """An int key was taken by distrax as jax.random.PRNGKey's seed, and so were True and -1, without a word; text, a
    float, a batch of keys, or an int traced under jax.jit failed deep inside JAX ("invalid PRNG key data",
    "categorical accepts a single key ... Use jax.vmap")."""
    agent = aj.load_agent(lstm_run)
    obs = jax.vmap(agent.env.reset)(jax.random.split(jax.random.key(0), 8)).obs
    carry = agent.initial_carry(8)
    sampled = agent.act(carry, obs, jax.random.key(3))[1]
    for same in (3, np.uint32(3), jax.random.PRNGKey(3)):
        np.testing.assert_array_equal(agent.act(carry, obs, same)[1], sampled)
    fix = r"^key must be one JAX key for the whole batch, e.g. jax.random.key\(0\) \(under jax.jit too\), or a seed"
    for key, given in (("0", "'0'"), (1.5, "1.5"), (jax.random.split(jax.random.key(0), 8), r"an array of key<fry> "
                                                                                          r"of shape \(8,\)"),
                       (jax.random.key_data(jax.random.split(jax.random.key(0), 3)).ravel(),
                        r"an array of uint32 of shape \(6,\)")):
        with pytest.raises(TypeError, match=rf"{fix}, a whole number from 0 to 4,294,967,295; got {given}\.$"):
            agent.act(carry, obs, key)
    with pytest.raises(TypeError, match=rf"{fix}.*got an array of int32 of shape \(\)\."):
        jax.jit(agent.act)(carry, obs, 0)
    for seed in (True, -1):
        with pytest.raises(ValueError, match=rf"^key given as a seed must be a whole number from 0 to 4,294,967,295, "
                                             rf"got {seed}\.$"):
            agent.act(carry, obs, seed)


@pytest.mark.parametrize("size", [0, -1, 2.5, "4", True])
def test_a_carry_for_no_whole_number_of_environments_is_refused_by_name(lstm_run, tmp_path, size):
    """`agent.initial_carry(-1)` and `(2.5)` failed inside JAX ("broadcast_in_dim shape must have every element be
    nonnegative", "Shapes must be 1D sequences of concrete values of integer type"); 0 gave an empty carry that no
    observation fits. The exported policy's initial_carry is the agent's."""
    agent = aj.load_agent(lstm_run)
    policy = aj.load_policy(aj.export_policy(lstm_run, tmp_path / "p.msgpack"))
    for make in (agent.initial_carry, policy.initial_carry):
        with pytest.raises(ValueError, match=rf"^batch_size must be a whole number of at least 1, got {size!r}\.$"):
            make(size)
    assert jax.tree.leaves(agent.initial_carry(np.int64(3)))[0].shape[0] == 3


@pytest.mark.parametrize("out", [None, 3])
def test_an_out_that_is_no_path_is_refused_by_name(lstm_run, out):
    """`aj.export_policy(run_dir, None)` said only Python's "expected str, bytes or os.PathLike object, not
    NoneType", naming no argument."""
    with pytest.raises(TypeError, match=rf"^out is where the policy is written \(a \.msgpack file's path or a folder, "
                                        rf"e\.g\. 'policy\.msgpack'\), got {out!r} \({type(out).__name__}\)\.$"):
        aj.export_policy(lstm_run, out)


def test_a_flag_of_an_agent_given_as_text_is_refused_not_read_as_true(lstm_run):
    """`agent.evaluate(deterministic="no")` evaluated the mode, as "no" is a true value, and
    `record_activity(agent, images="no")` was refused as images=True on a task without cameras."""
    agent = aj.load_agent(lstm_run)
    with pytest.raises(TypeError, match=r"^deterministic must be True or False, got 'no' \(str\)"):
        agent.evaluate(2, deterministic="no")
    with pytest.raises(TypeError, match=r"^images must be True or False, got 'no' \(str\)"):
        record_activity(agent, episodes=2, steps=2, images="no")
    with pytest.raises(TypeError, match=r"^stochastic must be True or False, got 0 \(int\)\.$"):
        aj.render_frames(lstm_run, stochastic=0)


def test_a_notebook_shows_an_agent_and_a_run_in_a_line_and_exports_from_python(lstm_run, tmp_path):
    """`agent` or `run` ending a cell printed 20 KB and 69 KB of arrays; export was only a command."""
    agent = aj.load_agent(lstm_run)
    assert repr(agent) == "Agent(task='CartPole', network='lstm', head=Categorical, cycle=2)"
    run = aj.resume(lstm_run)  # complete: trains nothing, returns the run
    assert repr(run) == (f"TrainingRun(run_dir={str(lstm_run)!r}, cycle=2, cycles_this_call=0, finished=True, "
                         "stopped_at=None)")
    out = aj.export_policy(lstm_run, tmp_path / "p.msgpack", checkpoint="latest")
    assert aj.load_policy(out).agent.cycle == 2
