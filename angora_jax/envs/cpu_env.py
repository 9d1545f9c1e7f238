"""`CpuEnv`: the eager twin of `MjxEnv`, for evaluation, rendering and the gymnasium view.

Physics runs in C MuJoCo (`mujoco.mj_step` on one `MjData`, float64); task logic is the very same
`MujocoTask` functions as on the MJX path, jitted once for a single environment. PRNG keys are split exactly as
in `Env.reset`/`Env.advance`, so the same key gives the same goals on both paths.
"""

from __future__ import annotations

import copy
from collections.abc import Callable

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from angora_jax.envs.cameras import HostCameras
from angora_jax.envs.core import Env, Sensation, State
from angora_jax.envs.mjx_env import MjxEnv
from angora_jax.envs.mujoco_task import MujocoEnv, MujocoTask, Snapshot, start_physics, step_physics


class CpuEnv(MujocoEnv):
    """One environment of `task` on C MuJoCo. Stateful: `reset(key)` starts an episode and `step(state, action)`
    must be passed the state it returned last. It never auto-resets: call `reset` when `state.done` is 1."""

    def __init__(self, task: MujocoTask, frame_skip: int, max_episode_steps: int):
        super().__init__(task, frame_skip, max_episode_steps)
        # A randomized task scales its own copy of the model at each reset (`ModelRandomizer.write`).
        self.model = task.model if task.randomizer is None else copy.deepcopy(task.model)
        self.data = mujoco.MjData(self.model)
        self._start_qpos = jax.jit(task.start_qpos)
        self._initial_qvel = jax.jit(task.initial_qvel)
        self._begin = jax.jit(self._begin_task)
        self._advance = jax.jit(self._advance_task)
        self._control = jax.jit(self._control_task)
        self._perceive = jax.jit(task.perceive)
        self._draw = None if task.randomizer is None else jax.jit(task.randomizer.draw)
        self._last: State | None = None
        # Camera vision is rendered with OpenGL from the C MuJoCo data (`envs.cameras`).
        self.cameras = None if task.vision is None else HostCameras(self.model, task.vision)

    def see(self, obs: Sensation, data: mujoco.MjData, info: dict[str, jax.Array]) -> Sensation:
        """`obs` `perceive`d with the camera frames of `data` when the task sees through cameras."""
        if self.cameras is None:
            return obs
        return self._perceive(obs, jnp.asarray(self.cameras.frames(data)), info)

    def _reset(self, key: jax.Array) -> tuple[Snapshot, Sensation, dict[str, jax.Array]]:
        pose_key, task_key = jax.random.split(key)
        factors = {}
        if self._draw is not None:  # the factors MjxEnv draws from the same key
            factors = self._draw(key)
            self.task.randomizer.write(self.model, factors)
        qvel = None  # a fixed start is at rest (`MujocoTask.initial_qvel`)
        if self.task.random_initial_qpos:
            qvel = np.asarray(self._initial_qvel(jax.random.fold_in(pose_key, 1)), np.float64)
        qpos = np.asarray(self._start_qpos(pose_key, task_key), np.float64)
        start_physics(self.task, qpos, self.data, qvel, self.model)
        snap = self.task.snapshot(self.data)
        info, obs = self._begin(key, task_key, snap, factors)
        return snap, self.see(obs, self.data, info), info

    def _step(self, physics: Snapshot, info: dict[str, jax.Array], action: jax.Array, key: jax.Array):
        ctrl, info = self._control(action, key, physics, info)
        self.data.ctrl[:] = np.asarray(ctrl, np.float64)
        step_physics(self.task, self.data, self.frame_skip, self.model)
        snap = self.task.snapshot(self.data)
        obs, reward, terminated, info, metrics = self._advance(key, physics, snap, info)
        return snap, self.see(obs, self.data, info), reward, terminated, info, metrics

    def reset(self, key: jax.Array) -> State:
        """Start an episode; `key` as for the MJX environment gives the same initial state and goal."""
        self._last = super().reset(key)
        return self._last

    def step(self, state: State, action: jax.Array) -> State:
        """Advance one policy step from `state` (the last state returned); no auto-reset."""
        if self._last is None:
            raise RuntimeError("CpuEnv.step called before reset: call env.reset(key) first.")
        if state is not self._last:
            raise ValueError("CpuEnv is stateful: pass the State returned by its last reset or step.")
        if self._last.done > 0:
            raise RuntimeError("The episode has ended (state.done == 1): call env.reset(key) first.")
        self._last, _ = self.advance(state, action)
        return self._last


def eager(env: Env) -> Env:
    """The environment to run one episode at a time on the CPU: the C MuJoCo twin of an `MjxEnv` (same task logic and
    keys), any other (pure-JAX) environment as it is."""
    return CpuEnv(env.task, env.frame_skip, env.max_episode_steps) if isinstance(env, MjxEnv) else env


def single_env_functions(env: Env) -> tuple[Callable[[jax.Array], State], Callable[..., tuple[State, jax.Array]]]:
    """`(reset, advance)` of one environment without auto-reset, ready to call eagerly: a `CpuEnv`'s own (its physics
    are C MuJoCo), a pure-JAX environment's jitted."""
    if isinstance(env, CpuEnv):
        return env.reset, env.advance
    return jax.jit(env.reset), jax.jit(env.advance)
