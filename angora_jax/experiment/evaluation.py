"""Evaluate a trained policy: per-episode statistics, a JSON record and a box plot.

Two paths compute the episodes. "cpu" (the default) is the eager path of `angora_jax.experiment.episodes`: C
MuJoCo (or the task's own JAX steps) in batches on the host, each episode the same whatever the batch. "batched"
runs all episodes at once on the training path (`angora_jax.ppo.make_evaluate`: MJX for MuJoCo tasks, one compiled
program, on the GPU when there is one): 480 cube episodes of up to 1,600 steps took 63 s on one H100;
`benchmarks/path_agreement.py` checks that both paths agree.
"""

from __future__ import annotations

import json
import math
import os
import time
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import jax
import numpy as np

from angora_jax.envs.cameras import check_path_renderer
from angora_jax.envs.cpu_env import CpuEnv
from angora_jax.envs.eager_batch import EagerBatch, batch_functions
from angora_jax.experiment.agent import Agent, load_agent, read_checkpoint
from angora_jax.experiment.config import ConfigError, check_count, check_flag, check_seed, override_strings, to_dict
from angora_jax.experiment.episodes import agent_policy, episode_keys, on_host, run_episodes
from angora_jax.experiment.evaluation_settings import DEFAULT_BATCH, PATHS
from angora_jax.experiment.run_dir import CONFIG_FILE, EVALUATIONS, numbered_paths, run_holding, unwritable_out
from angora_jax.ppo.evaluate import make_evaluate
from angora_jax.whole_files import written_whole
from angora_jax.wording import counted


@dataclass(frozen=True)
class Evaluation:
    """The outcome of `evaluate`.

    Attributes:
        episodes: per-episode values, name -> array `(episodes,)`: `episode_return` (undiscounted raw reward),
            `episode_length` (policy steps) and `metric/<name>` (each task metric at the episode's last step, e.g.
            `metric/goals_reached`, AngoraPy's consecutive goals reached, or `metric/success`).
        summary: name -> {mean, median, mode, std, stderr, min, max} of `episodes[name]`.
        meta: run directory, checkpoint, cycle, task, physics, episodes, batch, workers, stochastic, seed, wall seconds.
        json_path: the JSON record written (None when not saved).
        plot_path: the box plot written (None when not saved).
    """

    episodes: dict[str, np.ndarray]
    summary: dict[str, dict[str, float]]
    meta: dict[str, Any]
    json_path: Path | None = None
    plot_path: Path | None = None


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


def evaluate(run_dir: str | Path, checkpoint: str | int = "best", episodes: int = 480, stochastic: bool = False,
             seed: int = 0, save: bool | str | Path = True, batch: int = DEFAULT_BATCH, workers: int = 1,
             path: str = "cpu", env_overrides: Sequence[str] = ()) -> Evaluation:
    """Evaluate the policy saved in `run_dir` for `episodes` episodes.

    Neither `batch` nor `workers` changes any episode.

    Args:
        run_dir: the run directory.
        checkpoint: "best", "latest" or a cycle number (as for `load_agent`).
        episodes: episodes to run.
        stochastic: sample actions instead of taking the policy's mode.
        seed: picks the episodes' initial states and goals (those of `Agent.evaluate` with the same seed).
        save: write `RUN_DIR/evaluation/<checkpoint>-cycle<N>-<mode>-seed<S>.json` (`cycle<N>-...` alone for a
            checkpoint chosen by its cycle; with `-batched` before `.json` for that path) and a box plot `.png` of
            the same name (a `-2`, `-3`, ... suffix when taken: nothing is overwritten); a folder instead of True
            writes them there (a run on a share you may not write to), False writes nothing.
        batch: episodes run at once on the CPU path (at most `episodes`).
        workers: threads stepping the C MuJoCo physics of the batch (at most `batch`; see `EagerBatch`).
        path: "cpu" (the eager path) or "batched" (all episodes at once on the training path, each one at most the
            task's `max_episode_steps`; the only path of Gymnasium tasks, `gym:<id>`).
        env_overrides: task options that differ from the run's (`load_agent`); recorded, and `-changed` comes before
            the files' `.json`.
    """
    episodes, batch, workers = (check_count(name, count) for name, count in
                                (("episodes", episodes), ("batch", batch), ("workers", workers)))
    seed = check_seed("seed", seed)
    stochastic = check_flag("stochastic", stochastic)
    if path not in PATHS:
        raise ValueError(f"Unknown evaluation path {path!r}; choose one of {PATHS}.")
    check_save_folder(save, run_dir)
    env_overrides = override_strings(env_overrides, "env_overrides")
    agent = load_agent(run_dir, checkpoint, env_overrides)
    checkpoint = read_checkpoint(run_dir, checkpoint)  # named as read: a run without a best evaluates its latest
    changed = {"env_overrides": list(env_overrides)} if env_overrides else {}
    batched = path == "batched" or getattr(agent.env, "on_host", False)  # a Gymnasium task has its own simulator only
    try:
        check_path_renderer(agent.env, batched)
    except ValueError as error:
        raise ConfigError(str(error)) from None
    if batched:
        return _evaluate_batched(agent, run_dir, checkpoint, episodes, stochastic, seed, save, changed)
    # A known training renderer is enforced above (`CameraVision.renderer`); warn of the unknown.
    vision = getattr(getattr(agent.env, "task", None), "vision", None)
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
    return _evaluation(per_episode, meta, run_dir, save)


