"""Evaluate a trained policy on the eager CPU path: per-episode statistics, a JSON record and a box plot.

MuJoCo tasks run on their C MuJoCo twin (`CpuEnv`: plain `mujoco.mj_step`, the same task logic and PRNG keys as the
MJX training path); pure-JAX tasks run their own `reset`/`advance`, jitted for one environment. The policy is the
agent's single step for a batch of one, jitted once, with observations normalised by the saved statistics exactly as
in training (`Agent.act`). Episodes run one after another in this process (sequentially: each step is a few
milliseconds of C MuJoCo and one small jitted call, and JAX already uses the machine's cores for the latter).

Episode `i` starts from the same reset key as environment `i` of `Agent.evaluate` (the batched MJX path), so both
paths evaluate the same initial states and goals.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import jax
import numpy as np

from angora_jax.envs.core import Env, Sensation, State
from angora_jax.envs.cpu_env import CpuEnv, eager, single_env_functions
from angora_jax.experiment.agent import Agent, load_agent

EVALUATION_DIR = "evaluation"

# (carry, one observation (leaves `(size,)`), key) -> (carry, one env action); the carry is that of a batch of one.
Policy = Callable[[Any, Sensation, jax.Array], tuple[Any, jax.Array]]


@dataclass(frozen=True)
class Evaluation:
    """The outcome of `evaluate`.

    episodes: per-episode values, name -> array `(episodes,)`: `episode_return` (undiscounted raw reward),
        `episode_length` (policy steps) and `metric/<name>` (each task metric at the episode's last step, e.g.
        `metric/goals_reached`, AngoraPy's consecutive goals reached, or `metric/success`).
    summary: name -> {mean, median, mode, std, stderr, min, max} of `episodes[name]`.
    meta: run directory, checkpoint, cycle, task, physics, episodes, stochastic, seed, wall seconds.
    json_path, plot_path: the files written (None when not saved).
    """

    episodes: dict[str, np.ndarray]
    summary: dict[str, dict[str, float]]
    meta: dict[str, Any]
    json_path: Path | None = None
    plot_path: Path | None = None


def agent_policy(agent: Agent, stochastic: bool = False) -> Policy:
    """The agent's step for one environment, jitted once: the head's mode, or a sample with the given key when
    `stochastic`. Parameters and normaliser statistics are arguments of the compiled function, not constants."""

    def act(params, obs_stats, carry, obs, key):
        acting = replace(agent, state=agent.state.replace(params=params, obs_stats=obs_stats))
        carry, action, _ = acting.act(carry, jax.tree.map(lambda x: x[None], obs), key if stochastic else None)
        return carry, action[0]

    compiled = jax.jit(act)
    return lambda carry, obs, key: compiled(agent.params, agent.state.obs_stats, carry, obs, key)


def random_policy(env: Env) -> Policy:
    """Uniformly random actions in `env.action_spec` (no carry): for rendering a task without a trained agent."""
    spec = env.action_spec

    def act(carry, obs, key):
        if spec.discrete:
            return carry, jax.random.randint(key, (), 0, spec.num_actions)
        return carry, jax.random.uniform(key, spec.shape, minval=spec.low, maxval=spec.high)

    return act


def episode_keys(seed: int, episodes: int) -> tuple[jax.Array, jax.Array]:
    """Reset keys and acting keys, each `(episodes,)`; the reset keys are those of `Agent.evaluate(episodes, seed)`."""
    reset_key, act_key = jax.random.split(jax.random.key(seed))
    return jax.random.split(reset_key, episodes), jax.random.split(act_key, episodes)


def run_episode(env: Env, policy: Policy, carry: Any, reset_key: jax.Array, act_key: jax.Array,
                on_step: Callable[[State], None] | None = None, functions: tuple | None = None) -> dict[str, float]:
    """Run one episode of `env` (an eager environment, see `eager`) from `reset_key` to its end.

    carry: the policy's recurrent state at an episode's start (batch of one). on_step: called with the state after
    the reset and after every step (e.g. to render a frame). functions: `single_env_functions(env)`, to reuse their
    compilation across episodes. Returns episode_return, episode_length and `metric/<name>` at the last step.
    """
    reset, advance = functions or single_env_functions(env)
    state = reset(reset_key)
    if on_step is not None:
        on_step(state)
    episode_return = 0.0
    while True:
        carry, action = policy(carry, state.obs, jax.random.fold_in(act_key, state.steps))
        state, _ = advance(state, action)
        episode_return += float(state.reward)
        if on_step is not None:
            on_step(state)
        if state.done > 0:
            metrics = {f"metric/{name}": float(value) for name, value in state.metrics.items()}
            return {"episode_return": episode_return, "episode_length": float(state.steps), **metrics}


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


def evaluate(run_dir: str | Path, checkpoint: str | int = "best", episodes: int = 480, stochastic: bool = False,
             seed: int = 0, save: bool = True) -> Evaluation:
    """Evaluate the policy saved in `run_dir` for `episodes` episodes on the eager CPU path.

    checkpoint: "best", "latest" or a cycle number (as for `load_agent`). stochastic: sample actions instead of
    taking the policy's mode. save: write `RUN_DIR/evaluation/<checkpoint>-cycle<N>-<mode>-seed<S>.json` and a box
    plot `.png` of the same name (a `-2`, `-3`, ... suffix when taken: nothing is overwritten).
    """
    if episodes < 1:
        raise ValueError(f"episodes must be >= 1, got {episodes}.")
    agent = load_agent(run_dir, checkpoint)
    env = eager(agent.env)
    policy = agent_policy(agent, stochastic)
    functions = single_env_functions(env)
    start = time.perf_counter()
    rows = [run_episode(env, policy, agent.initial_carry(1), reset_key, act_key, functions=functions)
            for reset_key, act_key in zip(*episode_keys(seed, episodes), strict=True)]
    wall = time.perf_counter() - start
    per_episode = {name: np.array([row[name] for row in rows]) for name in rows[0]}
    meta = {
        "run_dir": str(run_dir),
        "checkpoint": checkpoint,
        "cycle": agent.cycle,
        "task": agent.config.env.task,
        "physics": "C MuJoCo (mujoco.mj_step)" if isinstance(env, CpuEnv) else "JAX, one environment, jitted",
        "episodes": episodes,
        "stochastic": stochastic,
        "seed": seed,
        "wall_seconds": wall,
    }
    result = Evaluation(per_episode, {name: summarize(v) for name, v in per_episode.items()}, meta)
    return save_evaluation(result, Path(run_dir) / EVALUATION_DIR) if save else result


def save_evaluation(result: Evaluation, directory: Path) -> Evaluation:
    """Write `result` as JSON plus its box plot into `directory` under a name not taken yet; return it with the
    paths."""
    directory.mkdir(parents=True, exist_ok=True)
    meta = result.meta
    actions = "stochastic" if meta["stochastic"] else "mode"
    stem = f"{meta['checkpoint']}-cycle{meta['cycle']}-{actions}-seed{meta['seed']}"
    record = {**meta, "summary": result.summary, "per_episode": {k: v.tolist() for k, v in result.episodes.items()}}
    for suffix in ("", *(f"-{i}" for i in range(2, 10_000))):
        json_path = directory / f"{stem}{suffix}.json"
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
