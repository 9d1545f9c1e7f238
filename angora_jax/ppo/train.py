"""`train(config, env)`: the thin Python loop around the compiled cycle, printing one line per cycle;
`training_cycles` is the same loop as a generator for callers that act between cycles (checkpoints, monitors), and
`seed_cycles` the loop for several seeds trained as one program."""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterator

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np

from angora_jax.envs.core import Env
from angora_jax.ppo.config import PPOConfig
from angora_jax.ppo.cycle import TrainState, make_cycle


class TrainingDivergedError(FloatingPointError):
    """The loss or the parameters became NaN or infinite."""


def train(
    config: PPOConfig,
    env: Env,
    network: nn.Module | None = None,
    log: Callable[[str], None] | None = print,
    state: TrainState | None = None,
    num_devices: int = 1,
) -> tuple[TrainState, list[dict[str, float]]]:
    """Run PPO cycles up to `config.num_cycles` and return the final state and one metrics dict per cycle run.

    env: the task (e.g. `angora_jax.make("CartPole")`); network: defaults to `config.network` from the registry.
    state: continue from this state (e.g. restored from a checkpoint) instead of a fresh one from `config.seed`.
    `log` receives one line per cycle (None for silence). Metrics are described in `training_cycles`. A state that
    has already run all cycles comes back unchanged with an empty history. num_devices: train data-parallel on
    this many devices (see `make_cycle`).
    """
    history: list[dict[str, float]] = []
    for latest, metrics in training_cycles(config, env, network, state, num_devices):
        state = latest
        history.append(metrics)
        if log is not None:
            log(format_metrics(metrics))
    return state, history


def training_cycles(
    config: PPOConfig,
    env: Env,
    network: nn.Module | None = None,
    state: TrainState | None = None,
    num_devices: int = 1,
) -> Iterator[tuple[TrainState, dict[str, float]]]:
    """Yield `(state, metrics)` after each cycle, from `state.cycle` (0 for a fresh state) to `config.num_cycles`.

    A generator, so that a caller can checkpoint, log or stop between cycles. Besides the cycle's metrics (see
    `make_cycle`), each dict holds cycle, env_steps, seconds (wall time of the cycle) and steps_per_second; the first
    cycle run by this call includes compilation, reported as compile_seconds. Raises TrainingDivergedError when
    training produces non-finite values.
    """
    init, cycle = make_cycle(env, network, config, num_devices)
    state = init(jax.random.key(config.seed)) if state is None else state
    first = int(state.cycle)
    for index in range(first, config.num_cycles):
        start = time.perf_counter()
        state, metrics = cycle(state)
        metrics = jax.device_get(metrics)
        yield state, cycle_record(config, metrics, index, first, time.perf_counter() - start)


def seed_cycles(
    config: PPOConfig, env: Env, seeds: list[int], network: nn.Module | None = None
) -> Iterator[tuple[TrainState, list[dict[str, float]]]]:
    """`training_cycles` for several seeds trained as one program (`make_cycle(..., num_seeds=len(seeds))`), from
    cycle 0: yield the states of all seeds (a leading seed axis on every leaf) and one metrics dict per seed, as a
    run of `config.replace(seed=seed)` alone would report them up to float rounding; their `seconds` (and
    `steps_per_second`, per seed) are the program's, shared by all seeds. Raises TrainingDivergedError naming the
    first seed whose training produced non-finite values."""
    init, cycle = make_cycle(env, network, config, num_seeds=len(seeds))
    state = init(jnp.stack([jax.random.key(seed) for seed in seeds]))
    for index in range(config.num_cycles):
        start = time.perf_counter()
        state, metrics = cycle(state)
        metrics = jax.device_get(metrics)
        seconds = time.perf_counter() - start
        yield state, [cycle_record(config, {name: value[i] for name, value in metrics.items()}, index, 0, seconds,
                                   seed) for i, seed in enumerate(seeds)]


def cycle_record(config: PPOConfig, metrics: dict[str, np.ndarray], index: int, first: int, seconds: float,
                 seed: int | None = None) -> dict[str, float]:
    """A finished cycle's metrics as floats with its count, env steps and timing (`compile_seconds` on the first
    cycle of a call); TrainingDivergedError when they are not finite (naming `seed`, when several train at once)."""
    steps_per_cycle = config.num_envs * config.rollout_length
    record = {name: float(value) for name, value in metrics.items()} | {
        "cycle": index + 1,
        "env_steps": (index + 1) * steps_per_cycle,
        "seconds": seconds,
        "steps_per_second": steps_per_cycle / seconds,
    }
    if index == first:
        record["compile_seconds"] = seconds
    if not record["finite"]:
        which = "" if seed is None else f" of seed {seed}"
        raise TrainingDivergedError(
            f"Training{which} diverged in cycle {index + 1}: the loss or the parameters are not finite "
            f"(loss={record['loss']}, grad_norm={record['grad_norm']}). Lower learning_rate (now "
            f"{config.learning_rate}) or max_grad_norm, keep normalization on, and check the task's rewards and "
            "observations for NaN or huge values."
        )
    return record


def format_metrics(metrics: dict[str, float]) -> str:
    """One line summarising a cycle."""

    def show(name: str, fmt: str) -> str:
        value = metrics.get(name, math.nan)
        return f"{name}={value:{fmt}}"

    parts = [
        f"cycle {metrics['cycle']:>4d}",
        f"steps {metrics['env_steps']:>10d}",
        show("episode_return", ".2f"),
        show("episode_length", ".1f"),
        *(f"{name}={value:.3f}" for name, value in metrics.items() if name.startswith("metric/")),
        show("loss", ".4f"),
        show("entropy", ".3f"),
        show("approx_kl", ".4f"),
        show("clip_fraction", ".3f"),
        show("explained_variance", ".3f"),
        show("learning_rate", ".2e"),
        f"sps={metrics['steps_per_second']:.0f}",
    ]
    return "  ".join(parts)
