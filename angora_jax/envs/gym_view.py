"""A `gymnasium.Env` view of every task, for third-party agents and tools.

MuJoCo tasks run on the eager C MuJoCo twin (`CpuEnv`, same task logic and keys as the MJX path); pure-JAX tasks
run their own functions, jitted for one environment. Ids are `AngoraJax/<Task>-v0`, e.g.
`gymnasium.make("AngoraJax/ShadowHandReach-v0", render_mode="rgb_array")`; keyword arguments go to the task.
"""

from __future__ import annotations

from typing import Any

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np

from angora_jax.envs.core import MODALITIES, Env, State, is_image
from angora_jax.envs.cpu_env import CpuEnv, eager, single_env_functions

# NAMESPACE and register_gymnasium_envs, once defined here, are found here still: envs.registry holds them, so that
# `import angora_jax` registers the tasks' ids without importing this view and JAX.
from angora_jax.envs.registry import NAMESPACE, make, register_gymnasium_envs  # noqa: F401
from angora_jax.envs.rendering import SceneRenderer, camera_named, check_pixels


class GymEnv(gymnasium.Env):
    """One environment of `task` behind the gymnasium API.

    Observations are a dict with one float32 array per non-empty Sensation modality (`asymmetric` holds the
    privileged value inputs; an agent may ignore it), except camera images: `vision` of a task with the `vision`
    option is uint8 `(cameras, height, width, channels)`. `info` holds the task metrics of the step. With
    `render_mode="rgb_array"`, `render()` returns a `(height, width, 3)` uint8 frame from the named `camera` of
    `rendering.CAMERAS`, which looks at the task's `camera_body` (the palm for hand tasks; MuJoCo tasks only).
    """

    metadata = {"render_modes": ["rgb_array"]}

    def __init__(self, task: str, render_mode: str | None = None, width: int = 320, height: int = 240,
                 camera: str = "front", **options: Any):
        check_pixels(width, height)
        self._task = task
        self._env: Env = eager(make(task, **options))
        self._eager = isinstance(self._env, CpuEnv)
        self._reset, self._advance = single_env_functions(self._env)
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}.")
        if render_mode and not self._eager:
            raise ValueError(f"Task {task!r} has no MuJoCo scene to render; use render_mode=None.")
        self.render_mode = render_mode
        self.metadata = {**self.metadata, "render_fps": round(1.0 / self._env.dt)}
        self._camera = camera_named(camera)
        self._size = (width, height)
        self._renderer: SceneRenderer | None = None
        self._state: State = self._reset(jax.random.key(0))
        self._modalities = [m for m in MODALITIES if getattr(self._state.obs, m).shape[-1] > 0]
        self.observation_space = gymnasium.spaces.Dict(
            {m: _space(getattr(self._state.obs, m)) for m in self._modalities})
        spec = self._env.action_spec
        self.action_space = (gymnasium.spaces.Discrete(spec.num_actions) if spec.discrete else
                             gymnasium.spaces.Box(np.asarray(spec.low), np.asarray(spec.high), dtype=np.float32))

    def _observation(self) -> dict[str, np.ndarray]:
        return {m: np.asarray(getattr(self._state.obs, m), self.observation_space[m].dtype) for m in self._modalities}

    def _info(self) -> dict[str, float]:
        return {name: float(value) for name, value in self._state.metrics.items()}

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        self._state = self._reset(jax.random.key(int(self.np_random.integers(2**31))))
        return self._observation(), self._info()

    def step(self, action):
        if isinstance(self.action_space, gymnasium.spaces.Discrete) and not self.action_space.contains(
                np.asarray(action)):  # the task would step as some valid action: jnp's int casts and indexing clip
            space = self.action_space
            raise ValueError(f"{self._task} takes one of the actions {space.start} to {space.start + space.n - 1} (its "
                             f"action_space is Discrete({space.n})), got {action!r}.")
        if isinstance(self.action_space, gymnasium.spaces.Box) and not np.isfinite(
                np.asarray(action, np.float64)).all():  # a NaN action makes a NaN physics state for every later step
            raise ValueError(f"{self._task} takes actions of finite numbers within its action_space "
                             f"{self.action_space}, got {action!r}.")
        self._state, _ = self._advance(self._state, jnp.asarray(action))
        terminated = bool(self._state.done) and not bool(self._state.truncated)
        return (self._observation(), float(self._state.reward), terminated, bool(self._state.truncated),
                self._info())

    def render(self) -> np.ndarray | None:
        if self.render_mode is None:
            return None
        if self._renderer is None:
            self._renderer = SceneRenderer(self._env.model, self._env.task.camera_body, self._camera, *self._size)
        return self._renderer.render(self._env.data)

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None


def _space(modality: Any) -> gymnasium.spaces.Box:
    if is_image(modality):
        return gymnasium.spaces.Box(0, 255, modality.shape, np.uint8)
    return gymnasium.spaces.Box(-np.inf, np.inf, modality.shape, np.float32)

