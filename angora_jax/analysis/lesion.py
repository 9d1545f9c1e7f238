"""In-silico lesions: silence units of a dense layer, a whole area, an input modality or an action component (a
muscle), and see what the task metric loses (`ablation`: many episodes per lesion, means with standard errors).

A unit of a dense layer is silenced by zeroing its kernel column and bias entry: its pre-activation is then 0, and
so is its output after the networks' tanh (or relu); a brain-area graph's LiF unit (`activation: lif`) then fires at
its constant resting rate, which carries no information either. The rest of the network is untouched, and an empty
unit set leaves the parameters bit for bit as they were. A modality is silenced at the network's input: its normalised
value is held at 0, the mean the normaliser saw in training (its variance is set to infinity), so the network
receives no information from it. An action component is silenced between the policy and the task
(`silence_actions`): the task receives 0 there, as a denervated muscle receives no excitation, whatever the policy
sends; the policy's output layer is not the place, since a head's parameters (a Beta's concentrations) give no action
of 0 when zeroed.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import replace

import jax
import jax.numpy as jnp
import numpy as np
import xarray as xr

from angora_jax.analysis.decoding import plot_path
from angora_jax.analysis.recording import episode_outcomes
from angora_jax.analysis.units import checked_units
from angora_jax.experiment.agent import Agent, check_agent
from angora_jax.experiment.config import ConfigError, check_count, check_number, check_seed
from angora_jax.wording import counted

# The kernels inside flax's recurrent cells, by their names: SimpleCell's input and hidden kernels, the GRU's and
# OptimizedLSTMCell's gate pre-activations. They are parts of one step of the cell rather than layers (recordings
# leave them out too); zeroing one is no lesion of the area.
CELL_PARTS = ({"i", "h"}, {"ir", "iz", "in", "hr", "hz", "hn"}, {"ii", "if", "ig", "io", "hi", "hf", "hg", "ho"})


def _kernels(agent: Agent) -> dict[tuple[str, ...], int]:
    """Every 2-D `kernel` of `agent`'s parameters: its module path -> its number of output units."""
    check_agent(agent)
    found = {}
    for path, leaf in jax.tree_util.tree_flatten_with_path(agent.params)[0]:
        names = tuple(str(getattr(p, "key", p)) for p in path)
        if names[-1] == "kernel" and leaf.ndim == 2:
            found[names[:-1]] = int(leaf.shape[-1])
    return found


def recurrent_cells(agent: Agent) -> list[str]:
    """The recurrent cells of `agent` (module paths, e.g. `network.PMC`): modules whose kernels are a cell's parts."""
    parts: dict[tuple[str, ...], set[str]] = {}
    for path in _kernels(agent):
        parts.setdefault(path[:-1], set()).add(path[-1])
    return sorted(".".join(path) for path, names in parts.items() if names in CELL_PARTS)


def dense_layers(agent: Agent) -> dict[str, int]:
    """The lesionable layers of `agent`: dense layer name (module path, as in recordings) -> its number of units."""
    cells = set(recurrent_cells(agent))
    return {".".join(path): units for path, units in _kernels(agent).items() if ".".join(path[:-1]) not in cells}


def lesion(agent: Agent, layer: str, units: Sequence[int] | np.ndarray) -> Agent:
    """`agent` with `units` (indices, whole numbers from 0 to the layer's count - 1; empty: the agent unchanged) of
    dense layer `layer` silenced; ConfigError naming the layers when `layer` is unknown or a recurrent cell, and
    naming units, the value and the range for a unit that is none of the layer's (1.5, True, -1)."""
    layers = dense_layers(agent)
    if layer in recurrent_cells(agent):
        feeding = [name for name in layers if name == f"{layer}_in"]
        instead = f"its input layer ({feeding[0]})" if feeding else "the layers feeding it"
        raise ConfigError(f"{layer!r} is a recurrent cell: its units feed back through gates, so there is no dense "
                          f"output to silence. Lesion {instead} or the areas it feeds instead; the agent's dense "
                          f"layers: {sorted(layers)}.")
    if layer not in layers:
        raise ConfigError(f"No dense layer {layer!r} to lesion; the agent's dense layers: {sorted(layers)}.")
    units = checked_units(units, layer, layers[layer], empty=True)
    if not units.size:
        return agent

    def silence(path, leaf):
        names = [str(getattr(p, "key", p)) for p in path]
        if ".".join(names[:-1]) != layer:
            return leaf
        return leaf.at[..., units].set(0.0)

    params = jax.tree_util.tree_map_with_path(silence, agent.params)
    return replace(agent, state=agent.state.replace(params=params))


