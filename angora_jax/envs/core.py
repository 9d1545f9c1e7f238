"""The environment contract: `Sensation`, `State`, `ActionSpec` and the `Env` base class.

Every environment is a pair of pure functions, `reset(key) -> State` and `step(state, action) -> State`,
that can be jitted and vmapped. `step` resets an episode by itself when it ends (auto-reset), so a batch of
environments can be rolled out with `lax.scan` without leaving the compiled program; the observation at the
episode's end is kept in `State.final_obs` for value bootstrapping on truncation.
"""

from __future__ import annotations

import abc
import numbers
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import serialization, struct

# The fields of a `Sensation`, in their order.
MODALITIES = ("proprioception", "touch", "muscle", "vision", "goal", "asymmetric")


@struct.dataclass
class Sensation:
    """Observation as a pytree of modalities; each field is a float32 array of shape `(..., size)`, except camera
    images in `vision`: uint8 `(..., cameras, height, width, channels)` (`envs.cameras`; networks encode them).

    A modality that a task does not provide is an empty array of shape `(..., 0)`, never None, so that all
    tasks share one pytree structure. `asymmetric` holds privileged inputs that only the value function reads.
    `muscle` is the muscle sense of muscle-driven bodies (the MyoHand): per muscle its length, velocity and force, as
    muscle spindles and Golgi tendon organs report them, and its activation, an efference copy of the motor command
    (`envs.myohand`); tasks driven by motors leave it empty.
    """

    proprioception: jax.Array
    touch: jax.Array
    muscle: jax.Array
    vision: jax.Array
    goal: jax.Array
    asymmetric: jax.Array

    @classmethod
    def make(cls, **modalities: jax.Array) -> Sensation:
        """Build a Sensation from the given modalities; missing ones become empty float32 arrays."""
        unknown = set(modalities) - set(MODALITIES)
        if unknown:
            raise ValueError(f"Unknown modalities {sorted(unknown)}; a Sensation has {MODALITIES}.")
        batch = next(iter(modalities.values())).shape[:-1] if modalities else ()
        empty = jnp.zeros(batch + (0,), jnp.float32)
        return cls(**{f: as_modality(modalities.get(f, empty)) for f in MODALITIES})

    def sizes(self) -> dict[str, int]:
        """Feature size of each modality (the last axis; the channels of images)."""
        return {k: int(v.shape[-1]) for k, v in self.__dict__.items()}


def _holds_nothing(field: Any) -> bool:
    """Whether a Sensation field (a modality's array, or a pytree per modality such as its running statistics) holds
    no features: every leaf with a feature axis has size 0."""
    return all(np.size(leaf) == 0 for leaf in jax.tree.leaves(field) if np.ndim(leaf) >= 1)


def _sensation_to_state_dict(sensation: Sensation) -> dict[str, Any]:
    return {name: serialization.to_state_dict(getattr(sensation, name)) for name in MODALITIES}


def _sensation_from_state_dict(target: Sensation, state: dict[str, Any]) -> Sensation:
    """`target` filled from a state dict (flax serialization: exported policies) that may lack modalities added after
    it was written (`muscle`): those hold nothing in `target` either, as for every task of that time."""
    missing = [name for name in MODALITIES if name not in state and not _holds_nothing(getattr(target, name))]
    if missing:
        raise ValueError(f"The saved observations have no {missing}, which this task observes: the file was written "
                         "for another task.")
    return target.replace(**{name: serialization.from_state_dict(getattr(target, name), state[name])
                             for name in MODALITIES if name in state})


# Exported policies written before the `muscle` modality existed stay readable.
serialization.register_serialization_state(Sensation, _sensation_to_state_dict, _sensation_from_state_dict,
                                           override=True)


def is_image(leaf) -> bool:
    """Whether a modality (an array or `jax.ShapeDtypeStruct`) holds camera images: uint8 pixels are never
    normalised or concatenated as features, networks encode them (`nets.visual`)."""
    return leaf.dtype == jnp.uint8


def as_modality(value) -> jax.Array:
    """A modality's array: uint8 images as they are, anything else as float32."""
    value = jnp.asarray(value)
    return value if is_image(value) else value.astype(jnp.float32)


@struct.dataclass
class ActionSpec:
    """Continuous actions lie in the box `[low, high]` (float32, shape `(size,)`); discrete actions are integers
    in `[0, num_actions)` and have `low`/`high` of shape `(0,)`."""

    low: jax.Array
    high: jax.Array
    num_actions: int = struct.field(pytree_node=False, default=0)

    @property
    def discrete(self) -> bool:
        return self.num_actions > 0

    @property
    def size(self) -> int:
        """Length of one action vector (1 for a discrete action)."""
        return 1 if self.discrete else int(self.low.shape[-1])

    @property
    def shape(self) -> tuple[int, ...]:
        return () if self.discrete else (self.size,)


