"""`EagerBatch`: several environments of one task on the eager CPU path, stepped together.

For a MuJoCo task each slot is a C MuJoCo twin (an `MjData` of its own, stepped with plain `mujoco.mj_step`, in a
thread pool when `workers > 1`: `mj_step` releases the GIL), while the task logic of all slots (action to `ctrl`, then
observation, reward, termination) runs as one jitted call per step, the same `MujocoTask` functions as on the MJX
path. A pure-JAX task steps all slots with one jitted call of its `advance`. Slots never auto-reset: the
caller starts a new episode in a slot with `reset(slot, key)`, exactly as `Env.reset(key)` would.

Each slot is computed on its own (`rowwise` functions, separate `MjData`), so a slot's episode does not depend on
the batch size, the other slots or the number of threads.
"""

from __future__ import annotations

import copy
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from angora_jax.envs.core import Env, State, step_keys
from angora_jax.envs.cpu_env import CpuEnv, eager
from angora_jax.envs.mujoco_task import MujocoEnv, Snapshot, step_physics
from angora_jax.envs.randomization import INFO_KEY


def rowwise(fn: Callable[..., Any]) -> Callable[..., Any]:
    """`fn` of one row (no batch axis) applied to every row of its arguments' leading axis, as one XLA loop
    (`lax.map`), for use inside `jax.jit`.

    Unlike `vmap` it runs the very same program for each row whatever the number of rows: under `vmap` XLA chooses
    matrix kernels by batch size, and their roundings differ (a policy's actions change in the last bits between a
    batch of 1 and of 64), which would make an episode depend on how many ran beside it.
    """
    def mapped(*batched: Any) -> Any:
        return jax.lax.map(lambda row: fn(*row), batched)

    return mapped


class _AfterPhysics(MujocoEnv):
    """`Env.advance` around physics that were already stepped in C MuJoCo: `state.physics` is the pair (snapshot at
    the step's start, snapshot at its end). Key splits, time limits and truncation thus stay those of `Env`."""

    def _reset(self, key: jax.Array):
        raise NotImplementedError("_AfterPhysics only finishes steps; CpuEnv.reset starts episodes.")

    def _step(self, physics: tuple[Snapshot, Snapshot], info, action, key):
        before, after = physics
        obs, reward, terminated, info, metrics = self._advance_task(key, before, after, info)
        return after, obs, reward, terminated, info, metrics


def _insert(batch: State, one: State, slot: jax.Array) -> State:
    return jax.tree.map(lambda b, o: b.at[slot].set(o), batch, one)


def batch_functions(env: Env) -> tuple[Env, dict[str, Callable[..., Any]]]:
    """The environment an `EagerBatch` of `env` steps (`eager(env)`) and its jitted calls: pass them to several
    batches (`EagerBatch(..., compiled=)`) and they compile once."""
    env = eager(env)
    functions = {"insert": jax.jit(_insert)}
    if isinstance(env, CpuEnv):
        after_physics = _AfterPhysics(env.task, env.frame_skip, env.max_episode_steps)

        def control(state: State, action: jax.Array) -> tuple[jax.Array, dict[str, jax.Array]]:
            step_key = step_keys(state.key)[1]  # the key `Env.advance` gives the step (action noise)
            return env._control_task(env.check_action(action), step_key, state.physics, state.info)

        def finish(state: State, action: jax.Array, after: Snapshot) -> State:
            return after_physics.advance(state.replace(physics=(state.physics, after)), action)[0]

        def perceive(state: State, frames: jax.Array) -> State:
            obs = env.task.perceive(state.obs, frames, state.info)
            return state.replace(obs=obs, final_obs=obs)  # slots never auto-reset: both show the same physics

        functions |= {"reset": env.reset, "control": jax.jit(rowwise(control)), "finish": jax.jit(rowwise(finish)),
                      "perceive": jax.jit(rowwise(perceive))}
    else:
        functions |= {"reset": jax.jit(env.reset), "advance": jax.jit(rowwise(lambda s, a: env.advance(s, a)[0]))}
    return env, functions



