"""User code from the command line and from installed packages: a config's `imports`, the `--import` option, plugins
of the entry-point group `angora_jax.plugins`, and a run that records its imports so that later commands import them
again; a module that cannot be imported exits 2 naming it and the fix."""

from __future__ import annotations

import importlib.metadata
import os
import subprocess
import sys
import textwrap
import venv
from pathlib import Path

import jax
import pytest
from tiny import TINY_PPO

import angora_jax as aj
from angora_jax.cli import main
from angora_jax.envs.registry import TASKS
from angora_jax.experiment import agent, programs
from angora_jax.experiment.run_dir import read_run_config
from angora_jax.nets import register_network
from angora_jax.nets.registry import NETWORKS
from angora_jax.ppo.distributions import HEADS
from angora_jax.registry import plugins

# Every run here is a cycle of a tiny CartPole with tasks and networks of its own, or refused before it trains; the
# other files that train the tiny CartPole compile quickly too, and share its programs (tests/quick_compile.py).
pytestmark = pytest.mark.usefixtures("quick_file_compiles")

ROOT = Path(__file__).resolve().parents[1]
# A task of the user's: CartPole under another name, so that nothing new compiles.
USER_TASK = """
from angora_jax.envs import make, register

register("UserCartPole", lambda **options: make("CartPole", **options))
"""
# A network of the user's: the `simple` model's builder under another name (the programs are the shipped config's).
USER_NETWORK = """
from angora_jax.nets import register_network
from angora_jax.nets.registry import NETWORKS

register_network("user_simple", NETWORKS.get("simple"))
"""


@pytest.fixture
def user_code(tmp_path, monkeypatch):
    """A folder on sys.path for the test's modules (`user_code(name, source)` writes one); the registries, the
    plugins' loaded flag and sys.modules are as before the test afterwards."""
    for registry in (TASKS, NETWORKS, HEADS):
        monkeypatch.setattr(registry, "_factories", dict(registry._factories))
    monkeypatch.setattr(plugins, "_loaded", False)
    folder = tmp_path / "user_code"
    folder.mkdir()
    monkeypatch.syspath_prepend(str(folder))
    written = []

    def write(name: str, source: str) -> str:
        (folder / f"{name}.py").write_text(textwrap.dedent(source))
        written.append(name)
        return name

    yield write
    for name in written:
        sys.modules.pop(name, None)


def forget(module: str, network: str) -> None:
    """What a new process would not have: the module imported and the network it registered."""
    sys.modules.pop(module)
    NETWORKS._factories.pop(network)


def trained_with(module: str, tmp_path: Path) -> Path:
    """tmp_path/r: a one-cycle CartPole run of the user's `user_simple` network, which `module` registers."""
    assert main(["train", "cartpole", *TINY_PPO, "ppo.num_cycles=1", "ppo.network.name=user_simple",
                 f"logging.run_root={tmp_path}", "logging.run_name=r", "logging.report=false",
                 "logging.progress=none", "--import", module]) == 0
    return tmp_path / "r"


def test_the_config_key_and_the_option_import_user_code_and_config_show_lists_both(user_code, tmp_path, capsys):
    task, network = user_code("user_task_a", USER_TASK), user_code("user_net_a", USER_NETWORK)
    config = tmp_path / "user.yaml"
    config.write_text(f"imports: [{task}]\nenv: {{task: UserCartPole}}\nppo: {{network: {{name: user_simple}}}}\n")
    assert main(["config", "show", str(config), "--import", network, "--import", task]) == 0
    shown = capsys.readouterr().out
    assert "  task: UserCartPole\n" in shown and shown.endswith(f"imports:\n- {task}\n- {network}\n"), "each once"
    assert "user_simple" in NETWORKS.names() and "UserCartPole" in aj.list_tasks()