def lesion_fraction(agent: Agent, layer: str, fraction: float, seed: int = 0) -> Agent:
    """`lesion` of a random `fraction` (0 to 1) of the layer's units, drawn with `seed` (a whole number from 0 to
    2**32 - 1); ConfigError for either outside its range."""
    fraction = check_number("fraction", fraction, 0.0, 1.0)
    seed = check_seed("seed", seed)
    size = dense_layers(agent).get(layer, 0)
    units = np.random.default_rng(seed).permutation(size)[: round(fraction * size)]
    return lesion(agent, layer, units)


def lesion_area(agent: Agent, area: str) -> Agent:
    """`agent` with every unit of the dense layer or cortical area `area` (e.g. `network.SSC_2`) silenced."""
    return lesion(agent, area, np.arange(dense_layers(agent).get(area, 1)))  # an unknown area: lesion's error


def silence_modality(agent: Agent, modality: str) -> Agent:
    """`agent` receiving nothing from input `modality` (e.g. "goal"): its normalised input is held at 0."""
    check_agent(agent)
    modalities = [name for name, stats in vars(agent.state.obs_stats).items() if stats.mean.shape[-1] > 0]
    if modality == "vision" and agent.config.ppo.network.visual is not None:
        raise ValueError("This agent sees camera images, which are not normalised inputs: silence what it sees with "
                         "lesion_area(agent, 'visual.decoder') (the visual area's output units).")
    if modality not in modalities:
        raise ValueError(f"No input modality {modality!r} to silence; {agent.config.env.task} has {modalities}.")
    if not agent.config.ppo.normalization.observations:
        raise ValueError("Silencing a modality holds its normalised input at 0; this run trained without "
                         "observation normalisation (ppo.normalization.observations=false).")
    stats = getattr(agent.state.obs_stats, modality)
    silenced = agent.state.obs_stats.replace(**{modality: stats.replace(var=jnp.full_like(stats.var, jnp.inf))})
    return replace(agent, state=agent.state.replace(obs_stats=silenced))


def silence_actions(agent: Agent, components: Sequence[int] | np.ndarray) -> Agent:
    """`agent` whose action `components` (indices) are forced to 0 before they reach the task: a muscle's lesion on a
    muscle-driven task (MyoHand: component i is muscle i's excitation, so the muscle stays at rest however the
    policy drives it). The policy and its recorded `action` are untouched; the task sees the silenced action (a
    recording's `task_muscle_excitation` holds the 0). The silenced components are a mask in the agent's state
    (`SilencedPolicyState`), data of its compiled programs rather than a constant: the agent, every lesion of it and
    any other mask run the same programs, so a lesion per muscle costs no compile of its own. Every path that acts
    for the agent silences them: `ablation`, `episode_outcomes`, `record_activity`, `Agent.act`, `Agent.evaluate`,
    the eager path and its videos. Silencing an agent again adds its components to those already silenced.

    Args:
        agent: the agent to lesion (continuous actions).
        components: indices into the action vector, whole numbers from 0 to its size - 1 (NumPy and JAX integers
            too); empty: the agent unchanged.

    Raises:
        ConfigError (a ValueError): discrete actions (0 is an action there, not silence), or a component that is
            none of the action's (1.5, True, -1, the size), naming components, the value and the range.
    """
    check_agent(agent)
    spec = agent.env.action_spec
    if spec.discrete:
        raise ConfigError("Silencing action components forces them to 0, which is a choice for discrete actions, not "
                          "silence: lesion the policy's areas (lesion_area) instead.")
    components = checked_units(components, "the action", spec.size, empty=True, name="components",
                               counts=f"{agent.config.env.task}'s action has {counted(spec.size, 'component')}")
    if not components.size:
        return agent
    state = agent.acting_state
    silenced = np.array(state.silenced, bool)  # a copy: the mask of `agent` stays as it was
    silenced[..., components] = True
    return replace(agent, state=state.replace(silenced=jnp.asarray(silenced)))


