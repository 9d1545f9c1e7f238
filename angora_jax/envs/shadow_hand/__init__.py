"""Shadow Dexterous Hand tasks, registered as `ShadowHandReach` and `ShadowHandFreeReach`."""

from __future__ import annotations

from angora_jax.envs.core import Env
from angora_jax.envs.cpu_env import CpuEnv
from angora_jax.envs.mjx_env import MjxEnv
from angora_jax.envs.registry import register
from angora_jax.envs.shadow_hand.model import load_scene
from angora_jax.envs.shadow_hand.reach import Reach, ReachReward

BACKENDS = {"mjx": MjxEnv, "cpu": CpuEnv}


def make_reach(free: bool = False, reward: dict[str, float] | None = None, frame_skip: int = 10,
               max_episode_steps: int = 100, relative_control: bool = True, backend: str = "mjx") -> Env:
    """Build a reach task. Defaults follow AngoraPy: 10 physics steps of 2 ms per policy step (0.02 s),
    100 policy steps per episode, relative joint-target control. `backend="cpu"` gives the eager MuJoCo twin."""
    if backend not in BACKENDS:
        raise ValueError(f"Unknown backend {backend!r}; choose one of {sorted(BACKENDS)}.")
    task = Reach(load_scene("reach.xml"), ReachReward.from_dict(reward), free=free, relative_control=relative_control)
    return BACKENDS[backend](task, frame_skip=frame_skip, max_episode_steps=max_episode_steps)


def make_free_reach(**options) -> Env:
    """`make_reach(free=True, ...)`: only the thumb and the target finger need to meet."""
    return make_reach(free=True, **options)


register("ShadowHandReach", make_reach)
register("ShadowHandFreeReach", make_free_reach)