def test_a_run_records_its_imports_and_resume_and_evaluate_import_them_again(user_code, tmp_path, capsys):
    module = user_code("user_net_b", USER_NETWORK)
    run_dir = trained_with(module, tmp_path)
    assert read_run_config(run_dir).imports == (module,)
    forget(module, "user_simple")
    assert main(["resume", str(run_dir)]) == 0, "a finished run, loaded with its network"
    forget(module, "user_simple")
    assert main(["evaluate", str(run_dir), "--episodes", "2"]) == 0
    assert "episode_return" in capsys.readouterr().out
    forget(module, "user_simple")
    (tmp_path / "user_code" / f"{module}.py").unlink()
    assert main(["check", str(run_dir)]) == 0, "its code not importable here damages nothing in the run"
    out = capsys.readouterr().out
    assert f"config: CartPole, user_simple network, 1 cycle; its own code cannot be used here, so resume and " \
           f"evaluate cannot either (the checks below do not need it): Module '{module}'" in out, out
    assert out.rstrip().endswith("OK: nothing is damaged or missing.")


def test_a_run_s_module_not_found_is_named_with_the_folder_it_was_imported_from(user_code, tmp_path, capsys,
                                                                            monkeypatch):
    """Own-task trial: a run trained with PYTHONPATH=. and evaluated from another folder, or after its module moved,
    was told only "Put the folder that holds it on PYTHONPATH (e.g. PYTHONPATH=/path/to/folder ...)"."""
    module = user_code("user_net_moved", USER_NETWORK)
    run_dir = trained_with(module, tmp_path)
    capsys.readouterr()
    folder = tmp_path / "user_code"
    # A new process, from another folder: the module's folder is not on its path.
    monkeypatch.setattr(sys, "path", [p for p in sys.path if p not in ("", str(folder), os.getcwd())])
    forget(module, "user_simple")
    assert main(["evaluate", str(run_dir), "--episodes", "2"]) == 2
    err = capsys.readouterr().err
    assert f"Module '{module}'" in err and f"The run imported it from {folder / module}.py when it last trained: " \
           f"put that folder on PYTHONPATH (PYTHONPATH={folder} angora-jax ...)" in err, err
    monkeypatch.chdir(folder)  # beside the module, without PYTHONPATH=.
    assert main(["resume", str(run_dir)]) == 2
    assert (f"It is in the current folder, which the command does not search: run it with that folder on PYTHONPATH "
            f"(PYTHONPATH={folder} angora-jax ...; PYTHONPATH=. from here)") in capsys.readouterr().err
    monkeypatch.chdir(tmp_path)
    (folder / f"{module}.py").rename(tmp_path / f"{module}.py.moved")
    assert main(["evaluate", str(run_dir)]) == 2
    assert f"{folder / module}.py when it last trained, and that file is no longer there (moved or deleted)" \
           in capsys.readouterr().err


def test_a_checkpoint_that_no_longer_fits_its_edited_own_code_names_the_module_not_the_config(user_code, tmp_path,
                                                                                              capsys):
    """Own-task trial: the run's module edited after training (an observation widened), evaluate and resume said
    "the run's config.yaml (ppo.network, env) was changed after training. Restore the config", which was not."""
    module = user_code("user_net_edited", USER_NETWORK)
    run_dir = trained_with(module, tmp_path)
    capsys.readouterr()
    forget(module, "user_simple")
    # A new process would have no programs or acting parts made for the module as it was.
    programs._programs.clear()
    agent._acting_parts.cache_clear()
    # The same network name, built 8 units wide instead of the config's 64.
    user_code(module, USER_NETWORK.replace('NETWORKS.get("simple"))', 'lambda network: NETWORKS.get("simple")('
                                           'dataclasses.replace(network, width=8)))\nimport dataclasses'))
    file = tmp_path / "user_code" / f"{module}.py"
    for argv in (["evaluate", str(run_dir)], ["resume", str(run_dir), "--num-cycles", "2"]):
        assert main(argv) == 2
        err = capsys.readouterr().err.splitlines()[-1]
        assert "do not fit what its own code builds now" in err and f"{module} ({file}) changed since the run " \
               "last trained" in err and "config.yaml" not in err, err
        forget(module, "user_simple")
    # The refused resume changed nothing: it had recorded --num-cycles 2 in config.yaml before its restore failed.
    assert "recorded in its config.yaml" not in err and read_run_config(run_dir).ppo.num_cycles == 1


