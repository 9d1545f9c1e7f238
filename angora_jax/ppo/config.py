"""`PPOConfig`: every setting of a training run as a frozen tree of plain dataclasses holding primitives.

The defaults follow AngoraPy (Weidler et al. 2023) and "Implementation matters" (Engstrom et al. 2020), scaled so
that a run fits a workstation. `validate()` checks the config alone; `validate_for(env)` also checks it against a
task (head vs action space, batch shapes).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

from angora_jax.envs.core import Env
from angora_jax.frozen_settings import settings
from angora_jax.nets.area_graph import AreaGraph, AreaSpec, ValueSpec, check_graph, policy_modalities
from angora_jax.nets.cortical import area_sizes
from angora_jax.nets.models import POLICY_MODALITIES, RECURRENT_CELLS
from angora_jax.nets.visual import make_visual_area
from angora_jax.ppo.episode_pool import Pool, compared_value
from angora_jax.wording import counted

# Counts (cycles, environments, steps, units) become int32 in JAX's arrays and loops (x64 is off), so they must fit.
INT32_MAX = 2**31 - 1
# What numpy's integers hold; the run's sizes are products of such counts, computed in Python's integers.
INT64_MAX = 2**63 - 1
# jax.random.key keeps a seed's low 32 bits (x64 off): key(2**32) is key(0) and key(-1) is key(2**32 - 1).
SEED_MAX = 2**32 - 1
# Settings are computed in float32: a larger number is inf there.
FLOAT32_MAX = 3.4028234663852886e38


@dataclass(frozen=True)
class Bounds:
    """The valid range of a numeric config field, declared beside it (`bounded`): finite, and within it (a tuple's or
    mapping's numbers each).

    Attributes:
        low: the smallest value allowed (see `open_low`).
        high: the largest value allowed.
        open_low: `low` itself is not allowed (`low < value`).
        why: what the number is, for messages.
    """

    low: float
    high: float
    open_low: bool = False
    why: str = ""

    def check(self, key: str, value: object) -> None:
        """Raise a ValueError naming `key`, the value and the range when a number of `value` lies outside; values of
        other types are left to the type check."""
        numbers = value.values() if isinstance(value, dict) else value if isinstance(value, tuple | list) else (value,)
        for number in numbers:
            if isinstance(number, bool) or not isinstance(number, int | float):
                continue
            if isinstance(number, float) and not math.isfinite(number):  # an int may be too large for isfinite
                raise ValueError(f"{key} must be a finite number, got {number}{self._allowed(number)}.")
            if number < self.low or (self.open_low and number == self.low):
                raise ValueError(f"{key} must be {'>' if self.open_low else '>='} {_show(self.low)}, got "
                                 f"{quote_number(number)}{self._allowed(number)}.")
            if number > self.high:
                raise ValueError(f"{key} must be <= {_show(self.high)}, got {quote_number(number)}"
                                 f"{self._allowed(number)}.")

    def _allowed(self, number: float) -> str:
        kind = "integers" if isinstance(number, int) else "numbers"
        span = (f"{kind} above {_show(self.low)} up to {_show(self.high)}" if self.open_low
                else f"{kind} from {_show(self.low)} to {_show(self.high)}")
        return f" (allowed: {span}{f': {self.why}' if self.why else ''})"


def bounded(default: object = dataclasses.MISSING, low: float = -FLOAT32_MAX, high: float = FLOAT32_MAX, *,
            open_low: bool = False, why: str = "", factory: object = dataclasses.MISSING) -> object:
    """A dataclass field (default `default`, or `factory()`) whose numbers must lie in `Bounds(low, high, ...)`."""
    return field(default=default, default_factory=factory, metadata={"bounds": Bounds(low, high, open_low, why)})


def count_field(default: object, low: int = 1, why: str = "") -> object:
    """A field of whole numbers from `low` to `INT32_MAX` (a count: cycles, steps, units)."""
    return bounded(default, low, INT32_MAX, why=why)


# The ranges of numeric fields of config sections declared in other modules, which `bounded` cannot annotate there.
OTHER_BOUNDS: dict[tuple[type, str], Bounds] = {
    (AreaSpec, "size"): Bounds(1, INT32_MAX, why="the area's units"),
    (ValueSpec, "sizes"): Bounds(1, INT32_MAX, why="units of each layer of the value net"),
}


def field_bounds(cls: type, name: str) -> Bounds | None:
    """The declared range of field `name` of config dataclass `cls` (`bounded` or `OTHER_BOUNDS`); None if none."""
    declared = next(f for f in dataclasses.fields(cls) if f.name == name).metadata.get("bounds")
    return declared or OTHER_BOUNDS.get((cls, name))


def check_bounds(config: object, prefix: str) -> None:
    """Check each number of dataclass `config`, and of the dataclasses it holds, against its field's declared range;
    a ValueError naming the key (`prefix.<field>`, or `<field>` when `prefix` is empty) for the first outside it."""
    for f in dataclasses.fields(config):
        value, key = getattr(config, f.name), f"{prefix}.{f.name}" if prefix else f.name
        bounds = field_bounds(type(config), f.name)
        if bounds is not None:
            bounds.check(key, value)
        for name, item in value.items() if isinstance(value, dict) else [(None, value)]:
            if dataclasses.is_dataclass(item) and not isinstance(item, type):
                check_bounds(item, key if name is None else f"{key}.{name}")


def _show(bound: float) -> str:
    return f"{bound:,}" if isinstance(bound, int) else f"{bound:g}"


def quote_number(number: float) -> str:
    """`number` for a message: a huge integer by its length (Python prints none of over 4,300 digits)."""
    if isinstance(number, int) and abs(number) >= 10**30:
        return f"a {int(math.log10(abs(number))) + 1:,}-digit integer"
    return repr(number)


@settings
class VisualConfig:
    """The visual area: a convolutional encoder of camera images (`angora_jax.nets.visual`), shared by the cameras,
    whose features (cameras x `features`) take the images' place in `vision` for the network.

    Attributes:
        encoder: "cornet_z" or "impala".
        widths: channels per stage (empty: the encoder's own).
        features: features the encoder gives per camera.
    """

    encoder: str = "cornet_z"
    widths: tuple[int, ...] = count_field((), why="channels of each stage")
    features: int = count_field(64, why="features per camera")


@settings
class NetworkConfig:
    """Which registered network to build and its sizes; `None` sizes mean the model's own default.

    Attributes:
        name: a name from `angora_jax.nets.list_networks()` ("simple", "deeper", "rnn", "lstm", "gru", "wide",
            "cortical", "areas").
        width: units of the dense layers (embedding width for recurrent models; the value net's for cortical).
        cell_size: units of the recurrent cell (ignored by feed-forward models; the premotor PMC for cortical).
        shared_trunk: one trunk for policy and value (the value head also reads `asymmetric`) instead of two.
        memory: units of a GRU beside the policy trunk of the simple and deeper networks (0: none), its output added
            to the trunk's through a layer that starts at zero: `ppo.init_from` a run of the same network without
            memory starts from its policy unchanged (`angora_jax.nets.models.FeedForward`).
        cell: the recurrent cell, "rnn", "lstm" or "gru", of the wide network (default lstm) and of the cortical model's
            premotor area PMC (default lstm); the rnn, lstm and gru networks are named for theirs.
        areas: the cortical model's area sizes that differ from AngoraPy's, e.g. `{SSC_1: 32, PMC: 64}`.
        graph: the brain-area graph of the areas network (`angora_jax.nets.area_graph.AreaGraph`): its areas (size,
            inputs, activation, recurrent cell), the area the policy head reads and the value net. The shipped configs
            shadow_reach_cortical_graph (the cortical model) and shadow_reach_shadowv2 hold examples.
        frozen: parameter paths (dotted module paths as in recordings, e.g. `network.SSC_1`) that training leaves
            unchanged: their updates are masked to zero (`optax.multi_transform`). Each must name a module.
        pretrained: parameter path -> where its values come from at the start of a run: a run directory (its best
            checkpoint; `RUN_DIR:latest` or `RUN_DIR:<cycle>` for another), whose parameters at the same path are taken,
            or a file written by `angora_jax.nets.components.save_component`. Shapes must match.
        visual: the visual area that encodes camera images (needed when the task's `vision` option renders them; its
            parameters are the module `visual`, e.g. `pretrained: {visual: encoder.msgpack}` and `frozen: [visual]`).
    """

    name: str = "simple"
    width: int | None = count_field(None, why="units of the dense layers")
    cell_size: int | None = count_field(None, why="units of the recurrent cell")
    shared_trunk: bool = False
    memory: int = bounded(0, 0, INT32_MAX, why="units of the GRU beside the policy trunk")
    cell: str | None = None
    areas: dict[str, int] = bounded(low=1, high=INT32_MAX, why="units of each area", factory=dict)
    graph: AreaGraph | None = None
    frozen: tuple[str, ...] = ()
    pretrained: dict[str, str] = field(default_factory=dict)
    visual: VisualConfig | None = None

    def validate(self) -> NetworkConfig:
        """Raise a ValueError naming the field when a setting cannot apply; return self."""
        if self.visual is not None:
            make_visual_area(self.visual)
        if self.cell is not None and self.cell not in RECURRENT_CELLS:
            raise ValueError(f"network.cell must be one of {RECURRENT_CELLS}, got {self.cell!r}.")
        if self.cell is not None and self.name not in ("wide", "cortical"):
            raise ValueError(f"network.cell applies to the wide and cortical networks, not {self.name!r}: the rnn, "
                             "lstm and gru networks are named for their cell, and simple and deeper have none.")
        if self.memory and self.name not in ("simple", "deeper"):
            raise ValueError(f"network.memory adds a GRU to the simple and deeper networks, not to {self.name!r}: "
                             "the rnn, lstm, gru, wide and cortical networks are recurrent already (network.cell_size "
                             "sizes their cell).")
        if self.areas and self.name != "cortical":
            raise ValueError(f"network.areas sizes the cortical network's areas, not {self.name!r}'s (an areas graph "
                             "sizes its own: network.graph.areas.<name>.size).")
        area_sizes(self.areas)
        if self.name == "areas":
            check_graph(self.graph)
            unused = [key for key in ("width", "cell_size", "shared_trunk") if getattr(self, key)]
            if unused:
                raise ValueError(f"The areas network takes no network.{' or network.'.join(unused)} (set it to null "
                                 "or false): its graph gives the sizes (network.graph.areas.<name>.size) and the value "
                                 "net (network.graph.value).")
        elif self.graph is not None:
            raise ValueError(f"network.graph is the areas network's, not {self.name!r}'s: set network.name=areas, or "
                             "remove network.graph.")
        if not all(isinstance(source, str) for source in self.pretrained.values()):
            raise ValueError(f"network.pretrained maps module paths to sources (a file or RUN_DIR), got "
                             f"{self.pretrained}.")
        for path in (*self.frozen, *self.pretrained):
            if not isinstance(path, str) or not path or path.startswith(".") or ".." in path:
                raise ValueError(f"network.frozen and network.pretrained name modules like 'network.SSC_1', got "
                                 f"{path!r}.")
        return self


@settings
class NormalizationConfig:
    """Running normalisation of observations (per modality) and of rewards (by the discounted return's std).

    Attributes:
        observations: standardise each observation modality by its running mean and std.
        rewards: divide rewards by the running std of the discounted return.
        clip: normalised observations are clipped to +-clip (standard deviations).
    """

    observations: bool = True
    rewards: bool = True
    clip: float = bounded(10.0, 0, open_low=True, why="standard deviations")


@settings
class StopAt:
    """End a run early, with a checkpoint, after the first cycle whose training metric reaches a value (AngoraPy's
    `--stop-early`).

    Attributes:
        value: the value to reach, in the metric's units.
        metric: a per-cycle metric, as `checkpoint.best_metric` names them ("episode_return", "metric/goals_reached").
        mode: "max" stops when the metric is >= value, "min" when it is <= value.
        episodes: a training metric is compared over this many of the latest episodes, as the best checkpoint's
            (`checkpoint.best_episodes`): the cycle's own when that many ended in it (hundreds on a GPU), else pooled
            with the cycles before it, and never before that many have ended, so that one lucky episode of a run
            with few environments does not end it. `eval/` metrics are compared as they are. 1: each cycle's own
            (a cycle in which no episode ended has no value and never stops the run).
    """

    # No default value: a target left out would be 0, which most runs reach in their first cycle.
    value: float = bounded(why="the metric's value that ends the run")
    metric: str = "episode_return"
    mode: str = "max"
    episodes: int = count_field(32, why="the episodes the metric is compared over")

    def validate(self) -> StopAt:
        """Raise a ValueError naming the field when a setting cannot apply; return self."""
        if self.mode not in ("max", "min"):
            raise ValueError(f"ppo.stop_at.mode must be 'max' or 'min', got {self.mode!r}.")
        if not isinstance(self.value, (int, float)) or not math.isfinite(self.value):
            raise ValueError(f"ppo.stop_at.value must be a finite number, got {self.value!r}.")
        return self

    def compared(self, pool: Pool, metrics: dict[str, float]) -> tuple[float, Pool]:
        """The value of this cycle's `metrics` that the target is compared with (`episodes` says which), and the pool
        of cycles that the next cycle's value continues (`compared_value`)."""
        return compared_value(pool, metrics, self.metric, self.episodes)

    def ended(self, value: float) -> str | None:
        """What ended the run at a cycle whose compared `value` reaches the target ("metric/goals_reached 30.4 >=
        30"), None when it does not."""
        if not (value >= self.value if self.mode == "max" else value <= self.value):
            return None
        return f"{self.metric} {value:.4g} {'>=' if self.mode == 'max' else '<='} {self.value:g}"


@settings
class BlocksConfig:
    """Policy blocks after SAPG (Singla, Agarwal, Pathak, "SAPG: Split and Aggregate Policy Gradients", ICML 2024):
    the environments are split into `count` contiguous blocks, each acting with its own policy. The policies are one
    network conditioned on a learned per-block embedding (one set of parameters, one optimizer). Every block learns
    from its own data with PPO's loss; the leader (block 0) also learns from the followers' data off-policy, through
    PPO's clipped ratio of its own probability to the follower's that acted. Evaluation, export and loaded agents act
    with the leader. `count` 1 (the default) is plain PPO, with the parameter and optimizer-state layout of runs
    saved before blocks existed.

    Attributes:
        count: M, the number of blocks; must divide `num_envs` and the minibatch tile's trajectories, so every
            minibatch holds each block's equal share (block j is environments j N / M to (j + 1) N / M - 1, so with
            `distribution.num_devices` = M each device holds one block).
        embedding_size: units of the learned block embedding, which the network reads beside the `goal` modality.
        leader_off_policy_weight: lambda, the weight of the leader's off-policy term beside its on-policy one (each a
            mean over its transitions, as SAPG weighs them); 0 leaves the blocks independent but for shared weights.
        entropy_coefs: one entropy weight per block (M numbers; SAPG gives followers different ones for diversity),
            instead of `entropy_coef` for all; constant over the run.
    """

    count: int = count_field(1, why="policy blocks")
    embedding_size: int = count_field(32, why="units of the block embedding")
    leader_off_policy_weight: float = bounded(1.0, 0, why="a loss weight")
    entropy_coefs: tuple[float, ...] = bounded((), 0, why="loss weights")

    @property
    def enabled(self) -> bool:
        """Whether the run has several blocks (else it is plain PPO)."""
        return self.count > 1


@settings
class PPOConfig:
    """One PPO run on a task given separately (the experiment config's `env` section names it). A cycle collects
    `num_envs * rollout_length` transitions, then runs `num_epochs` passes of minibatch updates over them.

    Attributes:
        seed: the run's PRNG seed (environments, initial parameters, minibatch draws); a run is reproducible from it.
        num_cycles: cycles to train (rollout plus updates each).
        num_envs: environments stepped in parallel (a run total, divided over the devices).
        rollout_length: policy steps per environment per cycle (T).
        chunk_length: truncated-BPTT chunk length s; the rollout stores the recurrent carry every s steps. Must divide
            `rollout_length`; equal to it means full BPTT.
        minibatch_size: transitions per minibatch, a multiple of `chunk_length`; a minibatch is a tile of n trajectories
            x m chunks with n * m * chunk_length = minibatch_size.
        num_epochs: passes of minibatch updates over each cycle's transitions.
        gamma: discount factor per policy step (0.99 weighs about the next 100 steps).
        gae_lambda: the lambda of generalised advantage estimation (1: Monte Carlo returns, 0: one-step TD).
        clip_epsilon: PPO's clip range of the probability ratio.
        value_coef: weight of the value loss beside the policy loss.
        entropy_coef: weight of the entropy bonus (exploration).
        learning_rate: Adam's learning rate.
        max_grad_norm: the global gradient norm is clipped to this.
        normalize_advantages: standardise the advantages of each minibatch (mean 0, std 1).
        bins: bins per action dimension of the multicategorical head.
        init_log_std: initial log standard deviation of the Gaussian head.
        beta_init_mean: the Beta head's initial mean action, as a fraction of each action's range (0.5: the middle;
            0.1 starts a muscle's excitation near rest).
        network: the network (`NetworkConfig`).
        normalization: running normalisation of observations and rewards (`NormalizationConfig`).
        head: "categorical" (discrete), "multicategorical" (continuous, `bins` per dimension), "gaussian", "beta", or
            "auto" (categorical for discrete tasks, gaussian for continuous ones), or a head added with `register_head`.
        value_clip: clip the value update to +-`clip_epsilon` around the rollout's values.
        lr_decay: decay the learning rate linearly to 0 over `num_cycles`.
        target_kl: None keeps the learning rate as `learning_rate` and `lr_decay` set it; a number adapts it to the
            policy's step instead (as rsl_rl and rl_games do): after each minibatch whose approximate KL to the rollout
            policy exceeds 2 * target_kl the rate is divided by 1.5, after one below target_kl / 2 it is multiplied by
            1.5, kept within [`lr_min`, `lr_max`]. Starts at `learning_rate`; the rate is part of the optimizer state,
            so it is checkpointed and a resume continues with it.
        lr_min: the lowest rate the KL-adaptive rule may set.
        lr_max: the highest rate the KL-adaptive rule may set.
        entropy_coef_final: None keeps `entropy_coef` constant; a number anneals it linearly from `entropy_coef` at the
            first cycle to this at the last (`num_cycles`).
        stop_at: end the run early once a per-cycle metric reaches a value (`StopAt`); None trains all `num_cycles`.
        init_from: a saved run, `RUN_DIR` (its best checkpoint) or `RUN_DIR:latest` / `RUN_DIR:<cycle>`, whose network
            parameters and observation statistics this run starts from, to fine-tune a trained policy on a changed task
            (e.g. the cube's pose-input policy reading a pose estimator's estimate). The network must have the same
            shapes; the optimizer, reward statistics and counters start afresh. `network.pretrained` loads over it.
        blocks: SAPG-style policy blocks with a leader (`BlocksConfig`); the default, one block, is plain PPO.
    """

    seed: int = bounded(0, 0, SEED_MAX, why="JAX keeps a seed's low 32 bits, so other seeds repeat these")
    num_cycles: int = count_field(100, why="cycles to train")
    # The memory estimate (validate) refuses far fewer environments than this with the largest that fits.
    num_envs: int = bounded(16, 1, INT64_MAX, why="environments in parallel")
    rollout_length: int = count_field(128, why="policy steps per cycle")
    chunk_length: int = count_field(16, why="policy steps per BPTT chunk")
    num_epochs: int = count_field(3, why="passes over each cycle's transitions")
    minibatch_size: int = count_field(512, why="transitions per minibatch")
    gamma: float = bounded(0.99, 0, 1, why="a discount factor")
    gae_lambda: float = bounded(0.95, 0, 1, why="GAE's lambda")
    clip_epsilon: float = bounded(0.2, 0, open_low=True, why="PPO's clip range")
    value_clip: bool = True
    value_coef: float = bounded(1.0, 0, why="a loss weight")
    entropy_coef: float = bounded(0.01, 0, why="a loss weight")
    learning_rate: float = bounded(1e-3, 0, open_low=True, why="Adam's step size")
    lr_decay: bool = False
    target_kl: float | None = bounded(None, 0, open_low=True, why="an approximate KL per minibatch")
    lr_min: float = bounded(1e-5, 0, open_low=True, why="the KL-adaptive rate's floor")
    lr_max: float = bounded(1e-2, 0, open_low=True, why="the KL-adaptive rate's ceiling")
    entropy_coef_final: float | None = bounded(None, 0, why="a loss weight")
    init_from: str | None = None
    max_grad_norm: float = bounded(0.5, 0, open_low=True, why="the gradient norm clipped to")
    normalize_advantages: bool = True
    head: str = "auto"
    bins: int = count_field(11, low=2, why="bins per action dimension")
    init_log_std: float = bounded(0.0, -20, 20, why="the log of the Gaussian head's std; exp(20) is 5e8")
    beta_init_mean: float = bounded(0.5, 0.01, 0.99, why="a fraction of each action's range")
    network: NetworkConfig = field(default_factory=NetworkConfig)
    normalization: NormalizationConfig = field(default_factory=NormalizationConfig)
    stop_at: StopAt | None = None
    blocks: BlocksConfig = field(default_factory=BlocksConfig)

    def replace(self, **changes) -> PPOConfig:
        """A copy with `changes` applied (frozen dataclasses cannot be edited in place)."""
        return dataclasses.replace(self, **changes)

    def _minibatch_hint(self) -> str:
        """", e.g. ppo.minibatch_size=M": a size that fits this batch, as few minibatches as the run's own (or 4),
        for a message; "" when none does."""
        batch = self.num_envs * self.rollout_length
        wanted = max(1, round(batch / self.minibatch_size)) if self.minibatch_size else 4
        for count in sorted(range(1, min(batch, 4096) + 1), key=lambda k: (abs(k - wanted), k)):
            size = batch // count
            if batch % count == 0 and size % self.chunk_length == 0 and tile_shape(
                    dataclasses.replace(self, minibatch_size=size)) is not None:
                return f", e.g. ppo.minibatch_size={size} ({count} minibatch{'es' if count > 1 else ''})"
        return ""

    def validate(self) -> PPOConfig:
        """Raise a ValueError naming the field when a setting is out of range or inconsistent; return self."""
        check_bounds(self, "PPOConfig")
        self.network.validate()
        if self.stop_at is not None:
            self.stop_at.validate()
        if self.head != "auto":
            # Here, not at the top: the heads' module imports distrax and TensorFlow Probability (0.7 s).
            from angora_jax.ppo.distributions import list_heads

            if self.head not in list_heads():
                raise ValueError(f"ppo.head must be 'auto' or one of {list_heads()}, got {self.head!r}.")
        if self.init_from is not None and (not isinstance(self.init_from, str) or not self.init_from):
            raise ValueError(f"ppo.init_from names a saved run, RUN_DIR[:best|latest|<cycle>]; got "
                             f"{self.init_from!r}.")
        if self.target_kl is not None and self.lr_decay:
            raise ValueError("ppo.target_kl adapts the learning rate and lr_decay decays it: set one of them "
                             "(lr_decay: false, or target_kl: null).")
        if self.target_kl is not None and not self.lr_min <= self.learning_rate <= self.lr_max:
            raise ValueError(f"ppo.learning_rate ({self.learning_rate}) is where the KL-adaptive rate starts: "
                             f"it must lie within [lr_min, lr_max] = [{self.lr_min}, {self.lr_max}].")
        if self.rollout_length % self.chunk_length:
            raise ValueError(
                f"ppo.chunk_length ({self.chunk_length}) must divide rollout_length ({self.rollout_length})."
            )
        batch = self.num_envs * self.rollout_length
        if self.minibatch_size % self.chunk_length or batch % self.minibatch_size:
            raise ValueError(
                f"ppo.minibatch_size ({self.minibatch_size}) must be a multiple of chunk_length "
                f"({self.chunk_length}) and divide num_envs * rollout_length ({batch}){self._minibatch_hint()}."
            )
        if tile_shape(self) is None:
            raise ValueError(
                f"ppo.minibatch_size ({self.minibatch_size}) admits no tile of n trajectories x m chunks with n "
                f"dividing num_envs ({self.num_envs}) and m dividing the "
                f"{counted(self.rollout_length // self.chunk_length, 'chunk')} per trajectory; pick a minibatch_size "
                "of (divisor of num_envs) * (divisor of chunks) * "
                "chunk_length."
            )
        self._validate_blocks()
        return self

    def _validate_blocks(self) -> None:
        blocks = self.blocks
        if not blocks.enabled:
            if blocks.entropy_coefs:
                raise ValueError("ppo.blocks.entropy_coefs gives each policy block its entropy weight, but "
                                 "ppo.blocks.count is 1: set count, or use ppo.entropy_coef.")
            return
        if blocks.entropy_coefs and len(blocks.entropy_coefs) != blocks.count:
            raise ValueError(f"ppo.blocks.entropy_coefs needs one weight per block ({blocks.count}), got "
                             f"{len(blocks.entropy_coefs)}; or leave it empty for ppo.entropy_coef in every block.")
        if blocks.entropy_coefs and self.entropy_coef_final is not None:
            raise ValueError("ppo.blocks.entropy_coefs fixes each block's entropy weight and ppo.entropy_coef_final "
                             "anneals the run's: set one of them (entropy_coef_final: null, or entropy_coefs: []).")
        trajectories = tile_shape(self)[0]
        if trajectories % blocks.count:
            raise ValueError(f"ppo.blocks.count={blocks.count} must divide the minibatch tile's "
                             f"{counted(trajectories, 'trajectory', 'trajectories')} (of ppo.num_envs="
                             f"{self.num_envs}, ppo.minibatch_size={self.minibatch_size}), so every minibatch holds "
                             "each block's equal share; pick a count that divides it, or a minibatch_size with more "
                             "trajectories per tile.")
        areas = self.network.graph.areas.values() if self.network.name == "areas" else ()
        if areas and not any("goal" in area.inputs for area in areas):
            raise ValueError("ppo.blocks conditions the network on each block's embedding through the goal modality, "
                             "which no area of network.graph reads: add goal to an area's inputs.")

    def validate_for(self, env: Env) -> PPOConfig:
        """`validate()`, then check the head against the task's action space; return self."""
        self.validate()
        head = self.head_for(env)
        if env.action_spec.discrete and head in ("multicategorical", "gaussian", "beta"):
            raise ValueError(
                f"ppo.head={head!r} needs continuous actions, but {_task_name(env)} has "
                f"{env.action_spec.num_actions} discrete actions; use head='categorical' or 'auto'."
            )
        images = env.sees_images
        if images and self.network.visual is None:
            raise ValueError(f"The task renders camera images ({_task_name(env)}'s vision is "
                             f"{env.observation_shapes().vision.shape} uint8), which the network needs a visual area "
                             "to see: set ppo.network.visual (e.g. {encoder: cornet_z, features: 64}).")
        if not images and self.network.visual is not None:
            raise ValueError("ppo.network.visual encodes camera images, but the task renders none: set the task's "
                             "vision option (env.options.vision) or remove ppo.network.visual.")
        if not env.action_spec.discrete and head == "categorical":
            raise ValueError(
                f"ppo.head='categorical' needs discrete actions, but {_task_name(env)} has continuous "
                "actions; use 'gaussian', 'beta', 'multicategorical' or 'auto'."
            )
        if self.network.graph is not None:
            shapes = env.observation_shapes()
            given = [m for m in POLICY_MODALITIES if math.prod(getattr(shapes, m).shape)]
            read = policy_modalities(self.network.graph)
            if not read & set(given):
                raise ValueError(
                    f"ppo.network.graph.policy={self.network.graph.policy!r} reads only {', '.join(sorted(read))}, "
                    f"which {_task_name(env)} gives nothing of with these options (a modality switched off, e.g. "
                    f"touch): list one it gives ({', '.join(given)}) in the inputs of an area on the way to the "
                    "policy, or switch the modality on.")
        return self

    def head_for(self, env: Env) -> str:
        """The head name after resolving "auto" for `env`."""
        if self.head != "auto":
            return self.head
        return "categorical" if env.action_spec.discrete else "gaussian"


def tile_shape(config: PPOConfig) -> tuple[int, int] | None:
    """The minibatch tile (n trajectories, m chunks) with the most trajectories, or None when none fits.

    The rollout holds `num_envs` trajectories of `rollout_length // chunk_length` chunks each; a tile needs n to
    divide num_envs, m to divide the chunk count and n * m * chunk_length == minibatch_size.
    """
    chunks = config.rollout_length // config.chunk_length
    per_minibatch = config.minibatch_size // config.chunk_length
    for n in range(min(config.num_envs, per_minibatch), 0, -1):
        if config.num_envs % n == 0 and per_minibatch % n == 0 and chunks % (per_minibatch // n) == 0:
            return n, per_minibatch // n
    return None


def _task_name(env: Env) -> str:
    """The task's class name (Reach, Pendulum), not the physics path's (MjxEnv) that holds it."""
    return type(getattr(env, "task", env)).__name__
