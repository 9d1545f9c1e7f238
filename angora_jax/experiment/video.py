"""Videos of episodes: a trained policy (or random actions) on the eager C MuJoCo path, rendered off screen.

    frames = render_frames("runs/reach", camera="side")      # list of (height, width, 3) uint8 arrays, in a notebook
    write_video(frames, "reach.mp4", fps=50)                  # MP4 through imageio-ffmpeg; a .gif needs only Pillow

Rendering needs an OpenGL backend (see `angora_jax.envs.rendering`: MUJOCO_GL=egl or osmesa); without one,
`RenderError` says which system package to install.
"""

from __future__ import annotations

import importlib.util
import struct
import warnings
from pathlib import Path
from typing import Any

import jax
import numpy as np

from angora_jax.envs.cpu_env import CpuEnv
from angora_jax.envs.eager_batch import EagerBatch, batch_functions
from angora_jax.envs.registry import make
from angora_jax.envs.rendering import RenderError, SceneRenderer, camera_named, check_pixels
from angora_jax.experiment.agent import Agent, load_agent
from angora_jax.experiment.config import check_count, check_flag, check_seed
from angora_jax.experiment.episodes import agent_policy, episode_keys, on_host, random_policy, run_episodes
from angora_jax.experiment.run_dir import unwritable_out
from angora_jax.ppo.memory import device_memory
from angora_jax.whole_files import written_whole
from angora_jax.wording import counted

# The files `write_video` writes, by suffix: MP4 through imageio-ffmpeg, GIF through Pillow. Any other suffix (or none)
# made imageio pick a still-image writer (TIFF for none, PNG for .png) after every frame had been rendered: a traceback,
# or one picture where a video was asked for.
VIDEO_SUFFIXES = (".mp4", ".gif")


def check_video_path(out: str | Path) -> Path:
    """`out` as a Path when a video can be written there: ValueError naming the suffixes otherwise, or the folder
    that is a file, not writable or a run's checkpoints (`unwritable_out`), FileExistsError when a file or folder is
    there already (nothing is overwritten). Checked before rendering, which takes minutes for long episodes, so that
    a mistyped --out costs nothing."""
    out = Path(out)
    if out.exists():
        raise FileExistsError(f"{out} exists already and is left untouched; choose another --out path.")
    if out.suffix.lower() not in VIDEO_SUFFIXES:
        suffix = f"ends in {out.suffix!r}" if out.suffix else "has no suffix"
        raise ValueError(f"--out {out} {suffix}, but a video is written as MP4 or GIF: give a name ending in .mp4 "
                         f"(imageio-ffmpeg) or .gif (Pillow), e.g. {out.with_suffix('.mp4')}.")
    if (why := unwritable_out(out)) is not None:
        raise ValueError(f"--out {out}: {why}; give a path in a folder you can write to.")
    return out


def render_frames(run_dir: str | Path | None = None, *, task: str | None = None, checkpoint: str | int = "best",
                  episodes: int = 1, camera: str = "front", width: int = 320, height: int = 240, seed: int = 0,
                  stochastic: bool = False, task_options: dict[str, Any] | None = None) -> list[np.ndarray]:
    """Frames of `episodes` consecutive episodes: the reset frame and one per policy step, each `(height, width, 3)`
    uint8 (one policy step is `env.dt` seconds of simulated time).

    Give either `run_dir` (the policy of its `checkpoint`, mode actions unless `stochastic`; the episodes are those
    of `evaluate(run_dir, seed=seed)`) or `task` (uniformly random actions; `task_options` go to the task).

    Args:
        camera: a name in `angora_jax.envs.rendering.CAMERAS`.
        width: frame width in pixels.
        height: frame height in pixels.

    Raises:
        RenderError: no GL backend, or a task without a MuJoCo scene.
    """
    return render_episodes(run_dir, task, checkpoint, episodes, camera, width, height, seed, stochastic,
                           task_options)[0]


