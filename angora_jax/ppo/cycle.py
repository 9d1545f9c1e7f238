"""One PPO training cycle as one compiled program: rollout, GAE, then epochs of truncated-BPTT minibatch updates.

`init, cycle = make_cycle(env, network, config)`; `state = init(key)`; `state, metrics = cycle(state)`.
With `num_devices=D > 1` the same cycle runs data-parallel on D devices (see `angora_jax.ppo.parallel`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax import struct
from jax.sharding import PartitionSpec as P

from angora_jax.envs.core import Env, Sensation
from angora_jax.nets import ActorCritic, make_network
from angora_jax.nets.components import (
    component,
    load_component,
    read_saved_run,
    shape_misfits,
    stop_frozen_gradients,
    with_component,
)
from angora_jax.nets.models import FeedForward
from angora_jax.nets.visual import make_visual_area
from angora_jax.ppo.blocks import (
    LEADER,
    block_mask,
    entropy_weights,
    environment_blocks,
    leader_off_policy_loss,
    row_blocks,
)
from angora_jax.ppo.config import PPOConfig, tile_shape
from angora_jax.ppo.distributions import PolicyHead, make_head
from angora_jax.ppo.gae import gae, next_values
from angora_jax.ppo.grown_inputs import (
    asymmetric_growth,
    grown_params,
    grown_stats,
    grows_inputs_only,
    rows_reading_new_inputs,
)
from angora_jax.ppo.losses import LossInputs, advantage_moments, normalized_advantages, ppo_loss
from angora_jax.ppo.normalization import RunningMeanStd, discounted_returns, observation_stats
from angora_jax.ppo.parallel import (
    AXIS,
    axis_name,
    data_parallel,
    environment_keys,
    local_share,
    per_device,
    pmean,
    psum,
)
from angora_jax.ppo.rollout import ActorState, Trajectory, make_rollout
from angora_jax.ppo.step_size import adapt_learning_rate, entropy_coef, learning_rate, make_optimizer
from angora_jax.ppo.tbptt import gather_carries, gather_sequences, minibatch_indices, unroll


@struct.dataclass
class TrainState:
    """Everything a run carries from cycle to cycle; arrays only, so it can be checkpointed and resumed.

    Attributes:
        params: network parameters.
        opt_state: optimizer state.
        obs_stats: a Sensation of `RunningMeanStd`, one per modality.
        reward_stats: running stats of the discounted return.
        discounted_return: `(N,)` the discounted return of each environment's running episode.
        actor: environment states, recurrent carries and episode accumulators of the N environments.
        key: PRNG key.
        cycle: int32 count of finished cycles.
    """

    params: Any
    opt_state: Any
    obs_stats: Sensation
    reward_stats: RunningMeanStd
    discounted_return: jax.Array
    actor: ActorState
    key: jax.Array
    cycle: jax.Array

    def without_environments(self) -> TrainState:
        """This state without what belongs to the N environments (`actor`, `discounted_return` become None): what a
        lean checkpoint keeps. `training_cycles` makes the environments afresh for such a state."""
        return self.replace(actor=None, discounted_return=None)

    @property
    def has_environments(self) -> bool:
        return self.actor is not None


@struct.dataclass
class Batch:
    """Training data of one cycle, leaves `(C, s, N, ...)`: the inputs to replay plus the loss inputs."""

    obs: Sensation
    resets: jax.Array
    loss: LossInputs


def average_gradients(grads: Any, axis: str | None = None) -> Any:
    """The one place where gradients are combined across devices: their mean over the mapped `axis`; a single
    device (`axis` None) needs no averaging. Each device's gradient is of the mean loss over its equal share of the
    minibatch, so the mean over devices is the gradient of the whole minibatch's mean loss."""
    return pmean(grads, axis)


def build_head(env: Env, config: PPOConfig) -> PolicyHead:
    """The policy head named by `config.head` for `env`'s action space, with the config's head options."""
    name = config.head_for(env)
    options = {"multicategorical": {"bins": config.bins}, "gaussian": {"init_log_std": config.init_log_std},
               "beta": {"init_mean": config.beta_init_mean}}
    return make_head(name, env.action_spec, **options.get(name, {}))


