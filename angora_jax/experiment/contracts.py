"""The task and network contracts, checked for a task or network of one's own before anything compiles.

A registered task or network that breaks the contract the trainer relies on (docs/tutorials/custom-task.md and
custom-model.md) used to fail deep inside JAX's tracing, with a traceback about broadcasting or a scan's carry types,
and exit 1. `check_own_code` traces the task's reset and step and the network's first step on abstract values
(`jax.eval_shape`: nothing is simulated or compiled) and raises UserCodeError naming the broken part, which the
command reports with exit 2. Tasks and networks that angora_jax ships are tested and not checked: tracing the Shadow
hand's MJX step alone takes seconds.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp

from angora_jax.envs.core import ActionSpec, Env, Sensation
from angora_jax.envs.cpu_env import CpuEnv
from angora_jax.envs.registry import TASKS, is_gymnasium
from angora_jax.nets.registry import NETWORKS, NetworkSettings
from angora_jax.registry import definition
from angora_jax.registry.plugins import UserCodeError

# Environments in the abstract batch the network is traced with: two, so that a batch axis mixed up with another
# shows.
BATCH = 2
TASK_CONTRACT = "docs/tutorials/custom-task.md and the Env contract in angora_jax/envs/core.py"
NETWORK_CONTRACT = "docs/tutorials/custom-model.md, 'The network contract'"


def check_own_code(task: str, network: NetworkSettings, env: Env) -> None:
    """Check the task `task` (built as `env`) and the network `network.name` against their contracts, unless
    angora_jax ships them; UserCodeError names what breaks a contract."""
    if not is_gymnasium(task) and not _shipped(factory := TASKS.get(task)):
        check_task(env, f"Task {task!r} ({definition(factory)})")
    if not _shipped(builder := NETWORKS.get(network.name)):
        check_network(builder, network, env, f"Network {network.name!r} ({definition(builder)})")


def check_task(env: Env, name: str) -> None:
    """Trace `env`'s reset and one step on abstract values and raise UserCodeError (naming the task as `name`) where
    they break the task contract: a missing attribute, a reset or step that raises, observations that are no
    Sensation of vectors, a reward or termination that is not one number per environment, metrics other than
    `metric_names`, or state (physics, observation, info) that changes its shapes from reset to step."""

    def broken(problem: str) -> UserCodeError:
        return UserCodeError(f"{name} breaks the task contract ({TASK_CONTRACT}): {problem.rstrip('.')}.")

    for attribute, what in (("action_spec", "an ActionSpec: the actions' bounds, or their number"),
                            ("max_episode_steps", "the policy steps per episode"),
                            ("dt", "the seconds per policy step")):
        if not hasattr(env, attribute):
            raise broken(f"it has no `{attribute}`, {what}")
    if not isinstance(env.action_spec, ActionSpec):
        raise broken(f"its action_spec is a {type(env.action_spec).__name__}, not an ActionSpec")
    if isinstance(env, CpuEnv):  # C MuJoCo, stepped eagerly: nothing to trace (and no training on it)
        return
    names = tuple(env.metric_names)
    key = jax.random.key(0)
    start = _traced(lambda: jax.eval_shape(env._reset, key), broken, "its _reset")
    if not (isinstance(start, tuple) and len(start) == 3):
        raise broken("its _reset must return (physics, observation, info)")
    physics, obs, info = start
    _check_sensation(obs, "_reset", broken)
    action = jax.ShapeDtypeStruct(env.action_spec.shape, jnp.int32 if env.action_spec.discrete else jnp.float32)
    step = _traced(lambda: jax.eval_shape(env._step, physics, info, action, key), broken,
                   f"its _step (given an action of shape {env.action_spec.shape})")
    if not (isinstance(step, tuple) and len(step) == 6):
        raise broken("its _step must return (physics, observation, reward, terminated, info, metrics)")
    physics_after, obs_after, reward, terminated, info_after, metrics = step
    for what, value in (("reward", reward), ("terminated", terminated)):
        if jnp.shape(value) != ():
            raise broken(f"its _step returned a {what} of shape {jnp.shape(value)}: one number per environment, "
                         "shape (), is expected (the trainer adds the batch axis)")
    if not isinstance(metrics, dict) or set(metrics) != set(names):
        given = sorted(metrics) if isinstance(metrics, dict) else type(metrics).__name__
        raise broken(f"its _step returned the metrics {given}, and its metric_names are {list(names)}: the two must "
                     "name the same metrics")
    for metric, value in metrics.items():
        if jnp.shape(value) != ():
            raise broken(f"its metric {metric!r} has shape {jnp.shape(value)}: a number per environment, shape ()")
    for what, before, after in (("physics", physics, physics_after), ("observation", obs, obs_after),
                                ("info", info, info_after)):
        mismatch = _mismatch(before, after)
        if mismatch:
            raise broken(f"its {what} after _step differs from _reset's ({mismatch}): a step must keep every shape, "
                         "as the environments are stepped in a compiled loop")


def check_network(builder: Callable[[NetworkSettings], Any], settings: NetworkSettings, env: Env, name: str) -> None:
    """Build the network with `builder(settings)`, trace its first step on a batch of `BATCH` observations of `env`
    and raise UserCodeError (naming the network as `name`) where it breaks the network contract: a builder that
    raises or returns no module, no `initial_carry`, a carry that changes its shapes, policy features that are not
    `(B, F)`, a value that is not `(B,)`, or policy features that read `obs.asymmetric`."""

    def broken(problem: str) -> UserCodeError:
        return UserCodeError(f"{name} breaks the network contract ({NETWORK_CONTRACT}): {problem.rstrip('.')}.")

    network = _traced(lambda: builder(settings), broken, "its builder, called with the run's ppo.network section,")

    if isinstance(network, type):
        raise broken(f"its builder returned the class {network.__name__}, not a module: return "
                     f"{network.__name__}(...)")
    if not isinstance(network, nn.Module):
        raise broken(f"its builder returned a {type(network).__name__}, not a flax.linen.Module")
    if not callable(getattr(network, "initial_carry", None)):
        raise broken(f"{type(network).__name__} has no initial_carry(batch_size) method (the recurrent state at an "
                     "episode's start; feed-forward models return jnp.zeros((batch_size, 0)))")
    carry = _traced(lambda: jax.eval_shape(lambda: network.initial_carry(BATCH)), broken,
                    f"its initial_carry({BATCH})")
    for path, leaf in jax.tree_util.tree_flatten_with_path(carry)[0]:
        if len(leaf.shape) == 0 or leaf.shape[0] != BATCH:
            raise broken(f"initial_carry({BATCH}) gave {jax.tree_util.keystr(path) or 'a carry'} of shape "
                         f"{leaf.shape}: every part needs the leading axis batch_size")
    one = env.observation_shapes()
    obs = jax.tree.map(lambda leaf: jax.ShapeDtypeStruct((BATCH, *leaf.shape), leaf.dtype), one)
    key = jax.random.key(0)
    empty = [jax.tree_util.keystr(path) for path, leaf in jax.tree_util.tree_flatten_with_path(one)[0]
             if 0 in leaf.shape]

    def broken_reading(problem: str) -> UserCodeError:
        # A network that reads only modalities this task leaves empty fails inside its layers (a division by a fan-in
        # of 0, a reshape): name the empty inputs, the likely cause, beside what it raised.
        if not empty:
            return broken(problem)
        inputs = ", ".join(f"obs{path}" for path in empty)
        return broken(f"{problem.rstrip('.')}. This task's observation has no values in {inputs}: "
                      "a network that reads only those has no input (read the task's other modalities, or "
                      "switch the sense on in env.options)")

    params = _traced(lambda: jax.eval_shape(network.init, key, carry, obs), broken_reading,
                     "its first call (init) on a batch of observations")
    output = _traced(lambda: jax.eval_shape(network.apply, params, carry, obs), broken_reading, "its first step")
    features, value = _returned(output, carry, "after a step", broken)
    if len(features.shape) != 2 or features.shape[0] != BATCH:
        raise broken(f"its policy features for {BATCH} environments have shape {features.shape}: (B, F) is expected")
    if value.shape != (BATCH,):
        raise broken(f"its value for {BATCH} environments has shape {value.shape}: (B,) is expected"
                     + (" (squeeze the last axis: value[..., 0])" if value.shape == (BATCH, 1) else ""))
    if getattr(network, "runs_sequences", False):
        _check_sequences(network, params, carry, obs, broken)
    if one.asymmetric.shape[-1]:
        _check_policy_ignores_asymmetric(network, obs, carry, broken)


# Steps of the abstract training chunk a network that runs sequences is traced with.
STEPS = 3


def _check_sequences(network: nn.Module, params: Any, carry: Any, obs: Sensation,
                     broken: Callable[[str], UserCodeError]) -> None:
    """A network that sets `runs_sequences` must also take a training chunk: `(carry, obs, resets, initial)` with obs
    leaves `(s, B, size)` and resets `(s, B)`, returning (final carry, `(s, B, F)`, `(s, B)`)."""
    chunk = jax.tree.map(lambda leaf: jax.ShapeDtypeStruct((STEPS, *leaf.shape), leaf.dtype), obs)
    resets = jax.ShapeDtypeStruct((STEPS, BATCH), jnp.bool_)
    output = _traced(lambda: jax.eval_shape(network.apply, params, carry, chunk, resets, carry), broken,
                     f"its call on a training chunk (runs_sequences = True: carry, obs of ({STEPS}, {BATCH}, size), "
                     f"resets ({STEPS}, {BATCH}), initial carry)")
    features, values = _returned(output, carry, "after a training chunk", broken)
    if len(features.shape) != 3 or features.shape[:2] != (STEPS, BATCH) or values.shape != (STEPS, BATCH):
        raise broken(f"on a training chunk of {STEPS} steps x {BATCH} environments it returned policy features of "
                     f"shape {features.shape} and values of shape {values.shape}: (s, B, F) and (s, B) are expected")


def _returned(output: Any, carry: Any, when: str, broken: Callable[[str], UserCodeError]) -> tuple[Any, Any]:
    """The policy features and values of a network call's `output`, once it is (carry, features, values) with the
    carry's shapes kept (the trainer scans the carry over time)."""
    if not (isinstance(output, tuple) and len(output) == 3):
        raise broken(f"its __call__ must return (carry, policy_features, value) {when}")
    mismatch = _mismatch(carry, output[0])
    if mismatch:
        raise broken(f"the carry it returns differs from initial_carry's ({mismatch}) {when}: the trainer scans it "
                     "over time")
    return output[1], output[2]


