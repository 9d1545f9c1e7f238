"""Episodes on the eager path: a policy for a batch of environments (`agent_policy`, `random_policy`) and the loop
that plays episodes with it (`run_episodes`), shared by `evaluation` and `video`.

MuJoCo tasks run on their C MuJoCo twin (plain `mujoco.mj_step`, the same task logic and PRNG keys as the MJX
training path); pure-JAX tasks run their own `reset`/`advance`. Many episodes run at once: an `EagerBatch` of `batch`
environments is stepped together; the policy is applied once per step to the whole batch (one jitted call, the
recurrent carry batched, observations normalised by the saved statistics as in training), the task logic of all
environments is one jitted call too, and the C MuJoCo physics can be stepped by `workers` threads. A slot whose
episode ends takes the next pending episode at once. One environment at a time, a reach step is nearly all the
dispatch of small JAX calls (about 2 ms, against 0.07 ms of `mj_step`); batched, each call serves every environment:
48 reach episodes take 0.9 s at 16 at a time against 6.6 s one at a time (`benchmarks/evaluation_speed.py`).

Episode `i` starts from the same reset key as environment `i` of `Agent.evaluate` (the batched MJX path), so both
paths evaluate the same initial states and goals, and acts with keys of its own. The jitted calls compute each
environment as a batch of one (`rowwise`), so every episode is the same, bit for bit, whatever `batch` and `workers`
are. JAX computations run on the host CPU even where a GPU is the default device.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import replace
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from angora_jax.envs.core import Env, Sensation
from angora_jax.envs.eager_batch import EagerBatch, rowwise
from angora_jax.experiment.agent import Agent

# (carry, observations (leaves `(B, size)`), keys `(B,)`, steps `(B,)`, starting `(B,)` bool) -> (carry, actions
# `(B, *action_shape)`). Row r acts with key `fold_in(keys[r], steps[r])` (steps: policy steps taken in its episode);
# rows with `starting` set begin an episode, so their recurrent carry is reset first. A policy may read its NumPy
# arguments after it has returned (JAX computes asynchronously and shares host memory): callers must not change them.
Policy = Callable[[Any, Sensation, jax.Array, np.ndarray, np.ndarray], tuple[Any, jax.Array]]



@contextmanager
def on_host() -> Iterator[jax.Device]:
    """Run JAX computations inside on the host's CPU (yields that device): the eager path steps small batches on the
    host, where a GPU would only add transfers and launch latency."""
    cpu = jax.devices("cpu")[0]
    with jax.default_device(cpu):
        yield cpu


def agent_policy(agent: Agent, stochastic: bool = False) -> Policy:
    """The agent's step for a batch of environments (see `Policy`), jitted once per batch size, on the host CPU: the
    head's mode, or with `stochastic` a sample from the row's key. Each row is computed as a batch of one (`rowwise`),
    so its actions do not depend on the batch. The agent's state (parameters, normaliser statistics and silenced
    action components, `Agent.acting_state`) is an argument of the compiled function, not a constant: agents of the
    same kind and their lesioned variants share it (`Agent.compiled`)."""
    fresh = jax.tree.map(lambda x: x[0], agent.initial_carry(1))  # one row's carry at an episode's start

    def act(state, carry, obs, keys, steps, starting):
        acting = replace(agent, state=state)  # never `agent.state`: that of the agent that compiled the function

        def row(carry, obs, key, step, start):
            carry = jax.tree.map(lambda c, f: jnp.where(start, f, c), carry, fresh)
            carry, obs = jax.tree.map(lambda x: x[None], (carry, obs))
            carry, action, _ = acting.act(carry, obs, jax.random.fold_in(key, step) if stochastic else None)
            return jax.tree.map(lambda x: x[0], (carry, action))

        return rowwise(row)(carry, obs, keys, steps, starting)

    compiled = agent.compiled_once(("policy", stochastic), lambda: jax.jit(act))
    cpu = jax.devices("cpu")[0]
    state = jax.device_put(agent.acting_state, cpu)
    # The carry is committed to the host like everything else, so that the first call compiles for the later ones.
    return lambda carry, obs, keys, steps, starting: compiled(state, jax.device_put(carry, cpu), obs, keys, steps,
                                                              starting)


def random_policy(env: Env) -> Policy:
    """Uniformly random actions in `env.action_spec` for each row from its own key (no carry): for rendering a task
    without a trained agent."""
    spec = env.action_spec

    def one(key):
        if spec.discrete:
            return jax.random.randint(key, (), 0, spec.num_actions)
        return jax.random.uniform(key, spec.shape, minval=spec.low, maxval=spec.high)

    compiled = jax.jit(rowwise(lambda key, step: one(jax.random.fold_in(key, step))))
    return lambda carry, obs, keys, steps, starting: (carry, compiled(keys, steps))


def episode_keys(seed: int, episodes: int) -> tuple[jax.Array, jax.Array]:
    """Reset keys and acting keys, each `(episodes,)`; the reset keys are those of `Agent.evaluate(episodes, seed)`."""
    reset_key, act_key = jax.random.split(jax.random.key(seed))
    return jax.random.split(reset_key, episodes), jax.random.split(act_key, episodes)


def run_episodes(batch: EagerBatch, policy: Policy, carry: Any, reset_keys: jax.Array, act_keys: jax.Array,
                 on_step: Callable[[int, int], None] | None = None,
                 max_steps: int | None = None) -> dict[str, np.ndarray]:
    """Run episode `i` from `reset_keys[i]` (acting with `act_keys[i]`) for every `i`, `batch.size` at a time: a slot
    whose episode ends takes the next pending one.

    Args:
        batch: the environments stepped together.
        policy: acts for the whole batch at each step (`Policy`).
        carry: the policy's recurrent state for a batch of `batch.size` (its rows are reset as episodes start).
        reset_keys: one reset key per episode, `(episodes,)`.
        act_keys: one acting key per episode, `(episodes,)`.
        on_step: called with (episode, slot) after an episode's reset and after each of its steps, e.g. to render
            `batch.physics(slot)`.
        max_steps: cut each episode after this many steps (a video's length); None plays each to its end.

    Returns:
        name -> `(episodes,)` array: episode_return, episode_length and `metric/<name>` at each episode's last step.
    """
    episodes = reset_keys.shape[0]
    slot_episode = np.full(batch.size, -1)  # the episode each slot runs; -1 when it has none left
    starting = np.zeros(batch.size, bool)
    pending = iter(range(episodes))
    results: dict[str, np.ndarray] = {}
    returns = np.zeros(episodes)

    def start(slot: int) -> None:
        episode = next(pending, -1)
        slot_episode[slot] = episode
        if episode >= 0:
            batch.reset(slot, reset_keys[episode])
            starting[slot] = True
            if on_step is not None:
                on_step(episode, slot)

    for slot in range(batch.size):
        start(slot)
    while (active := slot_episode >= 0).any():
        if starting.any():  # a new episode's acting keys, gathered only when the slots' episodes change
            slot_keys = act_keys[np.maximum(slot_episode, 0)]
        # A copy, since `starting` is cleared below: JAX on CPU uses a (64-byte aligned) NumPy argument's memory in
        # place and may compute after the call has returned, and would then miss a new episode's carry reset.
        carry, actions = policy(carry, batch.states.obs, slot_keys, np.asarray(batch.states.steps), starting.copy())
        starting[:] = False
        state = batch.step(actions, active)
        reward, done, steps, metrics = jax.device_get((state.reward, state.done, state.steps, state.metrics))
        for slot in np.flatnonzero(active):
            episode = slot_episode[slot]
            returns[episode] += float(reward[slot])
            if on_step is not None:
                on_step(episode, slot)
            if done[slot] > 0 or (max_steps is not None and steps[slot] >= max_steps):
                row = {"episode_return": returns[episode], "episode_length": float(steps[slot]),
                       **{f"metric/{name}": float(value[slot]) for name, value in metrics.items()}}
                for name, value in row.items():
                    results.setdefault(name, np.zeros(episodes))[episode] = value
                start(slot)
    return results
