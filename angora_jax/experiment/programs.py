"""The run's compiled programs: `cycle_programs` (its jitted `init` and `cycle`, kept for reuse within a process)
and `initial_state_shape` (its TrainState's shapes, traced without running). Both the runner and a loaded agent
(`agent.load_agent`, which restores a checkpoint into those shapes) need them, so they live below both."""

from __future__ import annotations

import dataclasses
import json
from collections import OrderedDict
from collections.abc import Callable

import jax

from angora_jax.envs.core import Env
from angora_jax.experiment.config import Config, num_devices, to_dict
from angora_jax.ppo.cycle import TrainState, make_cycle
from angora_jax.ppo.step_size import spanning_schedules
from angora_jax.registry import generation


def initial_state_shape(config: Config, env: Env) -> TrainState:
    """Shapes and dtypes of the run's TrainState on its devices (a tree of `jax.ShapeDtypeStruct`), computed without
    running (and without reading pretrained components or the run it starts from: where initial values come from does
    not change a shape)."""
    network = dataclasses.replace(config.ppo.network, pretrained={})
    init, _ = cycle_programs(dataclasses.replace(config, ppo=config.ppo.replace(network=network, init_from=None)), env)
    return jax.eval_shape(init, jax.random.key(config.ppo.seed))


# The programs of the last few distinct runs of this process (see cycle_programs); each holds its compiled code.
_PROGRAMS_KEPT = 4
_programs: OrderedDict[str, tuple[Callable, Callable]] = OrderedDict()


def cycle_programs(config: Config, env: Env) -> tuple[Callable, Callable]:
    """The run's jitted `init` and `cycle` (`make_cycle`), the same two functions for every run of this process
    whose task, PPO settings and devices are the same (the seed aside: it only picks the first key, and the cycle
    count unless a schedule ends at the last cycle: `ppo.lr_decay`, `ppo.entropy_coef_final`). A run resumed
    or trained in pieces in one process, or the same config trained again in a notebook, then reuses the traced and
    compiled programs: JAX's persistent cache saves only the compiling, and never holds MuJoCo Warp's programs (each
    trace gives them a new call id). Runs that read saved values when they start (`ppo.init_from`, pretrained
    components) get new functions: their files may have changed since."""
    ppo = config.ppo
    if ppo.init_from or ppo.network.pretrained:
        return make_cycle(env, None, ppo, num_devices(config))
    settings = to_dict(config)
    # The cycle count reaches the programs only through the schedules that end at the last cycle, so without them
    # a `resume --num-cycles N` in the same process reuses the programs instead of tracing and compiling them again.
    scheduled = bool(spanning_schedules(ppo))
    key = json.dumps({"env": settings["env"],
                      "ppo": {**settings["ppo"], "seed": None, **({} if scheduled else {"num_cycles": None})},
                      "distribution": settings["distribution"], "devices": num_devices(config),
                      "definitions": generation()}, sort_keys=True)
    if key not in _programs:
        _programs[key] = make_cycle(env, None, ppo, num_devices(config))
        if len(_programs) > _PROGRAMS_KEPT:
            _programs.popitem(last=False)
    _programs.move_to_end(key)
    return _programs[key]
