"""Brax's PPO and ours, side by side, training the same task of ours: with matched settings (`--recipes matched`,
the default: a like-for-like comparison of the two trainers' speed), or each with its own published recipe
(`--recipes own`: ours with its family config as it ships, Brax with the settings of Brax's training colab for its
version of the robot, `BRAX_RECIPES`: an anchor for the return and the wall time to a fixed return).

Brax (`brax.training.agents.ppo.train`, from PyPI: `pip install -e ".[bench]"`) trains our environment through
`BraxAdapter`, a `brax.envs.base.Env` over our `reset` and `advance` (a step without our auto-reset): Brax's own
training wrappers add the episode limit and auto-reset, as for any Brax environment. With matched settings, our
trainer runs the same task with the same number of environments, unroll (rollout) length, minibatch size, epochs,
learning rate, discount, GAE lambda, clipping, entropy and value coefficients, gradient clipping, observation
normalisation, the same feed-forward network (policy and value MLPs of the same widths, tanh, the value MLP also
reading the privileged `asymmetric` modality) and the same kind of policy (a Gaussian with state-independent learned
log std, actions clipped to the bounds), for the same number of env steps.

Reported per side: env steps/s with compilation excluded (all training segments after the first), the first
call's extra time (the first segment's time less what it takes at the steady rate: compilation, mostly), the
return at equal env steps and at equal wall time, and the training wall time to the first snapshot that reached a
target return (`--target`, by default the task's in `common.TARGETS`). Each side's policy is saved at `--snapshots`
evenly spaced points, and every snapshot is scored the same way afterwards: mean episode return (and the task's
metrics at the episode's end) of the deterministic policy (the Gaussian's mean) over `--eval-envs` episodes of our
environment, same keys for both. Wall time is training time: the sum of the training segments, the first
(compiling) one included, evaluation excluded.

Differences that remain, by design of the two libraries: Brax auto-resets an environment to the first state it
was reset to (same goal each episode of one environment; ours draws a fresh one), masks truncated steps out of
the loss instead of bootstrapping them, scales rewards by a constant instead of normalising them, and does not
clip normalised observations; initialisations differ (orthogonal here, LeCun uniform there).

    python benchmarks/brax_side_by_side.py --task Pendulum --num-envs 16 --timesteps 20000   # CPU, seconds
    python benchmarks/brax_side_by_side.py --num-envs 4096 --rollout-length 32 --timesteps 5000000 --eval-envs 512
    python benchmarks/brax_side_by_side.py --task HalfCheetah --recipes own --timesteps 50000000 --snapshots 20 \
        --eval-envs 128                                 # GPU: locomotion.yaml against Brax's HalfCheetah recipe
"""

from __future__ import annotations

import argparse
import dataclasses
import inspect
import json
import math
import os
import time
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import yaml
from brax.envs.base import Env as BraxEnv
from brax.envs.base import State as BraxState
from brax.envs.wrappers import training as brax_training
from brax.training.agents.ppo import networks as brax_networks
from brax.training.agents.ppo import train as brax_ppo
from common import TARGETS, env_step_rate, markdown_table, measure_compiled, study_folder, write_results
from flax import linen

from angora_jax.envs.core import Env, Sensation
from angora_jax.envs.random_rollout import random_action
from angora_jax.envs.registry import make
from angora_jax.experiment import load_config, validate
from angora_jax.nets import ActorCritic, make_network, policy_inputs, value_inputs
from angora_jax.ppo import NetworkConfig, PPOConfig, build_head, training_cycles
from angora_jax.ppo.normalization import normalize_observation


def device_put_replicated(tree: Any, devices: list) -> Any:
    """`jax.device_put_replicated`, which JAX 0.10 removed and Brax 0.14.2 (the newest on PyPI) still calls
    (google/brax issue 671): each leaf stacked once per device and laid out by an identity `pmap` over Brax's axis
    name, so that the training state has the layout of Brax's own `pmap` outputs; any other layout makes the
    training epoch compile a second time on its second call (measured: 10 s of the first 30 s on this CPU)."""
    stacked = jax.tree.map(lambda x: jnp.stack([x] * len(devices)), tree)
    return jax.pmap(lambda t: t, axis_name=brax_ppo._PMAP_AXIS_NAME, devices=devices)(stacked)


