"""How big a step each update takes: the optimizer with its learning rate (constant, linearly decayed or adapted to
the policy's KL step) and the entropy bonus's weight (constant or annealed).

A constant rate that suits the start of a run can be too large once the policy is sharp: the clip fraction and KL
stay high and the task metric falls from its peak. The KL-adaptive rule (Schulman et al. 2017's adaptive-KL idea
as rsl_rl and rl_games apply it to the step size) lowers the rate while updates move the policy too far and raises
it while they barely move it.
"""

from __future__ import annotations

from collections.abc import Sequence

import jax
import jax.numpy as jnp
import optax

from angora_jax.nets.components import frozen_optimizer
from angora_jax.ppo.config import PPOConfig

# rsl_rl's factor: one minibatch changes the rate by at most 1.5x.
ADAPT_FACTOR = 1.5


def make_optimizer(
    config: PPOConfig, updates_per_cycle: int, frozen: Sequence[str] = ()
) -> optax.GradientTransformation:
    """Gradient clipping and Adam at the config's learning rate, with zero updates for the `frozen` modules.

    With `target_kl` the rate is a hyperparameter held in the optimizer state (`optax.inject_hyperparams`), where
    `adapt_learning_rate` changes it; otherwise it follows a schedule of the update count (constant, or linear to 0
    over `num_cycles` with `lr_decay`), and the state holds no rate (checkpoints of such runs keep their layout).
    """

    def clipped_adam(learning_rate):
        return frozen_optimizer(
            optax.chain(optax.clip_by_global_norm(config.max_grad_norm), optax.adam(learning_rate, eps=1e-5)), frozen
        )

    if config.target_kl is not None:
        return optax.inject_hyperparams(clipped_adam)(learning_rate=config.learning_rate)
    return clipped_adam(schedule(config, updates_per_cycle))


def spanning_schedules(config: PPOConfig) -> list[str]:
    """The settings whose schedules end at the run's last cycle (`ppo.lr_decay`, `ppo.entropy_coef_final`): the only
    way `num_cycles` reaches the compiled programs, and why such a run cannot be lengthened mid-run."""
    return [name for name, on in (("ppo.lr_decay", config.lr_decay),
                                  ("ppo.entropy_coef_final", config.entropy_coef_final is not None)) if on]


def schedule(config: PPOConfig, updates_per_cycle: int) -> optax.Schedule:
    """The learning rate as a function of the update count, for runs without `target_kl`."""
    if config.lr_decay:
        return optax.linear_schedule(config.learning_rate, 0.0, config.num_cycles * updates_per_cycle)
    return optax.constant_schedule(config.learning_rate)


def adapt_learning_rate(opt_state: optax.OptState, approx_kl: jax.Array, config: PPOConfig) -> optax.OptState:
    """`opt_state` (of a `target_kl` optimizer) with its rate divided by 1.5 when `approx_kl` (a scalar, the same on
    every device) exceeds 2 * target_kl, multiplied by 1.5 when below target_kl / 2, within [lr_min, lr_max]."""
    rate = opt_state.hyperparams["learning_rate"]
    rate = jnp.where(approx_kl > 2 * config.target_kl, rate / ADAPT_FACTOR,
                     jnp.where(approx_kl < config.target_kl / 2, rate * ADAPT_FACTOR, rate))
    rate = jnp.clip(rate, config.lr_min, config.lr_max)
    return opt_state._replace(hyperparams=opt_state.hyperparams | {"learning_rate": rate})


def learning_rate(
    opt_state: optax.OptState, config: PPOConfig, updates: jax.Array, updates_per_cycle: int
) -> jax.Array:
    """The rate the next update uses (float32 scalar): the adapted one held in `opt_state`, or the schedule's after
    `updates` updates."""
    if config.target_kl is not None:
        return jnp.asarray(opt_state.hyperparams["learning_rate"], jnp.float32)
    return jnp.asarray(schedule(config, updates_per_cycle)(updates), jnp.float32)


def entropy_coef(config: PPOConfig, cycle: jax.Array) -> jax.Array:
    """The entropy bonus's weight in cycle `cycle` (0-based): `entropy_coef`, or with `entropy_coef_final` linearly
    from `entropy_coef` at cycle 0 to `entropy_coef_final` at the last cycle (`num_cycles - 1`) and after it."""
    if config.entropy_coef_final is None:
        return jnp.float32(config.entropy_coef)
    progress = jnp.clip(cycle / max(config.num_cycles - 1, 1), 0.0, 1.0)
    return jnp.float32(config.entropy_coef) + progress * (config.entropy_coef_final - config.entropy_coef)
