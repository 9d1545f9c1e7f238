"""Griffe extension for the API pages (mkdocs.yml): a subpackage's `__init__` re-exports names from its own modules
(its `__all__`), which the page renders again under each module, so every such class and function appeared twice.
On a subpackage's page the re-exports are not rendered; the top package's re-exports are the notebook API that its
own page (docs/api/angora_jax.md) lists, and stay."""

from __future__ import annotations

from typing import Any

import griffe


class ReexportsOnce(griffe.Extension):
    def on_package(self, *, pkg: griffe.Module, **kwargs: Any) -> None:
        for module in _subpackages(pkg):
            for member in module.members.values():
                if member.is_alias and member.target_path.startswith(f"{module.path}."):
                    member.public = False  # rendered once, under the module that defines it


def _subpackages(package: griffe.Module) -> list[griffe.Module]:
    found = []
    for module in package.modules.values():
        if module.is_init_module:
            found += [module, *_subpackages(module)]
    return found
