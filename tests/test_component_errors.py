"""What a run loads when it starts (`ppo.init_from`, `ppo.network.pretrained`) and what it freezes
(`ppo.network.frozen`), named wrongly: `angora-jax train` exits 2 with the key, the offending module, file or run,
and the fix, before it compiles anything or makes a run directory; never a traceback."""

import dataclasses
import shutil
from pathlib import Path

import numpy as np
import pytest
from flax import serialization
from tiny import TINY_PPO

import angora_jax as aj
from angora_jax.cli import main
from angora_jax.experiment import validate
from angora_jax.experiment.export import export_policy
from angora_jax.experiment.sources import check_sources
from angora_jax.nets.components import save_component

# Every run here is one cycle of a tiny task, module fixtures included (tests/quick_compile.py).
pytestmark = pytest.mark.usefixtures("quick_file_compiles")

TINY = [*TINY_PPO, "ppo.num_cycles=1", "logging.report=false", "logging.progress=none"]


@pytest.fixture(scope="module")
def source_run(tmp_path_factory) -> Path:
    """A CartPole run of the default width (64) with one checkpoint: what other runs start from or take parts of."""
    root = tmp_path_factory.mktemp("source")
    return aj.train("cartpole", [*TINY, f"logging.run_root={root}", "logging.run_name=source"]).run_dir


@pytest.fixture(scope="module")
def mountain_car_run(tmp_path_factory, source_run) -> Path:
    """A MountainCar run with discrete actions (the task's default), trained after `source_run` has compiled what the
    two share."""
    root = tmp_path_factory.mktemp("mountain_car")
    return aj.train("classic", [*TINY, "env.task=MountainCar", f"logging.run_root={root}",
                                "logging.run_name=discrete"]).run_dir


def refused(capsys, tmp_path: Path, *overrides: str, config: str = "cartpole") -> str:
    """stderr of `angora-jax train CONFIG` with `overrides`, which must exit 2 without a traceback and leave no run
    directory."""
    runs = tmp_path / "runs"
    code = main(["train", config, *TINY, f"logging.run_root={runs}", "logging.run_name=new", *overrides])
    err = capsys.readouterr().err
    assert code == 2, err
    assert "Traceback" not in err
    assert not (runs / "new").exists(), "nothing is left behind"
    return err


@pytest.mark.parametrize("key", ["frozen", "pretrained"])
def test_a_module_path_that_names_no_module_is_refused_with_the_modules_there_are(key, capsys, tmp_path):
    value = "[network.policy_trunc]" if key == "frozen" else f"{{network.policy_trunc: {tmp_path / 'x.msgpack'}}}"
    err = refused(capsys, tmp_path, f"ppo.network.{key}={value}")
    assert f"ppo.network.{key}" in err and "'network.policy_trunc'" in err
    assert "did you mean 'network.policy_trunk'" in err and "network.value_trunk" in err, "the modules there are"


def test_a_parameter_is_not_a_module(capsys, tmp_path):
    err = refused(capsys, tmp_path, "ppo.network.frozen=[network.value.kernel]")
    assert "ppo.network.frozen" in err and "'network.value.kernel' is a parameter" in err and "'network.value'" in err


