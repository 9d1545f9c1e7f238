"""User code that registers tasks, networks, heads and components: modules named by a config's `imports` or the
command's `--import`, and installed plugins, the packages that list a module or a callable under the entry-point
group `angora_jax.plugins`, e.g. in their pyproject.toml:

    [project.entry-points."angora_jax.plugins"]
    thumbs_up = "thumbs_up"                # a module: importing it registers what it defines
    hand_models = "hand_models:register"   # a callable: called once, with no arguments

Plugins load the first time any registry is listed or asked for a name it does not know (`Registry`), not when
angora_jax is imported: reading the installed packages' entry points costs tens of milliseconds, and importing a
plugin may import JAX models or MuJoCo scenes, which `import angora_jax` and a command such as `angora-jax doctor`
must not pay for; every path that builds a task or network from a name (training, resuming, loading a run or an
exported policy, `aj.make`) asks a registry first, so each sees the plugins without being told."""

from __future__ import annotations

import hashlib
import importlib
import importlib.metadata
import shlex
import sys
import types
from collections.abc import Iterable
from pathlib import Path

GROUP = "angora_jax.plugins"
_loaded = False
# Module name -> the file a run read in this process recorded it was imported from when it last trained
# (`remember_files`): a module not found then is named with that file, so that a command run from another folder, or
# after the file moved, says which folder to put on PYTHONPATH instead of "/path/to/folder".
_recorded_files: dict[str, str] = {}
# Task or network name -> where a run read in this process recorded its definition (`remember_definitions`): a name
# defined in a notebook (`__main__`) is not found by a command, and its message says to move it into a module.
_recorded_definitions: dict[str, str] = {}


class UserCodeError(ValueError):
    """A module or plugin that cannot be imported or raised while importing; the message names it, where it was
    named (a config key, an option, an installed package) and the fix."""


class ModuleNameError(UserCodeError):
    """A name given as a module that no module can have (a file path, an empty name): a mistake in the setting, not
    in the code it names."""


def import_modules(names: Iterable[str], source: str) -> None:
    """Import each module of `names` (dotted names, e.g. "mytasks.hand"), so that what it defines registers.

    Args:
        names: the modules to import.
        source: where the names came from, for the message (e.g. "the config's imports").

    Raises:
        UserCodeError: a name that is not a module name (ModuleNameError), a module that is not found (put its
            folder on PYTHONPATH or install it), or a module that raises while importing (its error, named).
    """
    for name in names:
        # A file's name or path (`thumbs_up.py`, `./thumbs_up.py`) is the usual slip: "thumbs_up.py" even passes as a
        # dotted name, and Python then imports thumbs_up and fails on its submodule "py", which read "not found" with
        # the advice to put on PYTHONPATH the folder already there.
        if name.endswith(".py") or not all(part.isidentifier() for part in name.split(".")):
            raise ModuleNameError(f"{name!r} ({source}) is not a module name: {_as_module(name)}")
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as error:
            if error.name is None or not (name == error.name or name.startswith(error.name + ".")):
                raise _raised(name, source, error) from error  # the module imports something missing
            raise UserCodeError(f"Module {name!r} ({source}) is not found. {_where_to_find(name)}") from None
        except Exception as error:  # user code may raise anything while importing; each one is named
            raise _raised(name, source, error) from error
        if getattr(module, "__file__", None) is None and hasattr(module, "__path__"):
            # A folder of that name where Python looks (the current one in Python) imports as an empty namespace
            # package, and the names that the module would register are then "unknown".
            raise UserCodeError(
                f"Module {name!r} ({source}) imported as the folder {', '.join(module.__path__)}, which holds no "
                f"{name.rsplit('.', 1)[-1]}.py or __init__.py: not the module that registers your code. Run from "
                "another folder, or put the module's own folder first on PYTHONPATH.")


def module_files(names: Iterable[str]) -> dict[str, dict[str, str]]:
    """The file each imported module of `names` was loaded from and its SHA-256, for a run's session record: a later
    command that cannot find the module names that file's folder, and one that finds the file changed says so.
    Modules that are not imported, or have no file, are left out."""
    files = {}
    for name in names:
        file = getattr(sys.modules.get(name), "__file__", None)
        if file is not None and Path(file).is_file():
            files[name] = {"file": str(Path(file).resolve()),
                           "sha256": hashlib.sha256(Path(file).read_bytes()).hexdigest()}
    return files


