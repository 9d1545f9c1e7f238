"""Experiment configs: YAML plus overrides load into typed dataclasses; bad input fails before any compile with
a message that names the key and what is allowed."""

import dataclasses
import importlib.util
import re
import time
import tracemalloc
import typing
from pathlib import Path

import jax
import numpy as np
import pytest
import yaml

import angora_jax as aj
from angora_jax.cli import main
from angora_jax.envs.randomization import Randomization
from angora_jax.experiment.config import (
    Config,
    ConfigError,
    check_count,
    check_number,
    checked,
    flatten,
    list_configs,
    load_config,
    override_strings,
    repeated_keys,
    to_dict,
    validate,
)
from angora_jax.experiment.config_reference import config_keys, field_descriptions, reference_markdown
from angora_jax.ppo import PPOConfig
from angora_jax.ppo.config import check_bounds, field_bounds


def test_named_config_loads_with_typed_overrides():
    config = load_config(
        "cartpole",
        ["ppo.num_cycles=7", "ppo.learning_rate=3e-4", "ppo.network.name=lstm", "env.options.max_episode_steps=200"],
    )
    assert isinstance(config, Config) and isinstance(config.ppo, PPOConfig)
    assert config.ppo.num_cycles == 7 and config.ppo.network.name == "lstm"
    # YAML 1.1 reads 3e-4 as a string; a float field takes it as the number it means.
    assert config.ppo.learning_rate == pytest.approx(3e-4) and isinstance(config.ppo.learning_rate, float)
    assert config.env.options == {"max_episode_steps": 200}
    assert validate(config).max_episode_steps == 200
    # Keys the file leaves out keep their defaults; the resolved form has every key.
    assert config.ppo.clip_epsilon == PPOConfig().clip_epsilon
    flat = flatten(to_dict(config))
    assert flat["ppo.network.name"] == "lstm" and "checkpoint.every" in flat and "distribution.num_devices" in flat


def test_resolved_config_round_trips_through_a_dict():
    config = load_config("cartpole", ["ppo.network.width=32", "logging.run_name=x"])
    assert load_config(to_dict(config)) == config


# The variants of the cube and of the MyoHand's tasks trace their costly scenes once each (3-6 s); `make test-fast`
# checks the first config of each of those tasks, and every config of the others.
@pytest.mark.parametrize("name", [
    pytest.param(name, marks=pytest.mark.slow)
    if name.startswith(("shadow_ihom_", "myohand_pose_", "myohand_reorient_")) else name for name in list_configs()])
def test_shipped_configs_are_valid(name):
    validate(load_config(name))