@pytest.mark.parametrize("where", ["config", "option"])
@pytest.mark.parametrize("problem, message", [
    ("missing", "Module 'user_missing' ({source}) is not found. Put the folder that holds it on PYTHONPATH"),
    ("raises", "Importing 'user_raises' ({source}) failed: RuntimeError: no GPU here"),
    ("needs", "Importing 'user_needs' ({source}) failed: ModuleNotFoundError: No module named 'not_installed_x'"),
    ("path", "'user_code/mine.py' ({source}) is not a module name"),
    # Its file's name, the module importable: not "not found, put its folder on PYTHONPATH" (it is there).
    ("file", "'user_plain.py' ({source}) is not a module name: give the module's name, user_plain (imports: "
             "[user_plain], or --import user_plain), with its folder on PYTHONPATH: PYTHONPATH="),
])
def test_a_module_that_cannot_be_imported_exits_2_naming_it_where_it_came_from_and_the_fix(
        where, problem, message, user_code, tmp_path, capsys):
    user_code("user_raises", "raise RuntimeError('no GPU here')\n")
    user_code("user_needs", "import not_installed_x\n")
    user_code("user_plain", "")
    module = {"missing": "user_missing", "path": "user_code/mine.py", "file": "user_plain.py"}.get(
        problem, f"user_{problem}")
    config = tmp_path / "c.yaml"
    config.write_text(f"extends: cartpole\nimports: ['{module}']\n" if where == "config" else "extends: cartpole\n")
    argv = ["train", str(config), f"logging.run_root={tmp_path}"] + (["--import", module] if where == "option" else [])
    assert main(argv) == 2
    err = capsys.readouterr().err
    source = ("listed under imports in the config; a run's config.yaml lists those it trained with" if where == "config"
              else "--import")
    assert err.startswith("angora-jax train: ") and message.format(source=source) in err and "Traceback" not in err
    assert not (tmp_path / "runs").exists() and not any(tmp_path.glob("CartPole-*"))


def test_a_cell_run_again_registers_its_network_again_and_another_definition_of_the_name_is_refused(user_code):
    """A notebook cell that registers a network refused to run a second time (editing a model meant restarting the
    kernel); a second definition under a registered name is still refused, naming the first."""
    cell = ("from angora_jax.nets import register_network\n"
            "from angora_jax.nets.registry import NETWORKS\n"
            "register_network('user_cell', lambda network: NETWORKS.get('simple')(network))\n")
    notebook = {"__name__": "__main__"}
    exec(cell, notebook)
    first = NETWORKS.get("user_cell")
    exec(cell, notebook)
    assert NETWORKS.get("user_cell") is not first, "the cell's new definition replaced its old one"
    with pytest.raises(ValueError, match=r"^Network 'user_cell' is already registered \(by __main__.<lambda>\): "
                                         r"choose another name$"):
        register_network("user_cell", NETWORKS.get("simple"))


def _edited_cell(width: int, name: str = "user_edit") -> None:
    """A notebook cell that registers the network `name`, run with this width. Each test takes its own name: the
    fixture's clean-up removes a name without counting a replacement, so a later test's first cell would not."""
    exec("import dataclasses\n"
         "from angora_jax.nets import register_network\n"
         "from angora_jax.nets.registry import NETWORKS\n"
         f"register_network({name!r},\n"
         f"                 lambda n: NETWORKS.get('simple')(dataclasses.replace(n, width={width})))\n",
         {"__name__": "__main__"})


def test_a_cell_edited_and_run_again_gives_the_same_config_new_programs(user_code):
    """The fast counterpart of the test below: the process's programs for a config (`cycle_programs`) are kept while
    no definition changes, and made anew once a cell has registered its network again (nothing compiled here)."""
    _edited_cell(8, "user_edit_fast")
    config = aj.load_config("cartpole", [*TINY_PPO, "ppo.network.name=user_edit_fast"])
    env = aj.make("CartPole")
    first = programs.cycle_programs(config, env)
    assert programs.cycle_programs(config, env) is first, "kept while no definition changed"
    _edited_cell(16, "user_edit_fast")
    assert programs.cycle_programs(config, env) is not first, "the edited network gets programs of its own"