def build_model(network: nn.Module, head: PolicyHead, config: PPOConfig) -> ActorCritic:
    """The network and head as the one module that training, evaluation and loaded agents apply, with the config's
    visual area and policy blocks (`ppo.blocks`; called without a block, it acts with the leader)."""
    return ActorCritic(network, head, make_visual_area(config.network.visual), config.blocks.count,
                       config.blocks.embedding_size)


def make_cycle(
    env: Env, network: nn.Module | None, config: PPOConfig, num_devices: int = 1
) -> tuple[Callable[[jax.Array], TrainState], Callable[[TrainState], tuple[TrainState, dict[str, jax.Array]]]]:
    """Build the jitted `init(key) -> TrainState` and `cycle(state) -> (state, metrics)`.

    Each cycle consumes `num_envs * rollout_length` environment steps. Metrics are float32 scalars: episodes
    (finished in this cycle), episode_return and episode_length (means over them, NaN if none finished; an
    environment's first episode counts its length from the staggered clock it starts with, so early cycles' lengths
    run long), `metric/<name>` task metrics at episode ends, the loss parts averaged over all minibatches,
    explained_variance, learning_rate and finite (1 if the losses and parameters are finite). With several devices
    they are over all devices. With policy blocks (`ppo.blocks.count` > 1) the episode metrics are the leader's, each
    block's are also given as `block<j>/<name>`, and the loss parts add the leader's off-policy term's
    (`leader_off_policy_loss`, `leader_clip_fraction`).

    Args:
        env: the task.
        network: a module following the network contract (see `angora_jax.nets`), or None to build `config.network`
            from the registry.
        config: the PPO settings.
        num_devices: D devices to run data-parallel on; `config.num_envs` and `config.minibatch_size` are totals that
            must divide by D (ValueError otherwise). For D > 1, `init` returns the state already laid out over the
            devices and `cycle` accepts any state of the run's shapes (e.g. one restored from a checkpoint) and lays it
            out first. D = 1 compiles the plain cycle, with no collectives; D > 1 computes the same cycle up to
            floating-point summation order (same random numbers, same minibatches).

    Returns:
        `(init, cycle)`; `cycle.lower(state)` gives the compiled program, as for a `jax.jit` function.
    """
    config.validate_for(env)
    problem = env.data_parallel_problem() if num_devices > 1 else None
    if problem:
        raise ValueError(f"{problem}: train it on one device (distribution.num_devices=1).")
    local = per_device(config, num_devices)
    env = env.sized_for(local.num_envs)
    axis = axis_name(num_devices)
    network = make_network(config.network) if network is None else network
    head = build_head(env, config)
    model = build_model(network, head, config)
    blocks = config.blocks
    num_envs, chunk_length = local.num_envs, config.chunk_length
    num_chunks = config.rollout_length // chunk_length
    tile = tile_shape(config)  # the run's minibatch tile; each device takes 1/D of its trajectories
    minibatch_rows = tile[0] // num_devices * tile[1]
    updates_per_cycle = config.num_epochs * (config.num_envs * config.rollout_length // config.minibatch_size)
    optimizer = make_optimizer(config, updates_per_cycle, config.network.frozen)
    norm = config.normalization

    def acting_blocks() -> jax.Array | None:
        # Traced inside the (per-device) program, where the device's index is known.
        return environment_blocks(config.num_envs, blocks.count, axis) if blocks.enabled else None

    def apply_fn(params, carry, obs):
        return model.apply({"params": params}, carry, obs, block=acting_blocks())

    rollout = make_rollout(
        env,
        apply_fn,
        head,
        network.initial_carry(num_envs),
        num_chunks,
        chunk_length,
        norm.observations,
        norm.clip,
        axis,
    )

    def init(key: jax.Array) -> TrainState:
        # The state of all config.num_envs environments, whatever the device count: on D devices each makes its
        # share from its block of the same per-environment keys (`environment_keys`), so the values do not depend
        # on D, while whatever a share of environments owns together (MuJoCo Warp's contact pool) is its own.
        env_key, param_key, key = jax.random.split(key, 3)
        env_state = jax.vmap(env.reset)(environment_keys(env_key, config.num_envs, axis))
        # Episode clocks start spread over [0, max_episode_steps): otherwise tasks without early termination (reach)
        # end every episode on the same step forever, so each cycle's batch holds one phase of the episode only and
        # consecutive updates chase different phases. The first episodes are shorter.
        first_steps = jax.random.randint(jax.random.fold_in(env_key, 1), (config.num_envs,), 0, env.max_episode_steps)
        env_state = env_state.replace(steps=local_share(first_steps, axis))
        carry = network.initial_carry(num_envs)
        params = model.init(param_key, carry, env_state.obs)["params"]
        zeros = jnp.zeros((num_envs,), jnp.float32)
        return TrainState(
            params=params,
            opt_state=optimizer.init(params),
            obs_stats=observation_stats(env.observation_shapes()),
            reward_stats=RunningMeanStd.create(),
            discounted_return=zeros,
            actor=ActorState(env_state, carry, zeros, zeros),
            key=key,
            cycle=jnp.zeros((), jnp.int32),
        )

    def loss_fn(params, sequences: Batch, start_carry, entropy_weight, rows):
        params = stop_frozen_gradients(params, config.network.frozen)
        # Camera images of all s steps are encoded as one batch, not step by step inside the recurrent scan.
        obs = model.apply({"params": params}, sequences.obs, method=ActorCritic.perceive)

        def forward(block):
            return unroll(
                lambda carry, obs, *sequence: model.apply({"params": params}, carry, obs, *sequence, block=block),
                jax.lax.stop_gradient(start_carry),  # truncated BPTT: no gradient across chunk borders
                network.initial_carry(minibatch_rows),
                obs,
                sequences.resets,
                model.runs_sequences,
            )

        _, policy_params, values = forward(rows)
        loss, parts = ppo_loss(
            head,
            policy_params,
            values,
            sequences.loss,
            config.clip_epsilon,
            config.value_coef,
            entropy_weight,
            config.value_clip,
        )
        if blocks.enabled and blocks.leader_off_policy_weight > 0:
            # The leader acting on every row; the term counts the followers' rows only.
            _, leader_params, _ = forward(jnp.full_like(rows, LEADER))
            off_policy, off_parts = leader_off_policy_loss(head, leader_params, sequences.loss, rows,
                                                           config.clip_epsilon, blocks.leader_off_policy_weight,
                                                           blocks.count)
            loss = loss + off_policy
            parts = parts | off_parts | {"loss": loss}
        return loss, parts

    def update_minibatch(batch: Batch, start_carries, env_blocks, entropy_weight, train, minibatch):
        params, opt_state = train
        (env_index, chunk_index), moments = minibatch
        rows = None
        if blocks.enabled:
            rows = row_blocks(env_blocks, env_index, chunk_index.shape[0])
            entropy_weight = entropy_weights(blocks, entropy_weight, rows)
        sequences = gather_sequences(batch, chunk_index, env_index)
        if config.normalize_advantages:
            loss_inputs = sequences.loss
            advantages = normalized_advantages(loss_inputs.advantages, *moments)
            sequences = sequences.replace(loss=loss_inputs.replace(advantages=advantages))
        start_carry = gather_carries(start_carries, chunk_index, env_index)
        grads, parts = jax.grad(loss_fn, has_aux=True)(params, sequences, start_carry, entropy_weight, rows)
        grads = average_gradients(grads, axis)
        parts["grad_norm"] = optax.tree.norm(grads)
        if config.target_kl is not None:
            # The minibatch's KL before this update, over all devices, so that every device sets the same rate.
            opt_state = adapt_learning_rate(opt_state, pmean(parts["approx_kl"], axis), config)
        updates, opt_state = optimizer.update(grads, opt_state, params)
        return (optax.apply_updates(params, updates), opt_state), parts

    def update_epoch(batch: Batch, start_carries, env_blocks, entropy_weight, train, key):
        indices = minibatch_indices(key, config.num_envs, num_chunks, tile, axis)
        moments = None
        if config.normalize_advantages:
            per_minibatch = jax.vmap(lambda e, c: gather_sequences(batch.loss.advantages, c, e))(*indices)
            moments = advantage_moments(per_minibatch, axis)
        return jax.lax.scan(lambda t, x: update_minibatch(batch, start_carries, env_blocks, entropy_weight, t, x),
                            train, (indices, moments))

    def cycle(state: TrainState) -> tuple[TrainState, dict[str, jax.Array]]:
        key, rollout_key, update_key = jax.random.split(state.key, 3)
        # The named scopes label the compiled ops by phase, which is how benchmarks/profile_cycle.py splits a
        # profile's device time.
        with jax.named_scope("rollout"):
            actor, obs_stats, traj, start_carries, last_value = rollout(
                state.params, state.obs_stats, state.actor, environment_keys(rollout_key, config.num_envs, axis)
            )

        def flat(x):  # (C, s, N, ...) -> (T, N, ...)
            return x.reshape((config.rollout_length,) + x.shape[2:])

        def chunked(x):  # (T, N, ...) -> (C, s, N, ...)
            return x.reshape((num_chunks, chunk_length) + x.shape[1:])

        rewards, dones, values = flat(traj.rewards), flat(traj.dones), flat(traj.values)
        reward_stats, discounted = state.reward_stats, state.discounted_return
        with jax.named_scope("advantages"):
            if norm.rewards:
                seen, discounted = discounted_returns(discounted, rewards, dones, config.gamma)
                reward_stats = reward_stats.update(seen, axis)
                rewards = reward_stats.scale(rewards, norm.clip)
            following = next_values(values, last_value, flat(traj.final_values), dones, flat(traj.truncated))
            advantages, targets = gae(rewards, values, following, dones, config.gamma, config.gae_lambda)
        batch = Batch(
            obs=traj.obs,
            resets=traj.resets,
            loss=LossInputs(traj.actions, traj.log_probs, traj.values, chunked(advantages), chunked(targets)),
        )
        entropy_weight = entropy_coef(config, state.cycle)
        env_blocks = acting_blocks()
        with jax.named_scope("update"):
            (params, opt_state), parts = jax.lax.scan(
                lambda t, k: update_epoch(batch, start_carries, env_blocks, entropy_weight, t, k),
                (state.params, state.opt_state),
                jax.random.split(update_key, config.num_epochs),
            )
        metrics = {name: pmean(value.mean(), axis) for name, value in parts.items()}
        if blocks.enabled:
            metrics |= block_episode_metrics(traj, env_blocks, blocks.count, axis)
        else:
            metrics |= episode_metrics(traj.dones, traj.episode_return, traj.episode_length, traj.metrics, axis)
        metrics["explained_variance"] = explained_variance(targets, values, axis)
        # The rate this cycle's first update used (the schedule's), or the one the KL rule left after its last.
        metrics["learning_rate"] = learning_rate(opt_state, config, state.cycle * updates_per_cycle, updates_per_cycle)
        metrics["entropy_coef"] = entropy_weight
        params_finite = jnp.all(jnp.array([jnp.all(jnp.isfinite(p)) for p in jax.tree.leaves(params)]))
        finite = (jnp.all(jnp.isfinite(parts["loss"])) & params_finite).astype(jnp.float32)
        metrics["finite"] = jnp.floor(pmean(finite, axis))  # 1 only where every device is finite
        new_state = TrainState(
            params=params,
            opt_state=opt_state,
            obs_stats=obs_stats,
            reward_stats=reward_stats,
            discounted_return=discounted,
            actor=actor,
            key=key,
            cycle=state.cycle + 1,
        )
        return new_state, metrics

    if num_devices == 1:
        # The state's placement is part of what a jitted function is compiled for: a fresh state is uncommitted, one
        # restored from a checkpoint is committed to the device (and the cycle's outputs then too), and each would
        # compile the cycle anew (a resume compiled it twice). Fixed shardings give every state one program.
        device = jax.sharding.SingleDeviceSharding(jax.local_devices()[0])
        init_fn = jax.jit(init, out_shardings=device)
        cycle_fn = jax.jit(cycle, in_shardings=device, out_shardings=device)
    else:
        specs = partition_specs()
        init_fn = data_parallel(init, P(), specs, num_devices)
        cycle_fn = data_parallel(cycle, specs, (specs, P()), num_devices)
    if config.network.pretrained or config.init_from:
        def rows_reading(params: Any, old_size: int) -> Any:
            def value_of(p: Any, obs: Sensation) -> jax.Array:
                return model.apply({"params": p}, network.initial_carry(obs.asymmetric.shape[0]), obs)[2]
            return rows_reading_new_inputs(value_of, params, env.observation_shapes(), old_size, jax.random.key(0))

        init_fn = _with_saved_values(init_fn, config.network.pretrained, config.init_from, rows_reading,
                                     config.network.memory)
    if num_devices == 1:
        return init_fn, cycle_fn
    return lambda key: cycle_fn.place(init_fn(key)), cycle_fn


def partition_specs() -> TrainState:
    """How a TrainState lies over the data-parallel mesh: what belongs to environments (their states, carries,
    accumulators, discounted returns) split over `AXIS` by environment, everything else replicated."""
    return TrainState(params=P(), opt_state=P(), obs_stats=P(), reward_stats=P(), discounted_return=P(AXIS),
                      actor=P(AXIS), key=P(), cycle=P())


def _with_saved_values(init: Callable[[jax.Array], TrainState], pretrained: dict[str, str], init_from: str | None,
                       rows_reading: Callable[[Any, int], Any], memory: int):
    """`init` followed by loading a saved run's parameters and observation statistics (`init_from`), then the
    `pretrained` components over them; on the host, when first called, so their values are not baked into a
    compiled program and a run only reads its sources when it starts from scratch. A saved run whose `asymmetric`
    inputs were fewer (`grown_inputs`) has its value function's new input weights found by `rows_reading(params,
    old_size)` and set to zero; one without the memory this run adds (`memory` units, `_memory_added`) has it as
    initialized."""
    loaded = {}

    def init_with_saved_values(key: jax.Array) -> TrainState:
        state = None
        if not loaded:
            if init_from:  # checked against the shapes first: a run that does not fit fails before any compile
                saved, shapes = read_saved_run(init_from), jax.eval_shape(init, key)
                growth = _saved_run_growth(shapes, _memory_added(shapes.params, saved, memory), init_from)
                state = init(key)
                saved = _memory_added(jax.device_get(state.params), saved, memory)
                loaded["run"] = (_carried(state, saved, growth, rows_reading, init_from) if growth else
                                 (_fitting(shapes.params, saved.params, "network parameters", init_from),
                                  _fitting(shapes.obs_stats, saved.obs_stats, "observation statistics", init_from)))
            loaded["components"] = {path: load_component(source, path) for path, source in pretrained.items()}
        state = init(key) if state is None else state
        params, obs_stats = loaded.get("run", (state.params, state.obs_stats))
        for path, values in loaded["components"].items():
            params = with_component(params, path, values)
        return state.replace(params=jax.device_put(params), obs_stats=jax.device_put(obs_stats))

    return init_with_saved_values


def _memory_added(params: Any, saved: Any, memory: int) -> Any:
    """The saved run `saved` with the memory modules of this run's `params` that its parameters lack taken from
    `params` (`network.memory`, `FeedForward.MEMORY_MODULES`): a run of the MLP without memory starts the same MLP
    with memory as itself, the memory's output layer being zero. `params` may hold shapes (`jax.eval_shape`), taken
    as zeros of those shapes where only shapes are checked. `saved` itself when this run has no memory (`memory` 0).
    """
    if not memory:
        return saved
    ours, theirs = params.get("network", {}), saved.params.get("network", {})
    added = {name: ours[name] for name in FeedForward.MEMORY_MODULES if name in ours and name not in theirs}
    added = jax.tree.map(lambda leaf: np.zeros(leaf.shape, leaf.dtype) if isinstance(leaf, jax.ShapeDtypeStruct)
                         else leaf, added)
    return saved.replace(params={**saved.params, "network": {**theirs, **added}}) if added else saved


def _saved_run_growth(shapes: TrainState, saved: Any, source: str) -> int:
    """0 when the saved run `source` fits `shapes` as it is; the entries `asymmetric` gained at its end when it fits
    but for them (`grown_inputs`, e.g. `env.options.value_sees_physics` turned on); SavedRunMisfit otherwise."""
    growth = asymmetric_growth(shapes.obs_stats, saved.obs_stats)
    if growth and grows_inputs_only(shapes.params, saved.params, growth):
        return growth
    _fitting(shapes.params, saved.params, "network parameters", source)
    _fitting(shapes.obs_stats, saved.obs_stats, "observation statistics", source)
    return 0


def _carried(state: TrainState, saved: Any, growth: int, rows_reading: Callable[[Any, int], Any],
             source: str) -> tuple[Any, Sensation]:
    """The saved run's parameters and observation statistics in `state`'s shapes, `asymmetric` having gained `growth`
    entries: the weights that read them at zero (`grown_inputs`)."""
    params = jax.device_get(state.params)
    old_size = state.obs_stats.asymmetric.mean.shape[0] - growth
    grown = grown_params(params, saved.params, rows_reading(params, old_size))
    if grown is None:
        raise SavedRunMisfit(f"ppo.init_from {source!r}: this run's value function reads {growth} more `asymmetric` "
                             "inputs, but the weights that read them could not be told apart (a network that "
                             "normalizes or mixes its inputs before its first dense layer); take the policy alone "
                             "with ppo.network.pretrained={MODULE: SOURCE, ...} instead (docs/tasks.md, Domain "
                             "randomization).")
    return grown, grown_stats(jax.device_get(state.obs_stats), saved.obs_stats)


class SavedRunMisfit(ValueError):
    """The network parameters or observation statistics of the run `ppo.init_from` names do not fit this run's."""


def _fitting(current: Any, saved: Any, what: str, source: str) -> Any:
    """`saved` as `current`'s dtypes, when it has `current`'s leaves and shapes; a SavedRunMisfit naming those that
    differ otherwise."""
    differing = shape_misfits(current, saved)
    if differing:
        value_only = all("['value" in misfit.split(":")[0] for misfit in differing)  # value_trunk, value, ...
        hint = (" Only the value function's parameters differ: to fine-tune the policy alone, take its modules with "
                "ppo.network.pretrained={MODULE: SOURCE, ...} instead, the value function starting afresh "
                "(docs/tasks.md, Domain randomization)." if value_only else "")
        raise SavedRunMisfit(f"ppo.init_from {source!r}: its {what} do not fit this run's ({'; '.join(differing[:4])})"
                             f"; give the saved run's network settings, on a task with its observation shapes.{hint}")
    return jax.tree.map(lambda old, new: jnp.asarray(new, dtype=old.dtype), current, saved)


def check_saved_values(env: Env, config: PPOConfig) -> None:
    """Check what `make_cycle`'s `init` will load and what training will freeze, without compiling or running
    anything: every module path of `network.frozen` and `network.pretrained` names a module of the run's parameters,
    and every source (`init_from`, `network.pretrained`) can be read and fits them. ValueError (SavedRunMisfit for a
    saved run that does not fit; any error reading a source, OSError included, as a ValueError) naming the key, the
    module or source, and the fix."""
    network = dataclasses.replace(config.network, frozen=(), pretrained={})
    init, _ = make_cycle(env, None, config.replace(network=network, init_from=None))
    shapes = jax.eval_shape(init, jax.random.key(0))
    for key, paths in (("frozen", config.network.frozen), ("pretrained", config.network.pretrained)):
        for path in paths:
            try:
                component(shapes.params, path)
            except ValueError as error:
                raise ValueError(f"ppo.network.{key} names {path!r}: {error} Name modules by their dotted paths, as "
                                 "recordings name layers.") from None
    if config.init_from:
        saved = _read_source("ppo.init_from", config.init_from, read_saved_run, config.init_from)
        _saved_run_growth(shapes, _memory_added(shapes.params, saved, config.network.memory), config.init_from)
    for path, source in config.network.pretrained.items():
        values = _read_source(f"ppo.network.pretrained[{path!r}]", source, load_component, source, path)
        differing = shape_misfits(component(shapes.params, path), values)
        if differing:
            raise ValueError(f"ppo.network.pretrained[{path!r}]: the values in {source!r} do not fit this network's "
                             f"module ({'; '.join(differing[:4])}); give the network the sizes the component was "
                             "trained with, or a component saved from a network of this run's sizes.")


def _read_source(key: str, source: str, read: Callable[..., Any], *args: Any) -> Any:
    """`read(*args)`, any error reading the source (a file or run that is missing, damaged or not one) as a ValueError
    that starts with `key` and `source`."""
    try:
        return read(*args)
    except (ValueError, OSError) as error:
        raise ValueError(f"{key}={source!r}: {error}") from None


def block_episode_metrics(traj: Trajectory, env_blocks: jax.Array, count: int, axis: str | None = None
                          ) -> dict[str, jax.Array]:
    """`episode_metrics` of each of `count` policy blocks, as `block<j>/<name>`, and the leader's (block 0) under the
    plain names, which is what `checkpoint.best_metric`, `ppo.stop_at` and the progress line read: the policy that
    evaluation acts with. `env_blocks` `(N,)` is each environment's block."""
    per_block = {}
    for block in range(count):
        mask = block_mask(env_blocks, block)
        per_block[block] = episode_metrics(traj.dones * mask, traj.episode_return * mask, traj.episode_length * mask,
                                           traj.metrics, axis)
    named = {f"block{block}/{name}": value for block, metrics in per_block.items() for name, value in metrics.items()}
    return per_block[LEADER] | named


def variance(x: jax.Array, axis: str | None = None) -> jax.Array:
    """Variance of all elements of `x`, pooled over the devices on `axis` (equal shares) when given."""
    if axis is None:
        return jnp.var(x)
    mean = pmean(x.mean(), axis)
    return pmean(((x - mean) ** 2).mean(), axis)


def explained_variance(targets: jax.Array, values: jax.Array, axis: str | None = None) -> jax.Array:
    """The share of the value targets' variance that the values explain, 1 - var(targets - values) / var(targets),
    pooled over the devices on `axis`: 1 for exact values, 0 for a constant."""
    return 1.0 - variance(targets - values, axis) / (variance(targets, axis) + 1e-8)


def episode_metrics(
    dones: jax.Array,
    returns: jax.Array,
    lengths: jax.Array,
    task_metrics: dict[str, jax.Array],
    axis: str | None = None,
) -> dict[str, jax.Array]:
    """Means over the episodes that ended in a rollout (NaN when none did); inputs are per-step arrays that are 0
    except where an episode ended, `task_metrics` holds the task's metrics at every step. With `axis`, the
    episodes of all devices count."""
    episodes = psum(dones.sum(), axis)
    denominator = jnp.where(episodes > 0, episodes, jnp.nan)
    metrics = {
        "episodes": episodes,
        "episode_return": psum(returns.sum(), axis) / denominator,
        "episode_length": psum(lengths.sum(), axis) / denominator,
    }
    for name, value in task_metrics.items():
        metrics[f"metric/{name}"] = psum((value * dones).sum(), axis) / denominator
    return metrics
