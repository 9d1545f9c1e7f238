"""Record a trained agent: every layer's activity per time step with the inputs, actions, rewards and task
variables, as one labelled `xarray.Dataset` (dims episode x time x unit) for the analyses in this package.

Episodes run batched on the training path (MJX for MuJoCo tasks, one compiled program), one per environment, for
`steps` policy steps from fresh starts, acting with the policy's mode. Variables:

    activity_<layer>   (episode, time, <layer>_unit)  a layer's output (flax `capture_intermediates`; layers named by
                                                       their module path, e.g. network.policy_trunk.Dense_0)
    input_<modality>   (episode, time, <modality>_feature)  raw observation (before normalisation)
    input_vision       (episode, time, camera, y, x, channel)  camera images (uint8), only with `images=True`
    action             (episode, time, action_dim)     the action the policy sent to the environment (a
                                                       silenced component, `silence_actions`, reached the
                                                       task as 0)
    reward, value      (episode, time)                 reward of the step, value estimate of the observation
    metric_<name>      (episode, time)                 the task's metrics at the step (e.g. goals_reached)
    task_<name>        (episode, time, <name>_component)  the state's task variables (`Env.task_variables`), seen
                                                       by the policy or not: hand tasks' fingertips (m) and
                                                       joint_angles (rad); the cube's position, orientation
                                                       (quaternion and, sign-free, rotation matrix), velocity,
                                                       angular velocity, goal_orientation, rotation to the
                                                       goal (quaternion_to_goal; rotation_to_goal, its matrix)
    alive              (episode, time)                 1 until the step that ends the episode (inclusive)
    time_in_episode    (episode, time)                 policy steps since the episode started, in s (coord `time`)

The visual area of a network that sees camera images (`visual.*`) encodes each camera's image on its own: its layers'
units are recorded per camera, camera-major (`cameras x units`). Its convolutional maps are not recorded (only layers
with one vector per environment are), and camera images only on request: they are large (a cube episode of 100
steps with two 64 x 64 RGB cameras holds 2.5 MB).

Only the first episode of each environment is kept: steps after it ended have `alive` 0 (their values belong to the
next episode and are kept for completeness, masked by the analyses).
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import xarray as xr
from flax import linen as nn

from angora_jax.analysis.decoding import check_recording
from angora_jax.envs.cameras import check_path_renderer
from angora_jax.envs.core import Sensation, is_image
from angora_jax.experiment.agent import Agent, check_agent, load_agent
from angora_jax.experiment.config import check_count, check_flag, check_seed, override_strings
from angora_jax.nets import ActorCritic
from angora_jax.ppo.evaluate import make_evaluate, sent_to_task
from angora_jax.whole_files import written_whole
from angora_jax.wording import counted

# Policy steps compiled as one program when recording until the episodes end: a recording stops at most this many
# steps after its longest episode ended (a cube episode lasts 100-5,000 steps).
RECORDING_CHUNK = 100


def layer_activity(agent: Agent, carry: Any, obs: Any) -> tuple[Any, jax.Array, jax.Array, dict[str, jax.Array]]:
    """One step of `agent` on raw observations with every layer's output: (carry, env action (mode), value,
    {layer name: (B, units)}). The action is the policy's, silenced components included: the task receives
    `sent_to_task(agent.state, action)`."""
    (carry, policy_params, value), state = agent.apply(carry, obs, capture_intermediates=_captures_activity,
                                                       mutable=["intermediates"])
    layers = {}
    batch = value.shape[0]
    for path, leaf in jax.tree_util.tree_flatten_with_path(state["intermediates"])[0]:
        names = [str(getattr(p, "key", getattr(p, "idx", p))) for p in path]
        call = names.index("__call__")
        # The path: the module's, "__call__", the call's number, then the place within its output (e.g. a cell's
        # carry and output, or a carry's entry per pathway).
        modules, outputs = names[:call], names[call + 2:]
        if not modules or leaf.ndim != 2 or leaf.shape[-1] == 0:
            continue  # the whole model's outputs, scalars per env, empty carries, convolutional maps
        if leaf.shape[0] != batch:  # the visual area's rows are (environment, camera) pairs
            leaf = leaf.reshape(batch, -1)
        layers[".".join([*modules, *outputs])] = leaf
    return carry, agent.head.env_action(agent.head.mode(policy_params)), value, layers


def _captures_activity(module: nn.Module, method_name: str) -> bool:
    """Capture the outputs of modules' `__call__`, except those of a recurrent cell's own submodules: they are parts
    of one step of the cell, not layers (the GRU's gate pre-activations `ir`, `hz`, ...; the "lstm" cell's
    `DenseParams`, which even return gate kernels: a weight matrix per step). The cell's output is recorded. Nor the
    network's own returned (carry, features, value): its layers are recorded under their names (`network.PMC.1`,
    `network.M1`), and the returned copies would only repeat them."""
    if method_name != "__call__" or isinstance(module.parent, nn.RNNCellBase):
        return False
    return not (isinstance(module.parent, ActorCritic) and module.name == "network")


def record_activity(agent: Agent | str | Path, episodes: int = 64, steps: int | None = None, seed: int = 0,
                    checkpoint: str | int = "best", images: bool = False,
                    env_overrides: Sequence[str] = ()) -> xr.Dataset:
    """Run `episodes` episodes of `agent` (an Agent, or a run directory loaded with `checkpoint` and the task options
    `env_overrides`, as `load_agent` takes them) for `steps` policy steps each (default: the task's episode length)
    and return the dataset described in the module docstring; `images` keeps camera images (`input_vision`) of a
    task that sees through cameras. With a cube policy reading a pose estimator (`pose_estimator=FILE`), the
    estimate (`input_vision`) lies beside the true pose (`task_cube_position`, `task_cube_orientation`)."""
    episodes = check_count("episodes", episodes)
    steps = None if steps is None else check_count("steps", steps)
    seed = check_seed("seed", seed)
    images = check_flag("images", images)
    env_overrides = override_strings(env_overrides, "env_overrides")
    if isinstance(agent, Agent):
        if env_overrides:
            raise ValueError("env_overrides apply when a run is loaded: give the run directory, or load the agent with "
                             "load_agent(run_dir, env_overrides=...).")
    else:
        agent = load_agent(agent, checkpoint, env_overrides)
    if images and not any(is_image(leaf) for leaf in jax.tree.leaves(agent.env.observation_shapes())):
        raise ValueError(f"images=True (--images) keeps camera images, but {agent.config.env.task} sees through no "
                         "camera (no image modality in its observations): record without it.")
    check_path_renderer(agent.env, batched=True)  # recording runs the training path
    record = _run_episodes(agent, episodes, steps, seed)
    return _dataset(agent, record, agent.env.dt, images).assign_attrs(env_overrides="; ".join(env_overrides))


def _run_episodes(agent: Agent, episodes: int, steps: int | None = None, seed: int = 0) -> dict[str, Any]:
    """`episodes` batched episodes of `agent` (the policy's mode) from the resets of `seed`, as host arrays
    `(time, episode, ...)`: inputs, action, value, reward, metrics, alive, steps, task (variables) and every layer's
    activity ("layers"). `steps` policy steps, or with None until every episode has ended (at most the task's
    episode length): the time axis then ends with the longest episode's last step. Compiled once per agent kind,
    episode count and length: parameters, normaliser statistics and silenced action components are arguments
    (`Agent.acting_state`), so variants of an agent (random weights, lesions, silenced muscles) reuse the program.
    The recorded `action` is the policy's; the task receives it with the silenced components at 0. Steps run in
    chunks, each copied to the host as it ends, since a whole cube episode of every layer for hundreds of episodes
    does not fit in GPU memory."""
    env = agent.env.sized_for(episodes)
    limit = steps or env.max_episode_steps
    chunk = min(RECORDING_CHUNK, limit)

    def start(key):
        reset_key, _ = jax.random.split(key)  # as `make_evaluate` does: a seed's episodes start alike in both
        return jax.vmap(env.reset)(jax.random.split(reset_key, episodes)), agent.initial_carry(episodes), jnp.ones(
            (episodes,), jnp.float32)

    def advance(policy_state, carry):
        acting = replace(agent, state=policy_state)  # never `agent.state`: that of the agent that compiled this

        def step(carry, _):
            state, net_carry, alive = carry
            net_carry, action, value, layers = layer_activity(acting, net_carry, state.obs)
            next_state = jax.vmap(env.step)(state, sent_to_task(policy_state, action))
            record = {"inputs": state.obs, "action": action, "value": value, "reward": next_state.reward,
                      "metrics": next_state.metrics, "alive": alive, "steps": state.steps,
                      "task": jax.vmap(env.task_variables)(state), "layers": layers}
            return (next_state, net_carry, alive * (1.0 - next_state.done)), record

        return jax.lax.scan(step, carry, None, length=chunk)

    programs = agent.compiled_once(("episodes", episodes, chunk),
                                   lambda: (jax.jit(start), jax.jit(advance)))
    # The shapes of a chunk's record, traced but not compiled: a recording too large for memory is refused before
    # XLA compiles or allocates it (`record --episodes 1000000` of CartPole ran over 5 minutes on 2 cores without
    # reaching the check after its first chunk).
    policy_state = agent.acting_state
    _, first = jax.eval_shape(programs[1], policy_state, jax.eval_shape(programs[0], jax.random.key(seed)))
    _check_fits_in_memory(first, episodes, chunk, limit)
    carry, records, done = programs[0](jax.random.key(seed)), [], 0
    while done < limit:
        carry, record = programs[1](policy_state, carry)
        records.append(jax.device_get(record))
        done += chunk
        if steps is None and not np.any(np.asarray(carry[2])):
            break
    record = jax.tree.map(lambda *parts: np.concatenate(parts)[:limit], *records)
    if steps is None:  # end with the longest episode's last step
        record = jax.tree.map(lambda x: x[:int(np.asarray(record["alive"]).sum(0).max())], record)
    return record


def _check_fits_in_memory(first: Any, episodes: int, chunk: int, limit: int) -> None:
    """ValueError before recording when `limit` steps, at the size of a chunk of `chunk` steps (`first`: its arrays
    or their shapes), would take more than this machine's memory (the recording is gathered on the host)."""
    needed = sum(math.prod(x.shape) * x.dtype.itemsize for x in jax.tree.leaves(first)) * -(-limit // chunk)
    memory = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    if needed > memory:
        raise ValueError(f"Recording {counted(episodes, 'episode')} x {counted(limit, 'step')} takes "
                         f"{needed / 2**30:,.1f} GiB, more than this machine's {memory / 2**30:,.1f} GiB of memory: "
                         "record fewer episodes or steps.")


def episode_outcomes(agent: Agent, episodes: int = 256, steps: int | None = None,
                     seed: int = 0) -> dict[str, np.ndarray]:
    """Per episode `(episodes,)` of `agent` (the policy's mode) from the starts of `seed`: episode_return (rewards
    through the episode's last step), episode_length (policy steps) and each task metric at the episode's last step
    (or at step `steps` when it has not ended by then). Runs the evaluation's program (`ppo.make_evaluate`), compiled
    once per agent kind, episode count and limit: the agent and its lesioned variants share it, silenced action
    components included (`Agent.acting_state`). The episodes are those `record_activity` records with the same seed.
    ConfigError for counts or a seed that `record_activity` refuses."""
    check_agent(agent)
    episodes = check_count("episodes", episodes)
    steps = None if steps is None else check_count("steps", steps)
    seed = check_seed("seed", seed)
    program = agent.compiled_once(("outcomes", episodes, steps), lambda: make_evaluate(
        agent.env, agent.network, agent.config.ppo, episodes, per_episode=True, steps=steps))
    totals = jax.device_get(program(agent.acting_state, jax.random.key(seed)))
    return {name.removeprefix("metric/"): np.asarray(value) for name, value in totals.items()}


def _dataset(agent: Agent, record: dict[str, Any], dt: float, images: bool) -> xr.Dataset:
    def episode_major(x):  # (time, episode, ...) -> (episode, time, ...)
        return np.swapaxes(np.asarray(x), 0, 1)

    data = {}
    for name, values in record["layers"].items():
        data[f"activity_{name}"] = (("episode", "time", f"{name}_unit"), episode_major(values),
                                    {"description": f"output of layer {name}"})
    for modality, values in vars(record["inputs"]).items():
        if is_image(values):
            if images:
                data[f"input_{modality}"] = (("episode", "time", "camera", "y", "x", "channel"),
                                             episode_major(values), {"description": "camera images"})
        elif values.shape[-1]:
            data[f"input_{modality}"] = (("episode", "time", f"{modality}_feature"), episode_major(values),
                                         {"description": f"raw observation, modality {modality}"})
    action = episode_major(record["action"])
    data["action"] = (("episode", "time", "action_dim")[: action.ndim], action, {"description": "action sent"})
    data["value"] = (("episode", "time"), episode_major(record["value"]), {"description": "value estimate"})
    data["reward"] = (("episode", "time"), episode_major(record["reward"]), {"description": "reward of the step"})
    for name, values in record["metrics"].items():
        data[f"metric_{name}"] = (("episode", "time"), episode_major(values), {"description": f"task metric {name}"})
    task = getattr(agent.env, "task", None)  # a MuJoCo task, through any wrapper that reads through to it
    labels = task.task_variable_labels() if task is not None else {}
    coords = {"time": ("time", np.arange(action.shape[1]) * dt, {"units": "s"})}
    for name, values in record["task"].items():
        data[f"task_{name}"] = (("episode", "time", f"{name}_component"), episode_major(values),
                                {"description": f"task variable {name} (see the task's task_variables)"})
        if name in labels:
            coords[f"{name}_component"] = list(labels[name])
    data["alive"] = (("episode", "time"), episode_major(record["alive"]),
                     {"description": "1 while the episode's first run lasts, through its last step"})
    data["time_in_episode"] = (("episode", "time"), episode_major(record["steps"]) * dt,
                               {"units": "s", "description": "time since the episode started"})
    return xr.Dataset(data, coords=coords,
                      attrs={"task": agent.config.env.task, "network": agent.config.ppo.network.name,
                             "cycle": agent.cycle, "policy_step_s": dt,
                             "camera_images": int(is_image(record["inputs"].vision))})


def replay_activity(agent: Agent, recording: xr.Dataset) -> xr.Dataset:
    """`recording` with its `activity_*` replaced by `agent`'s layer activity on the recorded inputs (each episode
    from the initial carry, step by step): another network's response to the same observations, e.g. the untrained
    control of `with_random_weights`, whose own behaviour would otherwise present other inputs."""
    check_agent(agent)
    check_recording(recording)
    recorded_task = recording.attrs.get("task")
    if recorded_task and recorded_task != agent.config.env.task:
        raise ValueError(f"The recording is of {recorded_task}, and this agent acts in {agent.config.env.task}: "
                         "replay a recording of its own task.")
    if recording.attrs.get("camera_images") and "input_vision" not in recording:
        raise ValueError("The agent saw camera images, which this recording did not keep: record it with "
                         "images=True (angora-jax record --images) to replay it.")
    names = [name for name in recording.data_vars if name.startswith("input_")]
    read = [f"input_{modality}" for modality, shape in vars(agent.env.observation_shapes()).items()
            if not is_image(shape) and shape.shape[-1]]
    if missing := [name for name in read if name not in names]:  # else the agent is handed an empty observation
        raise ValueError(f"The recording lacks the inputs this agent reads ({', '.join(missing)}): replay a recording "
                         "as record_activity returns it, with its input_* variables.")
    inputs = {name.removeprefix("input_"): jnp.asarray(np.swapaxes(recording[name].values, 0, 1)) for name in names}
    episodes = recording.sizes["episode"]

    def run(policy_state, inputs):
        acting = replace(agent, state=policy_state)

        def step(carry, obs):
            carry, _, _, layers = layer_activity(acting, carry, obs)
            return carry, layers

        return jax.lax.scan(step, acting.initial_carry(episodes), Sensation.make(**inputs))[1]

    layers = jax.device_get(jax.jit(run)(agent.state, inputs))
    replayed = recording.drop_vars([name for name in recording.data_vars if name.startswith("activity_")])
    for name, values in layers.items():
        replayed[f"activity_{name}"] = (("episode", "time", f"{name}_unit"), np.swapaxes(np.asarray(values), 0, 1),
                                        {"description": f"output of layer {name} on the recorded inputs"})
    return replayed.assign_attrs(replayed_cycle=agent.cycle)


def save_activity(dataset: xr.Dataset, path: str | Path) -> Path:
    """Write `dataset` as NetCDF (`xarray.open_dataset(path)` reads it back); refuses to overwrite."""
    check_recording(dataset)
    path = Path(path)
    if path.exists():
        raise FileExistsError(f"{path} exists; recordings are never overwritten: give another --out.")
    path.parent.mkdir(parents=True, exist_ok=True)
    # NetCDF 3 has no unsigned bytes: images are written as int8 marked `_Unsigned`, which xarray reads as uint8.
    images = {name: dataset[name].copy(data=dataset[name].values.view(np.int8)).assign_attrs(_Unsigned="true")
              for name in dataset.data_vars if dataset[name].dtype == np.uint8}
    with written_whole(path, replace=False) as draft:
        dataset.assign(images).to_netcdf(draft, engine="scipy")
    return path
