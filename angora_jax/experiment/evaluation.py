"""Evaluate a trained policy: per-episode statistics, a JSON record and a box plot.

Two paths compute the episodes. "cpu" (the default) is the eager path below. "batched" runs all episodes at once on
the training path (`angora_jax.ppo.make_evaluate`: MJX for MuJoCo tasks, one compiled program, on the GPU when there
is one): 480 cube episodes of up to 1,600 steps took 63 s on one H100; `benchmarks/path_agreement.py` checks that both
paths agree.

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

import json
import math
import time
import warnings
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from angora_jax.envs.core import Env, Sensation
from angora_jax.envs.cpu_env import CpuEnv
from angora_jax.envs.eager_batch import EagerBatch, batch_functions, rowwise
from angora_jax.experiment.agent import Agent, load_agent
from angora_jax.experiment.config import to_dict
from angora_jax.experiment.run_dir import numbered_paths
from angora_jax.ppo.evaluate import make_evaluate

EVALUATION_DIR = "evaluation"
# Episodes run at once by default: enough to spread the fixed cost of each step's JAX calls, few enough that a small
# evaluation still fills the batch.
DEFAULT_BATCH = 32

# (carry, observations (leaves `(B, size)`), keys `(B,)`, steps `(B,)`, starting `(B,)` bool) -> (carry, actions
# `(B, *action_shape)`). Row r acts with key `fold_in(keys[r], steps[r])` (steps: policy steps taken in its episode);
# rows with `starting` set begin an episode, so their recurrent carry is reset first. A policy may read its NumPy
# arguments after it has returned (JAX computes asynchronously and shares host memory): callers must not change them.
Policy = Callable[[Any, Sensation, jax.Array, np.ndarray, np.ndarray], tuple[Any, jax.Array]]


@dataclass(frozen=True)
class Evaluation:
    """The outcome of `evaluate`.

    episodes: per-episode values, name -> array `(episodes,)`: `episode_return` (undiscounted raw reward),
        `episode_length` (policy steps) and `metric/<name>` (each task metric at the episode's last step, e.g.
        `metric/goals_reached`, AngoraPy's consecutive goals reached, or `metric/success`).
    summary: name -> {mean, median, mode, std, stderr, min, max} of `episodes[name]`.
    meta: run directory, checkpoint, cycle, task, physics, episodes, batch, workers, stochastic, seed, wall seconds.
    json_path, plot_path: the files written (None when not saved).
    """

    episodes: dict[str, np.ndarray]
    summary: dict[str, dict[str, float]]
    meta: dict[str, Any]
    json_path: Path | None = None
    plot_path: Path | None = None


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
    so its actions do not depend on the batch. Parameters and normaliser statistics are arguments of the compiled
    function, not constants: agents of the same kind share it (`Agent.compiled`)."""
    fresh = jax.tree.map(lambda x: x[0], agent.initial_carry(1))  # one row's carry at an episode's start

    def act(params, obs_stats, carry, obs, keys, steps, starting):
        acting = replace(agent, state=agent.state.replace(params=params, obs_stats=obs_stats))

        def row(carry, obs, key, step, start):
            carry = jax.tree.map(lambda c, f: jnp.where(start, f, c), carry, fresh)
            carry, obs = jax.tree.map(lambda x: x[None], (carry, obs))
            carry, action, _ = acting.act(carry, obs, jax.random.fold_in(key, step) if stochastic else None)
            return jax.tree.map(lambda x: x[0], (carry, action))

        return rowwise(row)(carry, obs, keys, steps, starting)

    compiled = agent.compiled_once(("policy", stochastic), lambda: jax.jit(act))
    cpu = jax.devices("cpu")[0]
    params, obs_stats = jax.device_put((agent.params, agent.state.obs_stats), cpu)
    # The carry is committed to the host like everything else, so that the first call compiles for the later ones.
    return lambda carry, obs, keys, steps, starting: compiled(params, obs_stats, jax.device_put(carry, cpu), obs,
                                                              keys, steps, starting)


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

    carry: the policy's recurrent state for a batch of `batch.size` (its rows are reset as episodes start). on_step:
    called with (episode, slot) after an episode's reset and after each of its steps, e.g. to render
    `batch.physics(slot)`. max_steps: cut each episode after this many steps (a video's length); None plays each to
    its end. Returns name -> `(episodes,)` array: episode_return, episode_length and `metric/<name>` at each
    episode's last step.
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


def summarize(values: np.ndarray) -> dict[str, float]:
    """Mean, median, mode (the most frequent value, the smallest among ties: meaningful for counts such as goals
    reached or lengths), standard deviation, standard error of the mean, min and max of a 1-D array."""
    values = np.asarray(values, np.float64)
    distinct, counts = np.unique(values, return_counts=True)
    std = float(values.std(ddof=1)) if values.size > 1 else 0.0
    return {
        "mean": float(values.mean()),
        "median": float(np.median(values)),
        "mode": float(distinct[np.argmax(counts)]),
        "std": std,
        "stderr": std / math.sqrt(values.size),
        "min": float(values.min()),
        "max": float(values.max()),
    }


def agreement(a: np.ndarray, b: np.ndarray, bound: float = 3.0) -> dict[str, float | bool | None]:
    """Whether two samples of one quantity have the same mean within `bound` standard errors, e.g. the per-episode
    values of one checkpoint on the batched MJX path (`a`) and on the CPU path (`b`).

    Returns mean_a, stderr_a, mean_b, stderr_b, diff (mean_a - mean_b), stderr_diff (sqrt(stderr_a^2 + stderr_b^2),
    as for independent samples), diff_in_stderr (None when stderr_diff is 0) and agree (|diff| < bound * stderr_diff;
    for two constant samples, equal means). When both have one value per episode from the same initial states,
    stderr_paired (the standard error of the mean of a - b) is given too: smaller, since both paths start alike, it
    shows how closely they track each other, while `agree` asks whether they estimate the same mean.
    """
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    sa, sb = summarize(a), summarize(b)
    diff = sa["mean"] - sb["mean"]
    stderr_diff = math.hypot(sa["stderr"], sb["stderr"])
    result: dict[str, float | bool | None] = {
        "mean_a": sa["mean"], "stderr_a": sa["stderr"], "mean_b": sb["mean"], "stderr_b": sb["stderr"],
        "diff": diff, "stderr_diff": stderr_diff,
        "diff_in_stderr": diff / stderr_diff if stderr_diff > 0 else None,
        "agree": abs(diff) < bound * stderr_diff if stderr_diff > 0 else diff == 0,
    }
    if a.shape == b.shape:
        result["stderr_paired"] = summarize(a - b)["stderr"]
    return result


PATHS = ("cpu", "batched")


def evaluate(run_dir: str | Path, checkpoint: str | int = "best", episodes: int = 480, stochastic: bool = False,
             seed: int = 0, save: bool = True, batch: int = DEFAULT_BATCH, workers: int = 1,
             path: str = "cpu", env_overrides: Sequence[str] = ()) -> Evaluation:
    """Evaluate the policy saved in `run_dir` for `episodes` episodes.

    checkpoint: "best", "latest" or a cycle number (as for `load_agent`). stochastic: sample actions instead of
    taking the policy's mode. path: "cpu" (the eager path) or "batched" (all episodes at once on the training path,
    each one at most the task's `max_episode_steps`; the only path of Gymnasium tasks, `gym:<id>`). batch: episodes
    run at once on the CPU path (at most `episodes`). workers: threads stepping the C MuJoCo physics of the batch
    (at most `batch`; see `EagerBatch`). env_overrides: task options that differ from the run's (`load_agent`);
    recorded, and `-changed` comes before the files' `.json`. Neither batch nor workers changes any episode. save:
    write `RUN_DIR/evaluation/<checkpoint>-cycle<N>-<mode>-seed<S>.json` (with `-batched` before `.json` for that
    path) and a box plot `.png` of the same name (a `-2`, `-3`, ... suffix when taken: nothing is overwritten).
    """
    if episodes < 1 or batch < 1 or workers < 1:
        raise ValueError(f"episodes, batch and workers must be >= 1, got {episodes}, {batch}, {workers}.")
    if path not in PATHS:
        raise ValueError(f"Unknown evaluation path {path!r}; choose one of {PATHS}.")
    agent = load_agent(run_dir, checkpoint, env_overrides)
    changed = {"env_overrides": list(env_overrides)} if env_overrides else {}
    if path == "batched" or getattr(agent.env, "on_host", False):  # a Gymnasium task has its own simulator only
        return _evaluate_batched(agent, run_dir, checkpoint, episodes, stochastic, seed, save, changed)
    vision = getattr(getattr(agent.env, "task", None), "vision", None)
    # A known training renderer is enforced where the frames are drawn (`CameraVision.renderer`); warn of the unknown.
    if vision is not None and vision.renderer is None and getattr(agent.env, "impl", None) == "warp":
        warnings.warn("This agent sees camera images, and here they are rendered by MuJoCo Warp on the training path; "
                      "the CPU path draws them with OpenGL, which shades them differently (envs/cameras.py): use "
                      "path='batched' (--path batched) to evaluate it on the frames it trained on.", stacklevel=2)
    with on_host():
        policy = agent_policy(agent, stochastic)
        compiled = agent.compiled_once("eager batch", lambda: batch_functions(agent.env))
        with EagerBatch(agent.env, min(batch, episodes), workers, compiled) as envs:
            start = time.perf_counter()
            per_episode = run_episodes(envs, policy, agent.initial_carry(envs.size), *episode_keys(seed, episodes))
            wall = time.perf_counter() - start
    physics = "C MuJoCo (mujoco.mj_step)" if isinstance(envs.env, CpuEnv) else "JAX (jitted, batched)"
    meta = _record(agent, run_dir, checkpoint, episodes, stochastic, seed, wall, changed,
                   {"physics": physics, "batch": envs.size, "workers": envs.workers})
    result = Evaluation(per_episode, {name: summarize(v) for name, v in per_episode.items()}, meta)
    return save_evaluation(result, Path(run_dir) / EVALUATION_DIR) if save else result


def _evaluate_batched(agent: Agent, run_dir: str | Path, checkpoint: str | int, episodes: int, stochastic: bool,
                      seed: int, save: bool, changed: dict[str, Any]) -> Evaluation:
    """`evaluate` on the batched training path: one compiled program runs all `episodes` at once."""
    compiled = agent.compiled_once(("batched", episodes, stochastic), lambda: make_evaluate(
        agent.env, agent.network, agent.config.ppo, episodes, not stochastic, per_episode=True
    ).lower(agent.state, jax.random.key(seed)).compile())
    start = time.perf_counter()
    per_episode = {name: np.asarray(v) for name, v in jax.block_until_ready(
        compiled(agent.state, jax.random.key(seed))).items()}
    wall = time.perf_counter() - start
    env = agent.env.sized_for(episodes)
    physics = f"batched {type(env).__name__} ({getattr(env, 'impl', 'jax')}) on {jax.devices()[0].device_kind}"
    meta = _record(agent, run_dir, checkpoint, episodes, stochastic, seed, wall, changed,
                   {"physics": physics, "path": "batched", "batch": episodes, "workers": 1})
    result = Evaluation(per_episode, {name: summarize(v) for name, v in per_episode.items()}, meta)
    return save_evaluation(result, Path(run_dir) / EVALUATION_DIR) if save else result


def _record(agent: Agent, run_dir: str | Path, checkpoint: str | int, episodes: int, stochastic: bool, seed: int,
            wall: float, changed: dict[str, Any], where: dict[str, Any]) -> dict[str, Any]:
    """What an evaluation ran: the checkpoint, the task with the options it was evaluated with (the run's, changed
    by `env_overrides`), where the physics ran, the episodes and the seed."""
    return {
        "run_dir": str(run_dir),
        "checkpoint": checkpoint,
        "cycle": agent.cycle,
        "task": agent.config.env.task,
        "task_options": to_dict(agent.config)["env"]["options"],
        **where,
        "episodes": episodes,
        "stochastic": stochastic,
        "seed": seed,
        "wall_seconds": wall,
        **changed,
    }


def save_evaluation(result: Evaluation, directory: Path) -> Evaluation:
    """Write `result` as JSON plus its box plot into `directory` under a name not taken yet; return it with the
    paths."""
    directory.mkdir(parents=True, exist_ok=True)
    meta = result.meta
    actions = "stochastic" if meta["stochastic"] else "mode"
    stem = f"{meta['checkpoint']}-cycle{meta['cycle']}-{actions}-seed{meta['seed']}"
    stem += "-batched" if meta.get("path") == "batched" else ""
    stem += "-changed" if meta.get("env_overrides") else ""
    record = {**meta, "summary": result.summary, "per_episode": {k: v.tolist() for k, v in result.episodes.items()}}
    for json_path in numbered_paths(directory, stem, ".json"):
        try:
            with json_path.open("x") as file:  # "x": fails instead of overwriting an earlier evaluation
                json.dump(record, file, indent=1)
            break
        except FileExistsError:
            continue
    plot_path = json_path.with_suffix(".png")
    box_plot(result, plot_path)
    return replace(result, json_path=json_path, plot_path=plot_path)


def box_plot(result: Evaluation, path: Path) -> None:
    """One box per quantity (return, length, each task metric) over episodes, with the mean marked, as in AngoraPy's
    Figure 7 (right); titles give mean, median and mode."""
    import matplotlib

    matplotlib.use("Agg")  # files only: no display needed
    import matplotlib.pyplot as plt

    names = list(result.episodes)
    figure, axes = plt.subplots(1, len(names), figsize=(3.2 * len(names), 4), squeeze=False)
    for ax, name in zip(axes[0], names, strict=True):
        stats = result.summary[name]
        ax.boxplot(result.episodes[name], showmeans=True, widths=0.5)
        ax.set_xticks([1], [name.removeprefix("metric/")])
        ax.set_title(f"mean {stats['mean']:.3g}  median {stats['median']:.3g}\nmode {stats['mode']:.3g}", fontsize=9)
    meta = result.meta
    figure.suptitle(f"{meta['task']}, cycle {meta['cycle']}, {meta['episodes']} episodes, "
                    f"{'sampled' if meta['stochastic'] else 'mode'} actions", fontsize=10)
    figure.tight_layout()
    figure.savefig(path, dpi=100)
    plt.close(figure)
