"""`MjxEnv`: a `MujocoTask` simulated with MuJoCo MJX, pure and batched (the training path)."""

from __future__ import annotations

import jax
import numpy as np
from mujoco import mjx

from angora_jax.envs.core import Sensation
from angora_jax.envs.mujoco_task import MujocoEnv, MujocoTask, Snapshot, start_physics


class MjxEnv(MujocoEnv):
    """Run `task` in MJX: each policy step applies `task.control(action)` and advances `frame_skip` physics
    steps of `task.model.opt.timestep` seconds. Actions are float32 in [-1, 1] (shape `(nu,)`)."""

    def __init__(self, task: MujocoTask, frame_skip: int, max_episode_steps: int):
        super().__init__(task, frame_skip, max_episode_steps)
        self.mjx_model = mjx.put_model(task.model)
        # A fixed start is computed once on the CPU: it spares the compiled step (with its auto-reset) a forward pass.
        fixed_qpos = None if task.random_initial_qpos else np.asarray(task.initial_qpos(jax.random.key(0)))
        self._start = mjx.put_data(task.model, start_physics(task, fixed_qpos)) if fixed_qpos is not None else None
        self._data0 = mjx.make_data(self.mjx_model)

    def _reset(self, key: jax.Array) -> tuple[mjx.Data, Sensation, dict[str, jax.Array]]:
        pose_key, task_key = jax.random.split(key)
        if self._start is None:
            data = mjx.forward(self.mjx_model, self._data0.replace(qpos=self.task.initial_qpos(pose_key)))
            data = data.replace(ctrl=self.task.initial_control(Snapshot.of(data)))
        else:
            data = self._start
        info, obs = self.task.begin(task_key, Snapshot.of(data))
        return data, obs, info

    def _step(self, physics: mjx.Data, info: dict[str, jax.Array], action: jax.Array, key: jax.Array):
        prev = Snapshot.of(physics)
        data = physics.replace(ctrl=self.task.control(action, prev))
        data = jax.lax.fori_loop(0, self.frame_skip, lambda _, d: mjx.step(self.mjx_model, d), data)
        obs, reward, terminated, info, metrics = self.task.advance(key, prev, Snapshot.of(data), info)
        return data, obs, reward, terminated, info, metrics
