# The names angora_jax.envs gives (its __all__), each imported when first used: lazy_loader.attach_stub in
# __init__.py reads the imports here; type checkers, editors and the API pages read the imports and __all__.
from .core import ActionSpec, Env, Sensation, State
from .registry import list_tasks, make, register

__all__ = ["ActionSpec", "Env", "Sensation", "State", "list_tasks", "make", "register"]