@struct.dataclass
class State:
    """One environment's state after `reset` or `step` (add a leading axis for a batch).

    Attributes:
        physics: the simulator's state (an `mjx.Data` for MuJoCo tasks, a small array pytree for classic ones).
        obs: the observation the agent sees now; after an auto-reset, the first observation of the new episode.
        reward: float32 scalar, the reward of the step that led here (0 after reset).
        done: float32 scalar, 1 if the episode ended at this step (terminated or truncated).
        truncated: float32 scalar, 1 if the episode ended only because of a time limit: `max_episode_steps`, or a task's
            own clock, signalled by a boolean `info["time_out"]` (e.g. the cube task's goal timer).
        final_obs: the observation at the episode's end, before any auto-reset; equals `obs` when not done.
        steps: int32 scalar, policy steps taken in the current episode.
        info: task state that is not physics (goal, target finger, timers), a dict of arrays.
        metrics: task metrics of the current episode at this step (e.g. `success`), float32 scalars; a trainer reports
            their values at episode ends.
        key: the environment's own PRNG key (goal sampling, resets).
    """

    physics: Any
    obs: Sensation
    reward: jax.Array
    done: jax.Array
    truncated: jax.Array
    final_obs: Sensation
    steps: jax.Array
    info: dict[str, jax.Array]
    metrics: dict[str, jax.Array]
    key: jax.Array


