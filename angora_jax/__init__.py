"""angora_jax: goal-driven sensorimotor modeling in JAX (MJX Shadow-hand tasks, recurrent PPO).

The notebook API: `make_env(task, **options)`, `load_config(path_or_name, overrides)`, `train(config)` (what
`angora-jax train` does: run directory, checkpoints, metrics, report), `load_agent(run_dir)`, `evaluate(run_dir)`
(episode statistics on the eager CPU path), `render_frames(run_dir)` (video frames), `export_policy(run_dir, file)`
and `load_policy(file)` (the policy in one file, used without the run directory; `angora-jax export` writes it too).
Each is imported when first used (lazy_loader, from __init__.pyi), so that `import angora_jax` and every `angora-jax`
command start without JAX.
"""

import lazy_loader

# First: cpu_threads sizes XLA's CPU thread pool before anything starts JAX; opengl_backend imports MuJoCo, naming a
# MUJOCO_GL that cannot load.
from angora_jax import cpu_threads, opengl_backend  # noqa: F401
from angora_jax.envs.registry import list_tasks, make, register_gymnasium_envs
from angora_jax.envs.registry import make as make_env
from angora_jax.registry import registered_by

# The rest of the API and the subpackages as attributes (`aj.experiment`), each imported when first used: __init__.pyi
# lists them, where type checkers, editors and the API pages read them. make, make_env and list_tasks are imported
# above, as envs.registry is imported anyway (register_gymnasium_envs) and lazy_loader takes no alias (`as`) from a
# stub; so the API is `__all__` below, not lazy_loader's list (which has the subpackages and not make_env).
__getattr__ = lazy_loader.attach_stub(__name__, __file__)[0]

# Lower layers read saved runs and pose estimators through readers that higher ones register when imported: name
# those modules, for the first read to import (see nets.components, envs.shadow_hand).
registered_by("angora_jax.nets.components", "angora_jax.experiment.agent")
registered_by("angora_jax.envs.shadow_hand", "angora_jax.vision.estimator")
register_gymnasium_envs()

__all__ = [
    "evaluate", "export_policy", "list_configs", "list_tasks", "load_agent", "load_config", "load_policy", "make",
    "make_env", "render_frames", "resume", "train",
]


def __dir__() -> list[str]:
    return sorted({*globals(), *__all__})