if "device_put_replicated" not in vars(jax):
    jax.device_put_replicated = device_put_replicated

# Brax's observation keys: the policy reads "state", the value function "privileged_state".
POLICY_KEY, VALUE_KEY = "state", "privileged_state"


def brax_observation(obs: Sensation) -> dict[str, jax.Array]:
    """Our Sensation as Brax's observation dict: the policy modalities concatenated under "state", and those plus
    `asymmetric` under "privileged_state" (what our value network reads)."""
    return {POLICY_KEY: policy_inputs(obs), VALUE_KEY: value_inputs(obs)}


class BraxAdapter(BraxEnv):
    """One environment of ours as a Brax environment (wrap it with Brax's training wrappers, as `ppo.train` does).

    `pipeline_state` holds our whole `State`; `step` is our `advance` (no auto-reset) with the action clipped to
    the action bounds. `done` is set only on termination: Brax's EpisodeWrapper ends episodes after
    `max_episode_steps` and marks them as truncations, as our `State.truncated` would. A task's own clock (the
    cube's goal timer) is not passed on, so use tasks whose only truncation is the episode limit (reach, Pendulum).
    """

    def __init__(self, env: Env):
        if env.action_spec.discrete:
            raise ValueError(f"{type(env).__name__} has discrete actions; Brax's PPO needs continuous ones.")
        self.env = env

    def reset(self, rng: jax.Array) -> BraxState:
        state = self.env.reset(rng)
        return BraxState(pipeline_state=state, obs=brax_observation(state.obs), reward=state.reward,
                         done=state.done, metrics=dict(state.metrics))

    def step(self, state: BraxState, action: jax.Array) -> BraxState:
        action = jnp.clip(action, self.env.action_spec.low, self.env.action_spec.high)
        ended, _ = self.env.advance(state.pipeline_state, action)
        terminated = ended.done * (1.0 - ended.truncated)
        # Keys that Brax's wrappers added at reset (its evaluator's "reward") stay: a scan's carry keeps its shape.
        return state.replace(pipeline_state=ended, obs=brax_observation(ended.obs), reward=ended.reward,
                             done=terminated, metrics={**state.metrics, **ended.metrics})

    @property
    def observation_size(self) -> dict[str, tuple[int, ...]]:
        shapes = jax.eval_shape(lambda: brax_observation(self.env.reset(jax.random.key(0)).obs))
        return {k: tuple(v.shape) for k, v in shapes.items()}

    @property
    def action_size(self) -> int:
        return self.env.action_spec.size

    @property
    def backend(self) -> str:
        return "mjx" if hasattr(self.env, "mjx_model") else "jax"


@dataclasses.dataclass(frozen=True)
class Settings:
    """The matched settings of both trainers; Brax's names are derived in `brax_kwargs`."""

    num_envs: int
    rollout_length: int
    minibatches: int
    epochs: int
    width: int
    learning_rate: float
    entropy_coef: float
    init_log_std: float
    gamma: float
    cycles_per_snapshot: int
    snapshots: int
    seed: int

    @property
    def steps_per_cycle(self) -> int:
        return self.num_envs * self.rollout_length

    @property
    def env_steps(self) -> int:
        return self.steps_per_cycle * self.cycles_per_snapshot * self.snapshots

    def ppo_config(self) -> PPOConfig:
        """Ours: a two-layer `simple` MLP, one chunk per rollout (feed-forward: no truncated BPTT)."""
        return PPOConfig(
            seed=self.seed, num_cycles=self.cycles_per_snapshot * self.snapshots, num_envs=self.num_envs,
            rollout_length=self.rollout_length, chunk_length=self.rollout_length, num_epochs=self.epochs,
            minibatch_size=self.steps_per_cycle // self.minibatches, learning_rate=self.learning_rate,
            entropy_coef=self.entropy_coef, init_log_std=self.init_log_std, gamma=self.gamma, head="gaussian",
            network=NetworkConfig(name="simple", width=self.width),
        )

    def plan(self, env: Env) -> Plan:
        """Both sides' settings for `env`."""
        return Plan(self.ppo_config(), self.brax_kwargs(env), self.cycles_per_snapshot, self.snapshots)

    def brax_kwargs(self, env: Env) -> dict[str, Any]:
        """Brax's `ppo.train` arguments for the same run. One Brax training step is one of our cycles: it collects
        `batch_size * num_minibatches = num_envs` trajectories of `unroll_length` steps, one per environment."""
        ours = self.ppo_config()
        sizes = (self.width, self.width)
        network_factory = lambda obs_size, action_size, preprocess_observations_fn: (  # noqa: E731
            brax_networks.make_ppo_networks(
                obs_size, action_size, preprocess_observations_fn=preprocess_observations_fn,
                policy_hidden_layer_sizes=sizes, value_hidden_layer_sizes=sizes, activation=linen.tanh,
                policy_obs_key=POLICY_KEY, value_obs_key=VALUE_KEY, distribution_type="normal",
                noise_std_type="log", init_noise_std=math.exp(self.init_log_std)))
        return dict(
            num_timesteps=self.env_steps, num_envs=self.num_envs, episode_length=env.max_episode_steps,
            unroll_length=self.rollout_length, batch_size=self.num_envs // self.minibatches,
            num_minibatches=self.minibatches, num_updates_per_batch=self.epochs, learning_rate=self.learning_rate,
            entropy_cost=self.entropy_coef, discounting=self.gamma, gae_lambda=ours.gae_lambda,
            clipping_epsilon=ours.clip_epsilon,
            clipping_epsilon_value=ours.clip_epsilon if ours.value_clip else None,
            vf_loss_coefficient=ours.value_coef, max_grad_norm=ours.max_grad_norm,
            normalize_observations=ours.normalization.observations, normalize_advantage=ours.normalize_advantages,
            network_factory=network_factory, seed=self.seed, num_evals=self.snapshots + 1, run_evals=False,
        )