def render_episodes(run_dir: str | Path | Agent | None, task: str | None, checkpoint: str | int = "best",
                    episodes: int = 1, camera: str = "front", width: int = 320, height: int = 240, seed: int = 0,
                    stochastic: bool = False, task_options: dict[str, Any] | None = None,
                    max_steps: int | None = None) -> tuple[list[np.ndarray], float]:
    """`render_frames`, and the seconds of simulated time per frame. run_dir may also be an `Agent` in memory (a
    policy still training, `evaluation.video`); max_steps cuts each episode after that many steps."""
    if (run_dir is None) == (task is None):
        raise ValueError("Give either run_dir (a trained policy) or task (random actions), not both or neither.")
    check_pixels(width, height)  # before the policy is loaded or the task made
    episodes = check_count("episodes", episodes)
    seed = check_seed("seed", seed)
    stochastic = check_flag("stochastic", stochastic)
    with on_host():
        if run_dir is not None:
            agent = run_dir if isinstance(run_dir, Agent) else load_agent(run_dir, checkpoint)
            env, policy, carry = agent.env, agent_policy(agent, stochastic), agent.initial_carry(1)
            compiled = agent.compiled_once("eager batch", lambda: batch_functions(agent.env))
        else:
            env = make(task, **(task_options or {}))
            policy, carry, compiled = random_policy(env), None, None
        check_frames_fit(episodes, max_steps or env.max_episode_steps, width, height)
        with EagerBatch(env, 1, compiled=compiled) as batch:
            if not isinstance(batch.env, CpuEnv):
                raise RenderError(f"Task {type(batch.env).__name__} has no MuJoCo scene to render; only MuJoCo tasks "
                                  "have videos.")
            renderer = SceneRenderer(batch.env.model, batch.env.task.camera_body, camera_named(camera), width, height)
            frames: list[np.ndarray] = []
            try:
                run_episodes(batch, policy, carry, *episode_keys(seed, episodes),
                             on_step=lambda episode, slot: frames.append(renderer.render(batch.physics(slot))),
                             max_steps=max_steps)
            finally:
                renderer.close()
    return frames, batch.env.dt


def check_frames_fit(episodes: int, steps: int, width: int, height: int) -> None:
    """ValueError, before anything renders, when the frames of `episodes` episodes of up to `steps` policy steps at
    `width` x `height` would not fit in this machine's memory: every frame is held until the video is written, and
    stacked into one array then (twice the frames). Without it a long video of large frames ran for as long as the
    episodes took and was then killed by the kernel, with no message and nothing written."""
    check_pixels(width, height)
    frames = episodes * (steps + 1)
    needed = 2 * frames * width * height * 3
    memory = device_memory(jax.devices("cpu")[0])
    if memory is not None and needed > memory:
        raise ValueError(f"{counted(episodes, 'episode')} of up to {counted(steps, 'step')} at {width} x {height} "
                         f"pixels are up to {frames:,} frames, {needed / 2 / 1e9:,.1f} GB held in memory and twice "
                         f"that while the video is written, more than this machine's {memory / 1e9:,.0f} GB: render "
                         "fewer episodes "
                         "(--episodes) or smaller frames (--width, --height).")


def render_video(out: str | Path, run_dir: str | Path | None = None, *, task: str | None = None,
                 **options: Any) -> Path:
    """Render as `render_frames(run_dir, task=task, **options)` and write the frames to `out` at real-time speed
    (`1 / env.dt` frames per second). Refuses an existing `out`, one that is neither .mp4 nor .gif, or an MP4 of an
    odd width or height, before rendering anything (`check_video_path`, `check_frame_size`)."""
    check_video_path(out)
    check_frame_size(out, options.get("width"), options.get("height"))  # the defaults, 320 x 240, are even
    frames, dt = render_episodes(run_dir, task, **options)
    return write_video(frames, out, 1.0 / dt)


