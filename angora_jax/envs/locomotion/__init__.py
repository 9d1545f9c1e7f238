"""Gymnasium's MuJoCo tasks (v5) on MJX: `Hopper`, `Walker2d`, `HalfCheetah`, `Swimmer`, `Ant`, `Humanoid`,
`InvertedPendulum`, `InvertedDoublePendulum`, `Reacher` (see `tasks`). Each runs batched on MJX (MuJoCo Warp on a GPU
with warp-lang) or, with `backend="cpu"`, as its eager C MuJoCo twin."""

from __future__ import annotations

import functools

from angora_jax.envs.backends import on_backend
from angora_jax.envs.core import Env
from angora_jax.envs.locomotion.tasks import (
    GAITS,
    GymnasiumTask,
    InvertedDoublePendulum,
    InvertedPendulum,
    Locomotion,
    Reacher,
)
from angora_jax.envs.registry import register

# Policy steps per episode, as Gymnasium's registrations (`gymnasium.make(...).spec.max_episode_steps`).
EPISODE_STEPS = {"Reacher": 50}
OTHERS = {"InvertedPendulum": InvertedPendulum, "InvertedDoublePendulum": InvertedDoublePendulum, "Reacher": Reacher}


def make_locomotion(name: str, max_episode_steps: int | None = None, impl: str = "auto",
                    backend: str = "mjx", solver: str | None = None) -> Env:
    """Gymnasium's task `name` (v5).

    Args:
        max_episode_steps: None for Gymnasium's (1000; Reacher 50).
        impl: the MJX implementation ("auto": Warp on a GPU when warp-lang imports, else JAX).
        backend: "mjx" or "cpu".
        solver: the constraint solver of the forward-moving tasks (`GAITS`), "newton", "cg" or "pgs" (None: the task's,
            which is Gymnasium's but Newton for Humanoid; MJX has no PGS: "pgs" needs "cpu").
    """
    if solver is not None and name not in GAITS:
        raise ValueError(f"{name} takes no solver option; only {', '.join(GAITS)} do.")
    if solver == "pgs" and backend == "mjx":
        raise ValueError("MJX has no PGS solver (it has Newton and CG): solver='pgs' runs with backend='cpu' only.")
    task: GymnasiumTask = Locomotion(GAITS[name], impl, solver) if name in GAITS else OTHERS[name](impl)
    steps = EPISODE_STEPS.get(name, 1000) if max_episode_steps is None else max_episode_steps
    return on_backend(backend, task, task.frame_skip, steps)


for _name in [*GAITS, *OTHERS]:
    register(_name, functools.partial(make_locomotion, _name))

__all__ = ["make_locomotion"]
