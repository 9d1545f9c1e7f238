"""`train(config, env)`: the thin Python loop around the compiled cycle, printing one line per cycle;
`training_cycles` is the same loop as a generator for callers that act between cycles (checkpoints, monitors)."""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterator

import flax.linen as nn
import jax

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

    Metrics are described in `training_cycles`. A state that has already run all cycles comes back unchanged with an
    empty history.

    Args:
        config: the PPO settings.
        env: the task (e.g. `angora_jax.make("CartPole")`).
        network: defaults to `config.network` from the registry.
        log: receives one line per cycle (None for silence).
        state: continue from this state (e.g. restored from a checkpoint) instead of a fresh one from `config.seed`.
        num_devices: train data-parallel on this many devices (see `make_cycle`).
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
    programs: tuple[Callable, Callable] | None = None,
) -> Iterator[tuple[TrainState, dict[str, float]]]:
    """Yield `(state, metrics)` after each cycle, from `state.cycle` (0 for a fresh state) to `config.num_cycles`.

    A `state` without environments (`TrainState.without_environments`, from a lean checkpoint) continues with
    environments made afresh, from keys of the seed and the state's cycle (a finished one comes back as it is).

    A generator, so that a caller can checkpoint, log or stop between cycles. Besides the cycle's metrics (see
    `make_cycle`), each dict holds cycle, env_steps, seconds (wall time of the cycle) and steps_per_second; the first
    cycle run by this call includes compilation, reported as compile_seconds. Raises TrainingDivergedError when
    training produces non-finite values.

    Args:
        programs: `make_cycle(env, network, config, num_devices)`, made by the caller (to reuse across calls); made here
            when None.
    """
    init, cycle = make_cycle(env, network, config, num_devices) if programs is None else programs
    if state is None:
        state = init(jax.random.key(config.seed))
    elif not state.has_environments and int(state.cycle) < config.num_cycles:
        fresh = init(jax.random.fold_in(jax.random.key(config.seed), int(state.cycle)))
        state = state.replace(actor=fresh.actor, discounted_return=fresh.discounted_return)
    steps_per_cycle = config.num_envs * config.rollout_length
    first = int(state.cycle)
    for index in range(first, config.num_cycles):
        start = time.perf_counter()
        state, metrics = cycle(state)
        metrics = {name: float(value) for name, value in jax.device_get(metrics).items()}
        seconds = time.perf_counter() - start
        metrics |= {
            "cycle": index + 1,
            "env_steps": (index + 1) * steps_per_cycle,
            "seconds": seconds,
            "steps_per_second": steps_per_cycle / seconds,
        }
        if index == first:
            metrics["compile_seconds"] = seconds
        if not metrics["finite"]:
            raise TrainingDivergedError(
                f"Training diverged in cycle {index + 1}: the loss or the parameters are not finite "
                f"(loss={metrics['loss']}, grad_norm={metrics['grad_norm']}). Lower learning_rate (now "
                f"{config.learning_rate}) or max_grad_norm, keep normalization on, and check the task's rewards and "
                "observations for NaN or huge values."
            )
        yield state, metrics


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