def remember_files(files: dict[str, str]) -> None:
    """Record module name -> file, as a run's session records them (`module_files`), for the message of a module
    that is not found."""
    _recorded_files.update(files)


def remember_definitions(definitions: dict[str, str]) -> None:
    """Record task or network name -> its definition (`registry.definition`), as a run's session records them."""
    _recorded_definitions.update(definitions)


def defined_in_a_notebook(name: str) -> str:
    """The advice for a task or network `name` that is not registered here when a run read in this process recorded
    it as defined in `__main__` (a notebook or a script: no command can import it); "" otherwise."""
    where = _recorded_definitions.get(name, "")
    if not where.startswith("__main__."):
        return ""
    return (f" The run's {name!r} was defined in a notebook or script ({where}) when it trained, which a command "
            "cannot import: put that definition in a module file, give it with --import MODULE (its folder on "
            "PYTHONPATH), and list it under imports in later configs; in the notebook that defined it, "
            "aj.load_agent and aj.evaluate work as they are.")


def _root(name: str, file: Path) -> Path:
    """The folder to put on PYTHONPATH for module `name` loaded from `file` (a.b from ROOT/a/b.py, or a package's
    ROOT/a/__init__.py)."""
    folder = file.parent if file.name == "__init__.py" else file
    for _ in name.split("."):
        folder = folder.parent
    return folder


def _where_to_find(name: str) -> str:
    """The fix for module `name` that is not found: its folder, where the current folder or the run's record knows
    it, else the general advice."""
    relative = Path(*name.split("."))
    here = Path.cwd()
    if (here / relative.with_suffix(".py")).is_file() or (here / relative / "__init__.py").is_file():
        return (f"It is in the current folder, which the command does not search: run it with that folder on "
                f"PYTHONPATH (PYTHONPATH={shlex.quote(str(here))} angora-jax ...; PYTHONPATH=. from here).")
    recorded = _recorded_files.get(name)
    if recorded is not None:
        folder = _root(name, Path(recorded))
        if Path(recorded).is_file():
            return (f"The run imported it from {recorded} when it last trained: put that folder on PYTHONPATH "
                    f"(PYTHONPATH={shlex.quote(str(folder))} angora-jax ...).")
        return (f"The run imported it from {recorded} when it last trained, and that file is no longer there (moved "
                f"or deleted): put the folder that holds it now on PYTHONPATH (PYTHONPATH=/path/to/folder "
                f"angora-jax ...), or restore it there.")
    return ("Put the folder that holds it on PYTHONPATH (e.g. PYTHONPATH=/path/to/folder angora-jax ...; the current "
            "folder is not searched by the command) or pip install the package that provides it.")


def load_plugins() -> None:
    """Load every installed plugin (entry-point group `angora_jax.plugins`) once per process: import each module, or
    call each callable. Raises UserCodeError naming the plugin and its package when one fails."""
    global _loaded
    if _loaded:
        return
    _loaded = True  # before loading: a plugin that lists a registry while it is imported must not load plugins again
    for entry in importlib.metadata.entry_points(group=GROUP):
        package = entry.dist.name if entry.dist is not None else "an installed package"
        source = f"plugin {entry.name!r} of {package}, entry point {GROUP}"
        try:
            loaded = entry.load()
            if callable(loaded) and not isinstance(loaded, types.ModuleType):
                loaded()
        except Exception as error:  # as for import_modules: whatever the plugin raised, named
            raise UserCodeError(f"{_raised(entry.value, source, error)} Or uninstall it: pip uninstall {package}.") \
                from error


def _as_module(name: str) -> str:
    """What to give instead of `name`, which is no module name: for a Python file's name or path, its module name
    and the folder to put on PYTHONPATH (absolute, as the command may run from another folder later)."""
    file = Path(name)
    if file.suffix == ".py" and file.stem.isidentifier():
        folder = file.parent.resolve()
        return (f"give the module's name, {file.stem} (imports: [{file.stem}], or --import {file.stem}), with its "
                f"folder on PYTHONPATH: PYTHONPATH={shlex.quote(str(folder))} angora-jax ...")
    return ("give the dotted name Python imports (e.g. my_tasks or lab.hand_tasks, not a file path), with its folder "
            "on PYTHONPATH.")


def _raised(name: str, source: str, error: Exception) -> UserCodeError:
    return UserCodeError(f"Importing {name!r} ({source}) failed: {type(error).__name__}: {str(error).rstrip('.')}. "
                         "Fix that module "
                         "(python -c 'import " + name.split(":")[0] + "' shows where it fails).")
