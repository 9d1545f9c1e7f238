"""`load_agent(run_dir)`: a trained policy from a run directory, ready to act, evaluate and probe."""

from __future__ import annotations

import functools
import importlib.util
import json
import numbers
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp

from angora_jax.envs.core import Env, Sensation
from angora_jax.experiment.checkpoint import CheckpointError, Checkpoints, checkpoint_name
from angora_jax.experiment.config import (
    SEED_MAX,
    Config,
    ConfigError,
    DistributionConfig,
    check_count,
    check_flag,
    check_seed,
    load_config,
    override_strings,
    to_dict,
    validate,
)
from angora_jax.experiment.programs import initial_state_shape
from angora_jax.experiment.run_check import refused_as_edited
from angora_jax.experiment.run_dir import CHECKPOINTS, own_code_misfit, read_run_config, read_sessions, run_source
from angora_jax.nets import ActorCritic, make_network
from angora_jax.nets.components import register_run_reader
from angora_jax.ppo.cycle import build_head, build_model
from angora_jax.ppo.distributions import PolicyHead
from angora_jax.ppo.evaluate import PolicyState, SilencedPolicyState, make_evaluate, sent_to_task
from angora_jax.ppo.normalization import normalize_observation
from angora_jax.registry import generation
from angora_jax.saved_files import USE, msgpack_kind
from angora_jax.wording import counted