def _check_policy_ignores_asymmetric(network: nn.Module, shapes: Sensation, carry: Any,
                                     broken: Callable[[str], UserCodeError]) -> None:
    """Whether the policy features move with `obs.asymmetric`, at random parameters and random observations (not
    zeros: a ReLU's derivative at 0 is 0 and would hide a dependence)."""
    keys = iter(jax.random.split(jax.random.key(1), len(jax.tree.leaves(shapes)) + 1))
    obs = jax.tree.map(lambda s: jax.random.normal(next(keys), s.shape).astype(s.dtype), shapes)
    carry = jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), carry)

    @jax.jit
    def sensitivity(obs: Sensation) -> jax.Array:
        params = network.init(jax.random.key(2), carry, obs)

        def features(asymmetric: jax.Array) -> jax.Array:
            return network.apply(params, carry, obs.replace(asymmetric=asymmetric))[1]

        tangent = jax.jvp(features, (obs.asymmetric,), (jnp.ones_like(obs.asymmetric),))[1]
        return jnp.max(jnp.abs(tangent))

    if float(sensitivity(obs)) > 0:
        raise broken("its policy features change with obs.asymmetric, the privileged inputs only the value function "
                     "may read (a policy that reads them cannot act on what the body senses alone)")


def _check_sensation(obs: Any, where: str, broken: Callable[[str], UserCodeError]) -> None:
    if not isinstance(obs, Sensation):
        raise broken(f"its {where} returned a {type(obs).__name__} as the observation: a Sensation "
                     "(Sensation.make(proprioception=..., goal=...)) is expected")
    for modality, leaf in obs.__dict__.items():
        images = modality == "vision" and len(leaf.shape) == 4
        if len(leaf.shape) != 1 and not images:
            raise broken(f"its {where} returned the modality {modality} of shape {leaf.shape}: one vector (size,) per "
                         "environment is expected (the trainer adds the batch axis)")