class Env(abc.ABC):
    """Base class of all environments: subclasses write `_reset` and `_step`; auto-reset, time limits and input
    checks are done here once.

    Attributes a subclass sets: `action_spec`, `max_episode_steps` (policy steps per episode), `dt` (seconds of
    simulated time per policy step) and `metric_names`.
    """

    action_spec: ActionSpec
    max_episode_steps: int
    dt: float
    metric_names: tuple[str, ...] = ()

    @abc.abstractmethod
    def _reset(self, key: jax.Array) -> tuple[Any, Sensation, dict[str, jax.Array]]:
        """Start an episode: return (physics, observation, info)."""

    @abc.abstractmethod
    def _step(
        self, physics: Any, info: dict[str, jax.Array], action: jax.Array, key: jax.Array
    ) -> tuple[Any, Sensation, jax.Array, jax.Array, dict[str, jax.Array], dict[str, jax.Array]]:
        """Advance one policy step: return (physics, observation, reward, terminated, info, metrics)."""

    def reset(self, key: jax.Array) -> State:
        """Start a new episode. `key` is a PRNG key; vmap over a batch of keys for a batch of environments."""
        return self._begin_episode(key)

    def _begin_episode(self, key: jax.Array) -> State:
        # `step`'s auto-reset starts episodes here too, so that a backend can add to `reset` what `step` does its own
        # way (MjxEnv renders camera frames once per step, after the auto-reset).
        key, reset_key = jax.random.split(key)
        physics, obs, info = self._reset(reset_key)
        zero = jnp.zeros((), jnp.float32)
        return State(
            physics=physics,
            obs=obs,
            reward=zero,
            done=zero,
            truncated=zero,
            final_obs=obs,
            steps=jnp.zeros((), jnp.int32),
            info=info,
            metrics={name: zero for name in self.metric_names},
            key=key,
        )

    def step(self, state: State, action: jax.Array) -> State:
        """Apply one action (shape `action_spec.shape`, or a batch under vmap) and return the next state.

        When the episode ends, the returned state already holds the first observation of a fresh episode in
        `obs` and the last one of the ended episode in `final_obs`; `done`, `reward` and `metrics` describe the
        ended step.
        """
        ended, reset_key = self.advance(state, action)
        fresh = self._begin_episode(reset_key)
        done = ended.done > 0

        def pick(new, old):
            return jnp.where(done, new, old)

        return ended.replace(
            physics=self._select_physics(done, fresh.physics, ended.physics),
            obs=jax.tree.map(pick, fresh.obs, ended.obs),
            steps=jnp.where(done, 0, ended.steps),
            info=jax.tree.map(pick, fresh.info, ended.info),
        )

    def sized_for(self, num_envs: int) -> Env:
        """This environment prepared to run batches of `num_envs` (vmapped). Trainers and evaluators call it once
        with their batch; most environments need nothing and return themselves (MJX on Warp sizes its buffers)."""
        return self

    def data_parallel_problem(self) -> str | None:
        """Why this environment cannot be simulated data-parallel on several devices of one process (each device its
        share of the batch), or None when it can."""
        return None

    def physics_info(self, num_envs: int | None = None) -> dict[str, Any]:
        """What simulates this environment in batches of `num_envs` (as `sized_for(num_envs)` prepares it), for logs
        and the run directory: `engine` and `device`, and for MuJoCo tasks the MJX implementation (`impl`), `why` it
        was chosen, timestep, frame skip and Warp's buffer size."""
        return {"engine": "pure JAX", "device": str(jax.local_devices()[0])}

    def _select_physics(self, done: jax.Array, fresh: Any, ended: Any) -> Any:
        """Physics of `fresh` where `done`, else of `ended` (a backend whose physics share buffers overrides it)."""
        return jax.tree.map(lambda new, old: jnp.where(done, new, old), fresh, ended)

    def advance(self, state: State, action: jax.Array) -> tuple[State, jax.Array]:
        """One step without auto-reset: return the state at the step's end and the key to reset with."""
        action = self.check_action(action)
        key, step_key, reset_key = step_keys(state.key)
        physics, obs, reward, terminated, info, metrics = self._step(state.physics, state.info, action, step_key)
        steps = state.steps + 1
        terminated = jnp.asarray(terminated, bool)
        # A task with its own clock (e.g. a goal timer) ends episodes early through info["time_out"]: a truncation.
        time_out = jnp.logical_or(steps >= self.max_episode_steps, info.get("time_out", False))
        truncated = jnp.logical_and(time_out, jnp.logical_not(terminated))
        ended = State(
            physics=physics,
            obs=obs,
            reward=jnp.asarray(reward, jnp.float32),
            done=jnp.logical_or(terminated, truncated).astype(jnp.float32),
            truncated=truncated.astype(jnp.float32),
            final_obs=obs,
            steps=steps,
            info=info,
            metrics={k: jnp.asarray(v, jnp.float32) for k, v in metrics.items()},
            key=key,
        )
        return ended, reset_key

    def check_action(self, action: jax.Array) -> jax.Array:
        """Raise a ValueError naming the expected shape when `action` does not fit `action_spec`."""
        action = jnp.asarray(action)
        if action.shape != self.action_spec.shape:
            raise ValueError(
                f"{type(self).__name__}.step expects one action of shape {self.action_spec.shape}, got "
                f"{action.shape}; for a batch of environments use jax.vmap(env.step)."
            )
        if self.action_spec.discrete:
            return action.astype(jnp.int32)
        return action.astype(jnp.float32)

    @property
    def sees_images(self) -> bool:
        """Whether `vision` holds camera images (uint8) rather than features; answered without tracing a reset."""
        return False

    def task_variables(self, state: State) -> dict[str, jax.Array]:
        """Named quantities of one environment's state for probing a trained network (recordings decode them from
        its layers), whether or not the policy observes them: e.g. the cube's pose and angular velocity. Each a
        vector `(size,)`; none by default."""
        return {}

    def state_shapes(self) -> State:
        """Shapes and dtypes of one environment's state as `reset` returns it (leaves `jax.ShapeDtypeStruct`), without
        simulating. Traced once per environment object: tracing a MuJoCo task's reset takes seconds, and a run's
        checks (`validate`'s memory estimate) and set-up (the normalizer's shapes) each ask for it."""
        cache = getattr(self, "__dict__", None)  # an Env subclass of the user's with __slots__: traced each time
        if cache is not None and "_state_shapes" in cache:
            return cache["_state_shapes"]
        shapes = jax.eval_shape(self.reset, jax.random.key(0))
        if cache is not None:
            cache["_state_shapes"] = shapes
        return shapes

    def observation_shapes(self) -> Sensation:
        """Shapes and dtypes of one observation, as a Sensation of `jax.ShapeDtypeStruct`, without simulating."""
        return self.state_shapes().obs


# The steps of an episode count in int32 (`State.steps`), so a time limit must fit one.
MAX_EPISODE_STEPS = 2**31 - 1


def episode_limit(max_episode_steps: Any) -> int:
    """A task's `max_episode_steps` option checked: a ValueError naming the option and its range unless it is a whole
    number from 1 to `MAX_EPISODE_STEPS`."""
    if (isinstance(max_episode_steps, bool) or not isinstance(max_episode_steps, numbers.Integral)
            or not 1 <= max_episode_steps <= MAX_EPISODE_STEPS):
        raise ValueError(f"max_episode_steps must be a whole number from 1 to {MAX_EPISODE_STEPS:,} (policy steps per "
                         f"episode), got {max_episode_steps!r}: e.g. max_episode_steps: 500, or leave it out for the "
                         "task's own.")
    return int(max_episode_steps)


def step_keys(key: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
    """A state's key split for one step, as `Env.advance` splits it: (the next state's key, the step's key, the key
    to reset with)."""
    return tuple(jax.random.split(key, 3))