@dataclass(frozen=True)
class Agent:
    """A trained policy with everything needed to run it.

    Attributes:
        config: the run's config.
        env: its task.
        network: the policy/value network module.
        head: the policy head.
        state: the restored `PolicyState` (params, normaliser statistics); a `SilencedPolicyState` for an agent whose
            action components are silenced (`analysis.silence_actions`).
        cycle: the training cycle it was saved at.
        compiled: jitted functions of this agent's kind (see `compiled_once`), shared by every agent that `load_agent`
            makes from runs with the same task, network and head, and by their lesioned variants: parameters,
            normaliser statistics and silenced action components are their arguments (`acting_state`), so evaluating
            another checkpoint or lesion, or the same one again, does not compile again.
    """

    config: Config
    env: Env
    network: nn.Module
    head: PolicyHead
    state: PolicyState
    cycle: int
    compiled: dict[Any, Any] = field(default_factory=dict, repr=False, compare=False)

    def __repr__(self) -> str:
        # A notebook shows this for a cell ending in `agent`: not every parameter array.
        return (f"Agent(task={self.config.env.task!r}, network={self.config.ppo.network.name!r}, "
                f"head={type(self.head).__name__}, cycle={self.cycle})")

    def compiled_once(self, key: Any, build: Callable[[], Any]) -> Any:
        """`compiled[key]`, made by `build()` the first time (a jitted or compiled function of the agent's kind)."""
        if key not in self.compiled:
            self.compiled[key] = build()
        return self.compiled[key]

    @property
    def model(self) -> ActorCritic:
        """Network and head as one module: `model.apply({"params": agent.params}, carry, obs)`."""
        return build_model(self.network, self.head, self.config.ppo)

    @property
    def params(self) -> Any:
        return self.state.params

    @property
    def acting_state(self) -> PolicyState:
        """`state` as the compiled programs take it: a `SilencedPolicyState`, silencing no action component for an
        intact agent of continuous actions, so that the agent and its variants with silenced components share every
        program (one compile for all of `analysis.muscle_lesions`, not one per muscle); `state` itself for discrete
        actions, which are never silenced."""
        if isinstance(self.state, SilencedPolicyState) or self.env.action_spec.discrete:
            return self.state
        return SilencedPolicyState(params=self.state.params, obs_stats=self.state.obs_stats, cycle=self.state.cycle,
                                   silenced=jnp.zeros(self.env.action_spec.shape, bool))

    def initial_carry(self, batch_size: int) -> Any:
        """The recurrent state at an episode's start for `batch_size` environments (a whole number of at least 1:
        -1 or 2.5 failed inside JAX, 0 gave a carry no observation fits)."""
        return self.network.initial_carry(check_count("batch_size", batch_size))

    def apply(self, carry: Any, obs: Sensation, **apply_options: Any) -> Any:
        """One step of the model on raw observations (leaves `(B, size)`), normalised as in training.

        Returns `(carry, policy_params, value)`; `apply_options` go to flax's `apply`, e.g.
        `capture_intermediates=True` to also return every layer's activations for probing.
        """
        self._check_inputs(carry, obs)
        norm = self.config.ppo.normalization
        if norm.observations:
            obs = normalize_observation(self.state.obs_stats, obs, norm.clip)
        return self.model.apply({"params": self.params}, carry, obs, **apply_options)

    def _check_inputs(self, carry: Any, obs: Sensation) -> None:
        """ValueError (TypeError for no Sensation) naming what does not fit, before JAX fails deep inside the model:
        observations of another task or unbatched, or a carry made for another batch size. Shapes only: it costs
        nothing, under jit too."""
        if not isinstance(obs, Sensation):
            raise TypeError(f"obs must be a Sensation (a batch of the task's observations: jax.vmap(env.reset)(keys)"
                            f".obs, or a state's .obs), got {type(obs).__name__}.")
        sizes = {name: stats.mean.shape[-1] for name, stats in vars(self.state.obs_stats).items()}
        batch = None
        for name, leaf in vars(obs).items():
            shape = jnp.shape(leaf)
            images = sizes[name] == 0 and len(shape) == 5  # (B, cameras, height, width, channels): no stats
            if len(shape) < 2 or (not images and shape[-1] != sizes[name]):
                raise ValueError(
                    f"obs.{name} has shape {shape}; this agent ({self.config.env.task}) reads (B, {sizes[name]}) for "
                    f"a batch of B environments" + (": make one observation a batch of 1 with jax.tree.map(lambda x: "
                                                    "x[None], obs), or draw a batch with jax.vmap(env.reset)"
                                                    if len(shape) < 2 else ": observations of another task?"))
            batch = shape[0] if batch is None else batch
        carried = {jnp.shape(leaf)[0] for leaf in jax.tree.leaves(carry) if jnp.ndim(leaf)}
        if batch is not None and carried and carried != {batch}:
            raise ValueError(f"The carry is for a batch of {counted(sorted(carried)[0], 'environment')} and obs for "
                             f"{batch}: start it with agent.initial_carry({batch}).")

    def act(self, carry: Any, obs: Sensation,
            key: jax.Array | int | None = None) -> tuple[Any, jax.Array, jax.Array]:
        """Choose actions for a batch of B environments: the head's mode, or a sample when `key` is given: one JAX
        key for the whole batch (`jax.random.key(0)`) or a seed (an int, as `evaluate` takes one).

        carry: `initial_carry(B)` at episodes' starts, then what the previous call returned; obs: a Sensation of raw
        observations, leaves `(B, size)` (`jax.vmap(env.reset)(keys).obs`). Returns `(carry, env_actions, values)`:
        actions `(B, *action_shape)` ready for `jax.vmap(env.step)` (`(B,)` integers for discrete actions), 0 in the
        components the agent silences (`analysis.silence_actions`), values `(B,)` in the task's reward units
        (discounted return)."""
        key = None if key is None else sampling_key(key)
        carry, policy_params, value = self.apply(carry, obs)
        action = self.head.mode(policy_params) if key is None else self.head.sample(policy_params, key)
        return carry, sent_to_task(self.state, self.head.env_action(action)), value

    def evaluate(self, num_envs: int = 16, seed: int = 0, deterministic: bool = True) -> dict[str, float]:
        """One episode in each of `num_envs` fresh environments; means of episode_return, episode_length and the
        task metrics at episode ends (see `angora_jax.ppo.make_evaluate`)."""
        num_envs = check_count("num_envs", num_envs)
        seed = check_seed("seed", seed)
        deterministic = check_flag("deterministic", deterministic)
        evaluate = self.compiled_once(("evaluate", num_envs, deterministic), lambda: make_evaluate(
            self.env, self.network, self.config.ppo, num_envs, deterministic))
        return {k: float(v) for k, v in evaluate(self.acting_state, jax.random.key(seed)).items()}