def _traced(trace: Callable[[], Any], broken: Callable[[str], UserCodeError], what: str) -> Any:
    try:
        return trace()
    except UserCodeError:
        raise
    except Exception as error:  # the user's code, traced: anything it raises is its own
        first = str(error).strip().splitlines()[0] if str(error).strip() else ""
        raise broken(f"{what} raised {type(error).__name__}: {first[:400]}") from error


def _mismatch(before: Any, after: Any) -> str | None:
    """Where two abstract trees differ: their structure, or the first leaf of another shape or dtype."""
    if isinstance(before, dict) and isinstance(after, dict) and set(before) != set(after):
        return f"keys {sorted(before)} before, {sorted(after)} after"
    leaves_before, tree_before = jax.tree_util.tree_flatten_with_path(before)
    leaves_after, tree_after = jax.tree_util.tree_flatten_with_path(after)
    if tree_before != tree_after:
        return f"its structure: {str(tree_before)[:200]} before, {str(tree_after)[:200]} after"
    for (path, a), (_, b) in zip(leaves_before, leaves_after, strict=True):
        if jnp.shape(a) != jnp.shape(b) or jnp.result_type(a) != jnp.result_type(b):
            return (f"{jax.tree_util.keystr(path) or 'it'}: {jnp.shape(a)} {jnp.result_type(a)} before, "
                    f"{jnp.shape(b)} {jnp.result_type(b)} after")
    return None


def _shipped(factory: Callable) -> bool:
    return getattr(factory, "__module__", "").startswith("angora_jax.")