@dataclasses.dataclass(frozen=True)
class Plan:
    """What each side trains, with matched settings (`Settings.plan`) or each library's own (`own_plan`): our
    `PPOConfig` and Brax's `ppo.train` arguments for about the same env steps; our policy is kept every
    `cycles_per_snapshot` cycles, Brax's after each of its `snapshots` training epochs."""

    ours: PPOConfig
    brax: dict[str, Any]
    cycles_per_snapshot: int
    snapshots: int

    @property
    def steps_per_cycle(self) -> int:
        return self.ours.num_envs * self.ours.rollout_length


# Brax's own PPO settings for its versions of these robots (`train_fn` of Brax's training colab), for `--recipes own`:
# each library trains with what its authors publish for the task. Brax's colab trains Hopper and Walker2d with SAC, so
# it gives no PPO recipe for them. Every recipe also normalises observations, repeats no action and takes the
# episode limit of the task.
BRAX_RECIPES: dict[str, dict[str, Any]] = {
    "HalfCheetah": dict(num_envs=2048, batch_size=512, num_minibatches=32, unroll_length=20, num_updates_per_batch=8,
                        discounting=0.95, learning_rate=3e-4, entropy_cost=1e-3, reward_scaling=1.0),
    "Ant": dict(num_envs=4096, batch_size=2048, num_minibatches=32, unroll_length=5, num_updates_per_batch=4,
                discounting=0.97, learning_rate=3e-4, entropy_cost=1e-2, reward_scaling=10.0),
    "Humanoid": dict(num_envs=2048, batch_size=1024, num_minibatches=32, unroll_length=10, num_updates_per_batch=8,
                     discounting=0.97, learning_rate=3e-4, entropy_cost=1e-3, reward_scaling=0.1),
}
# The colab gives both pendulums one recipe.
BRAX_RECIPES["InvertedPendulum"] = BRAX_RECIPES["InvertedDoublePendulum"] = dict(
    num_envs=2048, batch_size=1024, num_minibatches=32, unroll_length=5, num_updates_per_batch=4, discounting=0.97,
    learning_rate=3e-4, entropy_cost=1e-2, reward_scaling=10.0)


def brax_recipe(task: str) -> dict[str, Any]:
    """Brax's published PPO settings for `task` (`BRAX_RECIPES`); ValueError naming the tasks that have one."""
    if task not in BRAX_RECIPES:
        raise ValueError(f"Brax publishes no PPO recipe for {task} (its colab trains Hopper and Walker2d with SAC): "
                         f"--recipes own takes one of {', '.join(BRAX_RECIPES)}; --recipes matched runs any task.")
    return dict(BRAX_RECIPES[task])