@pytest.mark.slow
def test_a_cell_edited_and_run_again_trains_and_loads_its_new_network_not_the_compiled_old_one(user_code, tmp_path):
    """The compiled programs of a process are kept by config (`cycle_programs`, `_acting_parts`), and a config names a
    network, not its code: after a notebook cell that registers a network was edited and run again, training the
    same config reused the old network's programs (its widths), and loading the run failed in Flax."""
    cell = _edited_cell

    def trained(name: str) -> int:
        assert main(["train", "cartpole", *TINY_PPO, "ppo.num_cycles=1", "ppo.network.name=user_edit",
                     f"logging.run_root={tmp_path}", f"logging.run_name={name}", "logging.report=false",
                     "logging.progress=none"]) == 0
        return sum(leaf.size for leaf in jax.tree.leaves(aj.load_agent(tmp_path / name).params))

    cell(8)
    narrow = trained("narrow")
    cell(16)
    assert trained("wide") > narrow, "the edited cell's wider network was trained and loaded"


def test_a_run_of_a_task_defined_in_a_notebook_says_to_move_it_into_a_module_when_a_command_reads_it(
        user_code, tmp_path, capsys):
    """`angora-jax evaluate` of a run whose task a notebook cell registered said to list 'the module' under imports,
    when there was none: the code lived in the notebook. The run records where its task and network were defined."""
    exec("from angora_jax.envs import make, register\n"
         "register('NotebookCartPole', lambda **options: make('CartPole', **options))\n", {"__name__": "__main__"})
    assert main(["train", "cartpole", *TINY_PPO, "ppo.num_cycles=1", "env.task=NotebookCartPole",
                 f"logging.run_root={tmp_path}", "logging.run_name=nb", "logging.report=false",
                 "logging.progress=none"]) == 0
    TASKS._factories.pop("NotebookCartPole")  # as in a new process: the command's
    capsys.readouterr()
    assert main(["evaluate", str(tmp_path / "nb"), "--episodes", "2"]) == 2
    err = capsys.readouterr().err
    assert "The run's 'NotebookCartPole' was defined in a notebook or script (__main__.<lambda>) when it trained, " \
           "which a command cannot import: put that definition in a module file, give it with --import MODULE" in err
    assert "Traceback" not in err, err


# CartPole with one part of its step changed (CHANGE), registered as BrokenCartPole.
BROKEN_TASK = """
import jax.numpy as jnp
from angora_jax.envs import register
from angora_jax.envs.classic.cartpole import CartPole

class BrokenCartPole(CartPole):
    def _step(self, physics, info, action, key):
        physics, obs, reward, terminated, info, metrics = super()._step(physics, info, action, key)
        CHANGE
        return physics, obs, reward, terminated, info, metrics

register("BrokenCartPole", BrokenCartPole)
"""


@pytest.mark.parametrize("change, message", [
    ("reward = jnp.stack([reward, reward])", "its _step returned a reward of shape (2,): one number per environment"),
    ("terminated = jnp.zeros((1,), bool)", "its _step returned a terminated of shape (1,)"),
    ("metrics = {'upright': reward}", "its _step returned the metrics ['upright'], and its metric_names are []"),
    ("obs = obs.replace(proprioception=jnp.concatenate([obs.proprioception] * 2))",
     "its observation after _step differs from _reset's (.proprioception: (4,) float32 before, (8,) float32 after)"),
    ("info = {**info, 'timer': reward}",
     "its info after _step differs from _reset's (keys [] before, ['timer'] after)"),
    ("reward = 1 / 0", "its _step (given an action of shape ()) raised ZeroDivisionError: division by zero"),
    ("raise ValueError('goal out of range.')", "raised ValueError: goal out of range.\n"),  # one full stop
])
def test_a_task_that_breaks_its_contract_exits_2_naming_the_part_before_anything_compiles(
        change, message, user_code, tmp_path, capsys):
    """A reward of shape (2,) or a step that changed a shape used to fail inside JAX's tracing of the compiled
    loop, with a traceback about broadcasting or scan carries, and exit 1."""
    module = user_code("user_broken_task", BROKEN_TASK.replace("CHANGE", change))
    assert main(["train", "cartpole", "env.task=BrokenCartPole", f"logging.run_root={tmp_path}", "--import",
                 module]) == 2
    err = capsys.readouterr().err
    assert err.startswith("angora-jax train: Task 'BrokenCartPole' (user_broken_task.BrokenCartPole) breaks the task "
                          "contract (docs/tutorials/custom-task.md") and message in err and "Traceback" not in err, err
    assert [path.name for path in tmp_path.iterdir()] == ["user_code"], "no run directory is made"


