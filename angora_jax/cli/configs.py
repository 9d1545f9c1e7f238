"""Verbs about configs and this installation: `config show` / `config reference`, `list-configs`, `list-tasks`,
`list-models`, `doctor`, and `run` (a random policy's rollout, a smoke test of a task)."""

from __future__ import annotations

import argparse
import math
import sys
import time

import numpy as np
import yaml

from angora_jax.cli.arguments import EXIT_FAILED, EXIT_OK, EXIT_USAGE, config_with_imports, positive_int, seed
from angora_jax.envs import list_tasks
from angora_jax.wording import counted

# The handlers import what they run (JAX, configs, networks) inside them: the parser, which every command builds, and
# `--help` need none of it.


def add_config(commands: argparse._SubParsersAction) -> None:
    """The `config` verb: its arguments and its handler."""
    config = commands.add_parser("config", help="show the config a run would use, every key resolved")
    config_commands = config.add_subparsers(dest="config_command", required=True)
    show = config_commands.add_parser("show", help="print the resolved config (YAML) of CONFIG with the overrides, "
                                                   "checked as train checks it before making a run directory "
                                                   "(saved sources such as ppo.init_from included), without running "
                                                   "anything")
    show.add_argument("config", help="YAML path or the name of a shipped config (see list-configs)")
    show.add_argument("overrides", nargs="*", default=[], metavar="KEY=VALUE", help="e.g. ppo.num_envs=32")
    show.set_defaults(handler=command_config_show)
    reference = config_commands.add_parser("reference", help="print every config key with its type, default and "
                                                             "description (Markdown; docs/config.md)")
    reference.set_defaults(handler=command_config_reference)


def add_list_configs(commands: argparse._SubParsersAction) -> None:
    """The `list-configs` verb: its arguments and its handler."""
    configs = commands.add_parser("list-configs", help="print the shipped configs and what each trains")
    configs.set_defaults(handler=command_list_configs)


def add_doctor(commands: argparse._SubParsersAction) -> None:
    """The `doctor` verb: its arguments and its handler."""
    doctor = commands.add_parser("doctor", help="what this machine gives angora_jax and what to install")
    doctor.set_defaults(handler=command_doctor)


def add_list_tasks(commands: argparse._SubParsersAction) -> None:
    """The `list-tasks` verb: its arguments and its handler."""
    tasks = commands.add_parser("list-tasks", help="print the registered task names")
    tasks.set_defaults(handler=lambda args: print("\n".join(list_tasks()) + "\nAny Gymnasium environment: gym:<id>, "
                                                  "simulated on the host (e.g. gym:LunarLander-v3)") or EXIT_OK)


def add_list_models(commands: argparse._SubParsersAction) -> None:
    """The `list-models` verb: its arguments and its handler."""
    models = commands.add_parser("list-models", help="print the registered networks and policy heads")
    models.set_defaults(handler=command_list_models)


def add_run(commands: argparse._SubParsersAction) -> None:
    """The `run` verb: its arguments and its handler."""
    run = commands.add_parser("run", help="roll out a random policy in a batch of environments (smoke test)")
    run.add_argument("--task", default="ShadowHandReach", help="task name (see list-tasks; default: ShadowHandReach)")
    run.add_argument("--num-envs", type=positive_int, default=8, help="environments stepped at once (default: 8)")
    run.add_argument("--steps", type=positive_int, default=100, help="policy steps per environment (default: 100)")
    run.add_argument("--seed", type=seed, default=0, help="seed of the resets and the random actions (default: 0)")
    run.set_defaults(handler=command_run)


def command_config_show(args: argparse.Namespace) -> int:
    """Print the config `train` would use after the checks `train` makes before it makes a run directory: `validate`
    and the saved sources (`check_sources`: ppo.init_from, ppo.network.pretrained and ppo.network.frozen read and
    fitted to the network, traced but not compiled). Without the sources' check a missing init_from passed here and
    failed only when the job started. What it cannot check is the run directory itself: `train` refuses a
    logging.run_name taken when the job starts, which may differ from now."""
    from angora_jax.experiment.config import to_dict, validate
    from angora_jax.experiment.sources import check_sources

    config = config_with_imports(args)
    check_sources(config, validate(config))
    print(f"# {args.config} {' '.join(args.overrides)}".rstrip() + ": what `angora-jax train` would use")
    print(yaml.safe_dump(to_dict(config), sort_keys=False), end="")
    return EXIT_OK


def command_config_reference(args: argparse.Namespace) -> int:
    from angora_jax.experiment.config_reference import reference_markdown

    print(reference_markdown(), end="")
    return EXIT_OK


def command_list_configs(args: argparse.Namespace) -> int:
    from angora_jax.experiment.config import list_configs

    shipped = list_configs()
    width = max(map(len, shipped))
    for name, description in shipped.items():
        print(f"{name:<{width}}  {description}")
    print("Train one with: angora-jax train NAME [key.sub=value ...]")
    return EXIT_OK


def command_doctor(args: argparse.Namespace) -> int:
    from angora_jax.experiment.doctor import diagnose

    found = diagnose()
    print(found.format())
    return EXIT_FAILED if found.problems else EXIT_OK


def command_list_models(args: argparse.Namespace) -> int:
    from angora_jax.nets import list_networks
    from angora_jax.ppo.distributions import list_heads

    print("networks (ppo.network.name):", ", ".join(list_networks()))
    print("policy heads (ppo.head):", ", ".join(["auto", *list_heads()]))
    return EXIT_OK


def command_run(args: argparse.Namespace) -> int:
    try:
        run_random(args.task, args.num_envs, args.steps, args.seed)
    except ValueError as error:
        print(f"angora-jax: {error}", file=sys.stderr)
        return EXIT_USAGE
    return EXIT_OK


def run_random(task: str, num_envs: int, num_steps: int, seed: int) -> dict[str, float]:
    """Roll out a random policy in `num_envs` batched environments for `num_steps` policy steps under one jit and
    print compile time, throughput and rewards. Returns the printed numbers."""
    import jax

    from angora_jax.envs import make
    from angora_jax.envs.random_rollout import batched_reset, episode_mean, make_random_rollout

    env = make(task).sized_for(num_envs)
    rollout = jax.jit(make_random_rollout(env, num_envs, num_steps))
    reset = jax.jit(batched_reset, static_argnums=(0, 2))
    key = jax.random.key(seed)
    start = time.perf_counter()
    state = reset(env, key, num_envs)
    compiled = rollout.lower(state, key).compile()
    compile_s = time.perf_counter() - start
    start = time.perf_counter()
    state, rewards, dones, metrics = jax.block_until_ready(compiled(state, key))
    wall = time.perf_counter() - start
    steps_per_s = num_envs * num_steps / wall
    result = {
        "compile_s": compile_s,
        "env_steps_per_s": steps_per_s,
        "sim_s_per_s": steps_per_s * env.dt,
        "mean_reward": float(np.mean(rewards)),
        "episodes_ended": float(np.sum(dones)),
    }
    for name, values in metrics.items():
        result[f"episode_{name}"] = float(episode_mean(values, dones))
    print(f"{task}: random policy, {counted(num_envs, 'env')} x {counted(num_steps, 'step')} on "
          f"{jax.devices()[0].platform}")
    for name, value in result.items():
        shown = "- (no episode ended: more --steps)" if math.isnan(value) else f"{value:,.4g}"
        print(f"  {name:>24}: {shown}")
    return result