class EagerBatch:
    """`size` slots of `env` (an `MjxEnv`, run on its C MuJoCo twin, or a pure-JAX env) stepped together.

    states: the slots' current `State`s, leaves with a leading axis `(size, ...)` (None before the first reset).
    workers: threads that step the C MuJoCo physics of the slots (1: in this thread; at most `size`); pure-JAX tasks
        use none.
    compiled: `batch_functions(env)` made earlier, to share its compiled calls between batches (None: made here).
    Use it as a context manager, or call `close()`, to stop the threads.
    """

    def __init__(self, env: Env, size: int, workers: int = 1,
                 compiled: tuple[Env, dict[str, Callable[..., Any]]] | None = None):
        if size < 1 or workers < 1:
            raise ValueError(f"size and workers must be >= 1, got size={size}, workers={workers}.")
        self.env, functions = batch_functions(env) if compiled is None else compiled
        self.size = size
        self.states: State | None = None
        # The slots' states live on the host CPU, committed there, so the jitted calls run on it on a GPU machine too
        # (and compile once rather than again when uncommitted arrays turn committed).
        self.device = jax.devices("cpu")[0]
        self._insert, self._reset_one = functions["insert"], functions["reset"]
        if isinstance(self.env, CpuEnv):
            self._control, self._finish = functions["control"], functions["finish"]
            self._perceive = functions["perceive"]
            self.datas = [mujoco.MjData(self.env.model) for _ in range(size)]
            # A randomized task's slots each simulate their own world (`CpuEnv` draws it at reset).
            randomized = self.env.task.randomizer is not None
            self.models = [copy.deepcopy(self.env.model) if randomized else self.env.model for _ in range(size)]
            self.workers = min(workers, size)
        else:
            self._advance = functions["advance"]
            self.datas = []
            self.workers = 1
        self._pool = ThreadPoolExecutor(self.workers, thread_name_prefix="mj_step") if self.workers > 1 else None

    def reset(self, slot: int, key: jax.Array) -> None:
        """Start a new episode in `slot` from `key` (the state `env.reset(key)` gives)."""
        state = jax.device_put(self._reset_one(key), self.device)
        if self.datas:
            mujoco.mj_copyData(self.datas[slot], self.env.model, self.env.data)
            if self.env.task.randomizer is not None:
                self.env.task.randomizer.write(self.models[slot], state.info[INFO_KEY])
        if self.states is None:
            self.states = jax.tree.map(lambda x: jnp.stack([x] * self.size), state)
        else:
            self.states = self._insert(self.states, state, int(slot))  # one compiled program for any int type

    def step(self, actions: jax.Array, active: np.ndarray) -> State:
        """Advance every slot by one policy step with `actions` (`(size, *action_shape)`) and return the new `states`.

        Slots that end (`done == 1`) stay ended until `reset`.

        Args:
            actions: one action per slot, `(size, *action_shape)`.
            active: `(size,)` bool; the physics of inactive slots (finished, nothing left to run) are not stepped and
                their new states are meaningless.
        """
        if self.states is None:
            raise RuntimeError("EagerBatch.step called before reset: start an episode in every slot first.")
        if not self.datas:
            self.states = self._advance(self.states, actions)
            return self.states
        ctrl, info = self._control(self.states, actions)
        ctrl = np.asarray(ctrl, np.float64)
        self.states = self.states.replace(info=info)  # the action delay's state, advanced
        slots = np.flatnonzero(active)
        if self._pool is None:
            self._step_physics(ctrl, slots)
        else:
            list(self._pool.map(lambda chunk: self._step_physics(ctrl, chunk), np.array_split(slots, self.workers)))
        # Converted to float32 in numpy (the same rounding as `Snapshot.of`), which costs far less than ten JAX calls.
        fields = self.env.task.snapshot_fields
        after = Snapshot(**{f: np.array([getattr(d, f) for d in self.datas], np.float32) for f in fields})
        self.states = self._finish(self.states, actions, after)
        if self.env.cameras is not None:
            # Only stepped slots are rendered (the states of the others are meaningless, see above).
            frames = np.zeros((self.size, *self.env.task.vision.frame_shape), np.uint8)
            for slot in slots:
                frames[slot] = self.env.cameras.frames(self.datas[slot])
            self.states = self._perceive(self.states, jax.device_put(frames, self.device))
        return self.states

    def _step_physics(self, ctrl: np.ndarray, slots: np.ndarray) -> None:
        for slot in slots:
            data = self.datas[slot]
            data.ctrl[:] = ctrl[slot]
            step_physics(self.env.task, data, self.env.frame_skip, self.models[slot])

    def physics(self, slot: int) -> mujoco.MjData:
        """The C MuJoCo data of `slot` (MuJoCo tasks only), e.g. to render it."""
        if not self.datas:
            raise TypeError(f"{type(self.env).__name__} is not a MuJoCo task: it has no MjData to show.")
        return self.datas[slot]

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown()

    def __enter__(self) -> EagerBatch:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