BAD = {
    "unknown key": (["ppo.gama=0.9"], r"Unknown key 'ppo.gama'.*Did you mean 'ppo.gamma'"),
    "key at the wrong level": (["seed=1"], r"Unknown key 'seed'. Did you mean 'ppo.seed' or 'evaluation.seed'\?"),
    "unknown section": (["model.name=lstm"], r"Unknown key 'model'.*Keys of the config: env, ppo"),
    "int expected": (["ppo.num_cycles=1.5"], r"ppo.num_cycles must be an integer, got 1.5"),
    "bool expected": (["ppo.normalization.rewards=maybe"], r"ppo.normalization.rewards must be true or false"),
    "section expected": (["ppo.network=lstm"], r"ppo.network must be a mapping"),
    "minibatch does not divide batch": (["ppo.minibatch_size=500"], r"minibatch_size \(500\).*divide"),
    "beta head on a discrete task": (["ppo.head=beta"], r"head='beta' needs continuous actions.*'categorical'"),
    "frozen not a list": (["ppo.network.frozen=network.M1"], r"ppo.network.frozen must be a list"),
    "unknown cortical area": (["ppo.network.name=cortical", "ppo.network.areas={V9: 3}"],
                              r"Unknown areas \['V9'\] in network.areas.*SSC_1"),
    "misspelt cortical area": (["ppo.network.name=cortical", "ppo.network.areas.SCC_1=3"],
                               r"Unknown areas \['SCC_1'\] in network.areas. Did you mean 'SSC_1'\? The cortical "
                               r"model's areas: \['SSC_1', 'SSC_2'"),
    "unknown network": (["ppo.network.name=lsmt"], r"ppo.network.name.*'lstm'.*Allowed networks: .*simple"),
    "unknown task": (["env.task=Cartpole"], r"env.task.*Did you mean 'CartPole'.*Pendulum"),
    "unknown env option": (["env.options.gravity_scale=2"], r"env.options do not fit task 'CartPole'.*gravity_scale"),
    "best metric the task lacks": (
        ["checkpoint.best_metric=metric/success"],
        r"checkpoint.best_metric.*episode_return",
    ),
    "more devices than present": (["distribution.num_devices=64"], r"distribution.num_devices=64 but JAX sees only"),
    "device count not positive": (["distribution.num_devices=0"], r"distribution.num_devices must be >= 1, got 0"),
    "device count a word": (["distribution.num_devices=some"], r"distribution.num_devices must be a positive"),
    "device count a yes/no word": (["distribution.num_devices=no"],
                                   r"^distribution.num_devices must be an integer or a string, got False \(bool\)\. "
                                   r"YAML reads yes, no, on, off, true and false as true or false: quote the value to "
                                   r"give it as text\.$"),
    "run name a yes/no word": (["logging.run_name=on"], r"^logging.run_name must be a string or null, got True "
                                                        r"\(bool\)\. YAML reads yes, no"),
    "not a finite number": (["ppo.learning_rate=nan"], r"ppo.learning_rate must be a finite number, got 'nan'"),
    "infinite": (["ppo.gamma=.inf"], r"ppo.gamma must be a finite number"),
    "too many environments": (
        ["ppo.num_envs=10000000000"],
        r"ppo.num_envs=10,000,000,000 .*cannot fit: it needs at least .* GiB per device .* Use ppo.num_envs <= ",
    ),
    "progress mode": (["logging.progress=fancy"], r"logging.progress.*auto, bar, lines, none"),
    "run name leaves run_root": (["logging.run_name=../escape"], r"run_name='../escape' must be a plain folder"),
    "run name with a folder": (["logging.run_name=a/b"], r"logging.run_name='a/b' must be a plain folder name"),
    "run name too long": (["logging.run_name=" + "a" * 300], r"logging.run_name='aaa.*' must be a plain folder name: "
                                                             r"at most 100 characters \(it has 300\) of letters"),
    "run name with a space": (["logging.run_name='my run'"], r"logging.run_name='my run' must be a plain folder name: "
                                                            r".*letters, digits, '.', '_', '-', '\+' and '='"),
    "run name like an option": (["logging.run_name=-x"], r"logging.run_name='-x' must be a plain folder name.*not "
                                                         r"starting with '.' or '-'"),
    "hidden run name": (["logging.run_name=.x"], r"logging.run_name='.x' must be a plain folder name"),
    "run name with NUL": (['logging.run_name="a\\0b"'], r"logging.run_name='a\\x00b' holds a NUL character"),
    "run root with NUL": (['logging.run_root="runs\\0"'], r"logging.run_root='runs\\x00' holds a NUL character"),
    "run root folder name too long": (["logging.run_root=runs/" + "b" * 256 + "/x"],
                                      r"logging.run_root='runs/bbb.*' has a folder name of 256 bytes \('bbb.*'\); "
                                      r"file systems allow 255"),
    "run root too long": (["logging.run_root=" + "/abc" * 1100], r"logging.run_root=.* is 4,400 bytes long; file "
                                                                 r"systems allow paths of 4,095"),
    "override value not YAML": (["ppo.num_envs=[1"], r"^Override 'ppo.num_envs=\[1': its value is not valid YAML "
                                                     r"\(expected ',' or '\]', but got '<stream end>' at character "
                                                     r"3\); add the missing '\]' \('ppo.num_envs=\[1\]'\) or quote "
                                                     r"the value to give it as text \('ppo.num_envs=\"\[1\"'\)\.$"),
    "override value no token": (["env.task=@x"], r"^Override 'env.task=@x': its value is not valid YAML \(found "
                                                 r"character '@' that cannot start any token at character 1\); quote "
                                                 r"the value to give it as text \('env.task=\"@x\"'\)\.$"),
    "override without =": (["ppo.num_cycles"], r"must look like key.sub=value, e.g. ppo.num_cycles=VALUE"),
    "override with a colon": (["ppo.learning_rate:3e-4"],
                              r"must look like key.sub=value, e.g. ppo.learning_rate=3e-4\.$"),
    "override with YAML's colon": (["ppo.learning_rate: 3e-4"],
                                   r"must look like key.sub=value, e.g. ppo.learning_rate=3e-4\.$"),
    "stop at a metric the task lacks": (["ppo.stop_at={metric: metric/goals_reached, value: 30}"],
                                        r"ppo.stop_at.metric.*episode_return"),
    "stop at an unknown mode": (["ppo.stop_at={value: 30, mode: above}"], r"ppo.stop_at.mode must be 'max' or 'min'"),
    "stop at no value": (["ppo.stop_at={metric: episode_return}"],
                         r"ppo.stop_at needs value \(the metric's value that ends the run\)"),
    "negative evaluation interval": (["evaluation.every=-1"], r"evaluation.every must be >= 0"),
    "huge integer for a number": (["ppo.gamma=1" + "0" * 400], r"ppo.gamma must be a finite number, got a 401-digit"),
    "integer too long to read": (["ppo.seed=1" + "0" * 5000], r"Override 'ppo.seed=10.*the integer on line 1 has 5,001 "
                                                              r"digits"),
    "not an integer, tagged as one": (["ppo.num_envs=!!int x"], r"'x' on line 1 is tagged !!int but is no integer"),
    "negative seed": (["ppo.seed=-1"], r"ppo.seed must be >= 0, got -1 \(allowed: integers from 0 to 4,294,967,295"),
    "seed beyond 32 bits": (["ppo.seed=100000000000000000000000"],
                            r"ppo.seed must be <= 4,294,967,295, got 100000000000000000000000 .*low 32 bits"),
    "evaluation seed beyond 32 bits": (["evaluation.seed=4294967296"], r"evaluation.seed must be <= 4,294,967,295"),
    "count beyond int32": (["ppo.num_cycles=2147483648"], r"ppo.num_cycles must be <= 2,147,483,647, got 2147483648"),
    "negative width": (["ppo.network.width=-3"], r"ppo.network.width must be >= 1, got -3"),
    "negative area size": (["ppo.network.name=cortical", "ppo.network.areas={PMC: -2}"],
                           r"ppo.network.areas must be >= 1, got -2"),
    "number beyond float32": (["ppo.learning_rate=1.0e39"], r"ppo.learning_rate must be <= 3.4028.*e\+38, got 1e\+39"),
    "huge initial log std": (["ppo.init_log_std=1000.0"], r"ppo.init_log_std must be <= 20, got 1000.0"),
    "zero clip": (["ppo.normalization.clip=0"], r"ppo.normalization.clip must be > 0, got 0"),
    "stop value beyond a float": (["ppo.stop_at={value: 1.0e400}"], r"ppo.stop_at.value must be a finite number"),
    "NUL in a path": (['ppo.init_from="run\\0x"'], r"ppo.init_from='run\\x00x' holds a NUL character"),
    "lone surrogate in a path": (['ppo.init_from="run\\ud800"'], r"ppo.init_from='run\\ud800' is not valid Unicode"),
    "non-string key in a section": (["ppo={1: x}"], r"Key 1 \(int\) of ppo is not a name"),
    "null key in a section": (["ppo={null: y}"], r"Key None \(NoneType\) of ppo is not a name"),
    "negative episode limit": (["env.options.max_episode_steps=-3"],
                               r"env.options do not fit task 'CartPole': max_episode_steps must be a whole number from "
                               r"1 to 2,147,483,647 \(policy steps per episode\), got -3"),
    "fractional episode limit": (["env.options.max_episode_steps=1.5"], r"max_episode_steps must be a whole number"),
    "infinite episode limit": (["env.options.max_episode_steps=.inf"],
                               r"env.options.max_episode_steps must be a finite number, got inf"),
    "option beyond int32": (["env.options.max_episode_steps=2147483648"],
                            r"max_episode_steps must be a whole number from 1 to 2,147,483,647"),
    "a misspelled task option": (["env.options.max_episode_step=10"],
                                 r"no option 'max_episode_step' \(did you mean 'max_episode_steps'\?\); its "
                                 r"options: max_episode_steps\."),
    "a minibatch larger than the batch, with a size that fits": (
        ["ppo.num_envs=2", "ppo.rollout_length=32", "ppo.minibatch_size=512"],
        r"minibatch_size \(512\) must .* divide num_envs \* rollout_length \(64\), e.g. ppo.minibatch_size=64 \(1 "),
    "best by an evaluation that never runs": (
        ["checkpoint.best_metric=eval/episode_return"],
        r"checkpoint.best_metric='eval/episode_return' names a held-out .* set evaluation.every=N",
    ),
}


@pytest.mark.parametrize("case", BAD)
def test_bad_config_fails_naming_the_key(case):
    overrides, message = BAD[case]
    with pytest.raises(ConfigError, match=message):
        validate(load_config("cartpole", overrides))


@pytest.mark.parametrize("overrides, named", [
    (["ppo.network.width=100000000"], "ppo.network.width=100,000,000 makes a network of 20,000,001,500,000,003 "),
    (["ppo.network.name=gru", "ppo.network.cell_size=3000000"], "ppo.network.cell_size=3,000,000 make a network"),
    (["ppo.network.memory=3000000"], "ppo.network.memory=3,000,000 make a network")])
