"""Public names that a package's `__init__` gives without importing the modules that define them until a name is
first used (PEP 562's module `__getattr__`): importing them all up front cost `import angora_jax`, and so every
`angora-jax` command down to `--help` and a mistyped config name, about 3 s of CPU (JAX, the models, distrax with
TensorFlow Probability, Orbax, every environment).

A package declares its names as imports under `if TYPE_CHECKING:`, where type checkers, editors and the API pages
(griffe) read them, lists them in `__all__` and ends with `lazy_names(__name__)`, which reads that block from the
package's source (as scientific Python's lazy_loader reads a stub file): one list of what comes from where, not a
second one to keep in step with it."""

from __future__ import annotations

import ast
import importlib
import importlib.util
import sys
import types
from pathlib import Path
from typing import Any

# Package name -> {public name -> (module, name there)}, from each package's `if TYPE_CHECKING:` imports.
_declared: dict[str, dict[str, tuple[str, str]]] = {}


def lazy_names(package: str) -> None:
    """Give the package `package` (its `__init__` calls this last) the names it imports under `if TYPE_CHECKING:`,
    each imported from its module when first used; `dir()` lists them with the rest."""
    module = sys.modules[package]
    _declared[package] = declared_imports(Path(module.__file__).read_bytes())
    module.__class__ = _LazyPackage


def declared_imports(source: str | bytes) -> dict[str, tuple[str, str]]:
    """{name -> (module, name there)} of the `from module import name [as name]` statements in the top-level
    `if TYPE_CHECKING:` blocks of `source`."""
    found = {}
    for node in ast.parse(source).body:
        if isinstance(node, ast.If) and ast.unparse(node.test) == "TYPE_CHECKING":
            for statement in node.body:
                if isinstance(statement, ast.ImportFrom) and statement.module:
                    found.update({alias.asname or alias.name: (statement.module, alias.name)
                                  for alias in statement.names})
    return found


def _imported(package: str, name: str) -> Any:
    module, attribute = _declared[package][name]
    return getattr(importlib.import_module(module), attribute)


class _LazyPackage(types.ModuleType):
    """A package whose declared names are imported when first asked for."""

    def __getattr__(self, name: str) -> Any:  # only for names not set on the package yet
        if name in _declared[self.__name__]:
            value = _imported(self.__name__, name)
            setattr(self, name, value)  # later uses find it at once
            return value
        # A submodule, as `aj.experiment.Checkpoints` found it when `import angora_jax` imported every layer.
        if (name.isidentifier() and not name.startswith("__")
                and importlib.util.find_spec(f"{self.__name__}.{name}") is not None):
            return importlib.import_module(f"{self.__name__}.{name}")
        raise AttributeError(f"module {self.__name__!r} has no attribute {name!r}")

    def __dir__(self) -> list[str]:
        return sorted({*super().__dir__(), *_declared[self.__name__]})

    def __setattr__(self, name: str, value: Any) -> None:
        # Importing a submodule binds it on its package under its own name, which may be a name the package gives:
        # `angora_jax.ppo.train`, the module, over `train`, the function. An `__init__` that imported the function
        # itself bound it after the module, and so kept it; so does this.
        if (isinstance(value, types.ModuleType) and value.__name__ == f"{self.__name__}.{name}"
                and name in _declared[self.__name__]):
            value = _imported(self.__name__, name)
        super().__setattr__(name, value)
