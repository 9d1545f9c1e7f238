"""A trained policy in one file: `export_policy(run_dir, out)` writes it, `load_policy(file)` acts from it with no run
directory (for another machine, a robot controller, a colleague's notebook).

The file is msgpack (flax's serialization): the format name, the run's config (JSON; acting uses its task and model)
and the `PolicyState` (network parameters, observation normaliser, training cycle).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import jax
from flax import serialization, traverse_util

from angora_jax.envs.core import Sensation
from angora_jax.experiment.agent import Agent, acting_parts, load_agent
from angora_jax.experiment.checkpoint import describe_misfits, misfits
from angora_jax.experiment.config import load_config, to_dict
from angora_jax.experiment.run_dir import CONFIG_FILE, RunDirError, run_dir_path, run_source, unwritable_out
from angora_jax.whole_files import written_whole

FORMAT = "angora_jax.policy/1"


SUFFIX = ".msgpack"


def policy_path(out: str | Path, run_dir: str | Path) -> Path:
    """Where `export_policy(run_dir, out)` writes: `out` itself when it names a .msgpack file; inside the folder `out`
    when it is one, or ends with '/' (then made), as `<folder>/<run name>.msgpack` (as `cp` copies into a folder).
    ValueError, naming the name to give, for any other name (`x.txt`, `policy`): the file is msgpack, whatever its
    name, and a name without a suffix may have meant a folder; ValueError too when the folder it goes in cannot be
    written (`unwritable_out`); TypeError for what is no path (None)."""
    if not isinstance(out, str | os.PathLike):
        raise TypeError(f"out is where the policy is written (a {SUFFIX} file's path or a folder, e.g. "
                        f"'policy{SUFFIX}'), got {out!r} ({type(out).__name__}).")
    text, out = str(out), Path(out)

    def in_folder() -> Path:
        return out / f"{Path(run_source(run_dir)[0]).resolve().name}{SUFFIX}"

    into = out.is_dir() or text.endswith(("/", os.sep))
    if (why := unwritable_out(out / "policy" if into else out)) is not None:
        raise ValueError(f"--out {text}: {why}; give a path in a folder you can write to.")
    if into:
        return in_folder()
    if out.suffix.lower() != SUFFIX:
        into = f", or {text}/ to write {in_folder()}" if not out.suffix else ""
        raise ValueError(f"an exported policy is a msgpack file: give --out a name ending in {SUFFIX} (e.g. "
                         f"{out.with_suffix(SUFFIX) if out.name else 'policy' + SUFFIX}){into}, not {out.name}.")
    return out


def export_policy(run_dir: str | Path, out: str | Path, checkpoint: str | int = "best") -> Path:
    """Write the policy of `run_dir`'s checkpoint ("best", "latest" or a cycle, as `load_agent` takes it) to `out`
    (a .msgpack file, or a folder to write `<run name>.msgpack` in: `policy_path`; ValueError for another name); an
    existing file is never overwritten (FileExistsError). Returns the path written."""
    run_dir_path(run_dir)  # TypeError for what is no path (the TrainingRun train returned), before `out` is made
    out = policy_path(out, run_dir)
    if out.exists():
        raise FileExistsError(f"{out} exists; exporting never overwrites a file: give another --out.")
    agent = load_agent(run_dir, checkpoint)
    content = {
        "format": FORMAT,
        "config": json.dumps(to_dict(agent.config), sort_keys=True),
        "state": serialization.to_state_dict(jax.device_get(agent.state)),
    }
    out.parent.mkdir(parents=True, exist_ok=True)
    with written_whole(out, replace=False) as draft:
        draft.write_bytes(serialization.msgpack_serialize(content))
    return out


@dataclass(frozen=True)
class Policy:
    """An exported policy, acting deterministically (the head's mode), as `evaluate` does by default.

    Attributes:
        agent: the `Agent` rebuilt from the file (its task, network, head and parameters), for what `act` does not
            cover: values, sampled actions, probing.
    """

    agent: Agent

    def initial_carry(self, batch_size: int) -> Any:
        """The recurrent state at an episode's start for `batch_size` environments (empty for feed-forward nets)."""
        return self.agent.initial_carry(batch_size)

    def act(self, carry: Any, obs: Sensation) -> tuple[Any, jax.Array]:
        """One step for a batch of raw observations (leaves `(B, size)`): `(carry, actions)`, actions ready for the
        task's `step` (`(B, action_dim)` floats in [-1, 1] for continuous tasks, `(B,)` integers for discrete ones).
        Pure: jit it, or call it inside a jitted rollout."""
        carry, actions, _ = self.agent.act(carry, obs)
        return carry, actions


def load_policy(path: str | Path) -> Policy:
    """The policy in a file written by `export_policy` (or `angora-jax export`). Raises FileNotFoundError when there
    is no such file, RunDirError when the file is not an exported policy or its parameters do not fit the network and
    task its config builds here (their code changed since the export)."""
    path = Path(path)
    if path.is_dir() and (path / CONFIG_FILE).is_file():
        raise FileNotFoundError(f"{path} is a run directory, not an exported policy: aj.load_agent({str(path)!r}) "
                                f"loads its policy, or aj.export_policy({str(path)!r}, FILE) writes one to load here "
                                "(angora-jax export RUN_DIR --out FILE).")
    if not path.is_file():
        raise FileNotFoundError(f"No exported policy at {path}: write one with aj.export_policy(RUN_DIR, FILE) or "
                                "angora-jax export RUN_DIR --out FILE.")
    try:
        content = serialization.msgpack_restore(path.read_bytes())
    except Exception as error:  # msgpack raises several types for a file that is not msgpack
        raise RunDirError(f"{path} is not an exported policy (not msgpack: {error}).") from None
    if not isinstance(content, dict) or content.get("format") != FORMAT:
        raise RunDirError(f"{path} is not an exported policy of this version (format {FORMAT!r} expected).")
    config = load_config(json.loads(content["config"]))
    env, network, head, template, compiled = acting_parts(config)
    # flax fills any arrays into the template: parameters of another layout failed only when acting, deep in flax.
    found = misfits(*(traverse_util.flatten_dict(tree, sep=".") for tree in (
        content["state"], serialization.to_state_dict(template))))
    if found:
        raise RunDirError(
            f"{path} holds parameters that do not fit the {config.ppo.network.name!r} network and {config.env.task} "
            f"task they were exported with, as this angora_jax builds them ({describe_misfits(found)}): their code "
            "changed since the export (a task or network of your own edited, or another angora_jax version). Load it "
            "with the code it was exported with, or export it again from its run.")
    state = serialization.from_state_dict(template, content["state"])
    return Policy(Agent(config, env, network, head, state, int(state.cycle), compiled))
