"""angora_jax: goal-driven sensorimotor modeling in JAX (MJX Shadow-hand tasks, recurrent PPO).

The notebook API: `make_env(task, **options)`, `load_config(path_or_name, overrides)`, `train(config)` (what
`angora-jax train` does: run directory, checkpoints, metrics, report) and `load_agent(run_dir)`.
"""

from angora_jax.envs import list_tasks, make
from angora_jax.envs.gym_view import register_gymnasium_envs
from angora_jax.experiment import load_agent, load_config, resume, train

make_env = make
register_gymnasium_envs()

__all__ = ["list_tasks", "load_agent", "load_config", "make", "make_env", "resume", "train"]
