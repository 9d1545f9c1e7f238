"""`load_agent(run_dir)`: a trained policy from a run directory, ready to act, evaluate and probe."""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import flax.linen as nn
import jax

from angora_jax.envs.core import Env, Sensation
from angora_jax.experiment.checkpoint import Checkpoints
from angora_jax.experiment.config import Config, DistributionConfig, validate
from angora_jax.experiment.run_dir import CHECKPOINTS, read_run_config
from angora_jax.experiment.runner import initial_state_shape
from angora_jax.nets import ActorCritic, make_network
from angora_jax.ppo.cycle import TrainState, build_head
from angora_jax.ppo.distributions import PolicyHead
from angora_jax.ppo.evaluate import make_evaluate
from angora_jax.ppo.normalization import normalize_observation


@dataclass(frozen=True)
class Agent:
    """A trained policy with everything needed to run it.

    config: the run's config. env: its task. network: the policy/value network module. head: the policy head.
    state: the restored TrainState (params, normaliser statistics, ...). cycle: the training cycle it was saved at.
    """

    config: Config
    env: Env
    network: nn.Module
    head: PolicyHead
    state: TrainState
    cycle: int

    @property
    def model(self) -> ActorCritic:
        """Network and head as one module: `model.apply({"params": agent.params}, carry, obs)`."""
        return ActorCritic(self.network, self.head)

    @property
    def params(self) -> Any:
        return self.state.params

    def initial_carry(self, batch_size: int) -> Any:
        """The recurrent state at an episode's start for `batch_size` environments."""
        return self.network.initial_carry(batch_size)

    def apply(self, carry: Any, obs: Sensation, **apply_options: Any) -> Any:
        """One step of the model on raw observations (leaves `(B, size)`), normalised as in training.

        Returns `(carry, policy_params, value)`; `apply_options` go to flax's `apply`, e.g.
        `capture_intermediates=True` to also return every layer's activations for probing.
        """
        norm = self.config.ppo.normalization
        if norm.observations:
            obs = normalize_observation(self.state.obs_stats, obs, norm.clip)
        return self.model.apply({"params": self.params}, carry, obs, **apply_options)

    def act(self, carry: Any, obs: Sensation, key: jax.Array | None = None) -> tuple[Any, jax.Array, jax.Array]:
        """Choose actions for a batch: the head's mode, or a sample when `key` is given. Returns
        `(carry, env_actions, values)` with actions ready for `jax.vmap(env.step)`."""
        carry, policy_params, value = self.apply(carry, obs)
        action = self.head.mode(policy_params) if key is None else self.head.sample(policy_params, key)
        return carry, self.head.env_action(action), value

    def evaluate(self, num_envs: int = 16, seed: int = 0, deterministic: bool = True) -> dict[str, float]:
        """One episode in each of `num_envs` fresh environments; means of episode_return, episode_length and the
        task metrics at episode ends (see `angora_jax.ppo.make_evaluate`)."""
        evaluate = make_evaluate(self.env, self.network, self.config.ppo, num_envs, deterministic)
        return {k: float(v) for k, v in evaluate(self.state, jax.random.key(seed)).items()}


def load_agent(run_dir: str | Path, checkpoint: str | int = "best") -> Agent:
    """The policy saved in `run_dir`. checkpoint: "best" (falls back to "latest" when the run keeps no best),
    "latest", or a cycle number with a checkpoint (see `RUN_DIR/checkpoints`)."""
    config = read_run_config(run_dir)
    # Acting needs the task and the model, not the training machine: a run trained on more devices or with TensorBoard
    # (and copied here) loads too.
    here = replace(config, distribution=DistributionConfig(), logging=replace(config.logging, tensorboard=False))
    env = validate(here)
    checkpoints = Checkpoints(Path(run_dir) / CHECKPOINTS, config.checkpoint, create=False)
    try:
        which = "latest" if checkpoint == "best" and not checkpoints.steps("best") else checkpoint
        restored = checkpoints.restore(initial_state_shape(config, env), which)
    finally:
        checkpoints.close()
    network = make_network(config.ppo.network)
    return Agent(config, env, network, build_head(env, config.ppo), restored.state, int(restored.state.cycle))