def test_a_network_too_large_for_the_device_is_refused_before_anything_is_allocated(overrides, named, tmp_path, capsys):
    """A mistyped width (100000000 for 1000) passed every check, then stalled while its parameters were allocated.
    Counted from shapes: CartPole's 4 inputs, two dense layers of 10^8 and the heads give 2.0000001500000003e16
    parameters; with their gradients and Adam's two moments 4 x 4 bytes each. 4,096 units or fewer are not traced."""
    from angora_jax.cli import main
    from angora_jax.envs.registry import make
    from angora_jax.ppo.memory import CHECKED_ABOVE_UNITS, network_too_large

    with pytest.raises(ConfigError, match=named + r".* GiB, against .* GiB on cpu device 0 .*Use fewer units"):
        validate(load_config("cartpole", overrides))
    assert main(["train", "cartpole", *overrides, f"logging.run_root={tmp_path}"]) == 2
    assert "make" in capsys.readouterr().err and not list(tmp_path.iterdir()), "refused before a run was made"
    width = load_config("cartpole", [f"ppo.network.width={CHECKED_ABOVE_UNITS}"]).ppo
    assert network_too_large(width, make("CartPole")) is None


@pytest.mark.parametrize("rollout_length", [16, 32])
def test_the_memory_bound_counts_every_stored_transition_of_a_cycle(rollout_length):
    """CartPole stores per transition 4 observation floats, one action slot and 9 scalars (log-probability, value,
    reward, done, truncated, final value, reset, episode return and length): 56 bytes, `rollout_length` of them per
    environment per cycle, besides one environment state each; 8 environments on 2 devices hold 4 each."""
    from angora_jax.envs.registry import make
    from angora_jax.ppo.memory import estimate_memory

    config = PPOConfig(num_envs=8, rollout_length=rollout_length, chunk_length=8, minibatch_size=32)
    memory = estimate_memory(config, make("CartPole"), num_devices=2)
    assert (memory.transition, memory.num_envs) == ((4 + 1 + 9) * 4, 4)
    assert memory.total - 4 * memory.env_state == 4 * rollout_length * 56
    if memory.available is not None:
        assert memory.max_envs == memory.available // (memory.env_state + rollout_length * 56)


def test_the_memory_bound_and_the_observation_shapes_share_one_trace_of_reset():
    """Tracing a MuJoCo task's reset takes seconds (the cube's: 3-4 s on a CPU core), and `validate`'s memory bound
    and a run's set-up (the normalizer's shapes) each need its shapes: one trace per environment object serves both."""
    from angora_jax.envs.classic.cartpole import CartPole
    from angora_jax.ppo.memory import estimate_memory

    traced = []

    class Counted(CartPole):
        def _reset(self, key):
            traced.append(key)
            return super()._reset(key)

    env = Counted()
    memory = estimate_memory(PPOConfig(num_envs=8, rollout_length=16, chunk_length=8, minibatch_size=32), env)
    assert env.observation_shapes() == jax.eval_shape(CartPole().reset, jax.random.key(0)).obs
    assert env.state_shapes().obs == env.observation_shapes() and len(traced) == 1, "traced again"
    assert memory.env_state == sum(leaf.size * leaf.dtype.itemsize for leaf in jax.tree.leaves(env.state_shapes()))
    Counted().observation_shapes()
    assert len(traced) == 2, "another environment object has its own shapes"


@pytest.mark.slow  # three Warp builds of the hand: 11 s of the fast tier
@pytest.mark.skipif(importlib.util.find_spec("warp") is None, reason="MuJoCo Warp needs warp-lang")
def test_on_warp_the_memory_bound_sizes_an_environment_only_for_camera_vision():
    """On MuJoCo Warp the bound leaves the physics state out, so a task without camera vision is traced as it is;
    sizing it for one would build it again (`validate` of the die's MyoHand on a CPU: 12.4 s so, 5.3 s not). Warp
    renders camera vision only in an environment sized for its batch: a seeing task is traced as a batch of one."""
    from angora_jax.envs.registry import make
    from angora_jax.ppo.memory import estimate_memory

    config = PPOConfig(num_envs=8, rollout_length=16, chunk_length=8, minibatch_size=32)
    blind = make("ShadowHandReach", physics={"impl": "warp"})
    memory = estimate_memory(config, blind)
    assert not blind._sized, "sized for the estimate"
    sized = jax.eval_shape(blind.sized_for(1).reset, jax.random.key(0)).replace(physics=())
    assert memory.env_state == sum(leaf.size * leaf.dtype.itemsize for leaf in jax.tree.leaves(sized))
    seeing = make("ShadowHandReach", vision={"cameras": ["front"], "width": 8, "height": 8}, physics={"impl": "warp"})
    estimate_memory(config, seeing)
    assert list(seeing._sized) == [1], "a seeing task traced unsized, where Warp cannot render"


# A small valid graph on CartPole (proprioception only; goal is empty there), which each bad case below changes; the
# cartpole config's width does not apply to it.
GRAPH = ["ppo.network.name=areas", "ppo.network.width=null",
         "ppo.network.graph={areas: {S1: {size: 4, inputs: [proprioception]}, M1: {size: 4, inputs: [S1, goal]}}, "
         "policy: M1}"]
