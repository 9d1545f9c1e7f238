"""Task registry: `make(name, **options)` builds an environment by name; `list_tasks()` lists the names;
`register_gymnasium_envs()` gives each task a Gymnasium id.

It imports neither JAX nor a task until a task is made or asked about (the environments' modules, JAX and the host
view of Gymnasium's environments are imported inside its functions): `import angora_jax` lists the tasks to register
their Gymnasium ids, which would otherwise cost every `angora-jax` command a second."""

from __future__ import annotations

import difflib
import inspect
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import gymnasium

from angora_jax.registry import Registry

if TYPE_CHECKING:
    from angora_jax.envs.core import Env

# The tasks shipped in angora_jax.envs, by the module that registers each, imported when one of its tasks is first
# made or asked about (`Registry`); tests/test_layering.py checks that each module registers exactly these.
SHIPPED_TASKS = {
    **dict.fromkeys(("CartPole", "Pendulum", "Acrobot", "MountainCar", "MountainCarContinuous"),
                    "angora_jax.envs.classic"),
    **dict.fromkeys(("Hopper", "Walker2d", "HalfCheetah", "Swimmer", "Ant", "Humanoid", "InvertedPendulum",
                     "InvertedDoublePendulum", "Reacher"), "angora_jax.envs.locomotion"),
    **dict.fromkeys(("MyoHandPose", "MyoHandReach", "MyoHandReorient"), "angora_jax.envs.myohand"),
    **dict.fromkeys(("ShadowHandReach", "ShadowHandFreeReach", "ShadowHandReachSequential",
                     "ShadowHandFreeReachSequential", "ShadowHandCube"), "angora_jax.envs.shadow_hand"),
}
TASKS: Registry[Callable[..., Env]] = Registry("task", "tasks", SHIPPED_TASKS)
# Gymnasium's namespace of the tasks' ids: `gymnasium.make("AngoraJax/ShadowHandReach-v0")`.
NAMESPACE = "AngoraJax"


def register(name: str, factory: Callable[..., Env]) -> None:
    """Make `factory(**options) -> Env` available as `make(name, **options)`."""
    TASKS.register(name, factory)


def list_tasks() -> list[str]:
    """Names of all registered tasks, sorted."""
    return TASKS.names()


def make(name: str, **options) -> Env:
    """Build the task `name`; `options` go to its constructor (e.g. reward coefficients, episode length).
    `gym:<id>` is any Gymnasium environment, simulated on the host (`angora_jax.envs.host`)."""
    if not isinstance(name, str):
        raise TypeError(f"make takes a task's name (e.g. 'CartPole'; aj.list_tasks() lists them), got "
                        f"{_given_for_a_name(name)}.")
    if is_gymnasium(name):
        from angora_jax.envs.host import make_gymnasium

        return make_gymnasium(name, **options)
    constructor = TASKS.get(name)
    if (unknown := unknown_option(name, options)) is not None:
        raise TypeError(f"Task {name!r} {unknown}")
    _refuse_non_bools(name, constructor, options)
    return constructor(**options)


def _given_for_a_name(given: object) -> str:
    """What `make` was given where a task's name goes, and what to give instead when the given thing holds a task:
    a Config (or its `env` section), an agent, an Env already made."""
    from angora_jax.envs.core import Env

    kind = type(given).__name__
    if isinstance(given, Env):
        return f"the task itself (a {kind}): use it as it is"
    if isinstance(getattr(given, "env", None), Env):
        return f"a{'n' if kind[0] in 'AEIOU' else ''} {kind}: its task is {kind.lower()}.env"
    section = getattr(given, "env", given)
    if isinstance(getattr(section, "task", None), str) and isinstance(getattr(section, "options", None), dict):
        return (f"a{'n' if kind[0] in 'AEIOU' else ''} {kind}: aj.make(config.env.task, **config.env.options) makes "
                "its task")
    return "None" if given is None else f"{given!r} ({kind})"


def unknown_option(name: str, options: dict[str, Any]) -> str | None:
    """"has no option 'x' (did you mean 'y'?); its options: ..." for the first of `options` that task `name`'s
    constructor takes by no name (Python's own error says only "__init__() got an unexpected keyword argument");
    None when it takes them all, or any keyword, or has no signature to read."""
    try:
        parameters = inspect.signature(TASKS.get(name)).parameters
    except (TypeError, ValueError):
        return None
    if any(p.kind is inspect.Parameter.VAR_KEYWORD for p in parameters.values()):
        return None
    names = [key for key, p in parameters.items()
             if p.kind in (inspect.Parameter.POSITIONAL_OR_KEYWORD, inspect.Parameter.KEYWORD_ONLY)]
    unknown = next((key for key in options if key not in names), None)
    if unknown is None:
        return None
    close = difflib.get_close_matches(str(unknown), names, n=1)
    return (f"has no option {unknown!r}{f' (did you mean {close[0]!r}?)' if close else ''}; its options: "
            f"{', '.join(names) or 'none'}.")


def _refuse_non_bools(name: str, constructor: Any, options: dict[str, Any]) -> None:
    """ValueError for an option its constructor declares `bool` given anything else: a quoted "no" or "false" from
    YAML is a non-empty string, so `touch: "no"` silently switched 97 touch sensors on."""
    try:
        parameters = inspect.signature(constructor).parameters
    except (TypeError, ValueError):  # a callable without a signature to read: nothing to check
        return
    for key, value in options.items():
        declared = parameters[key].annotation if key in parameters else None
        if declared in (bool, "bool") and not isinstance(value, bool):
            raise ValueError(f"{name}'s option {key} must be true or false, got {value!r} ({type(value).__name__}); "
                             "in YAML write it unquoted: true or false.")


def is_gymnasium(name: str) -> bool:
    """Whether task `name` is a Gymnasium id run on the host (`gym:<id>`) rather than a registered task."""
    from angora_jax.envs.host import PREFIX

    return name.startswith(PREFIX)


def register_gymnasium_envs() -> None:
    """Register `AngoraJax/<Task>-v0` for every task registered so far and not with Gymnasium yet; call it again after
    registering a task of your own. Gymnasium imports the view (`angora_jax.envs.gym_view.GymEnv`) when it makes one."""
    # The names so far, without loading plugins: `import angora_jax` calls this (angora_jax.registry.plugins: why).
    for task in TASKS.names(plugins=False):
        env_id = f"{NAMESPACE}/{task}-v0"
        if env_id not in gymnasium.registry:
            gymnasium.register(id=env_id, entry_point="angora_jax.envs.gym_view:GymEnv", kwargs={"task": task})
