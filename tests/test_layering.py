"""The packages form layers, and each imports only its own and those below it, at import time or inside a function: envs
-> nets -> ppo -> experiment -> vision -> analysis (it looks inside agents and pose estimators) -> the package's
public API (its `__init__`) -> cli, with angora_jax.registry, angora_jax.whole_files (result files written whole or
not at all, which networks' component files need too), angora_jax.saved_files (which kind of saved file a file is,
for messages in every layer), angora_jax.wording (did-you-mean hints and count words, for messages in every layer,
below registry too, whose refusals use it) and angora_jax.cpu_threads (XLA's CPU thread pool, sized before JAX
starts) below all. Where a lower layer needs something of a higher one (reading a saved run's policy for `init_from`,
reading a pose estimator file for the cube), the higher one registers it with the lower
(`nets.components.register_run_reader`, `envs.shadow_hand.register_pose_estimator_reader`), and the package's
`__init__` names the higher module for the lower one to import at its first read (`registry.registered_by`). Inside a
layer, no modules import each other in a circle (what two need of each other goes into a module below both). Imports
under `if TYPE_CHECKING:` are not counted: for type hints they never run. A package's public names come from its
`__init__.pyi` stub (lazy_loader imports each when first used, from its own modules: checked below)."""

import ast
import importlib
import subprocess
import sys
import textwrap
import types
from pathlib import Path

import pytest

import angora_jax

# "api": the package itself (`import angora_jax as aj`), the public API its __init__ gathers.
LAYERS = {"wording": -1, "registry": 0, "whole_files": 0, "saved_files": 0, "opengl_backend": 0, "cpu_threads": 0,
          "frozen_settings": 0, "envs": 1, "nets": 2, "ppo": 3, "experiment": 4, "vision": 5,
          "analysis": 6, "api": 7, "cli": 8}
PACKAGE = Path(angora_jax.__file__).parent