def check_save_folder(save: bool | str | Path, run_dir: str | Path) -> None:
    """ConfigError, before any episode runs, when `save` names a folder that no evaluation of `run_dir` can be
    written into: a file is there (never overwritten), a file is on its way, it cannot be written, or it is inside
    another run (read there as that run's, and set aside with its later cycles by its resume); True and False
    pass."""
    if isinstance(save, bool):
        return
    if not isinstance(save, str | os.PathLike):
        raise TypeError(f"save is True (into RUN_DIR/{EVALUATIONS}), False (nothing written) or a folder to write "
                        f"into; got {save!r} ({type(save).__name__}).")
    folder = Path(save)
    if folder.exists() and not folder.is_dir():
        raise ConfigError(f"save (--out) {folder} is a file, and an evaluation writes its JSON and box plot into a "
                          f"folder without overwriting anything: give a folder, a new or an existing one (e.g. "
                          f"{folder.parent / EVALUATIONS}).")
    if (why := unwritable_out(folder / "evaluation.json")) is not None:
        raise ConfigError(f"save (--out) {folder}: {why}; give a folder you can write to.")
    if (folder / CONFIG_FILE).is_file():  # its JSON and box plot would lie among the run's own files
        raise ConfigError(f"save (--out) {folder} is a run directory itself: a run's evaluations go in its "
                          f"{EVALUATIONS} folder ({folder / EVALUATIONS}, the default): give that or another folder.")
    if (other := run_holding(folder)) is not None and other.resolve() != Path(run_dir).resolve():
        raise ConfigError(f"save (--out) {folder} is inside the run {other}, not {run_dir}: an evaluation of "
                          f"{run_dir} there would be read as {other}'s. Give {Path(run_dir) / EVALUATIONS} (the "
                          "default) or a folder outside every run.")


def _evaluation(per_episode: dict[str, np.ndarray], meta: dict[str, Any], run_dir: str | Path,
                save: bool | str | Path) -> Evaluation:
    """The `Evaluation` of `per_episode`, its quantities in one order whichever path made them (the batched path's
    come back from JAX sorted by name, the CPU path's in the task's order): return, length, then the task's metrics
    by name. Saved in the run's evaluation folder when `save` is True, in the folder `save` names if it is one."""
    first = [name for name in ("episode_return", "episode_length") if name in per_episode]
    ordered = {name: per_episode[name] for name in first + sorted(set(per_episode) - set(first))}
    result = Evaluation(ordered, {name: summarize(v) for name, v in ordered.items()}, meta)
    if not save:
        return result
    return save_evaluation(result, Path(run_dir) / EVALUATIONS if save is True else Path(save))


def _evaluate_batched(agent: Agent, run_dir: str | Path, checkpoint: str | int, episodes: int, stochastic: bool,
                      seed: int, save: bool | str | Path, changed: dict[str, Any]) -> Evaluation:
    """`evaluate` on the batched training path: one compiled program runs all `episodes` at once."""
    state = agent.acting_state  # the silenced action components are its data: one program for any lesion
    compiled = agent.compiled_once(("batched", episodes, stochastic), lambda: make_evaluate(
        agent.env, agent.network, agent.config.ppo, episodes, not stochastic, per_episode=True
    ).lower(state, jax.random.key(seed)).compile())
    start = time.perf_counter()
    per_episode = {name: np.asarray(v) for name, v in jax.block_until_ready(
        compiled(state, jax.random.key(seed))).items()}
    wall = time.perf_counter() - start
    env = agent.env.sized_for(episodes)
    physics = f"batched {type(env).__name__} ({getattr(env, 'impl', 'jax')}) on {jax.devices()[0].device_kind}"
    meta = _record(agent, run_dir, checkpoint, episodes, stochastic, seed, wall, changed,
                   {"physics": physics, "path": "batched", "batch": episodes, "workers": 1})
    return _evaluation(per_episode, meta, run_dir, save)


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
    # A checkpoint chosen by its cycle (`--checkpoint 100`, or each of `--checkpoint snapshots`) is named once.
    named = "" if str(meta["checkpoint"]).isdigit() else f"{meta['checkpoint']}-"
    stem = f"{named}cycle{meta['cycle']}-{actions}-seed{meta['seed']}"
    stem += "-batched" if meta.get("path") == "batched" else ""
    stem += "-changed" if meta.get("env_overrides") else ""
    record = {**meta, "summary": result.summary, "per_episode": {k: v.tolist() for k, v in result.episodes.items()}}
    for json_path in numbered_paths(directory, stem, ".json"):
        try:
            with written_whole(json_path, replace=False) as draft:  # never over an earlier evaluation
                draft.write_text(json.dumps(record, indent=1))
            break
        except FileExistsError:
            continue
    plot_path = json_path.with_suffix(".png")
    with written_whole(plot_path) as draft:
        box_plot(result, draft)
    return replace(result, json_path=json_path, plot_path=plot_path)


def _number(value: float) -> str:
    """`value` for a plot title, never rounded to look like a round score or in powers of ten: three significant
    digits wrote CartPole's mean return of 499.9 as 500, a perfect score, and a cube return of 1,316 as 1.32e+03."""
    if abs(value) >= 1e4:
        return f"{value:,.0f}"
    return f"{value:,.1f}" if abs(value) >= 100 else f"{value:.4g}"


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
        ax.set_title(f"mean {_number(stats['mean'])}  median {_number(stats['median'])}\n"
                     f"mode {_number(stats['mode'])}", fontsize=9)
    meta = result.meta
    figure.suptitle(f"{meta['task']}, cycle {meta['cycle']}, {counted(meta['episodes'], 'episode')}, "
                    f"{'sampled' if meta['stochastic'] else 'mode'} actions", fontsize=10)
    figure.tight_layout()
    figure.savefig(path, dpi=100)
    plt.close(figure)
