"""The API pages (docs/api/, mkdocstrings through griffe) render each class and function once: a subpackage's
`__init__` re-exports names of its own modules, which its page would show beside those modules, so
docs/tools/griffe_reexports.py leaves them to the modules; the top package's page lists its re-exports, the notebook
API. The strict site build (tests/test_docs.py, slow tier) renders the pages; this checks the rule in a second."""

import sys
from pathlib import Path

import griffe

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "docs" / "tools"))

from griffe_reexports import ReexportsOnce  # noqa: E402


def shown_twice(package: griffe.Module) -> list[str]:
    """Public names of a subpackage (at any depth) that its own modules define: rendered twice on its page."""
    found = []
    for module in package.modules.values():
        if module.is_init_module:
            found += [f"{module.path}.{name}" for name, member in module.members.items() if member.is_alias
                      and member.is_public and member.target_path.startswith(f"{module.path}.")]
            found += shown_twice(module)
    return found


def test_each_object_is_rendered_once_and_the_top_package_keeps_its_api():
    assert "griffe_reexports.py:ReexportsOnce" in (ROOT / "mkdocs.yml").read_text()
    plain = griffe.load("angora_jax", search_paths=[str(ROOT)])
    assert "angora_jax.experiment.Agent" in shown_twice(plain)  # what the pages showed before the extension
    package = griffe.load("angora_jax", search_paths=[str(ROOT)], extensions=griffe.load_extensions(ReexportsOnce()))
    assert shown_twice(package) == []
    assert package["load_agent"].is_public and package["train"].is_public