def brax_changes(assignments: list[str]) -> dict[str, Any]:
    """`KEY=VALUE` strings (values read as YAML: numbers, booleans) as a dict; ValueError naming one without `=`."""
    changes, known = {}, inspect.signature(brax_ppo.train).parameters
    for assignment in assignments:
        key, sep, value = assignment.partition("=")
        if not sep or not key:
            raise ValueError(f"--brax takes KEY=VALUE changes to Brax's recipe, e.g. num_envs=16; got {assignment!r}.")
        if key not in known:
            raise ValueError(f"--brax {assignment}: Brax's ppo.train has no argument {key!r} (our config's keys, "
                             "e.g. ppo.num_envs=16, go after the options, before --brax).")
        changes[key] = yaml.safe_load(value)
    return changes


def own_plan(env: Env, ours: PPOConfig, recipe: dict[str, Any], timesteps: int, snapshots: int) -> Plan:
    """Each library's own settings: ours (`ours`, e.g. the task's family config as it ships) and Brax's `recipe`
    (Brax's default networks: a tanh-squashed Gaussian, 4 x 32 policy and 5 x 256 value MLPs), for about `timesteps`
    env steps each (whole cycles of ours; Brax rounds up to whole training steps) and `snapshots` evaluation points.
    Both use `ours.seed`."""
    steps_per_cycle = ours.num_envs * ours.rollout_length
    per_snapshot = max(1, round(timesteps / (steps_per_cycle * snapshots)))
    ours = dataclasses.replace(ours, num_cycles=per_snapshot * snapshots)
    brax = {**recipe, "num_timesteps": steps_per_cycle * per_snapshot * snapshots,
            "episode_length": env.max_episode_steps, "normalize_observations": True, "action_repeat": 1,
            "seed": ours.seed, "num_evals": snapshots + 1, "run_evals": False}
    return Plan(ours, brax, per_snapshot, snapshots)


@dataclasses.dataclass
class Run:
    """One side's training: `segments` are (env steps, wall s) of each timed piece of training (a cycle of ours,
    a Brax training epoch); `snapshots` are (env steps, training wall s so far, policy parameters)."""

    segments: list[tuple[int, float]] = dataclasses.field(default_factory=list)
    snapshots: list[tuple[int, float, Any]] = dataclasses.field(default_factory=list)
    total_wall_s: float = 0.0

    def wall_s(self) -> float:
        return sum(s for _, s in self.segments)

    def summary(self) -> dict[str, float]:
        """Steady env steps/s (all segments after the first) and the first segment's extra time over that rate."""
        if len(self.segments) < 2:
            raise ValueError("A steady rate needs at least 2 training segments: use --snapshots 2 or more.")
        steps = sum(n for n, _ in self.segments[1:])
        rate = steps / sum(s for _, s in self.segments[1:])
        first_steps, first_s = self.segments[0]
        return {"env_steps_per_s": rate, "first_call_extra_s": first_s - first_steps / rate,
                "train_wall_s": self.wall_s(), "total_wall_s": self.total_wall_s}


def train_ours(env: Env, plan: Plan) -> Run:
    """Our trainer (`training_cycles`, the loop under `angora_jax.ppo.train`); one segment per cycle, the policy
    kept every `cycles_per_snapshot` cycles."""
    run, start = Run(), time.perf_counter()
    for state, metrics in training_cycles(plan.ours, env):
        run.segments.append((plan.steps_per_cycle, metrics["seconds"]))
        if metrics["cycle"] % plan.cycles_per_snapshot == 0:
            run.snapshots.append((metrics["env_steps"], run.wall_s(), (state.params, state.obs_stats)))
    run.total_wall_s = time.perf_counter() - start
    return run


def train_brax(env: Env, plan: Plan) -> tuple[Run, Callable]:
    """Brax's `ppo.train` on `BraxAdapter(env)`; one segment per training epoch (its training steps between two
    evaluation points, in one compiled call), the policy kept after each. Returns the run and Brax's `make_policy`."""
    run, epochs = Run(), []

    def progress(step: int, metrics: dict) -> None:
        epochs.append((step, float(metrics["training/walltime"])))

    def keep(step: int, make_policy: Callable, params: Any) -> None:
        if step > 0:
            run.snapshots.append((step, None, params))

    start = time.perf_counter()
    make_policy, _, _ = brax_ppo.train(BraxAdapter(env), progress_fn=progress, policy_params_fn=keep, **plan.brax)
    run.total_wall_s = time.perf_counter() - start
    steps, walls = [step for step, _ in epochs], [wall for _, wall in epochs]
    run.segments = [(n - m, b - a) for m, n, a, b in zip([0, *steps[:-1]], steps, [0.0, *walls[:-1]], walls,
                                                         strict=True)]
    run.snapshots = [(step, wall, params) for (step, _, params), wall in zip(run.snapshots, walls, strict=True)]
    return run, make_policy