# A task with privileged inputs (CartPole's state, again, as `asymmetric`) and networks of the user's, each breaking
# one part of the network contract.
BROKEN_NETWORKS = """
import flax.linen as nn
import jax.numpy as jnp
from angora_jax.envs import register
from angora_jax.envs.classic.cartpole import CartPole
from angora_jax.nets import register_network

class PrivilegedCartPole(CartPole):
    def _reset(self, key):
        physics, obs, info = super()._reset(key)
        return physics, obs.replace(asymmetric=physics), info

    def _step(self, physics, info, action, key):
        physics, obs, *rest = super()._step(physics, info, action, key)
        return physics, obs.replace(asymmetric=physics), *rest

class Net(nn.Module):
    carry_size: int = 3
    value_axis: bool = False
    reads_asymmetric: bool = False

    def initial_carry(self, batch_size):
        return jnp.zeros((batch_size, 3))

    @nn.compact
    def __call__(self, carry, obs):
        seen = obs.proprioception + (obs.asymmetric if self.reads_asymmetric else 0)
        features = nn.Dense(8)(seen)
        value = nn.Dense(1)(jnp.concatenate([obs.proprioception, obs.asymmetric], -1))
        return jnp.zeros((carry.shape[0], self.carry_size)), features, value if self.value_axis else value[:, 0]

class NoCarry(nn.Module):
    @nn.compact
    def __call__(self, carry, obs):
        return carry, nn.Dense(8)(obs.proprioception), nn.Dense(1)(obs.proprioception)[:, 0]

class ClaimsSequences(Net):
    runs_sequences = True

class TouchOnly(Net):
    @nn.compact
    def __call__(self, carry, obs):
        return carry, nn.Dense(8)(obs.touch), nn.Dense(1)(obs.proprioception)[:, 0]

register("PrivilegedCartPole", PrivilegedCartPole)
register_network("user_fine", lambda network: Net())
register_network("user_claims_sequences", lambda network: ClaimsSequences())
register_network("user_value_axis", lambda network: Net(value_axis=True))
register_network("user_carry_grows", lambda network: Net(carry_size=5))
register_network("user_reads_asymmetric", lambda network: Net(reads_asymmetric=True))
register_network("user_no_carry", lambda network: NoCarry())
register_network("user_class", lambda network: Net)
register_network("user_no_argument", lambda: Net())
register_network("user_touch_only", lambda network: TouchOnly())
"""