def runtime_imports(tree: ast.AST) -> list[tuple[int, str, tuple[str, ...]]]:
    """(line, module, names) of every `angora_jax...` import in `tree` outside `if TYPE_CHECKING:` blocks, at the top
    or inside a function; names: what `from module import ...` takes (empty for `import module`)."""
    found = []

    def visit(node: ast.AST) -> None:
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            for child in node.orelse:
                visit(child)
            return
        if isinstance(node, ast.Import):
            found.extend((node.lineno, alias.name, ()) for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            found.append((node.lineno, node.module, tuple(alias.name for alias in node.names)))
        for child in ast.iter_child_nodes(node):
            visit(child)

    visit(tree)
    return [found_import for found_import in found if found_import[1].split(".")[0] == "angora_jax"]


def layer_of(module: str) -> str:
    """The layer of `angora_jax.X...` (X a package or a top-level module); "api" for the package itself."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "api"


def test_every_package_imports_only_its_own_and_lower_layers():
    files = sorted(PACKAGE.rglob("*.py"))
    assert len(files) > 50
    upward = []
    for file in files:
        relative = file.relative_to(PACKAGE)
        if relative.as_posix() == "__init__.py":
            continue
        source = relative.parts[0].removesuffix(".py")
        assert source in LAYERS, f"{relative}: a new package; give it a layer in LAYERS"
        for line, module, _ in runtime_imports(ast.parse(file.read_text(), str(file))):
            target = layer_of(module)
            assert target in LAYERS, f"{relative}:{line} imports {module}, outside every layer"
            if target != source and LAYERS[target] >= LAYERS[source]:
                upward.append(f"{relative}:{line} ({source}) imports {module} ({target})")
    assert not upward, "imports of a layer from one not above it:\n" + "\n".join(upward)


def test_the_check_sees_upward_imports_in_functions_and_ignores_type_hints():
    tree = ast.parse("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from angora_jax.ppo import config\n"
                     "def f():\n    from angora_jax.experiment.agent import saved_policy\n"
                     "import angora_jax.envs.core\n")
    assert runtime_imports(tree) == [(5, "angora_jax.experiment.agent", ("saved_policy",)),
                                     (6, "angora_jax.envs.core", ())]
    assert layer_of("angora_jax.registry") == "registry" and layer_of("angora_jax") == "api"


def module_name(file: Path) -> str:
    """The dotted name of a file of the package: `angora_jax.experiment.agent`; a package's `__init__` is the
    package."""
    parts = file.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def import_graph(trees: dict[str, ast.AST]) -> dict[str, set[str]]:
    """module -> the modules of `trees` it imports at run time (`runtime_imports`). `from package import name` imports
    the module `package.name` where there is one, else the package (its `__init__`)."""
    graph = {}
    for module, tree in trees.items():
        imported = set()
        for _, target, names in runtime_imports(tree):
            submodules = {f"{target}.{name}" for name in names} & trees.keys()
            imported |= submodules or ({target} & trees.keys())
            if len(submodules) < len(names):  # some names are the package's (or module's) own
                imported |= {target} & trees.keys()
        graph[module] = imported - {module}
    return graph


def find_circle(graph: dict[str, set[str]]) -> list[str] | None:
    """One circle of `graph` as `[a, b, ..., a]` (a imports b, ..., which imports a), or None when there is none:
    a depth-first search that stops at the first import back into the path it is on."""
    done: set[str] = set()

    def search(module: str, path: list[str]) -> list[str] | None:
        for target in sorted(graph[module]):
            if target in path:
                return [*path[path.index(target):], target]
            if target not in done:
                circle = search(target, [*path, target])
                if circle:
                    return circle
        done.add(module)
        return None

    for module in sorted(graph):
        circle = None if module in done else search(module, [module])
        if circle:
            return circle
    return None


def test_no_modules_import_each_other_in_a_circle():
    trees = {module_name(file): ast.parse(file.read_text(), str(file)) for file in sorted(PACKAGE.rglob("*.py"))}
    graph = import_graph(trees)
    assert "angora_jax.experiment.programs" in graph["angora_jax.experiment.agent"]
    circle = find_circle(graph)
    assert circle is None, ("modules import each other in a circle (move what they need of each other into a module "
                            "below them): " + " -> ".join(circle or []))


def test_the_circle_check_sees_function_level_imports_and_ignores_type_hints():
    sources = {
        "angora_jax.p": "",
        "angora_jax.p.a": "from angora_jax.p import b\n",
        "angora_jax.p.b": "def f():\n    from angora_jax.p.c import g\n",
        "angora_jax.p.c": "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from angora_jax.p.a import h\n",
    }
    trees = {module: ast.parse(source) for module, source in sources.items()}
    graph = import_graph(trees)
    assert graph == {"angora_jax.p": set(), "angora_jax.p.a": {"angora_jax.p.b"}, "angora_jax.p.b": {"angora_jax.p.c"},
                     "angora_jax.p.c": set()}
    assert find_circle(graph) is None
    trees["angora_jax.p.c"] = ast.parse("import angora_jax.p.a\n")
    assert find_circle(import_graph(trees)) == ["angora_jax.p.a", "angora_jax.p.b", "angora_jax.p.c", "angora_jax.p.a"]
    trees["angora_jax.p.c"] = ast.parse("from angora_jax.p import X\n")  # a name the package's __init__ holds
    trees["angora_jax.p"] = ast.parse("from angora_jax.p.a import X\n")
    assert find_circle(import_graph(trees)) == ["angora_jax.p", "angora_jax.p.a", "angora_jax.p.b", "angora_jax.p.c",
                                                "angora_jax.p"]


def test_lower_layers_read_runs_and_estimators_through_the_readers_the_higher_ones_registered(monkeypatch):
    from angora_jax.envs import shadow_hand
    from angora_jax.experiment.agent import saved_policy
    from angora_jax.nets import components
    from angora_jax.vision.estimator import PoseEstimator

    assert components._run_reader is saved_policy and shadow_hand._pose_estimator_reader == PoseEstimator.load
    monkeypatch.setattr(components, "_run_reader", None)
    monkeypatch.setattr(shadow_hand, "_pose_estimator_reader", None)
    with pytest.raises(RuntimeError, match="needs angora_jax.experiment, which registers the run-directory reader"):
        components.read_saved_run("runs/x:latest")
    with pytest.raises(RuntimeError, match="needs angora_jax.vision, which registers the reader"):
        shadow_hand.read_pose_estimator("estimator.pose.msgpack")


def test_the_package_and_the_command_load_mujoco_mjx_only_when_a_task_needs_it():
    """`mujoco.mjx` (MuJoCo Warp's import with it) is most of the package's import time: the package, the command and
    a CartPole environment start without it; a hand task loads it."""
    check = ("import sys, angora_jax as aj, angora_jax.cli; aj.make('CartPole'); print('mujoco.mjx' in sys.modules); "
             "aj.make('ShadowHandReach'); print('mujoco.mjx' in sys.modules)")
    done = subprocess.run([sys.executable, "-c", check], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.split() == ["False", "True"], done.stdout


def stub_imports(stub: Path) -> tuple[dict[str, str], set[str], set[str], list[str] | None]:
    """({name -> module it comes from}, {subpackages}, {aliases}, its `__all__`) of a package's `__init__.pyi`:
    lazy_loader.attach_stub reads `from .module import name` and `from . import subpackage` (`name as other` names
    it `other` for type checkers only); an alias, `other = name`, is for type checkers alone."""
    package, names, subpackages, aliases, listed = module_name(stub.with_suffix(".py")), {}, set(), set(), None
    for node in ast.parse(stub.read_text()).body:
        if isinstance(node, ast.Assign):
            (target,) = node.targets
            if target.id == "__all__":
                listed = ast.literal_eval(node.value)
            else:
                aliases.add(target.id)
        elif isinstance(node, ast.ImportFrom):
            assert node.level == 1, f"{stub}: lazy_loader takes relative imports only"
            if node.module:
                names.update({alias.asname or alias.name: f"{package}.{node.module}" for alias in node.names})
            else:
                subpackages.update(alias.name for alias in node.names)
    return names, subpackages, aliases, listed


def test_a_package_gives_its_public_names_from_its_own_modules_when_first_used():
    """A package's public names (its `__all__`) are the imports of its `__init__.pyi` stub, where type checkers, editors
    and the API pages read them, and lazy_loader imports each from its module when first used: a subpackage's come
    from its own modules (the top package, the public API, gathers every layer's, and gives the subpackages as
    attributes); each resolves and `dir()` lists it; the top package's make, make_env and list_tasks, imported by its
    `__init__`, are the stub's too."""
    stubs = {module_name(stub.with_suffix(".py")): stub_imports(stub) for stub in sorted(PACKAGE.rglob("__init__.pyi"))}
    assert {f"angora_jax{sub}" for sub in ("", ".envs", ".experiment", ".ppo", ".vision")} <= set(stubs)
    for package, (declared, subpackages, aliases, listed) in stubs.items():
        module = importlib.import_module(package)
        if package != "angora_jax":
            outside = sorted(source for source in declared.values() if not source.startswith(f"{package}."))
            assert not outside, f"{package} gives names of modules outside it: {outside}"
            assert not subpackages, package
        assert sorted(module.__all__) == sorted({*declared, *aliases}) == sorted(listed or module.__all__), package
        for name in module.__all__:
            value = getattr(module, name)
            assert not isinstance(value, types.ModuleType) and name in dir(module), f"{package}.{name}"
        for name in subpackages:
            assert getattr(module, name) is importlib.import_module(f"{package}.{name}"), f"{package}.{name}"


def test_the_package_and_the_command_import_jax_and_the_tasks_only_when_used():
    """`import angora_jax` and the command's parser (every command, `--help` and a mistyped verb among them) import
    neither JAX nor distrax, Orbax or a task: the shipped tasks are listed, and their Gymnasium ids registered, from
    `envs.registry.SHIPPED_TASKS`; making one imports its module alone; a submodule named as a public name of its
    package (`angora_jax.ppo.train`) leaves the name to the function; a lower layer's reader imports the module that
    registers it (`registry.registered_by`); and each shipped task is registered by the module the table names."""
    check = textwrap.dedent("""
        import importlib, sys
        import gymnasium
        import angora_jax as aj, angora_jax.cli
        from angora_jax.envs.registry import SHIPPED_TASKS, TASKS
        angora_jax.cli.parser()
        heavy = ("jax", "distrax", "orbax.checkpoint", "angora_jax.experiment.config", "angora_jax.envs.classic")
        print([module for module in heavy if module in sys.modules])
        ids = {id for id in gymnasium.registry if id.startswith("AngoraJax/")}
        print(TASKS.names(plugins=False) == sorted(SHIPPED_TASKS), ids == {f"AngoraJax/{t}-v0" for t in SHIPPED_TASKS})
        aj.make("CartPole")
        print("angora_jax.envs.classic" in sys.modules, "angora_jax.envs.shadow_hand" in sys.modules)
        import angora_jax.ppo.train
        from angora_jax.ppo import train
        print(train is sys.modules["angora_jax.ppo.train"].train)
        from angora_jax.nets import components
        try:
            components.read_saved_run("no_such_run")
        except Exception as error:
            print(type(error).__name__, "angora_jax.experiment.agent" in sys.modules)
        for module in dict.fromkeys(SHIPPED_TASKS.values()):
            importlib.import_module(module)
            print(all(name in TASKS._shipped_factories for name, by in SHIPPED_TASKS.items() if by == module))
        print(sorted(TASKS._shipped_factories) == sorted(SHIPPED_TASKS), TASKS._factories)
    """)
    done = subprocess.run([sys.executable, "-c", check], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.splitlines() == ["[]", "True True", "True False", "True", "FileNotFoundError True",
                                        "True", "True", "True", "True", "True {}"], done.stdout
