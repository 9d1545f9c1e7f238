"""Held-out evaluation during training (`evaluation.every`): the policy's deterministic score on fixed fresh
episodes, logged beside the training metrics."""

from __future__ import annotations

from collections.abc import Callable

import jax

from angora_jax.envs.core import Env
from angora_jax.experiment.config import Config
from angora_jax.ppo.cycle import TrainState
from angora_jax.ppo.evaluate import PolicyState, make_evaluate
from angora_jax.ppo.parallel import host_copy


def held_out_evaluation(config: Config, env: Env) -> Callable[[TrainState], dict[str, float]] | None:
    """`evaluate(state) -> {"eval/<metric>": mean}` for cycles that `config.evaluation` makes due, or None when it
    evaluates never. `evaluate(state)` returns {} for a cycle that is not due.

    Each process evaluates the same episodes alone on its first device, from its own copy of the replicated
    parameters: no program spans the processes, and all of them get the same values, so decisions taken on them
    (the best checkpoint, `ppo.stop_at`) agree.
    """
    settings = config.evaluation
    if not settings.every:
        return None
    run_episodes = make_evaluate(env, None, config.ppo, settings.episodes)
    key = jax.random.key(settings.seed)
    device = jax.local_devices()[0]

    def evaluate(state: TrainState) -> dict[str, float]:
        if not is_due(int(host_copy(state.cycle)), settings.every, config.ppo.num_cycles):
            return {}
        policy = PolicyState(params=state.params, obs_stats=state.obs_stats, cycle=state.cycle)
        values = jax.device_get(run_episodes(jax.device_put(host_copy(policy), device), key))
        return {f"eval/{name}": float(value) for name, value in values.items()}

    return evaluate


def is_due(cycle: int, every: int, last: int) -> bool:
    """Whether a task run every `every` cycles and after the `last` (an evaluation, a video) is due after `cycle`."""
    return cycle % every == 0 or cycle == last