def sampling_key(key: object) -> jax.Array:
    """`Agent.act`'s `key` as one JAX key: a key (typed, or the raw uint32 words of `jax.random.PRNGKey`) as it is, an
    int as the seed of `jax.random.key`, checked as `evaluate`'s seed is (True or -1 were taken as seeds without a
    word). Anything else is a TypeError naming what to pass: text, a float, a batch of keys or an int traced under
    jit failed deep inside JAX ("invalid PRNG key data", "categorical accepts a single key")."""
    if isinstance(key, numbers.Integral):  # numpy integers too
        return jax.random.key(check_seed("key given as a seed", key))
    dtype, shape = getattr(key, "dtype", None), getattr(key, "shape", None)
    if dtype is not None and jax.dtypes.issubdtype(dtype, jax.dtypes.prng_key) and shape == ():
        return key
    if dtype == jnp.uint32 and shape == jax.random.key_data(jax.random.key(0)).shape:  # the default kind's words
        return key
    given = repr(key) if dtype is None else f"an array of {dtype} of shape {tuple(shape)}"
    raise TypeError(f"key must be one JAX key for the whole batch, e.g. jax.random.key(0) (under jax.jit too), or a "
                    f"seed, a whole number from 0 to {SEED_MAX:,}; got {given}.")


def check_agent(agent: object) -> None:
    """TypeError naming what to do when `agent` is not an Agent: a run directory (what `record_activity` and
    `evaluate` take) or an exported `Policy` given where probing needs the agent itself, as a notebook easily does."""
    if isinstance(agent, Agent):
        return
    if isinstance(agent, str | Path):
        given, fix = f"the name {str(agent)!r}", f"load it first: agent = aj.load_agent({str(agent)!r})"
    elif isinstance(getattr(agent, "agent", None), Agent):
        given, fix = f"a {type(agent).__name__}", "give its .agent"
    else:
        given, fix = f"a {type(agent).__name__}", "load one with aj.load_agent(run_dir)"
    raise TypeError(f"This analysis takes an Agent, not {given}: {fix}.")


def load_agent(run_dir: str | Path, checkpoint: str | int = "best", env_overrides: Sequence[str] = ()) -> Agent:
    """The policy saved in `run_dir`.

    Only the parameters and observation statistics are read: the training environments' states in the checkpoint
    may have another layout than the current task's (e.g. the scene changed since training).

    Args:
        run_dir: the run directory.
        checkpoint: "best" (falls back to "latest" when the run keeps no best), "latest", or a cycle number with a
            checkpoint (see `RUN_DIR/checkpoints`; an int, a numpy integer or its digits as text).
        env_overrides: task options that differ from the run's, as `key.sub=value` strings applied to `env.options` as
            training applies overrides, for acting in a changed task whose observations the network still fits (e.g.
            `pose_estimator=FILE`: a cube policy trained on the true pose sees it through a pose estimator).

    Raises:
        CheckpointError: the parameters do not fit the config's network.
    """
    agent, read, latest = _restore_agent(run_dir, checkpoint, env_overrides)
    _note_early_best(run_dir, read, agent, latest, "--checkpoint latest; in Python checkpoint='latest'")
    return agent