@pytest.mark.parametrize("network, message", [
    ("user_value_axis", "its value for 2 environments has shape (2, 1): (B,) is expected (squeeze the last axis"),
    ("user_carry_grows", "the carry it returns differs from initial_carry's (it: (2, 3) float32 before, (2, 5)"),
    ("user_reads_asymmetric", "its policy features change with obs.asymmetric, the privileged inputs only the value"),
    ("user_no_carry", "NoCarry has no initial_carry(batch_size) method"),
    ("user_class", "its builder returned the class Net, not a module: return Net(...)"),
    ("user_no_argument", "its builder, called with the run's ppo.network section, raised TypeError: <lambda>() takes"),
    ("user_claims_sequences", "its call on a training chunk (runs_sequences = True: carry, obs of (3, 2, size), resets "
                              "(3, 2), initial carry) raised TypeError"),
    ("user_touch_only", "no values in obs.touch"),
])
def test_a_network_that_breaks_its_contract_exits_2_naming_the_part_before_anything_compiles(
        network, message, user_code, tmp_path, capsys):
    """A value of shape (B, 1), a growing carry or a builder without its argument failed inside JAX with exit 1; a
    policy reading the value function's privileged inputs trained silently."""
    module = user_code("user_broken_networks", BROKEN_NETWORKS)
    argv = ["train", "cartpole", "env.task=PrivilegedCartPole", f"logging.run_root={tmp_path}", "--import", module]
    assert main([*argv, f"ppo.network.name={network}"]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"angora-jax train: Network '{network}' (user_broken_networks.<lambda>) breaks the network "
                          "contract (docs/tutorials/custom-model.md") and message in err and "Traceback" not in err, err
    assert [path.name for path in tmp_path.iterdir()] == ["user_code"], "no run directory is made"
    assert main(["config", "show", "cartpole", "env.task=PrivilegedCartPole", "ppo.network.name=user_fine",
                 "--import", module]) == 0, "the network that keeps the contract passes"


def test_installed_plugins_load_at_the_first_registry_lookup_and_a_broken_one_is_named(user_code, monkeypatch):
    user_code("user_plugin", "from angora_jax.envs import make, register\n\ndef setup():\n"
                             "    register('PluginCartPole', lambda **options: make('CartPole', **options))\n")
    user_code("user_broken_plugin", "raise ImportError('needs libfoo')\n")
    installed = [importlib.metadata.EntryPoint("cartpole_again", "user_plugin:setup", plugins.GROUP)]
    monkeypatch.setattr(importlib.metadata, "entry_points", lambda group: installed if group == plugins.GROUP else [])
    assert "PluginCartPole" not in TASKS._factories
    assert type(aj.make("PluginCartPole")) is type(aj.make("CartPole"))
    assert plugins._loaded
    installed[:] = [importlib.metadata.EntryPoint("broken", "user_broken_plugin", plugins.GROUP)]
    monkeypatch.setattr(plugins, "_loaded", False)
    with pytest.raises(plugins.UserCodeError, match=r"Importing 'user_broken_plugin' \(plugin 'broken' of an "
                                                    r"installed package.*ImportError: needs libfoo.*pip uninstall"):
        aj.list_tasks()


# A PEP 517 build backend of a few lines for the test's plugin package, in its own folder (`backend-path`), so that
# pip builds it offline with nothing to download: a wheel of the package's modules and the entry points that its
# pyproject.toml lists.
BACKEND = """
import base64, hashlib, tomllib, zipfile
from pathlib import Path


def build_wheel(wheel_directory, config_settings=None, metadata_directory=None):
    project = tomllib.loads(Path("pyproject.toml").read_text())["project"]
    name, version = project["name"].replace("-", "_"), project["version"]
    info = f"{name}-{version}.dist-info"
    files = {path.as_posix(): path.read_bytes() for path in Path(name).rglob("*.py")}
    files[f"{info}/METADATA"] = f"Metadata-Version: 2.1\\nName: {project['name']}\\nVersion: {version}\\n".encode()
    files[f"{info}/WHEEL"] = b"Wheel-Version: 1.0\\nGenerator: test\\nRoot-Is-Purelib: true\\nTag: py3-none-any\\n"
    files[f"{info}/entry_points.txt"] = "".join(
        f"[{group}]\\n" + "".join(f"{key} = {value}\\n" for key, value in entries.items())
        for group, entries in project["entry-points"].items()).encode()
    record = [f"{path},sha256={base64.urlsafe_b64encode(hashlib.sha256(data).digest()).rstrip(b'=').decode()},"
              f"{len(data)}" for path, data in files.items()]
    files[f"{info}/RECORD"] = "\\n".join([*record, f"{info}/RECORD,,", ""]).encode()
    wheel = f"{name}-{version}-py3-none-any.whl"
    with zipfile.ZipFile(Path(wheel_directory) / wheel, "w") as archive:
        for path, data in files.items():
            archive.writestr(path, data)
    return wheel
"""


