"""`Registry`: named factories with one behaviour for tasks, networks and policy heads. Listing a registry, or asking
it for a name it does not know, first loads the installed plugins (`angora_jax.registry.plugins`), so that their
names are there."""

from __future__ import annotations

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
    """Factories by name; `kind` (e.g. "task") and `plural` name them in error messages."""

    def __init__(self, kind: str, plural: str):
        self.kind, self.plural = kind, plural
        self._factories: dict[str, F] = {}

    def register(self, name: str, factory: F) -> None:
        """Make `factory` available as `name`. A name is registered once, except by the same definition again (the
        same module and qualified name), which replaces it: a notebook cell or a reloaded module run a second time.
        A replacement changes `generation()`, so that programs compiled from the old definition are not reused."""
        global _replacements
        registered = self._factories.get(name)
        if registered is not None and definition(registered) != definition(factory):
            raise ValueError(f"{self.kind.capitalize()} {name!r} is already registered (by {definition(registered)}): "
                             "choose another name")
        if registered is not None and registered is not factory:
            _replacements += 1
        self._factories[name] = factory

    def names(self, plugins: bool = True) -> list[str]:
        """Registered names, sorted.

        Args:
            plugins: load the installed plugins first, so that their names are included (False: only the names
                registered so far).
        """
        if plugins:
            load_plugins()
        return sorted(self._factories)

    def get(self, name: str) -> F:
        """The factory registered as `name`, perhaps by an installed plugin; a ValueError lists the known names
        otherwise."""
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