AREA = "ppo.network.graph.areas"
BAD_GRAPHS = {
    "cycle without recurrence": ([f"{AREA}.S1.inputs=[proprioception, M1]"],
                                 r"network.graph.areas: (S1 -> M1 -> S1|M1 -> S1 -> M1) form a loop of dense areas.*"
                                 r"make one of them recurrent \(cell: rnn, lstm or gru\)"),
    "self-loop without recurrence": ([f"{AREA}.M1.inputs=[S1, M1]"], r"M1 -> M1 form a loop of dense areas"),
    "edge from an area that does not exist": ([f"{AREA}.M1.inputs=[S1, SS1]"],
                                              r"network.graph.areas.M1.inputs names 'SS1', which is neither an area "
                                              r"nor an input \(did you mean 'S1'\?\).*areas are S1, M1"),
    "policy from an area that does not exist": (["ppo.network.graph.policy=M_1"],
                                                r"network.graph.policy='M_1' is not an area \(did you mean 'M1'"),
    "value reads nothing": (["ppo.network.graph.value.inputs=[]"], r"network.graph.value.inputs is empty"),
    "value from an area that does not exist": (["ppo.network.graph.value.inputs=[S1, V1]"],
                                               r"network.graph.value.inputs names 'V1'"),
    "input that reaches nothing": ([f"{AREA}.T1={{size: 4, inputs: [touch]}}"],
                                   r"network.graph.areas.T1 reaches neither head.*its inputs \(touch\) reach nothing"),
    "recurrent area that reaches nothing": ([f"{AREA}.R1={{size: 4, inputs: [goal, R1], cell: gru}}"],
                                            r"network.graph.areas.R1 reaches neither head"),
    "policy that no input reaches": ([f"{AREA}={{R1: {{size: 4, inputs: [M1], cell: rnn}}, M1: {{size: 4, "
                                      "inputs: [R1]}}"], r"policy='M1': no input modality reaches it"),
    "policy that reads only what the task does not give": (  # trained silently on inputs of width 0
        [f"{AREA}.S1.inputs=[touch]"], r"policy='M1' reads only goal, touch, which CartPole gives nothing of with "
                                       r"these options .*list one it gives \(proprioception\)"),
    "area that reads asymmetric": ([f"{AREA}.S1.inputs=[proprioception, asymmetric]"],
                                   r"network.graph.areas.S1 reads 'asymmetric', which only the value function"),
    "unknown activation": ([f"{AREA}.S1.activation=sigmoid"],
                           r"network.graph.areas.S1.activation='sigmoid' is unknown; use one of tanh, relu, lif"),
    "unknown cell": ([f"{AREA}.S1.cell=lsmt"], r"network.graph.areas.S1.cell='lsmt' is unknown \(did you mean 'lstm'"),
    "size not positive": ([f"{AREA}.S1.size=0"],
                          r"network.graph.areas.S1.size must be >= 1, got 0 \(allowed: integers from 1 to "
                          r"2,147,483,647: the area's units\)"),
    "size missing": ([f"{AREA}.S1={{inputs: [proprioception]}}"], r"ppo.network.graph.areas.S1 needs size"),
    # A misspelt area in an override made a new area, refused for what it lacked ("needs inputs", "reaches neither
    # head") without a word about the area the user meant.
    "override of a misspelt area": ([f"{AREA}.S_1.size=8"],
                                    r"ppo.network.graph.areas.S_1 needs inputs .*Did you mean "
                                    r"ppo.network.graph.areas.S1\? 'S_1' is not one of .*entries \(S1, M1\)"),
    "misspelt area made whole that reaches nothing": (
        [f"{AREA}.S_1={{size: 4, inputs: [proprioception]}}"],
        r"areas.S_1 reaches neither head.*If you meant the area 'S1', an override of a name that is not an area's "
        r"makes a new area: the areas are S1, M1"),
    "size missing from a new area named unlike any": ([f"{AREA}.Q={{inputs: [S1]}}"], r"areas.Q needs size[^?]*$"),
    "no inputs": ([f"{AREA}.S1.inputs=[]"], r"network.graph.areas.S1.inputs is empty"),
    "input listed twice": ([f"{AREA}.M1.inputs=[S1, goal, S1]"], r"network.graph.areas.M1.inputs lists S1 more than"),
    "area named like a modality": ([f"{AREA}.goal={{size: 4, inputs: [S1]}}"], r"'goal' names an input modality"),
    "area name with a dot": ([f"{AREA}={{PMC.in: {{size: 4, inputs: [proprioception]}}}}",
                              "ppo.network.graph.policy=x"], r"'PMC.in' cannot name an area; use letters, digits"),
    "no graph": (["ppo.network.graph=null"], r"network.name=areas needs network.graph"),
    "graph of another network": (["ppo.network.name=simple"], r"network.graph is the areas network's, not 'simple'"),
    "sizes the graph gives": (["ppo.network.width=32"], r"The areas network takes no network.width \(set it to null"),
}


@pytest.mark.parametrize("case", BAD_GRAPHS)
def test_a_bad_brain_area_graph_is_refused_naming_the_area(case):
    overrides, message = BAD_GRAPHS[case]
    with pytest.raises(ConfigError, match=message):
        validate(load_config("cartpole", [*GRAPH, *overrides]))


def test_the_small_graph_of_the_bad_cases_is_valid_and_loops_through_recurrence():
    validate(load_config("cartpole", GRAPH))
    validate(load_config("cartpole", [*GRAPH, f"{AREA}.S1.inputs=[proprioception, M1]", f"{AREA}.M1.cell=gru"]))


def test_one_override_given_as_a_string_is_one_override():
    """aj.train("cartpole", "ppo.num_cycles=1") read the string letter by letter: "Override 'p' must look like ..."."""
    assert load_config("cartpole", "ppo.num_cycles=1").ppo.num_cycles == 1
    with pytest.raises(ConfigError, match=r"Override 'ppo.num_cycles 1' must look like key.sub=value, e.g. "
                                          r"ppo.num_cycles=1\.$"):
        load_config("cartpole", ["ppo.num_cycles 1"])  # it suggested "ppo.num_cycles 1=VALUE"


@pytest.mark.parametrize("ppo, message", [
    ({"num_envs": "8"}, r"ppo.num_envs must be an integer, got '8' \(str\)"),  # was: "not all arguments converted"
    ({"num_cycles": 2.0}, r"ppo.num_cycles must be an integer, got 2.0 \(float\)"),  # was: TypeError in training
    ({"num_envs": -8}, r"ppo.num_envs must be >= 1, got -8"),
])
def test_a_config_changed_in_python_is_checked_as_a_file_s_before_a_run_directory_is_made(tmp_path: Path, ppo,
                                                                                           message):
    """A Config changed with dataclasses.replace skipped load_config's type checks: validate passed num_cycles=2.0
    and train failed inside the training loop ('float' object cannot be interpreted as an integer), num_envs="8"
    failed as "not all arguments converted during string formatting", and a Path run_root or a numpy seed, which a
    notebook easily gives, passed validate and then failed as yaml's RepresenterError writing config.yaml."""
    config = load_config("cartpole", [f"logging.run_root={tmp_path}"])
    changed = dataclasses.replace(config, ppo=dataclasses.replace(config.ppo, **ppo))
    with pytest.raises(ConfigError, match="^" + message):
        validate(changed)
    with pytest.raises(ConfigError, match="^" + message):
        aj.train(changed)
    assert list(tmp_path.iterdir()) == []
    plain = dataclasses.replace(config, logging=dataclasses.replace(config.logging, run_root=tmp_path),
                                ppo=dataclasses.replace(config.ppo, seed=np.int64(3), gamma=np.float32(0.5),
                                                        network={"name": "gru"}))
    validate(plain)
    assert checked(plain) == dataclasses.replace(config, ppo=dataclasses.replace(
        config.ppo, seed=3, gamma=0.5, network=load_config(None, ["ppo.network.name=gru"]).ppo.network))
    assert yaml.safe_load(yaml.safe_dump(to_dict(checked(plain))))["logging"]["run_root"] == str(tmp_path)


@pytest.mark.parametrize("overrides, given", [
    ({"ppo.num_envs": 8, "ppo.network.name": "gru"}, "a dict"),
    ({"ppo": {"num_envs": 8, "network": {"name": "gru"}}}, "a dict"),
    ([("ppo.num_envs", 8), "ppo.network.name=gru"], r"\('ppo.num_envs', 8\) \(tuple\)"),
])
def test_overrides_given_as_a_dict_or_pairs_are_answered_with_the_list_to_give(tmp_path: Path, overrides, given):
    """A notebook's natural `aj.train("cartpole", {"ppo.num_envs": 8})` read the dict's keys as overrides ("Override
    'ppo.num_envs' must look like key.sub=value, e.g. ppo.num_envs=VALUE", the 8 dropped unsaid), and pairs failed
    with AttributeError ('tuple' object has no attribute 'partition'); env_overrides likewise, and one string of them
    was read letter by letter ("got 'm'")."""
    wanted = r"give \['ppo.num_envs=8', 'ppo.network.name=gru'\], not " + given
    with pytest.raises(ConfigError, match=r"^overrides are KEY=VALUE strings.*" + wanted):
        load_config("cartpole", overrides)
    with pytest.raises(ConfigError, match=r"^env_overrides are KEY=VALUE strings.*" + wanted):
        aj.load_agent(tmp_path, env_overrides=overrides)
    with pytest.raises(ConfigError, match=r"^env_overrides are KEY=VALUE strings.*" + wanted):
        aj.evaluate(tmp_path, env_overrides=overrides)
    assert override_strings("max_episode_steps=20", "env_overrides") == ["max_episode_steps=20"]


