"""Components: named sub-networks of a parameter tree, to pretrain, transplant and freeze (AngoraPy's pretrainable
components).

A component is addressed by its module path with dots, as in recordings and lesions: `network.SSC_1` is
`params["network"]["SSC_1"]`. `save_component` writes one to a file (flax msgpack); a config's
`network.pretrained` loads components from such files or from other runs into a new run's initial parameters, and
`network.frozen` keeps components fixed during training (`frozen_optimizer`: their updates are masked to zero;
`stop_frozen_gradients`: the loss has no backward pass through them).
"""

from __future__ import annotations

import difflib
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import jax
import numpy as np
import optax
from flax import serialization

from angora_jax.registry import import_registrar
from angora_jax.saved_files import COMPONENT, USE, content_kind
from angora_jax.whole_files import written_whole

# How a component file is written, for messages about files that are not one.
WRITE_COMPONENTS = ("write components with angora_jax.nets.components.save_component(agent.params, PATH, FILE) or "
                    "`angora-jax pretrain-vision --out FILE`")

# What reads a saved run's policy (an object with `params` and `obs_stats`) from "RUN_DIR[:best|latest|<cycle>]":
# run directories belong to the experiment layer, which builds on nets and ppo, so it registers its reader here
# (angora_jax.experiment.agent) and nets and ppo never import it.
_run_reader: Callable[[str], Any] | None = None


def register_run_reader(reader: Callable[[str], Any]) -> None:
    """Make `reader(source) -> saved policy` the way `read_saved_run` (and so `init_from` and run-directory
    components) reads runs. angora_jax.experiment registers its `saved_policy` when it is imported (the first read
    imports it where `import angora_jax` did not)."""
    global _run_reader
    _run_reader = reader


def read_saved_run(source: str | Path) -> Any:
    """The saved policy (`params`, `obs_stats`) of the run `source` ("RUN_DIR[:best|latest|<cycle>]"), read by the
    registered reader; RuntimeError naming the fix when none is registered."""
    if _run_reader is None:  # `import angora_jax` names the module that registers it, without importing it
        import_registrar(__name__)
    if _run_reader is None:
        raise RuntimeError(f"Reading the saved run {str(source)!r} needs angora_jax.experiment, which registers the "
                           "run-directory reader: import angora_jax first.")
    return _run_reader(str(source))


def module_paths(params: Any) -> list[str]:
    """Every module path in `params` (each nested mapping), e.g. `["network", "network.SSC_1", ...]`."""
    found = []

    def walk(tree: Any, prefix: str) -> None:
        for key, value in tree.items():
            if isinstance(value, Mapping):
                found.append(f"{prefix}{key}")
                walk(value, f"{prefix}{key}.")

    walk(params, "")
    return found


def component(params: Any, path: str) -> Any:
    """The subtree of `params` at module path `path`; ValueError listing the modules when there is none."""
    tree = params
    for key in path.split("."):
        if not isinstance(tree, Mapping) or key not in tree:
            modules = module_paths(params)
            close = difflib.get_close_matches(path, modules, n=1)
            guess = f"; did you mean {close[0]!r}?" if close else ""
            raise ValueError(f"No module {path!r} in the parameters{guess} Modules: {', '.join(modules)}.")
        tree = tree[key]
    if not isinstance(tree, Mapping):
        raise ValueError(f"{path!r} is a parameter, not a module; give its module, e.g. {path.rsplit('.', 1)[0]!r}.")
    return tree


def with_component(params: Any, path: str, values: Any) -> Any:
    """`params` with the module at `path` replaced by `values` (same structure and shapes; ValueError otherwise)."""
    current = component(params, path)
    differing = shape_misfits(current, values)
    if differing:
        raise ValueError(f"The values for {path!r} do not fit this network's ({'; '.join(differing[:4])}).")
    keys = path.split(".")

    def replace(tree: Any, depth: int) -> Any:
        if depth == len(keys):
            return jax.tree.map(lambda old, new: np.asarray(new, dtype=old.dtype), current, dict(values))
        return {**tree, keys[depth]: replace(tree[keys[depth]], depth + 1)}

    return replace(params, 0)


