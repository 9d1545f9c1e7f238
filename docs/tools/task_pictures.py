"""Render the still pictures of the tasks page (docs/assets/tasks/<Task>.png) from the C MuJoCo twin.

Random actions, a few policy steps in, with the same renderer as `angora-jax render`: cheap on a CPU with an OpenGL
backend (MUJOCO_GL=egl), so the pictures can be made again whenever a scene changes:

    MUJOCO_GL=egl python docs/tools/task_pictures.py
"""

from __future__ import annotations

from pathlib import Path

import imageio.v3 as iio

from angora_jax.experiment.video import render_frames

OUT = Path(__file__).resolve().parent.parent / "assets" / "tasks"
# Task -> (camera, policy steps in): a frame where the scene has moved from its start but not yet ended. Only the hand
# tasks: the cameras (`envs.rendering.CAMERAS`) are placed for the hand and see little of a locomotion body.
PICTURES = {
    "ShadowHandReach": ("front", 10),
    "ShadowHandFreeReach": ("side", 10),
    "ShadowHandCube": ("front", 3),
}


def main() -> None:
    OUT.mkdir(parents=True, exist_ok=True)
    for task, (camera, step) in PICTURES.items():
        frames = render_frames(task=task, camera=camera, width=320, height=240)
        path = OUT / f"{task}.png"
        iio.imwrite(path, frames[min(step, len(frames) - 1)])
        print(path)


if __name__ == "__main__":
    main()