def test_bad_files_fail_clearly(tmp_path: Path):
    with pytest.raises(ConfigError, match=r"not found. Did you mean 'cartpole'\? Give a YAML path or the name of a "
                                          r"shipped config: .*cartpole"):
        load_config("cartpol")
    broken = tmp_path / "broken.yaml"
    broken.write_text("ppo: {num_cycles: 3\n")
    with pytest.raises(ConfigError, match=r"broken.yaml is not valid YAML: .* \(line 2, column 1\): fix that line"):
        load_config(broken)
    tabbed = tmp_path / "tabbed.yaml"  # PyYAML's "found character '\t' that cannot start any token": name the fix
    tabbed.write_text("extends: cartpole\nppo:\n\tnum_envs: 4\n")
    with pytest.raises(ConfigError, match=r"\(line 3, column 1\): YAML indents with spaces, never tabs: replace the "
                                          r"tabs on that line with spaces") as refused:
        load_config(tabbed)
    assert "\n" not in str(refused.value)
    listed = tmp_path / "list.yaml"
    listed.write_text("- ppo\n")
    with pytest.raises(ConfigError, match="must hold a mapping of sections"):
        load_config(listed)
    binary = tmp_path / "weights.bin"
    binary.write_bytes(bytes(range(128, 256)))
    with pytest.raises(ConfigError, match=r"weights.bin is not a text file \(not UTF-8\): a config is a YAML file"):
        load_config(binary)
    for text in ("", "# only a comment\n"):
        (tmp_path / "empty.yaml").write_text(text)
        with pytest.raises(ConfigError, match="empty.yaml holds no settings .* Name a shipped config .*cartpole"):
            load_config(tmp_path / "empty.yaml")
    with pytest.raises(ConfigError, match="is a directory; give a config's YAML file"):
        load_config(tmp_path)
    # A dotted key in a file is one key of that name to YAML: say to nest it, not only that it is unknown.
    for text, nested in [('extends: cartpole\n"ppo.num_envs": 8\n', r"\(`ppo:` then `  num_envs: 8`\); dotted keys "
                          r"are for command-line overrides \(ppo.num_envs=8\)\.$"),
                         ("ppo:\n  network.name: lstm\n", r"\(`ppo:` then `  network:` then `    name: lstm`\)")]:
        (tmp_path / "dotted.yaml").write_text(text)
        with pytest.raises(ConfigError, match=r"^Unknown key 'ppo\.(num_envs|network\.name)': in a YAML file, write it "
                                              rf"nested {nested}"):
            load_config(tmp_path / "dotted.yaml")
    # A misspelt part is named at once, not after the user has nested the key as told.
    for text, misspelt in [('extends: cartpole\n"ppo.num_envz": 8\n', "there is no key 'ppo.num_envz': did you mean "
                            "'ppo.num_envs'?"),
                           ('extends: cartpole\n"ppo.stop_at.valeu": 3\n', "there is no key 'ppo.stop_at.valeu': did "
                            "you mean 'ppo.stop_at.value'?")]:
        (tmp_path / "dotted.yaml").write_text(text)
        with pytest.raises(ConfigError, match=re.escape(f"Nested, it is still unknown: {misspelt}")):
            load_config(tmp_path / "dotted.yaml")


