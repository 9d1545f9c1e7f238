"""Any Gymnasium environment under the env contract, simulated on the host: `make("gym:LunarLander-v3")`.

The compiled programs (training cycle, evaluation, recording) call back into Python once per policy step for the
whole batch (`jax.pure_callback`, batched under `vmap`): a `gymnasium.vector.SyncVectorEnv` with one copy per
environment of the batch steps them all, with Gymnasium's own time limit and its same-step autoreset (after an
episode's end the observation is the next episode's first and the last one is kept for bootstrapping, as the contract
has it). Everything else is the code that trains MJX tasks: acting, GAE, TBPTT, updates, checkpoints, evaluation,
recording, CLI and report. Slower by nature: each step leaves the compiled program and the simulator is Gymnasium's.

Spaces: the observation, encoded by `gymnasium.spaces.flatten` (a Box flattened, Discrete and MultiDiscrete one-hot,
MultiBinary as 0/1, Dict and Tuple as their parts end to end), is `proprioception`; so a cognitive task with discrete
states (AngoraPy's Tower of Hanoi, Gymnasium's FrozenLake or Blackjack) trains as a control task does. Discrete actions
train a categorical head, Box actions a continuous one. Episode statistics come from the rewards and ends; such tasks
have no task metrics.

What lives outside JAX: the simulators. A batch size gets its vector environment once per process (`sized_for`),
seeded from the keys of the first `reset`; a state's `physics` is only each environment's slot in that batch. So a
resumed run starts fresh episodes, and a host task trains on one device.
"""

from __future__ import annotations

import functools
from typing import Any

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np

from angora_jax.envs.core import ActionSpec, Env, Sensation, State, episode_limit
from angora_jax.wording import counted

PREFIX = "gym:"