def make_policy_evaluator(env: Env, act: Callable[[Any, Sensation], jax.Array], num_envs: int) -> Callable:
    """Jitted `evaluate(policy, key) -> metrics`: `num_envs` fresh environments of ours run one episode each with
    `act(policy, obs) -> actions` (a batch); metrics are the mean episode return and the mean of each task metric
    at the episode's end. The same keys give both trainers the same episodes."""

    def evaluate(policy: Any, key: jax.Array) -> dict[str, jax.Array]:
        state = jax.vmap(env.reset)(jax.random.split(key, num_envs))

        def step(carry, _):
            state, running, ret, ends = carry
            state = jax.vmap(env.step)(state, act(policy, state.obs))
            ended = running * state.done
            ends = {k: ends[k] + ended * v for k, v in state.metrics.items()}
            return (state, running * (1.0 - state.done), ret + running * state.reward, ends), None

        zeros = jnp.zeros((num_envs,), jnp.float32)
        carry = (state, jnp.ones_like(zeros), zeros, {k: zeros for k in env.metric_names})
        (_, _, ret, ends), _ = jax.lax.scan(step, carry, None, length=env.max_episode_steps)
        return {"episode_return": ret.mean(), **{f"metric/{k}": v.mean() for k, v in ends.items()}}

    return jax.jit(evaluate)


def ours_act(env: Env, config: PPOConfig) -> Callable[[Any, Sensation], jax.Array]:
    """Our deterministic policy: normalise with the saved statistics, take the head's mode, clip to the bounds."""
    network = make_network(config.network)
    head = build_head(env, config)
    model = ActorCritic(network, head)

    def act(policy, obs: Sensation) -> jax.Array:
        params, obs_stats = policy
        obs = normalize_observation(obs_stats, obs, config.normalization.clip)
        carry = network.initial_carry(obs.proprioception.shape[0])
        _, policy_params, _ = model.apply({"params": params}, carry, obs)
        return head.env_action(head.mode(policy_params))

    return act


def brax_act(env: Env, make_policy: Callable) -> Callable[[Any, Sensation], jax.Array]:
    """Brax's deterministic policy (its Gaussian's mean), clipped to the bounds as `BraxAdapter` does."""

    def act(params, obs: Sensation) -> jax.Array:
        action, _ = make_policy(params, deterministic=True)(brax_observation(obs), jax.random.key(0))
        return jnp.clip(action, env.action_spec.low, env.action_spec.high)

    return act


def score(env: Env, run: Run, act: Callable, num_envs: int, seed: int) -> list[dict[str, float]]:
    """Each snapshot's evaluation (see `make_policy_evaluator`) with its env steps and training wall time."""
    evaluate = make_policy_evaluator(env, act, num_envs)
    key = jax.random.key(seed + 1_000_003)  # one key, apart from training's, for every snapshot of both sides
    return [{"env_steps": steps, "train_wall_s": wall,
             **{k: float(v) for k, v in jax.device_get(evaluate(policy, key)).items()}}
            for steps, wall, policy in run.snapshots]


def at_wall_time(curve: list[dict[str, float]], wall_s: float) -> dict[str, float] | None:
    """The last evaluated snapshot reached within `wall_s` of training, or None."""
    reached = [point for point in curve if point["train_wall_s"] <= wall_s + 1e-9]
    return reached[-1] if reached else None


