"""Videos of the policy while it trains (`evaluation.video`): one episode every N cycles, rendered from the
parameters in memory (no checkpoint needed) and written to `RUN_DIR/videos/cycle_NNNNNN.gif`."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from angora_jax.experiment.agent import Agent, acting_parts
from angora_jax.experiment.config import Config
from angora_jax.experiment.held_out import is_due
from angora_jax.experiment.run_dir import VIDEOS, numbered_paths
from angora_jax.experiment.video import render_episodes, write_video
from angora_jax.ppo.cycle import TrainState
from angora_jax.ppo.evaluate import PolicyState
from angora_jax.ppo.parallel import host_copy


def training_videos(config: Config, run_dir: Path) -> Callable[[TrainState], Path | None] | None:
    """`video(state) -> path` of the GIF written for a cycle that `config.evaluation.video` makes due (None for
    other cycles), or None when the config asks for no videos. The first call renders and compiles the eager acting
    path once; later videos reuse it."""
    settings = config.evaluation.video
    if settings is None:
        return None
    env, network, head, _, compiled = acting_parts(config)

    def video(state: TrainState) -> Path | None:
        cycle = int(host_copy(state.cycle))
        if not is_due(cycle, settings.every, config.ppo.num_cycles):
            return None
        policy = PolicyState(params=host_copy(state.params), obs_stats=host_copy(state.obs_stats),
                             cycle=host_copy(state.cycle))
        agent = Agent(config, env, network, head, policy, cycle, compiled)
        frames, dt = render_episodes(agent, None, camera=settings.camera, width=settings.width,
                                     height=settings.height, seed=config.evaluation.seed, max_steps=settings.steps)
        # A resumed run repeats the cycles after its checkpoint: a repeated cycle's video goes beside the first.
        names = numbered_paths(run_dir / VIDEOS, f"cycle_{cycle:06d}", ".gif")
        out = next((path for path in names if not path.exists()), None)
        if out is None:
            raise FileExistsError(f"{run_dir / VIDEOS} holds 10,000 videos of cycle {cycle}; move some away.")
        return write_video(frames, out, 1.0 / dt)

    return video
