"""`train(config)`: the thin Python loop around the compiled cycle, printing one line per cycle."""

from __future__ import annotations

import math
import time
from collections.abc import Callable

import flax.linen as nn
import jax

from angora_jax.envs.core import Env
from angora_jax.envs.registry import make
from angora_jax.ppo.config import PPOConfig
from angora_jax.ppo.cycle import TrainState, make_cycle


class TrainingDivergedError(FloatingPointError):
    """The loss or the parameters became NaN or infinite."""


def train(
    config: PPOConfig,
    env: Env | None = None,
    network: nn.Module | None = None,
    log: Callable[[str], None] | None = print,
) -> tuple[TrainState, list[dict[str, float]]]:
    """Run `config.num_cycles` PPO cycles and return the final state and one metrics dict per cycle.

    env: defaults to `make(config.task)`; network: defaults to `config.network` from the registry. Besides the
    cycle's metrics (see `make_cycle`), each dict holds cycle, env_steps, seconds (wall time of the cycle) and
    steps_per_second; the first cycle's wall time includes compilation, reported as compile_seconds.
    `log` receives one line per cycle (None for silence). Raises TrainingDivergedError when training produces
    non-finite values.
    """
    env = make(config.task) if env is None else env
    init, cycle = make_cycle(env, network, config)
    state = init(jax.random.key(config.seed))
    steps_per_cycle = config.num_envs * config.rollout_length
    history: list[dict[str, float]] = []
    for index in range(config.num_cycles):
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
        if index == 0:
            metrics["compile_seconds"] = seconds
        history.append(metrics)
        if not metrics["finite"]:
            raise TrainingDivergedError(
                f"Training diverged in cycle {index + 1}: the loss or the parameters are not finite "
                f"(loss={metrics['loss']}, grad_norm={metrics['grad_norm']}). Lower learning_rate (now "
                f"{config.learning_rate}) or max_grad_norm, keep normalization on, and check the task's rewards and "
                "observations for NaN or huge values."
            )
        if log is not None:
            log(format_metrics(metrics))
    return state, history


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