def env_alone_rates(env: Env, plan: Plan) -> dict[str, float]:
    """Env steps/s of each side's environment stepping alone, random actions, `rollout_length` steps of `num_envs`
    environments per timed run: ours (`env.step`, which computes a fresh reset for every environment at every step
    and keeps it where an episode ended) and Brax's (`BraxAdapter` under Brax's training wrappers, which copy the
    stored first state instead). Tells apart the environment's share of a speed difference from the learner's."""
    n, steps, seed = plan.ours.num_envs, plan.ours.rollout_length, plan.ours.seed
    ours = env_step_rate(env, n, steps, seed=seed)
    wrapped = brax_training.wrap(BraxAdapter(env), episode_length=env.max_episode_steps)
    state = jax.jit(wrapped.reset)(jax.random.split(jax.random.PRNGKey(seed), n))

    def rollout(state, key):
        def one(state, key):
            return wrapped.step(state, random_action(env, key, n)), None

        return jax.lax.scan(one, state, jax.random.split(key, steps))[0]

    brax = measure_compiled(rollout, state, jax.random.key(seed + 1))
    return {"angora_jax": ours["env_steps_per_s"], "brax": n * steps / brax.seconds}


def first_snapshot_past(curve: list[dict[str, float]], target: float | None) -> dict[str, float] | None:
    """The first evaluated snapshot whose return reached `target` (its training wall time is an upper bound on the
    time to that return, at the snapshots' spacing), or None (also without a target)."""
    if target is None:
        return None
    return next((point for point in curve if point["episode_return"] >= target), None)