def check_frame_size(out: str | Path, width: int | None, height: int | None) -> None:
    """ValueError when the frames of an MP4 `out` would have an odd width or height: H.264 (yuv420p) keeps colour at
    half the resolution, and ffmpeg refused such frames only once every frame had been rendered, which `render`
    reported as ffmpeg failing."""
    check_pixels(320 if width is None else width, 240 if height is None else height)  # None: the defaults
    odd = [(name, size) for name, size in (("width", width), ("height", height)) if size is not None and size % 2]
    if Path(out).suffix.lower() == ".mp4" and odd:
        given = " and ".join(f"--{name} {size}" for name, size in odd)
        even = " and ".join(f"--{name} {size + 1}" for name, size in odd)
        raise ValueError(f"An MP4's frames have an even width and height (H.264 keeps colour at half the resolution), "
                         f"not {given}: give {even}, or write a .gif.")


def write_video(frames: list[np.ndarray], out: str | Path, fps: float) -> Path:
    """Write `frames` to `out` (`.mp4` through imageio-ffmpeg, `.gif` through Pillow) at `fps` frames per second.
    Refuses to overwrite an existing file (FileExistsError) and other suffixes (ValueError, `check_video_path`)."""
    import imageio.v3 as iio

    out = check_video_path(out)
    if not frames:
        raise ValueError("No frames to write.")
    check_frame_size(out, frames[0].shape[1], frames[0].shape[0])
    out.parent.mkdir(parents=True, exist_ok=True)
    with written_whole(out, replace=False) as draft:
        if out.suffix.lower() == ".gif":
            # Encoded in memory, then written: Pillow writing to the file itself met a full disk when it flushed, and
            # again when its plugin was collected, which printed a traceback ("Exception ignored in ...") at exit.
            draft.write_bytes(iio.imwrite("<bytes>", np.stack(frames), extension=".gif", duration=1000.0 / fps,
                                          loop=0))
        else:
            try:
                with warnings.catch_warnings():
                    # JAX warns at every fork; imageio-ffmpeg forks only to exec ffmpeg, which runs no Python code.
                    warnings.filterwarnings("ignore", message="os.fork\\(\\) was called", category=RuntimeWarning)
                    iio.imwrite(draft, np.stack(frames), fps=fps, macro_block_size=1)
            except (ImportError, RuntimeError, OSError) as error:
                if isinstance(error, OSError) and error.errno is not None:
                    raise  # the system's own (a read-only folder): the command names the file and the fix
                if importlib.util.find_spec("imageio_ffmpeg") is not None:
                    raise RenderError(_ffmpeg_failed(out, str(error).splitlines()[0])) from None
                raise RenderError(
                    f"Cannot encode {out} ({error}). MP4 needs the imageio-ffmpeg package (`pip install -c "
                    f"constraints.txt -e .` installs it); or write a .gif, which needs only Pillow."
                ) from error
            if not whole_mp4(draft):
                raise RenderError(_ffmpeg_failed(out, "the file it wrote is cut short"))
    return out


def _ffmpeg_failed(out: Path, why: str) -> str:
    return (f"ffmpeg could not finish {out} ({why}; ffmpeg's own error, printed above, says why: a full disk, for "
            "one), and nothing was written: free space on that disk, or choose another --out, and render again.")


def whole_mp4(path: Path) -> bool:
    """Whether `path` is a whole MP4 file: top-level boxes that end exactly where the file ends, its index (`moov`)
    among them. imageio-ffmpeg ignores ffmpeg's exit status, so a file ffmpeg could not finish (a full disk or a
    file-size limit while it wrote: 'Error writing trailer') was renamed into place, cut short, and `render` said
    'Video: ...' with exit 0."""
    size, at, kinds = path.stat().st_size, 0, set()
    with path.open("rb") as file:
        while at + 8 <= size:
            file.seek(at)
            length, kind = struct.unpack(">I4s", file.read(8))
            if length == 1:  # a 64-bit size follows the type
                length = struct.unpack(">Q", file.read(8))[0]
            elif length == 0:  # the box runs to the end of the file
                length = size - at
            if length < 8:
                return False
            kinds.add(kind)
            at += length
    return at == size and b"moov" in kinds