def _restore_agent(run_dir: str | Path, checkpoint: str | int,
                   env_overrides: Sequence[str]) -> tuple[Agent, str | int, int]:
    """`load_agent`'s agent, the checkpoint read (`read_checkpoint`) and the cycle of the run's latest checkpoint (0
    when it keeps none)."""
    env_overrides = override_strings(env_overrides, "env_overrides")
    saved = read_run_config(run_dir)
    config = _seeing_as_trained(saved, run_dir)
    if env_overrides:
        for override in env_overrides:
            if "=" not in override:
                raise ConfigError(f"A task option is given as KEY=VALUE, e.g. max_episode_steps=20 (--env-option "
                                  f"max_episode_steps=20; in Python env_overrides=['max_episode_steps=20']), got "
                                  f"{override!r}.")
        # Given with the prefix that config files use (env.options.touch=true), an option means the same.
        config = load_config(to_dict(config), [f"env.options.{override.removeprefix('env.options.')}"
                                               for override in env_overrides])
    try:
        env, network, head, template, compiled = acting_parts(config)
    except ConfigError as error:
        if (edited := refused_as_edited(run_dir, saved, error)) is not None:
            raise edited from None
        raise
    checkpoints = Checkpoints(Path(run_dir) / CHECKPOINTS, config.checkpoint, create=False)
    which = read_checkpoint(run_dir, checkpoint)
    try:
        try:
            state = checkpoints.restore(template, which, partial=True).state
        except CheckpointError as error:
            # The run's own module edited since training (an observation widened) would be blamed on its config.yaml.
            if error.misfits and (changed := own_code_misfit(run_dir, error.misfits)) is not None:
                raise CheckpointError(changed, misfits=error.misfits) from None
            if not (env_overrides and error.misfits):
                raise
            # The network's inputs changed with the options, not the run's config (which the message would blame).
            raise CheckpointError(
                f"The task options {', '.join(env_overrides)} change what the network reads, so its checkpoint does "
                f"not fit them ({error.misfits}): give only options that keep the observations' sizes (e.g. "
                "randomization, reward, pose_estimator), or train a run with them.", misfits=error.misfits) from None
        latest = max(checkpoints.steps("latest"), default=0)
    finally:
        checkpoints.close()
    return Agent(config, env, network, head, state, int(state.cycle), compiled), which, latest


_noted_early_best: set[tuple[str, int]] = set()


def _note_early_best(run_dir: str | Path, read: str | int, agent: Agent, latest: int, how: str) -> None:
    """Once per run and cycle in a process: a note when the checkpoint `read` is the best and from the first half of
    the run (`how` names the way to read the latest instead)."""
    key = (str(Path(run_dir).resolve()), agent.cycle)
    if read != "best" or agent.cycle > latest / 2 or key in _noted_early_best:
        return
    _noted_early_best.add(key)
    # Using an early network unawares: a best metric that never rose (a success rate of 0) keeps cycle 1.
    print(f"Note: the best checkpoint of {run_dir} is cycle {agent.cycle}, from the first half of its {latest} "
          f"cycles: its {agent.config.checkpoint.best_metric} was not beaten after it (one that never rose keeps an "
          f"early cycle). The latest checkpoint ({how}) holds cycle {latest}.", file=sys.stderr, flush=True)


def read_checkpoint(run_dir: str | Path, checkpoint: str | int) -> str | int:
    """The checkpoint that `load_agent` reads for `checkpoint`: "latest" for "best" when the run keeps no best (its
    best metric is null, or fewer than `checkpoint.best_episodes` episodes had ended)."""
    checkpoint = checkpoint_name(checkpoint)
    best = Path(run_dir) / CHECKPOINTS / "best"
    kept = best.is_dir() and any(path.name.isdigit() for path in best.iterdir())
    return "latest" if checkpoint == "best" and not kept else checkpoint


def snapshot_cycles(run_dir: str | Path) -> list[int]:
    """The cycles of the snapshots that a run keeps for probing (`checkpoint.snapshot_every`), ascending; empty when
    it keeps none."""
    config = read_run_config(run_dir)  # TypeError or RunDirError for what is no run directory
    checkpoints = Checkpoints(Path(run_dir) / CHECKPOINTS, config.checkpoint, create=False)
    try:
        return checkpoints.steps("snapshots")
    finally:
        checkpoints.close()


