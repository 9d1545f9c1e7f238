"""Environments: the pure `reset`/`step` contract, the task registry and the tasks (each task's module is imported
when the task is first made or asked about: `registry.SHIPPED_TASKS`)."""

import lazy_loader

# The names this package gives (its __all__), each imported when first used: __init__.pyi lists them, where type
# checkers, editors and the API pages read them.
__getattr__, __dir__, __all__ = lazy_loader.attach_stub(__name__, __file__)