class GymnasiumHost(Env):
    """`gymnasium.make(env_id, **kwargs)` as a batched task stepped on the host (module docstring).

    max_episode_steps: the time limit (default: the registered one); dt: seconds per step for sim-s/s reports
    (default: the environment's own `dt` where it has one, else 1).
    """

    on_host = True

    def __init__(self, env_id: str, max_episode_steps: int | None = None, num_envs: int = 1, **kwargs: Any):
        if max_episode_steps is not None:
            episode_limit(max_episode_steps)
        try:
            probe = gymnasium.make(env_id, max_episode_steps=max_episode_steps, **kwargs)
        except gymnasium.error.Error as error:
            raise ValueError(f"gymnasium.make({env_id!r}) failed: {error}") from None
        observation, action = probe.observation_space, probe.action_space
        try:
            flat = gymnasium.spaces.flatten_space(observation)
        except NotImplementedError:
            flat = None
        if not isinstance(flat, gymnasium.spaces.Box):
            raise ValueError(f"{env_id} observes {observation}, which has no fixed-size encoding: host tasks take "
                             "observations that gymnasium.spaces.flatten_space makes a Box (Box, Discrete, "
                             "MultiDiscrete, MultiBinary, Text, and Dict or Tuple of these). Wrap the environment to "
                             "observe such a space and register it.")
        if isinstance(action, gymnasium.spaces.Discrete):
            self.action_spec = ActionSpec(low=jnp.zeros(0), high=jnp.zeros(0), num_actions=int(action.n))
        elif isinstance(action, gymnasium.spaces.Box):
            self.action_spec = ActionSpec(low=jnp.asarray(action.low, jnp.float32).reshape(-1),
                                          high=jnp.asarray(action.high, jnp.float32).reshape(-1))
        else:
            raise ValueError(f"{env_id} acts in {action}; host tasks take Discrete or Box actions.")
        self.env_id, self.kwargs, self.num_envs = env_id, kwargs, num_envs
        self.max_episode_steps = int(probe.spec.max_episode_steps or 1_000_000)
        self.dt = float(getattr(probe.unwrapped, "dt", 1.0))
        self.observation_space = observation
        self.observation_size = int(flat.shape[0])
        probe.close()
        self._vector: gymnasium.vector.VectorEnv | None = None
        self._started = False

    def sized_for(self, num_envs: int) -> GymnasiumHost:
        """The same task with its own vector environment of `num_envs` copies (one per batch size per process)."""
        return _sized(self, num_envs) if num_envs != self.num_envs else self

    def data_parallel_problem(self) -> str | None:
        return f"{self.physics_info()['engine']} is simulated on the host, in one process"

    def physics_info(self, num_envs: int | None = None) -> dict[str, Any]:
        return {"engine": f"Gymnasium {gymnasium.__version__} on the host ({self.env_id})", "device": "host CPU"}

    def reset(self, key: jax.Array) -> State:
        """Start fresh episodes in every environment of the batch (vmap over keys; one call resets them all)."""
        obs, slot = jax.pure_callback(
            self._host_reset,
            (jax.ShapeDtypeStruct((self.observation_size,), jnp.float32), jax.ShapeDtypeStruct((), jnp.int32)),
            jax.random.key_data(key), vmap_method="broadcast_all")
        zero = jnp.zeros((), jnp.float32)
        sensation = Sensation.make(proprioception=obs)
        return State(physics=slot, obs=sensation, reward=zero, done=zero, truncated=zero, final_obs=sensation,
                     steps=jnp.zeros((), jnp.int32), info={}, metrics={}, key=key)

    def step(self, state: State, action: jax.Array) -> State:
        """Step every environment of the batch (vmap over states and actions; one call steps them all)."""
        size = (self.observation_size,)
        obs, reward, terminated, truncated, final_obs = jax.pure_callback(
            self._host_step,
            (jax.ShapeDtypeStruct(size, jnp.float32), jax.ShapeDtypeStruct((), jnp.float32),
             jax.ShapeDtypeStruct((), jnp.bool_), jax.ShapeDtypeStruct((), jnp.bool_),
             jax.ShapeDtypeStruct(size, jnp.float32)),
            self.check_action(action), vmap_method="broadcast_all")
        done = jnp.logical_or(terminated, truncated)
        return state.replace(
            obs=Sensation.make(proprioception=obs), final_obs=Sensation.make(proprioception=final_obs),
            reward=reward, done=done.astype(jnp.float32),
            truncated=jnp.logical_and(truncated, jnp.logical_not(terminated)).astype(jnp.float32),
            steps=jnp.where(done, 0, state.steps + 1))

    def _reset(self, key):  # the contract's per-environment hooks; this task overrides reset and step whole
        raise NotImplementedError("GymnasiumHost steps whole batches on the host: use reset and step.")

    _step = _reset

    def _host_reset(self, keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        keys = np.asarray(keys)  # callbacks receive JAX arrays; Gymnasium wants NumPy
        batched = keys.ndim == 2  # under vmap; one environment otherwise
        keys = keys.reshape(-1, keys.shape[-1])
        seed = int(np.random.SeedSequence(keys[0].tolist()).generate_state(1)[0])
        obs, _ = self._batch(len(keys)).reset(seed=seed)
        self._started = True
        outputs = (self._flat(obs), np.arange(len(keys), dtype=np.int32))
        return outputs if batched else tuple(x[0] for x in outputs)

    def _host_step(self, action: np.ndarray) -> tuple[np.ndarray, ...]:
        action = np.asarray(action)
        batched = action.ndim > len(self.action_spec.shape)
        batch = action.reshape((-1, *self.action_spec.shape))
        vector = self._batch(len(batch))
        if not self._started:  # a state restored from a checkpoint: these simulators never started here
            vector.reset(seed=0)
            self._started = True
        obs, reward, terminated, truncated, info = vector.step(batch)
        final = self._flat(obs).copy()
        for index in np.flatnonzero(np.logical_or(terminated, truncated)):
            final[index] = gymnasium.spaces.flatten(self.observation_space, info["final_obs"][index])
        outputs = (self._flat(obs), np.asarray(reward, np.float32), np.asarray(terminated, bool),
                   np.asarray(truncated, bool), final)
        return outputs if batched else tuple(x[0] for x in outputs)

    def _batch(self, size: int) -> gymnasium.vector.VectorEnv:
        if size != self.num_envs:
            raise ValueError(f"{self.env_id}: a batch of {counted(size, 'environment')} reached a host task sized for "
                             f"{self.num_envs}; get one with env.sized_for({size}).")
        if self._vector is None:
            self._vector = gymnasium.make_vec(
                self.env_id, num_envs=size, vectorization_mode="sync",
                vector_kwargs={"autoreset_mode": gymnasium.vector.AutoresetMode.SAME_STEP},
                max_episode_steps=self.max_episode_steps, **self.kwargs)
        return self._vector

    def _flat(self, obs: Any) -> np.ndarray:
        """The batch's observations as `(num_envs, observation_size)` float32, each encoded as `flatten` does."""
        if isinstance(self.observation_space, gymnasium.spaces.Box):  # flattening a Box is a reshape: skip the loop
            return np.asarray(obs, np.float32).reshape(self.num_envs, -1)
        items = gymnasium.vector.utils.iterate(self._batch(self.num_envs).observation_space, obs)
        return np.stack([gymnasium.spaces.flatten(self.observation_space, item) for item in items]).astype(np.float32)


@functools.cache
def _cached(env_id: str, kwargs: tuple, max_episode_steps: int, num_envs: int) -> GymnasiumHost:
    return GymnasiumHost(env_id, max_episode_steps, num_envs, **dict(kwargs))


def _sized(env: GymnasiumHost, num_envs: int) -> GymnasiumHost:
    return _cached(env.env_id, tuple(sorted(env.kwargs.items())), env.max_episode_steps, num_envs)


def make_gymnasium(name: str, **options: Any) -> GymnasiumHost:
    """`make("gym:<id>", **options)`: `options` are `max_episode_steps` and keyword arguments of `gymnasium.make`."""
    return GymnasiumHost(name.removeprefix(PREFIX), **options)