def compare(env: Env, plan: Plan, eval_envs: int, env_alone: bool = False,
            target: float | None = None) -> dict[str, Any]:
    """Train both sides, score their snapshots; rows for the table and both learning curves. With `env_alone`,
    each row also has its environment's rate alone (`env_alone_rates`); with a `target` return, the training wall
    seconds and env steps of each side's first snapshot that reached it."""
    seed = plan.ours.seed
    ours = train_ours(env, plan)
    brax, make_brax_policy = train_brax(env, plan)
    curves = {"angora_jax": score(env, ours, ours_act(env, plan.ours), eval_envs, seed),
              "brax": score(env, brax, brax_act(env, make_brax_policy), eval_envs, seed)}
    summaries = {"angora_jax": ours.summary(), "brax": brax.summary()}
    equal_wall = min(s["train_wall_s"] for s in summaries.values())
    rows = []
    for side, curve in curves.items():
        at_wall = at_wall_time(curve, equal_wall)
        rows.append({
            "trainer": side, **summaries[side], "env_steps": curve[-1]["env_steps"],
            "final_return": curve[-1]["episode_return"],
            **{f"final_{k}": v for k, v in curve[-1].items() if k.startswith("metric/")},
            "equal_wall_s": equal_wall,
            "return_at_equal_wall": at_wall["episode_return"] if at_wall else None,
            "env_steps_at_equal_wall": at_wall["env_steps"] if at_wall else None,
            "target": target,
            "seconds_to_target": past["train_wall_s"] if (past := first_snapshot_past(curve, target)) else None,
            "env_steps_to_target": past["env_steps"] if past else None,
        })
    if env_alone:
        for row, rate in zip(rows, env_alone_rates(env, plan).values(), strict=True):
            row["env_alone_steps_per_s"] = rate
    rows[0]["speed_over_brax"] = rows[0]["env_steps_per_s"] / rows[1]["env_steps_per_s"]
    return {"rows": rows, "curves": curves}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--task", default="ShadowHandReach")
    parser.add_argument("--recipes", choices=("matched", "own"), default="matched",
                        help="matched: both sides with the settings below; own: ours with --config (and the "
                             "overrides), Brax with its published recipe for the task (BRAX_RECIPES, and --brax)")
    parser.add_argument("--options", default="{}", help="task options as JSON (matched recipes)")
    parser.add_argument("--num-envs", type=int, default=16)
    parser.add_argument("--rollout-length", type=int, default=16, help="Brax's unroll_length")
    parser.add_argument("--minibatches", type=int, default=4, help="minibatches per epoch (Brax's num_minibatches)")
    parser.add_argument("--epochs", type=int, default=4, help="Brax's num_updates_per_batch")
    parser.add_argument("--width", type=int, default=64, help="units of both layers of both MLPs")
    parser.add_argument("--learning-rate", type=float, default=3e-4)
    parser.add_argument("--entropy-coef", type=float, default=0.01)
    parser.add_argument("--init-log-std", type=float, default=-1.0)
    parser.add_argument("--gamma", type=float, default=0.99)
    parser.add_argument("--config", default="locomotion", help="our config for --recipes own (default: locomotion)")
    parser.add_argument("--brax", nargs="*", default=[], metavar="KEY=VALUE",
                        help="changes to Brax's recipe for --recipes own, e.g. num_envs=16 batch_size=8 on a CPU")
    parser.add_argument("--timesteps", type=int, default=2048, help="env steps per side (rounded to whole cycles)")
    parser.add_argument("--snapshots", type=int, default=4, help="evaluation points per side (>= 2)")
    parser.add_argument("--eval-envs", type=int, default=16, help="episodes per evaluation")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--target", type=float, default=None,
                        help="return to time each side to (default: the task's in common.TARGETS, if any)")
    parser.add_argument("--env-alone", action="store_true",
                        help="also time each side's env stepping alone (two more compiles)")
    parser.add_argument("--out", default=None,
                        help="JSON path (default: results/brax_side_by_side/brax_side_by_side_<task>_<platform>[_own]"
                             ".json)")
    parser.add_argument("overrides", nargs="*", help="key.sub=value overrides of --config (--recipes own)")
    args = parser.parse_args()

    if args.snapshots < 2:
        parser.error("--snapshots must be >= 2: the first training segment includes compilation.")
    if args.recipes == "own":
        try:
            recipe = brax_recipe(args.task) | brax_changes(args.brax)
        except ValueError as error:
            parser.error(str(error))
        config = load_config(args.config, [f"env.task={args.task}", f"ppo.seed={args.seed}", *args.overrides])
        env = validate(config)
        plan = own_plan(env, config.ppo, recipe, args.timesteps, args.snapshots)
        described = {"config": args.config, "overrides": args.overrides, "options": config.env.options}
    else:
        if args.num_envs % args.minibatches:
            parser.error(f"--minibatches ({args.minibatches}) must divide --num-envs ({args.num_envs}): a Brax "
                         "minibatch is num_envs / minibatches whole trajectories.")
        env = make(args.task, **json.loads(args.options))
        per_snapshot = max(1, round(args.timesteps / (args.num_envs * args.rollout_length * args.snapshots)))
        settings = Settings(args.num_envs, args.rollout_length, args.minibatches, args.epochs, args.width,
                            args.learning_rate, args.entropy_coef, args.init_log_std, args.gamma, per_snapshot,
                            args.snapshots, args.seed)
        settings.ppo_config().validate_for(env)
        plan = settings.plan(env)
        described = {"options": json.loads(args.options), "settings": dataclasses.asdict(settings)}
    target = args.target if args.target is not None else TARGETS.get(args.task)
    result = compare(env, plan, args.eval_envs, args.env_alone, target)
    rows = result["rows"]
    config = {"task": args.task, "recipes": args.recipes, **described, "eval_envs": args.eval_envs,
              "env_steps": plan.steps_per_cycle * plan.cycles_per_snapshot * plan.snapshots,
              "ours": dataclasses.asdict(plan.ours),
              "brax": {k: v for k, v in plan.brax.items() if k != "network_factory"}, "target": target,
              "curves": result["curves"]}
    suffix = "_own" if args.recipes == "own" else ""
    name = f"brax_side_by_side_{args.task}_{jax.devices()[0].platform}{suffix}.json"
    out = args.out or os.path.join(study_folder("brax_side_by_side"), name)
    path = write_results("brax_side_by_side", config, rows, out, study="brax_side_by_side")
    metric_columns = [(k, k.removeprefix("final_metric/"), ".3f") for k in rows[0] if k.startswith("final_metric/")]
    print(markdown_table(rows, [
        ("trainer", "trainer", "s"), ("env_steps_per_s", "env steps/s (no compile)", ",.0f"),
        ("env_alone_steps_per_s", "env alone steps/s", ",.0f"),
        ("first_call_extra_s", "first call extra s", ".1f"), ("train_wall_s", "train wall s", ".1f"),
        ("env_steps", "env steps", ",d"), ("final_return", "return (final)", ".2f"), *metric_columns,
        ("return_at_equal_wall", "return at equal wall", ".2f"),
        ("env_steps_at_equal_wall", "its env steps", ",d"),
        ("seconds_to_target", f"train s to {target:g}" if target is not None else "train s to target", ".1f"),
        ("env_steps_to_target", "its env steps", ",d"),
    ]))
    print(f"ours / Brax env steps/s: {rows[0]['speed_over_brax']:.2f}; equal wall time {rows[0]['equal_wall_s']:.1f} s")
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