def test_shipped_configs_are_found_by_name_from_any_directory(tmp_path: Path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    shipped = list_configs()
    assert {"cartpole", "shadow_reach", "shadow_ihom", "shadow_ihom_paper"} <= set(shipped)
    assert all(shipped.values()), "every shipped config starts with a comment that says what it trains"
    for name, text in shipped.items():
        assert text.count("(") == text.count(")") and text.count("`") % 2 == 0, (name, text)
    assert load_config("shadow_reach").env.task == "ShadowHandReach"


def test_a_config_extends_one_under_the_home_folder_written_with_a_tilde(tmp_path: Path, monkeypatch):
    """`extends: ~/configs/base.yaml` was 'not found': no shell expands a `~` inside a file."""
    monkeypatch.setenv("HOME", str(tmp_path))
    (tmp_path / "base.yaml").write_text("extends: cartpole\nppo: {num_cycles: 9}\n")
    (tmp_path / "elsewhere").mkdir()
    (tmp_path / "elsewhere" / "run.yaml").write_text("extends: ~/base.yaml\n")
    assert load_config(tmp_path / "elsewhere" / "run.yaml").ppo.num_cycles == 9


def test_a_config_extends_another_by_name_or_relative_path(tmp_path: Path):
    # The shipped 4-GPU recipe is the fast cube at the same sizes per GPU: 4x its environments and minibatch samples.
    fast, four = to_dict(load_config("shadow_ihom")), to_dict(load_config("shadow_ihom_4gpu"))
    changed = {key for key, value in flatten(four).items() if flatten(fast)[key] != value}
    assert changed == {"ppo.num_envs", "ppo.minibatch_size", "distribution.num_devices"}
    assert (four["ppo"]["num_envs"], four["ppo"]["minibatch_size"]) == (
        4 * fast["ppo"]["num_envs"], 4 * fast["ppo"]["minibatch_size"])
    # The cortical cube, measured with the 32-step recipe shadow_ihom shipped before, keeps its sizes, rate and saves.
    cortical = load_config("shadow_ihom_cortical")
    ppo, checkpoint = to_dict(cortical)["ppo"], cortical.checkpoint
    assert (ppo["rollout_length"], ppo["minibatch_size"], ppo["learning_rate"]) == (32, 16384, 3e-4)
    assert (checkpoint.every, checkpoint.lean) == (10, ("best", "snapshots"))
    # The randomized cube was measured as the fast cube's second stage: shadow_ihom with the ranges and a learning rate
    # decaying over a fixed length, nothing else.
    randomized = to_dict(load_config("shadow_ihom_randomized"))
    assert {key for key, value in flatten(randomized).items() if flatten(fast).get(key) != value} == {
        f"env.options.randomization.{key}" for key in randomized["env"]["options"]["randomization"]} | {
        "ppo.num_cycles", "ppo.lr_decay"}
    assert (randomized["ppo"]["num_cycles"], randomized["ppo"]["lr_decay"]) == (900, True)
    # The 2-GPU recipe is the 4-GPU one at the same sizes per GPU: half the environments and minibatch samples.
    two = to_dict(load_config("shadow_ihom_2gpu"))
    assert {key for key, value in flatten(two).items() if flatten(four)[key] != value} == {
        "ppo.num_envs", "ppo.minibatch_size"}
    assert (two["ppo"]["num_envs"] * 2, two["ppo"]["minibatch_size"] * 2) == (
        four["ppo"]["num_envs"], four["ppo"]["minibatch_size"])
    # A file next to its base, which itself extends a shipped config; sections merge, lists and values replace.
    (tmp_path / "base.yaml").write_text("extends: cartpole\nppo: {num_cycles: 9, network: {width: 32}}\n")
    (tmp_path / "run.yaml").write_text("extends: base.yaml\nppo: {network: {width: 16}}\ncheckpoint: {lean: [best]}\n")
    config = load_config(tmp_path / "run.yaml", ["ppo.gamma=0.9"])
    assert (config.ppo.num_cycles, config.ppo.network.width, config.ppo.gamma) == (9, 16, 0.9)
    assert config.ppo.network.name == load_config("cartpole").ppo.network.name and config.checkpoint.lean == ("best",)


@pytest.mark.parametrize("text, message", [
    ("extends: missing.yaml\n", r"Config file 'missing.yaml' not found \(extended by .*run.yaml\)"),
    ("extends: run.yaml\n", r"extends goes round in a circle: .*run.yaml -> .*run.yaml"),
    ("extends: [cartpole]\n", r"extends names one config .*got \['cartpole'\]"),
    ("extends: shadow_rech\n", r"Config file 'shadow_rech' not found \(extended by .*run.yaml\)\. Did you mean "
                               r"'shadow_reach'\? Give a YAML path"),
])
def test_a_bad_extends_fails_naming_the_file(tmp_path: Path, text, message):
    (tmp_path / "run.yaml").write_text(text)
    with pytest.raises(ConfigError, match=message):
        load_config(tmp_path / "run.yaml")


def test_the_config_reference_describes_every_key_and_docs_hold_it_as_generated():
    """Every key of every config section has a type, a default and a description read from its class's docstring;
    docs/config.md is what `angora-jax config reference` prints (regenerate it after changing a config class)."""
    keys = config_keys()
    assert [key.key for key in keys][:3] == ["env", "env.task", "env.options"] and len(keys) > 50
    assert {key.key for key in keys} >= {f"ppo.{name}" for name in to_dict(load_config("cartpole"))["ppo"]}
    undescribed = [key.key for key in keys if len(key.description) < 10]
    assert not undescribed, f"config keys without a description in their class's docstring: {undescribed}"
    by_key = {key.key: key for key in keys}
    assert by_key["distribution.num_devices"].type == "int | str" and by_key["ppo.init_from"].default == "null"
    assert by_key["logging.run_name"].description.startswith("the run directory's name; None makes one")
    assert by_key["checkpoint.best_mode"].description == '"max" or "min".'
    # A pipe inside a code span splits no cell in the site's Markdown, which would print an escaping backslash.
    assert "| `ppo.init_from` | `str | None` | `null` |" in reference_markdown()
    docs = Path(__file__).resolve().parents[1] / "docs" / "config.md"
    assert docs.read_text() == reference_markdown(), "stale: angora-jax config reference > docs/config.md"


def test_a_field_missing_from_its_docstring_has_no_description():
    @dataclasses.dataclass(frozen=True)
    class Section:
        """A section.

        Attributes:
            first: described.
            second: also described, over
                two lines.
            other: not a field, so not a key.

        third is mentioned below the section, not in it.
        """

        first: int = 1
        second: str = "x"
        third: float = 0.5

    assert field_descriptions(Section) == {"first": "described.", "second": "also described, over two lines."}
    assert [key.description for key in config_keys(Section)][2] == ""


def _alias_bomb(levels: int = 9) -> str:
    """YAML whose aliases expand to 10**levels strings ("billion laughs") in a few hundred bytes."""
    lines = ["l0: &l0 [lol, lol, lol, lol, lol, lol, lol, lol, lol, lol]"]
    lines += [f"l{i}: &l{i} [{', '.join([f'*l{i - 1}'] * 10)}]" for i in range(1, levels)]
    return "\n".join(lines)


def test_an_alias_bomb_is_refused_at_once_in_a_file_and_in_an_override(tmp_path: Path):
    """A few hundred bytes of nested aliases expand to a billion values; reading them must not hang or eat memory."""
    bomb = _alias_bomb()
    (tmp_path / "bomb.yaml").write_text(f"env:\n  options:\n    {bomb.replace(chr(10), chr(10) + '    ')}\n")
    override = "env.options.junk={" + bomb.replace("\n", ", ") + "}"
    for source, overrides, where in [(tmp_path / "bomb.yaml", [], r"bomb.yaml"), ("cartpole", [override], "Override")]:
        tracemalloc.start()
        started = time.perf_counter()
        with pytest.raises(ConfigError, match=rf"{where}.* expands to more than 10,000 values .*aliases"):
            load_config(source, overrides)
        _, peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
        assert time.perf_counter() - started < 5 and peak < 50e6


def test_plain_anchors_and_aliases_still_work(tmp_path: Path):
    (tmp_path / "run.yaml").write_text(
        "extends: cartpole\n"
        "evaluation: {every: &every 5}\n"
        "checkpoint: {every: *every, snapshot_every: *every}\n"
        "ppo:\n  <<: &sizes {num_envs: 32, minibatch_size: 512}\n  network: {frozen: &modules [network.a]}\n"
    )
    config = load_config(tmp_path / "run.yaml", ["ppo.network.pretrained={x: &p run, y: *p}"])
    assert (config.checkpoint.every, config.checkpoint.snapshot_every, config.evaluation.every) == (5, 5, 5)
    assert (config.ppo.num_envs, config.ppo.network.frozen) == (32, ("network.a",))
    assert config.ppo.network.pretrained == {"x": "run", "y": "run"}


@pytest.mark.parametrize("text, message", [
    ("x: &a [*a]\n", r"alias \*a \(line 1\) refers to itself"),
    ("x: " + "[" * 500 + "]" * 500 + "\n", r"nested more than 50 levels deep"),
])
def test_self_referring_and_deeply_nested_yaml_is_refused(tmp_path: Path, text, message):
    (tmp_path / "run.yaml").write_text(text)
    with pytest.raises(ConfigError, match=rf"run.yaml.*{message}"):
        load_config(tmp_path / "run.yaml")
    with pytest.raises(ConfigError, match=rf"Override 'env.options.x=.*{message}"):
        load_config("cartpole", [f"env.options.x={text.removeprefix('x: ').strip()}"])


@pytest.mark.parametrize("text, key, lines", [
    ("ppo: {num_cycles: 3}\nenv: {task: CartPole}\nppo: {gamma: 0.9}\n", "ppo", (1, 3)),
    ("ppo:\n  num_cycles: 3\n  gamma: 0.9\n  num_cycles: 4\n", "num_cycles", (2, 4)),
    ("env:\n  options: {1: a, true: b}\n", "True", (2, 2)),
])
def test_a_key_given_twice_is_refused_with_both_lines(tmp_path: Path, text, key, lines):
    (tmp_path / "run.yaml").write_text(text)
    with pytest.raises(ConfigError, match=rf"run.yaml: key '?{key}'? appears twice in one mapping, on line {lines[0]} "
                                          rf"and line {lines[1]}"):
        load_config(tmp_path / "run.yaml")
    with pytest.raises(ConfigError, match=r"Override 'ppo={gamma: 0.9, gamma: 0.8}': key 'gamma' appears twice"):
        load_config("cartpole", ["ppo={gamma: 0.9, gamma: 0.8}"])


def test_a_key_overridden_twice_is_named_with_the_one_used(capsys, tmp_path, quick_compiles):
    """Trust trial: `train cartpole ppo.learning_rate=1e-3 ppo.learning_rate=2e-3` trained at 2e-3 without a word.
    The last one still wins (command lines built from a shared part repeat keys on purpose), and is named."""
    assert repeated_keys(["ppo.learning_rate=1e-3", "ppo.num_envs=8", "ppo.learning_rate = 2e-3"]) == [
        "ppo.learning_rate is given 2 times ('ppo.learning_rate=1e-3', then 'ppo.learning_rate = 2e-3'): the last one "
        "is used."]
    assert repeated_keys(["ppo.network.width=8", "ppo.network={name: gru}", "ppo.num_envs=8"]) == []
    assert main(["train", "cartpole", "ppo.num_cycles=2", "ppo.num_cycles=1", "ppo.num_envs=4", "ppo.minibatch_size=32",
                 "ppo.num_epochs=1", f"logging.run_root={tmp_path}", "logging.run_name=r", "logging.report=false",
                 "logging.progress=none"]) == 0
    assert "ppo.num_cycles is given 2 times ('ppo.num_cycles=2', then 'ppo.num_cycles=1'): the last one is used." \
        in capsys.readouterr().err
    assert load_config(tmp_path / "r" / "config.yaml").ppo.num_cycles == 1


def test_a_section_given_as_an_override_merges_into_the_configs_as_in_a_file():
    """`ppo={num_envs: 1024}` on shadow_ihom trained with PPOConfig's defaults for its other ppo keys (the shipped
    ones dropped without a word), and after `ppo.num_cycles=5` undid it; sections merge key by key, as `extends`
    does, and a mapping of named entries (`ppo.network.graph.areas`) is still replaced whole."""
    shipped = load_config("shadow_ihom").ppo
    merged = load_config("shadow_ihom", ["ppo.num_cycles=5", "ppo={num_envs: 1024}"]).ppo
    assert merged == dataclasses.replace(shipped, num_envs=1024, num_cycles=5)


def test_a_section_left_empty_is_refused_not_reset_to_the_defaults(tmp_path: Path):
    """`ppo:` with its keys commented out, over `extends: shadow_ihom`, trained with PPOConfig's defaults: the
    shipped config's 11 ppo settings dropped without a word; `ppo=null` on the command line likewise."""
    (tmp_path / "run.yaml").write_text("extends: shadow_ihom\nppo:\n#  num_envs: 8\n")
    message = r"ppo is empty \(null\), which would set all its keys to their defaults: give its keys under it, or "
    with pytest.raises(ConfigError, match=message):
        load_config(tmp_path / "run.yaml")
    with pytest.raises(ConfigError, match=message):
        load_config("shadow_ihom", ["ppo="])
    with pytest.raises(ConfigError, match=message.replace("ppo is", "ppo.network is")):
        load_config("cartpole", ["ppo.network=null"])
    assert load_config("cartpole", ["logging.wandb=null"]).logging.wandb is None  # an optional section: none


@pytest.mark.parametrize("key, text, message", [
    ("ppo.num_envs", "010", r"'010' \(line 1\) is octal in YAML 1.1, read as 8: write 10 \(or 8 if octal was meant\)"),
    ("env.options.max_episode_steps", "-0100", r"'-0100' \(line 1\) is octal in YAML 1.1, read as -64"),
    ("ppo.seed", "1:30", r"'1:30' \(line 1\) is a base-60 number in YAML 1.1, read as 90"),
    ("ppo.learning_rate", "1:30.5", r"'1:30.5' \(line 1\) is a base-60 number in YAML 1.1, read as 90.5"),
])
def test_a_number_yaml_1_1_reads_as_octal_or_base_60_is_refused_not_misread(tmp_path: Path, key, text, message):
    """PyYAML reads `010` as 8 and `1:30` as 90 (YAML 1.1): `ppo.num_envs=010` trained 8 environments."""
    with pytest.raises(ConfigError, match=rf"Override '{key}={text}': {message}"):
        load_config("cartpole", [f"{key}={text}"])
    *sections, leaf = key.split(".")
    (tmp_path / "run.yaml").write_text("".join(f"{'  ' * i}{s}:\n" for i, s in enumerate(sections))
                                       + f"{'  ' * len(sections)}{leaf}: {text}\n")
    with pytest.raises(ConfigError, match=rf"run.yaml.*{message.replace('line 1', f'line {len(sections) + 1}')}"):
        load_config(tmp_path / "run.yaml")
    # the same value as text, and what reads the same either way, are kept
    assert load_config("cartpole", [f"logging.run_name='{text}'"]).logging.run_name == text
    assert load_config("cartpole", ["ppo.seed=007", "evaluation.every=00", "ppo.learning_rate=0.010"]).ppo.seed == 7


@pytest.mark.parametrize("text, message", [
    ("1: x\n", r"Key 1 \(int\) of the config is not a name: keys are words such as 'env'"),
    ("null: y\n", r"Key None \(NoneType\) of the config is not a name"),
    ("ppo: {network: {2.5: x}}\n", r"Key 2.5 \(float\) of ppo.network is not a name"),
])
def test_a_key_that_is_not_a_string_is_refused_by_name(tmp_path: Path, text, message):
    (tmp_path / "run.yaml").write_text(text)
    with pytest.raises(ConfigError, match=message):
        load_config(tmp_path / "run.yaml")


@pytest.mark.parametrize("ranges, message", [
    ({"friction": [float("inf"), float("inf")]}, r"randomization.friction is a range of scale factors: give \[lo, hi\] "
                                                 r"of finite numbers, got \[inf, inf\]"),
    ({"joint_damping": [0.5, float("nan")]}, r"randomization.joint_damping .* of finite numbers"),
    ({"armature": [0.5, 10**400]}, r"randomization.armature .* of finite numbers"),
    ({"action_noise": float("inf")}, r"randomization.action_noise is a standard deviation: give a finite number >= 0"),
    ({"action_delay": [0, 2**40]}, r"randomization.action_delay's maximum must be <= 1,000 policy steps, got "
                                   r"1099511627776"),
])
def test_randomization_ranges_must_be_finite(ranges, message):
    with pytest.raises(ValueError, match=message):
        Randomization.from_options(ranges, cube=True)


def _numeric_fields(cls: type, prefix: str = "") -> typing.Iterator[tuple[type, str, str]]:
    """(class, field, key) of every field of config dataclass `cls`, and of the dataclasses it holds, typed with a
    number (int or float, alone or in a union, tuple or mapping)."""
    hints = typing.get_type_hints(cls)
    for f in dataclasses.fields(cls):
        kinds, key = [hints[f.name]], f"{prefix}{f.name}"
        while kinds:
            kind = kinds.pop()
            if dataclasses.is_dataclass(kind):
                yield from _numeric_fields(kind, f"{key}.")
            elif kind in (int, float):
                yield cls, f.name, key
            kinds += typing.get_args(kind)


def test_every_numeric_key_declares_its_range():
    numeric = {key: field_bounds(cls, name) for cls, name, key in _numeric_fields(Config)}
    assert {"ppo.seed", "ppo.network.graph.areas.size", "evaluation.video.width", "distribution.num_devices",
            "ppo.stop_at.value", "checkpoint.snapshot_every"} <= set(numeric)
    assert not [key for key, bounds in numeric.items() if bounds is None], "numeric keys without a declared range"
    # The defaults lie in their ranges.
    check_bounds(Config(), "")


def test_python_arguments_that_are_no_count_or_number_in_range_are_config_errors_naming_them():
    """The shared checks of arguments given in Python (counts, fractions, rates) raise a ConfigError, as check_seed
    does: the error of a bad setting, which the command line answers with exit 2 and the message, where a bare
    ValueError (check_count's before) is a traceback. Numpy numbers are taken; bools, text and NaN are not."""
    assert check_count("jitter", np.int64(0), least=0) == 0 and check_number("blur", np.float32(0.5), 0, 1) == 0.5
    for bad in (0, -2, 2.5, "4", True, None):
        said = re.escape(repr(bad))
        with pytest.raises(ConfigError, match=rf"^episodes must be a whole number of at least 1, got {said}\.$"):
            check_count("episodes", bad)
    for bad in (1.5, -0.1, float("nan"), float("inf"), "0.5", True, None):
        said = re.escape(repr(bad))
        with pytest.raises(ConfigError, match=rf"^fraction must be a number from 0 to 1, got {said}\.$"):
            check_number("fraction", bad, 0.0, 1.0)
    with pytest.raises(ConfigError, match=r"^learning_rate must be a number above 0, got 0\.$"):
        check_number("learning_rate", 0, 0.0, open_low=True)
    with pytest.raises(ConfigError, match=r"^learning_rate must be a number above 0, got a 401-digit integer\.$"):
        check_number("learning_rate", 10**400, 0.0, open_low=True)  # past a float's range: no OverflowError
    for bad in (0, 1, 0.0, 1.0):  # a fraction held out: neither none nor all
        with pytest.raises(ConfigError, match=rf"^held_out must be a number above 0 and below 1, got {bad!r}\.$"):
            check_number("held_out", bad, 0.0, 1.0, open_low=True, open_high=True)
    assert check_number("held_out", 0.25, 0.0, 1.0, open_low=True, open_high=True) == 0.25


@pytest.mark.parametrize("source, message", [
    (42, r"^A config is the name of a shipped config \(e.g. 'cartpole'\), a YAML file's path, a dict or a Config; got "
         r"42 \(int\)\.$"),
    (["cartpole"], r"^A config is the name .*; got \['cartpole'\] \(list\)\.$"),
])
def test_a_config_given_as_what_is_no_name_path_or_dict_is_refused_naming_what_to_give(source, message):
    """`aj.train(42)` or `aj.load_config(["cartpole"])` failed in pathlib: "expected str, bytes or os.PathLike object,
    not int"."""
    with pytest.raises(ConfigError, match=message):
        load_config(source)
    with pytest.raises(ConfigError, match=message):
        aj.train(source)


def test_a_config_loaded_already_given_to_load_config_is_returned_checked_and_takes_overrides():
    """`aj.load_config(config)` of a Config (loaded in an earlier cell) failed in pathlib; it is the config itself.
    Overrides with it were refused, by `train` too, pointing to a `replace()` a Config lacks: they apply to a copy, as
    to the config's own file, and a bad one is refused by name as there; every shipped config survives the trip."""
    config = load_config("cartpole", ["ppo.num_cycles=3"])
    assert load_config(config) == config
    changed = load_config(config, ["ppo.num_cycles=4", "ppo.num_envs=8"])
    assert (changed.ppo.num_cycles, changed.ppo.num_envs, config.ppo.num_cycles) == (4, 8, 3)
    assert changed == load_config("cartpole", ["ppo.num_cycles=3", "ppo.num_cycles=4", "ppo.num_envs=8"])
    with pytest.raises(ConfigError, match=r"Unknown key 'ppo.num_env'.*Did you mean 'ppo.num_envs'"):
        load_config(config, ["ppo.num_env=8"])
    for name in list_configs():
        assert load_config(load_config(name), ["ppo.seed=0"]) == load_config(name, ["ppo.seed=0"]), name


def test_a_run_root_that_is_a_file_or_inside_one_is_refused_before_anything_is_made(tmp_path: Path):
    """logging.run_root naming a file (or a folder inside one) failed in pathlib's mkdir: "[Errno 17] File exists"
    and "[Errno 20] Not a directory", with no word of which key to change."""
    file = tmp_path / "notes.txt"
    file.write_text("mine")
    for root in (file, file / "runs"):
        # The key's value as other messages show it, shortened when long (a deep temporary folder here).
        with pytest.raises(ConfigError, match=rf"^logging.run_root='.+' cannot hold run directories: "
                                              rf"{re.escape(str(file))} is a file\. Choose a folder for runs "
                                              r"\(e.g. logging.run_root=runs\)\.$"):
            aj.train("cartpole", [f"logging.run_root={root}", "logging.run_name=a"])
    assert file.read_text() == "mine" and sorted(tmp_path.iterdir()) == [file]


def test_assigning_to_a_loaded_config_says_how_to_change_it_and_the_ways_it_names_work():
    """`config.ppo.num_envs = 8` raised dataclasses' "cannot assign to field 'num_envs'", naming no way to change it;
    every section of the config tree (down to a brain-area graph's areas) now names them, and they work."""
    import jax

    config = aj.load_config("shadow_reach_cortical_graph", ["logging.wandb.mode=disabled"])

    def sections(settings):
        yield settings
        for f in dataclasses.fields(settings):
            value = getattr(settings, f.name)
            if dataclasses.is_dataclass(value):
                yield from sections(value)
            elif isinstance(value, dict):
                yield from (v for v in value.values() if dataclasses.is_dataclass(v))

    kinds = set()
    for section in sections(config):
        name = dataclasses.fields(section)[0].name
        refusal = (rf"^cannot assign to field {name!r}: this {type(section).__name__} is frozen .*"
                   r"aj\.load_config\(config, .*dataclasses\.replace\(section, ")
        with pytest.raises(dataclasses.FrozenInstanceError, match=refusal):
            setattr(section, name, None)
        with pytest.raises(dataclasses.FrozenInstanceError, match="make a changed copy with dataclasses.replace"):
            delattr(section, name)
        kinds.add(type(section).__name__)
    assert {"Config", "PPOConfig", "NetworkConfig", "AreaGraph", "AreaSpec", "ValueSpec", "WandbConfig"} <= kinds, kinds
    changed = dataclasses.replace(config, ppo=dataclasses.replace(config.ppo, num_envs=8))
    assert aj.load_config(changed).ppo.num_envs == 8 == aj.load_config(config, ["ppo.num_envs=8"]).ppo.num_envs
    # The graph is a flax module's attribute: still hashable and equal to a copy, so still a static argument of jit.
    graph = config.ppo.network.graph
    copy = dataclasses.replace(graph)
    assert copy == graph and hash(copy) == hash(graph)
    assert jax.jit(lambda x, graph: x * len(graph.areas), static_argnums=1)(1.0, copy) == len(graph.areas)
