"""The Shadow Dexterous Hand model: OpenAI's Gym hand as shipped in `gymnasium-robotics`, prepared for MJX.

We read the package's MJCF and meshes (never import the package, which registers many unrelated environments)
and make every change for MJX in code on a `mujoco.MjSpec`, one line of reason each.
"""

from __future__ import annotations

import importlib.util
import os
from collections.abc import Callable

import mujoco

FINGERTIP_SITES = ("robot0:S_fftip", "robot0:S_mftip", "robot0:S_rftip", "robot0:S_lftip", "robot0:S_thtip")
PALM_BODY = "robot0:palm"


def asset_dir() -> str:
    """Folder of the Gym hand MJCF files inside the installed `gymnasium-robotics`."""
    spec = importlib.util.find_spec("gymnasium_robotics")
    if spec is None or spec.origin is None:
        raise ModuleNotFoundError(
            "The Shadow-hand model files come from the 'gymnasium-robotics' package: pip install gymnasium-robotics."
        )
    return os.path.join(os.path.dirname(spec.origin), "envs", "assets", "hand")


def load_scene(scene: str = "reach.xml", edit: Callable[[mujoco.MjSpec], None] | None = None) -> mujoco.MjModel:
    """Compile a Gym hand scene (`reach.xml`, `manipulate_block.xml`, ...) with our MJX preparations.

    `edit`, when given, changes the prepared `MjSpec` in place before compiling (a task's own scene changes)."""
    path = os.path.join(asset_dir(), scene)
    if not os.path.exists(path):
        raise FileNotFoundError(f"No Shadow-hand scene {scene!r} in {asset_dir()}.")
    spec = mujoco.MjSpec.from_file(path)
    for geom in spec.geoms:
        # MJX refuses geom margins/gaps for (box, mesh) pairs; the Gym hand's 0.5 mm margin is a contact softener.
        geom.margin = 0.0
        geom.gap = 0.0
    floor = spec.geom("floor0")
    if floor is not None:
        # The hand hangs in the air: the floor can never be touched, yet a plane makes MJX test every hand geom.
        spec.delete(floor)
    if edit is not None:
        edit(spec)
    return spec.compile()