def saved_policy(source: str | Path) -> PolicyState:
    """The parameters and observation statistics saved in a run, named `RUN_DIR` (its best checkpoint, or its
    latest when it keeps no best), `RUN_DIR:latest` or `RUN_DIR:<cycle>`; FileNotFoundError when there is no such
    run directory."""
    run_dir, which = run_source(source)
    if Path(run_dir).is_file():  # e.g. an exported policy or a component given to ppo.init_from
        kind = msgpack_kind(run_dir)
        raise ValueError(f"{str(source)!r} is a file, not a run directory: name the run it came from, as "
                         f"RUN_DIR[:best|latest|<cycle>]{f'. The file is {kind}: {USE[kind]}' if kind else ''}.")
    if not Path(run_dir).is_dir():
        raise FileNotFoundError(f"{str(source)!r} is neither a file nor a run directory: it does not exist. Give a "
                                "component file, or a run as RUN_DIR[:best|latest|<cycle>].")
    agent, read, latest = _restore_agent(run_dir, which, ())
    _note_early_best(run_dir, read, agent, latest, f"name it as {run_dir}:latest, e.g. ppo.init_from={run_dir}:latest")
    return agent.state


register_run_reader(saved_policy)


def acting_parts(config: Config) -> tuple[Env, nn.Module, PolicyHead, PolicyState, dict[Any, Any]]:
    """Environment, network, head, `PolicyState` template (shapes) and shared compiled functions for acting as
    `config`'s run does, on this machine."""
    # Acting needs the task and the model, not the training machine: a run trained on more devices, with TensorBoard,
    # W&B or MuJoCo Warp (and copied here) loads too.
    here = replace(
        config,
        env=replace(config.env, options=_without_missing_warp(config.env.options)),
        distribution=DistributionConfig(),
        logging=replace(config.logging, tensorboard=False, wandb=None),
    )
    return _acting_parts(json.dumps(to_dict(_acting_config(here)), sort_keys=True), generation())


def _acting_config(config: Config) -> Config:
    """What acting depends on: the task and the model; not the run's name, length, seed, logging or checkpoints."""
    ppo = replace(config.ppo, seed=0, num_cycles=1, lr_decay=False)
    return replace(config, ppo=ppo, logging=replace(config.logging, run_name=None), checkpoint=replace(
        config.checkpoint, best_metric=None))


@functools.lru_cache(maxsize=8)
def _acting_parts(config_json: str, definitions: int) -> tuple[Env, nn.Module, PolicyHead, PolicyState,
                                                               dict[Any, Any]]:
    """Environment, network, head, checkpoint template and the shared `Agent.compiled` of one acting config (a
    JSON text, hashable) and generation of registered definitions (`registry.generation()`: a task or network
    registered again after an edit builds anew): made once per process, so that loading agents of one kind again
    builds and compiles nothing again."""
    config = load_config(json.loads(config_json))
    env = validate(config, new_run=False)
    shape = initial_state_shape(config, env)
    template = PolicyState(params=shape.params, obs_stats=shape.obs_stats, cycle=shape.cycle)
    return env, make_network(config.ppo.network), build_head(env, config.ppo), template, {}


def _seeing_as_trained(config: Config, run_dir: str | Path) -> Config:
    """`config` with its camera vision (if any) tied to the renderer it trained with (`vision.renderer`, from the
    run's first session): a pixel policy acts only on frames drawn as it learned them, and a path that renders
    otherwise refuses, naming the fix (the option `vision.renderer=null` lifts it)."""
    vision = config.env.options.get("vision")
    sessions = read_sessions(run_dir)
    impl = sessions[0].get("physics", {}).get("impl") if sessions else None
    if not isinstance(vision, dict) or "renderer" in vision or impl is None:
        return config
    options = {**config.env.options, "vision": {**vision, "renderer": "warp" if impl == "warp" else "cpu"}}
    return replace(config, env=replace(config.env, options=options))


def _without_missing_warp(options: dict[str, Any]) -> dict[str, Any]:
    """Env options with MJX's own implementation ("jax") in place of MuJoCo Warp when warp-lang is not installed: the
    same model and policy, only the batched physics of `Agent.evaluate` computed another way (the eager evaluation
    path steps C MuJoCo either way)."""
    physics = options.get("physics") or {}
    if physics.get("impl") != "warp" or importlib.util.find_spec("warp") is not None:
        return options
    return {**options, "physics": {**physics, "impl": "jax"}}