def shape_misfits(current: Any, given: Any) -> list[str]:
    """The leaves whose shapes differ between the trees `current` (this network's) and `given` (a source's), each
    as `['a']['kernel']: (4, 8) here, (4, 64) in the source` ("none" where a tree lacks the leaf); empty when the
    trees fit."""
    def shapes(tree: Any) -> dict[str, tuple[int, ...]]:
        return {jax.tree_util.keystr(path): np.shape(leaf) for path, leaf in jax.tree_util.tree_leaves_with_path(tree)}

    ours, theirs = shapes(current), shapes(given)
    return [f"{name}: {ours.get(name, 'none')} here, {theirs.get(name, 'none')} in the source"
            for name in sorted(ours.keys() | theirs.keys()) if ours.get(name) != theirs.get(name)]


def save_component(params: Any, path: str, file: str | Path) -> Path:
    """Write the module `path` of `params` (e.g. `agent.params`) to `file`, whole or not at all (`written_whole`: a
    crash while writing leaves no half file); refuses to overwrite."""
    file = Path(file)
    if file.exists():
        raise FileExistsError(f"{file} exists; components are never overwritten: give another file.")
    file.parent.mkdir(parents=True, exist_ok=True)
    data = serialization.msgpack_serialize(jax.device_get(component(params, path)))
    with written_whole(file, replace=False) as draft:
        draft.write_bytes(data)
    return file


def load_component(source: str | Path, path: str) -> Any:
    """The module `path` from `source`: a file of `save_component`, or a run directory (`RUN_DIR`, its best
    checkpoint, or `RUN_DIR:latest` / `RUN_DIR:<cycle>`), from whose parameters the same path is taken."""
    if Path(source).is_file():
        return read_component_file(source)
    return component(read_saved_run(source).params, path)


def read_component_file(file: str | Path) -> dict[str, Any]:
    """The module saved in `file` by `save_component`; ValueError naming the file and how to write one when it holds
    none (damaged, cut short or another kind of file)."""
    try:
        values = serialization.msgpack_restore(Path(file).read_bytes())
    except (ValueError, TypeError) as error:  # what msgpack (ExtraData, FormatError, ...) and flax raise on bad bytes
        values, cause = None, f"{type(error).__name__}: {error}"
    else:
        cause = ("it holds no parameters" if isinstance(values, dict)
                 else f"it holds a {type(values).__name__}, not a module's parameters")
    if not isinstance(values, dict) or not values:
        raise ValueError(f"{file} is not a component file ({cause}): it is damaged, cut short or another kind of "
                         f"file; {WRITE_COMPONENTS}, or give a run directory.")
    if (kind := content_kind(values)) != COMPONENT:
        raise ValueError(f"{file} is {kind}, not a component file: {USE[kind]}. {WRITE_COMPONENTS[0].upper()}"
                         f"{WRITE_COMPONENTS[1:]}, or give a run directory.")
    return values


def with_pretrained(params: Any, pretrained: Mapping[str, str | Path]) -> Any:
    """`params` with every `module path -> source` of `pretrained` loaded (see `load_component`)."""
    for path, source in pretrained.items():
        params = with_component(params, path, load_component(source, path))
    return params


def _frozen_labels(tree: Any, frozen: Sequence[str]) -> Any:
    """`tree` with each leaf replaced by "frozen" (under one of the module paths `frozen`) or "trained"; a ValueError
    naming the modules when a path names none."""
    for path in frozen:
        component(tree, path)

    def label(key_path, _):
        dotted = ".".join(str(getattr(k, "key", k)) for k in key_path)
        return "frozen" if any(dotted.startswith(f"{path}.") for path in frozen) else "trained"

    return jax.tree_util.tree_map_with_path(label, tree)


def frozen_optimizer(optimizer: optax.GradientTransformation, frozen: Sequence[str]) -> optax.GradientTransformation:
    """`optimizer` for all parameters but those under the module paths `frozen`, whose updates are zero (and which
    hold no optimizer state). Its `init(params)` raises a ValueError naming the modules when a path names none."""
    if not frozen:
        return optimizer
    return optax.multi_transform({"trained": optimizer, "frozen": optax.set_to_zero()},
                                 lambda tree: _frozen_labels(tree, frozen))


def stop_frozen_gradients(params: Any, frozen: Sequence[str]) -> Any:
    """`params` with the modules under `frozen` behind `jax.lax.stop_gradient`: a loss of these params then has no
    backward pass through a frozen area whose inputs need no gradient (a frozen visual area: its convolutions are
    run forward only), besides its zero updates from `frozen_optimizer`."""
    if not frozen:
        return params
    return jax.tree.map(lambda label, leaf: jax.lax.stop_gradient(leaf) if label == "frozen" else leaf,
                        _frozen_labels(params, frozen), params)