@pytest.mark.parametrize("damage", ["truncated", "text", "empty", "list"])
def test_a_damaged_component_file_is_refused_naming_the_file_and_how_to_write_one(damage, source_run, capsys,
                                                                                 tmp_path):
    saved = save_component(aj.load_agent(source_run).params, "network", tmp_path / "whole.msgpack").read_bytes()
    file = tmp_path / "component.msgpack"
    contents = {"truncated": saved[: len(saved) // 2], "text": b"network: not msgpack", "empty": b"",
                "list": serialization.msgpack_serialize([1, 2])}
    file.write_bytes(contents[damage])
    err = refused(capsys, tmp_path, f"ppo.network.pretrained={{network: {file}}}")
    assert "ppo.network.pretrained" in err and str(file) in err and "not a component file" in err
    assert "save_component" in err and "pretrain-vision" in err, "how to write one"


def test_a_component_file_is_written_whole_or_not_at_all(source_run, tmp_path, monkeypatch):
    """A full disk halfway through `save_component` left half a file, which blocked the next save to that name and
    read as damaged; now nothing is left, and the next save goes through."""
    params, file = aj.load_agent(source_run).params, tmp_path / "part.msgpack"
    write_bytes = Path.write_bytes

    def disk_fills(path, data):
        write_bytes(path, data[: len(data) // 2])
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(Path, "write_bytes", disk_fills)
    with pytest.raises(OSError, match="No space left"):
        save_component(params, "network", file)
    assert list(tmp_path.iterdir()) == []
    monkeypatch.setattr(Path, "write_bytes", write_bytes)
    assert save_component(params, "network", file) == file and file.stat().st_size > 0


def test_a_component_of_another_size_is_refused_naming_the_shapes(source_run, capsys, tmp_path):
    file = save_component(aj.load_agent(source_run).params, "network", tmp_path / "wide.msgpack")
    err = refused(capsys, tmp_path, f"ppo.network.pretrained={{network: {file}}}", "ppo.network.width=8")
    assert "ppo.network.pretrained" in err and str(file) in err and "do not fit" in err
    assert "['policy_trunk']['Dense_0']['kernel']: (4, 8) here, (4, 64) in the source" in err


def test_a_run_of_another_width_is_refused_naming_the_setting_that_differs(source_run, capsys, tmp_path):
    err = refused(capsys, tmp_path, f"ppo.init_from={source_run}", "ppo.network.width=8")
    assert "ppo.init_from" in err and str(source_run) in err and "do not fit" in err
    assert "(4, 8) here, (4, 64) in the source" in err
    assert "ppo.network.width=64" in err, "the saved run's setting that makes the difference"


def test_a_run_of_other_task_options_is_refused_naming_only_the_options_that_change_its_shapes(mountain_car_run,
                                                                                                capsys, tmp_path):
    """Of the task options set otherwise, only those that change the observations or actions are named, and one the
    saved run left to its default says so: a randomized cube run started from an unrandomized one listed every
    randomization key, each as None in the saved run, and the episode length beside the option that made the misfit."""
    err = refused(capsys, tmp_path, "env.task=MountainCar", "env.options={continuous: true, max_episode_steps: 50}",
                  f"ppo.init_from={mountain_car_run}", config="classic")
    assert "do not fit" in err and "(64, 1) here" in err, err
    assert "The saved run has env.options.continuous not set (this run: env.options.continuous=True)." in err, err
    assert "max_episode_steps" not in err, "an episode length changes no shape"


def test_a_run_of_another_task_is_refused_naming_the_task_not_a_width(source_run, capsys, tmp_path):
    """A cube run given to init_from in a reach run: the message suggested the saved run's width, which cannot make
    165 observations fit 68, and never said the saved run was of another task."""
    code = main(["train", "pendulum", *TINY, f"logging.run_root={tmp_path}", f"ppo.init_from={source_run}"])
    err = capsys.readouterr().err
    assert code == 2 and "The saved run was trained on CartPole and this run is Pendulum" in err, err
    assert "start from a run of Pendulum" in err and "ppo.network.width" not in err


@pytest.mark.parametrize("key", ["ppo.init_from", "ppo.network.pretrained"])
@pytest.mark.parametrize("problem", ["no checkpoint", "damaged checkpoint", "no config", "missing"])
def test_a_source_run_that_cannot_be_read_is_refused_naming_the_key_and_the_cause(problem, key, source_run, capsys,
                                                                                  tmp_path):
    run = tmp_path / "source"
    if problem != "missing":
        shutil.copytree(source_run, run)
    if problem == "no checkpoint":
        shutil.rmtree(run / "checkpoints")
    elif problem == "damaged checkpoint":
        for file in (run / "checkpoints").rglob("*"):
            if file.is_file() and file.parent.name == "d":  # the arrays' data files of Orbax's OCDBT store
                file.write_bytes(file.read_bytes()[:20])
    elif problem == "no config":
        (run / "config.yaml").unlink()
    value = str(run) if key == "ppo.init_from" else f"{{network: {run}}}"
    err = refused(capsys, tmp_path, f"{key}={value}")
    assert f"{key}" in err and str(run) in err
    cause = {"no checkpoint": "No checkpoints", "damaged checkpoint": "checkpoint", "no config": "no config.yaml",
             "missing": "is neither a file nor a run directory: it does not exist"}[problem]
    assert cause in err


def test_a_file_given_to_init_from_is_named_as_a_file_with_what_it_is(source_run, capsys, tmp_path):
    """An exported policy given to ppo.init_from was said not to exist ("neither a file nor a run directory")."""
    file = export_policy(source_run, tmp_path / "policy.msgpack")
    err = refused(capsys, tmp_path, f"ppo.init_from={file}")
    assert f"'{file}' is a file, not a run directory: name the run it came from, as RUN_DIR" in err
    assert "an exported policy (`angora-jax export`)" in err and "does not exist" not in err


def test_sources_that_fit_pass_the_check(source_run, tmp_path):
    """The check refuses nothing that loads: a run from the saved run, with a component of it loaded and frozen."""
    file = save_component(aj.load_agent(source_run).params, "network.value", tmp_path / "value.msgpack")
    config = aj.load_config("cartpole", [*TINY, f"ppo.init_from={source_run}", "ppo.network.frozen=[network.value]",
                                         f"ppo.network.pretrained={{network.value: {file}}}"])
    check_sources(config, validate(config))


def test_a_pose_estimator_and_a_component_given_for_each_other_are_named_as_what_they_are(source_run, tmp_path):
    """`pose_estimator=encoder.msgpack` (pretrain-vision's first file) ended in KeyError 'encoder_options'; a file that
    is no msgpack in "unpack(b) received extra data"; a pose estimator given as a component in a list of sizes."""
    from angora_jax.nets.components import read_component_file
    from angora_jax.vision.estimator import PoseEstimator

    component = save_component(aj.load_agent(source_run).params, "network", tmp_path / "encoder.msgpack")
    with pytest.raises(ValueError, match=r"encoder.msgpack is a network component .* not a pose estimator: give the "
                                         r"OUT.pose.msgpack"):
        PoseEstimator.load(component)
    with pytest.raises(FileNotFoundError, match=r"No pose estimator at gone.pose.msgpack \(a relative path, read from "
                                                r"the current directory .*give the file's full path"):
        PoseEstimator.load("gone.pose.msgpack")
    (tmp_path / "config.yaml").write_text("env: {task: CartPole}\n")
    with pytest.raises(ValueError, match=r"config.yaml is no file of angora_jax \(not msgpack"):
        PoseEstimator.load(tmp_path / "config.yaml")
    pose = tmp_path / "encoder.pose.msgpack"
    pose.write_bytes(serialization.msgpack_serialize({"params": {"IT": {"bias": np.zeros(2)}}, "encoder_options": {}}))
    with pytest.raises(ValueError, match=r"is a pose estimator .*, not a component file: give it as "
                                         r"env.options.pose_estimator=FILE"):
        read_component_file(pose)


def test_an_init_from_whose_value_function_alone_misfits_points_to_taking_the_policy_alone():
    """A source trained without `value_sees_physics` (or another value-only input) differs in its value function's
    inputs only: the refusal says so and names the way docs/tasks.md gives (`ppo.network.pretrained`, the policy's
    modules), not only "give the saved run's network settings"."""
    from angora_jax.ppo.cycle import SavedRunMisfit, _fitting
    ours = {"network": {"policy_trunk": {"kernel": np.zeros((5, 4))}, "value_trunk": {"kernel": np.zeros((9, 4))}},
            "policy_head": {"kernel": np.zeros((4, 2))}}
    theirs = {**ours, "network": {**ours["network"], "value_trunk": {"kernel": np.zeros((7, 4))}}}
    with pytest.raises(SavedRunMisfit, match=r"Only the value function's.*ppo\.network\.pretrained"):
        _fitting(ours, theirs, "network parameters", "runs/src")
    policy_too = {**theirs, "policy_head": {"kernel": np.zeros((4, 3))}}
    with pytest.raises(SavedRunMisfit) as refused:
        _fitting(ours, policy_too, "network parameters", "runs/src")
    assert "Only the value function's" not in str(refused.value)


def test_a_memory_added_to_a_saved_mlp_starts_as_that_mlp_and_training_puts_it_to_use(source_run):
    """`ppo.network.memory` with `ppo.init_from` a run of the same MLP without memory: the saved parameters carry
    over, the GRU is initialized and its output layer is zero, so the policy and value start as the saved run's
    whatever the GRU's state; a cycle of training moves the output layer off zero. Recurrent networks refuse it."""
    import jax

    from angora_jax.nets import make_network
    from angora_jax.ppo import NetworkConfig, PPOConfig, make_cycle
    from angora_jax.ppo.cycle import build_head, build_model

    config = aj.load_config("cartpole", [*TINY, "ppo.network.memory=8", f"ppo.init_from={source_run}"])
    env = aj.make(config.env.task, **config.env.options)
    init, cycle = make_cycle(env, None, config.ppo)
    state = init(jax.random.key(0))
    saved = aj.load_agent(source_run).state
    assert set(state.params["network"]) == {*saved.params["network"], "policy_memory", "memory_out"}
    np.testing.assert_array_equal(state.params["network"]["memory_out"]["kernel"], 0.0)

    obs = jax.vmap(env.reset)(jax.random.split(jax.random.key(1), 5)).obs
    obs = obs.replace(proprioception=jax.random.normal(jax.random.key(2), obs.proprioception.shape))
    plain = config.ppo.replace(network=dataclasses.replace(config.ppo.network, memory=0))
    with_memory = build_model(make_network(config.ppo.network), build_head(env, config.ppo), config.ppo)
    without = build_model(make_network(plain.network), build_head(env, plain), plain)
    remembered = jax.random.normal(jax.random.key(3), (5, 8))  # whatever the GRU holds
    _, policy_now, value_now = with_memory.apply({"params": state.params}, remembered, obs)
    _, policy, value = without.apply({"params": saved.params}, without.initial_carry(5), obs)
    np.testing.assert_allclose(policy_now, policy, rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(value_now, value, rtol=1e-6, atol=1e-6)

    trained, _ = cycle(state)
    assert np.abs(np.asarray(trained.params["network"]["memory_out"]["kernel"])).max() > 0
    with pytest.raises(ValueError, match="network.memory adds a GRU to the simple and deeper networks"):
        PPOConfig(network=NetworkConfig(name="lstm", memory=8)).validate()
