"""`Registry`: named factories with one behaviour for tasks, networks and policy heads. Listing a registry, or asking
it for a name it does not know, first loads the installed plugins (`angora_jax.registry.plugins`), so that their
names are there. The names a package ships may be declared with the module that registers them, which is imported
only when one of them is asked for; and a module of a lower layer that reads what a higher one registers may be
given the module that registers it (`registered_by`), imported when it is first needed."""

from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import Generic, TypeVar

from angora_jax.registry.plugins import load_plugins
from angora_jax.wording import did_you_mean

F = TypeVar("F", bound=Callable)

# How many times a registered name has been given another definition in this process (a notebook cell run again
# after an edit, a reloaded module). Caches of built or compiled programs key on it beside the config: the config
# names a task or network, not its code, and a program traced from the old definition would otherwise be reused.
_replacements = 0


def generation() -> int:
    """A number that changes whenever a task, network or head registered under a name is replaced by another
    definition in this process: part of the key of every cache of programs built from registered factories."""
    return _replacements


class Registry(Generic[F]):
    """Factories by name; `kind` (e.g. "task") and `plural` name them in error messages. `shipped` maps the names that
    the package itself registers to the module that registers each (`{"CartPole": "angora_jax.envs.classic"}`): they
    are listed without importing anything, and a module is imported when one of its names is first asked for, so that
    listing the tasks (a config's did-you-mean, the Gymnasium ids that `import angora_jax` registers) imports no
    environment, and making CartPole imports no hand."""

    def __init__(self, kind: str, plural: str, shipped: dict[str, str] | None = None):
        self.kind, self.plural = kind, plural
        self._factories: dict[str, F] = {}
        self._shipped = shipped or {}
        # Apart from `_factories`: a shipped module registers its names once per process, when it is first imported,
        # so they must outlive a copy of `_factories` put back over them (a test's, after a module it ran registered).
        self._shipped_factories: dict[str, F] = {}

    def register(self, name: str, factory: F) -> None:
        """Make `factory` available as `name`. A name is registered once, except by the same definition again (the
        same module and qualified name), which replaces it: a notebook cell or a reloaded module run a second time.
        A replacement changes `generation()`, so that programs compiled from the old definition are not reused."""
        global _replacements
        factories = self._factories
        if name in self._shipped:
            factories = self._shipped_factories
            if name not in factories:  # its module registers it first, and another definition is refused below
                importlib.import_module(self._shipped[name])  # nothing new when this call is that module's own
            if name not in factories:
                factories[name] = factory
                return
        registered = factories.get(name)
        if registered is not None and definition(registered) != definition(factory):
            raise ValueError(f"{self.kind.capitalize()} {name!r} is already registered (by {definition(registered)}): "
                             "choose another name")
        if registered is not None and registered is not factory:
            _replacements += 1
        factories[name] = factory

    def names(self, plugins: bool = True) -> list[str]:
        """Registered names, sorted, the shipped ones included without importing their modules.

        Args:
            plugins: load the installed plugins first, so that their names are included (False: only the names
                registered so far).
        """
        if plugins:
            load_plugins()
        return sorted({*self._factories, *self._shipped})

    def get(self, name: str) -> F:
        """The factory registered as `name`, perhaps by an installed plugin or a shipped module, imported now; a
        ValueError lists the known names otherwise."""
        if name in self._shipped:
            if name not in self._shipped_factories:
                importlib.import_module(self._shipped[name])
            return self._shipped_factories[name]
        if name not in self._factories:
            load_plugins()
        try:
            return self._factories[name]
        except KeyError:
            names = self.names()
            raise ValueError(f"Unknown {self.kind} {name!r}.{did_you_mean(name, names)} Known {self.plural}: "
                             f"{', '.join(names)}.") from None


def definition(factory: Callable) -> str:
    """Where `factory` was defined: module and qualified name (a lambda's is `<lambda>` in its function or module)."""
    return f"{getattr(factory, '__module__', '?')}.{getattr(factory, '__qualname__', type(factory).__qualname__)}"


# A lower layer's module that reads what a higher one registers with it (the run-directory reader of
# nets.components, the pose estimator reader of envs.shadow_hand) -> the module whose import registers it. The
# package's `__init__` names these modules here instead of importing them (Orbax and the checkpoints, the pose
# network: a second of every `angora-jax` command); the reader imports its registrar the first time it finds nothing
# registered (`import_registrar`).
_registrars: dict[str, str] = {}


def registered_by(reader: str, registrar: str) -> None:
    """Name the module `registrar` as the one whose import registers what the module `reader` reads."""
    _registrars[reader] = registrar


def import_registrar(reader: str) -> None:
    """Import the module named to register what the module `reader` reads (`registered_by`), if one is."""
    if reader in _registrars:
        importlib.import_module(_registrars[reader])