@pytest.mark.slow
def test_a_plugin_package_installed_in_a_fresh_venv_trains_and_evaluates_from_the_command(tmp_path):
    """The whole way a lab uses it: a package that lists its module under `angora_jax.plugins` in pyproject.toml,
    pip-installed into a new venv, whose command trains a run of the plugin's task and network and evaluates it with
    nothing imported by hand. No network: the venv sees this checkout and the project's packages (pip among them)
    through a .pth file, and pip builds the plugin without build isolation, with its own in-tree backend. About 20 s
    of CPU (pip, two command processes); it found `import angora_jax` loading plugins (gym_view listed the tasks)."""
    package = tmp_path / "lab"
    (package / "lab_plugin").mkdir(parents=True)
    (package / "pyproject.toml").write_text(textwrap.dedent("""
        [build-system]
        requires = []
        build-backend = "backend"
        backend-path = ["."]

        [project]
        name = "lab-plugin"
        version = "0.1"

        [project.entry-points."angora_jax.plugins"]
        lab = "lab_plugin"
    """))
    (package / "backend.py").write_text(BACKEND)
    (package / "lab_plugin" / "__init__.py").write_text(USER_TASK + USER_NETWORK)
    env_dir = tmp_path / "venv"
    venv.create(env_dir)
    python = env_dir / "bin" / "python"
    where = "import sysconfig; print(sysconfig.get_path('purelib'))"
    site = subprocess.run([python, "-c", where], capture_output=True, text=True, check=True).stdout.strip()
    project_site = subprocess.run([sys.executable, "-c", where], capture_output=True, text=True, check=True).stdout
    (Path(site) / "project.pth").write_text(f"{ROOT}\n{project_site.strip()}\n")
    pip = [python, "-m", "pip", "install", "-q", "--no-deps", "--no-build-isolation", "--no-index", str(package)]
    done = subprocess.run(pip, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    assert list(Path(site).glob("lab_plugin-0.1.dist-info")), "installed into the new venv"
    environment = {key: value for key, value in os.environ.items() if key != "PYTHONPATH"}
    command = [python, "-m", "angora_jax.cli"]
    train = [*command, "train", "cartpole", *TINY_PPO, "ppo.num_cycles=1", "env.task=UserCartPole",
             "ppo.network.name=user_simple", f"logging.run_root={tmp_path / 'runs'}", "logging.run_name=lab",
             "logging.report=false", "logging.progress=none"]
    for argv in (train, [*command, "evaluate", str(tmp_path / "runs" / "lab"), "--episodes", "2"]):
        done = subprocess.run(argv, capture_output=True, text=True, timeout=300, env=environment, cwd=tmp_path)
        assert done.returncode == 0, done.stderr[-3000:]
    assert "episode_return" in done.stdout and read_run_config(tmp_path / "runs" / "lab").imports == ()
    check = "import angora_jax, angora_jax.registry.plugins as p; print(p._loaded)"
    done = subprocess.run([python, "-c", check], capture_output=True, text=True, env=environment)
    assert done.stdout.split() == ["False"], "import angora_jax loads no plugin"


def test_a_folder_named_like_the_module_is_named_not_taken_for_it(tmp_path, monkeypatch):
    """A folder `leaky/` where Python looks (a notebook's current folder) imported as an empty namespace package, so
    the run's own network was "unknown: list the module under imports", which the run did."""
    (tmp_path / "ghost_module_of_a_test").mkdir()
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.delitem(sys.modules, "ghost_module_of_a_test", raising=False)
    with pytest.raises(plugins.UserCodeError, match=r"'ghost_module_of_a_test' \(the run\) imported as the folder .*"
                                            r"ghost_module_of_a_test, which holds no ghost_module_of_a_test.py"):
        plugins.import_modules(["ghost_module_of_a_test"], "the run")
    sys.modules.pop("ghost_module_of_a_test", None)