def ablation(agent: Agent, lesions: Mapping[str, Agent], episodes: int = 256, steps: int | None = None,
             seed: int = 0) -> xr.Dataset:
    """The task outcomes of `agent` (as "intact") and of each lesioned variant in `lesions` (name -> Agent, e.g. from
    `lesion_area`, `silence_modality`, `lesion_fraction`) over the same `episodes` starts: per lesion and outcome
    (episode_return, episode_length, every task metric at the episode's end) the mean and its standard error,
    `mean`, `sem` (dims lesion x outcome), and the per-episode values `outcome_values` (lesion x outcome x episode).
    On a CPU an unchanged agent gives bit-identical outcomes; on a GPU, runs of the same program differ slightly
    (XLA's GPU reductions are not deterministic unless XLA_FLAGS=--xla_gpu_deterministic_ops=true)."""
    if not isinstance(lesions, Mapping) or not all(isinstance(v, Agent) for v in lesions.values()):
        raise ValueError("lesions must map a name to a lesioned Agent, e.g. {'SSC lesioned': lesion_area(agent, "
                         f"'network.SSC_2')}}; got {type(lesions).__name__}" + (
                             f" holding {sorted({type(v).__name__ for v in lesions.values()})}"
                             if isinstance(lesions, Mapping) else "") + ".")
    episodes = check_count("episodes", episodes)
    variants = {"intact": agent, **lesions}
    values = {name: episode_outcomes(variant, episodes, steps, seed) for name, variant in variants.items()}
    outcomes = list(values["intact"])
    table = np.array([[np.asarray(values[name][o], np.float64) for o in outcomes] for name in variants])
    return xr.Dataset(
        {"mean": (("lesion", "outcome"), table.mean(-1)),
         "sem": (("lesion", "outcome"), table.std(-1, ddof=1) / np.sqrt(episodes)),
         "outcome_values": (("lesion", "outcome", "episode"), table)},
        coords={"lesion": list(variants), "outcome": outcomes},
        attrs={"episodes": episodes, "task": agent.config.env.task, "cycle": agent.cycle},
    )


def plot_ablation(result: xr.Dataset, outcome: str, path: str) -> None:
    """Bars of `outcome`'s mean per lesion with +-1 standard error."""
    plot_path("plot_ablation", result, "mean", "ablation", path)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    mean, sem = result["mean"].sel(outcome=outcome).values, result["sem"].sel(outcome=outcome).values
    fig, ax = plt.subplots(figsize=(1.5 + 0.8 * len(mean), 3.5))
    ax.bar(range(len(mean)), mean, yerr=sem, capsize=3, color="tab:blue")
    ax.set_xticks(range(len(mean)), result["lesion"].values, rotation=30, ha="right")
    ax.set_ylabel(f"{outcome}\n(mean +- s.e.m., {counted(result.attrs['episodes'], 'episode')})")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def with_random_weights(agent: Agent, seed: int = 0) -> Agent:
    """`agent` with freshly initialised parameters (same network, head and normaliser): the untrained control for
    decoding and similarity (what structure alone gives, before learning). `seed`: a whole number from 0 to
    2**32 - 1 (ConfigError otherwise)."""
    check_agent(agent)
    seed = check_seed("seed", seed)
    shapes = agent.env.observation_shapes()
    obs = jax.tree.map(lambda s: jnp.zeros((1, *s.shape), s.dtype), shapes)
    params = agent.model.init(jax.random.key(seed), agent.initial_carry(1), obs)["params"]
    return replace(agent, state=agent.state.replace(params=params))
