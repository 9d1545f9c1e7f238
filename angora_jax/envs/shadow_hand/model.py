"""The Shadow Dexterous Hand model: OpenAI's Gym hand as shipped in `gymnasium-robotics`, prepared for MJX.

We read the package's MJCF and meshes (never import the package, which registers many unrelated environments)
and make every change for MJX in code on a `mujoco.MjSpec`, one line of reason each.
"""

from __future__ import annotations

import dataclasses
import importlib.util
import os
from collections.abc import Callable

import mujoco

from angora_jax.envs.mjx_env import choose_impl
from angora_jax.envs.mujoco_task import MJX_IMPLS, set_mjx_impl
from angora_jax.envs.rendering import add_cameras

FINGERTIP_SITES = ("robot0:S_fftip", "robot0:S_mftip", "robot0:S_rftip", "robot0:S_lftip", "robot0:S_thtip")
PALM_BODY = "robot0:palm"
HAND_JOINT_PREFIX = "robot0:"  # every joint of the hand; objects in a scene have their own names
# Hand geoms that collide in the Gym scenes but never touch anything a task needs. The thumb-base boxes collide with
# every hand geom (contype and conaffinity 1) yet lie under the palm and the thumb's proximal capsule; the forearm's
# 455-vertex convex mesh collides only with them (and with a cube that has already dropped below the palm, which
# ends a cube episode). Under random actions (C MuJoCo: 20,000 physics steps of reach, 20 cube episodes) none of them
# touched anything, yet they are 86 of reach's 106 MJX contacts, and their two box-mesh pairs take 94% of the
# temporary memory of a reach step (`benchmarks/results/physics_throughput/physics_throughput.md`).
UNTOUCHED_GEOMS = ("robot0:C_forearm", "robot0:V_thbase", "robot0:V_thhub")
# The Gym scene whose hand carries the touch sensors of its `robot_touch_sensors_92.xml` and
# `shared_touch_sensors_92.xml` includes (the cube's scene); `add_touch_sensors` gives any hand scene the same ones.
TOUCH_SCENE = "manipulate_block_touch_sensors.xml"


@dataclasses.dataclass(frozen=True)
class PhysicsSettings:
    """Simulation settings of a scene. Defaults are the Gym hand's own (`GYM_PHYSICS`); tasks choose faster ones
    from measurements (`benchmarks/physics_throughput.py`).

    Attributes:
        timestep: physics step in s.
        iterations: the Newton solver's iteration cap.
        ls_iterations: the line search's iteration cap.
        impl: the MJX implementation of the batched path, "jax" (MJX's own, any device), "warp" (MuJoCo Warp through
            MJX; needs `pip install warp-lang==1.18.0`, the version mujoco-mjx 3.17's `warp` extra pins) or "auto"
            (Warp on a GPU when warp-lang is installed, else JAX; `mjx_env.resolve_impl`). The C MuJoCo twin ignores
            it.
        contact_caps: when > 0, MJX's JAX implementation tests at most this many nearest geom pairs per collision
            function and keeps at most this many deepest contacts per contact dimension (the custom numerics
            `max_geom_pairs` and `max_contact_points`, as in the Menagerie hand tuned for MJX); 0 keeps every
            candidate. C MuJoCo and Warp ignore it.
        warp_max_envs: with impl "warp", the batch size Warp's shared contact buffer is sized for (every candidate pair
            touching in every environment); None (the default) sizes it for the batch that a trainer or evaluator runs
            (`Env.sized_for`). A larger batch can run out of contact slots; a smaller setting saves GPU memory (Warp's
            collision step also allocates about 1 KB per slot on every call: 2 GiB for the cube at 32,768 envs).
    """

    timestep: float = 0.002
    iterations: int = 20
    ls_iterations: int = 50
    impl: str = "auto"
    contact_caps: int = 0
    warp_max_envs: int | None = None

    def __post_init__(self):
        if self.timestep <= 0 or self.iterations < 1 or self.ls_iterations < 1:
            raise ValueError(f"PhysicsSettings need timestep > 0 and iterations, ls_iterations >= 1, got {self}.")
        if self.warp_max_envs is not None and self.warp_max_envs < 1:
            raise ValueError(f"warp_max_envs must be >= 1 (the batch Warp's buffers hold), got {self.warp_max_envs}.")
        if self.contact_caps < 0:
            raise ValueError(f"contact_caps must be >= 0 (0: no cap), got {self.contact_caps}.")
        if self.impl not in (*MJX_IMPLS, "auto"):
            raise ValueError(f"Unknown MJX implementation impl={self.impl!r}; choose one of {(*MJX_IMPLS, 'auto')}.")

    def with_options(self, options: dict[str, float | str] | None) -> PhysicsSettings:
        """These settings with `options` (field name -> value) changed; unknown names raise a ValueError."""
        options = dict(options or {})
        known = {f.name for f in dataclasses.fields(self)}
        if set(options) - known:
            raise ValueError(f"Unknown physics settings {sorted(set(options) - known)}; known: {sorted(known)}.")
        return dataclasses.replace(self, **options)

    def frame_skip(self, control_dt: float) -> int:
        """Physics steps per policy step of `control_dt` s; a ValueError when it is not a whole multiple."""
        skip = round(control_dt / self.timestep)
        if skip < 1 or abs(skip * self.timestep - control_dt) > 1e-9:
            raise ValueError(f"control_dt ({control_dt} s) must be a whole multiple of the timestep "
                             f"({self.timestep} s).")
        return skip

    def apply(self, spec: mujoco.MjSpec) -> None:
        spec.option.timestep = self.timestep
        spec.option.iterations = self.iterations
        spec.option.ls_iterations = self.ls_iterations
        set_mjx_impl(spec, *choose_impl(self.impl))
        if self.contact_caps:
            for name in ("max_geom_pairs", "max_contact_points"):
                spec.add_numeric(name=name, data=[self.contact_caps])


GYM_PHYSICS = PhysicsSettings()


def asset_dir() -> str:
    """Folder of the Gym hand MJCF files inside the installed `gymnasium-robotics`."""
    spec = importlib.util.find_spec("gymnasium_robotics")
    if spec is None or spec.origin is None:
        raise ModuleNotFoundError(
            "The Shadow-hand model files come from the 'gymnasium-robotics' package: pip install gymnasium-robotics."
        )
    return os.path.join(os.path.dirname(spec.origin), "envs", "assets", "hand")


def remove_from_collision(spec: mujoco.MjSpec, names: tuple[str, ...]) -> None:
    """Take the named geoms out of collision detection (they stay visible)."""
    for name in names:
        geom = spec.geom(name)
        if geom is None:
            raise ValueError(f"No geom {name!r} in the scene.")
        geom.contype = 0
        geom.conaffinity = 0


def add_touch_sensors(spec: mujoco.MjSpec) -> None:
    """Give the hand in `spec` the 97 touch sensors of Gym's touch scenes (`TOUCH_SCENE`), in their order: each reads
    the normal forces (N) of the contacts inside its site's zone. Sensors and sites the scene already has (the five
    fingertip sensors of every Gym hand scene) are kept; the others are copied, sites onto the bodies of the same
    names. Sites carry no mass and collide with nothing, so the dynamics stay those of the scene."""
    source = mujoco.MjSpec.from_file(os.path.join(asset_dir(), TOUCH_SCENE))
    for sensor in source.sensors:
        if sensor.type != mujoco.mjtSensor.mjSENS_TOUCH or spec.sensor(sensor.name) is not None:
            continue
        if spec.site(sensor.objname) is None:
            site = source.site(sensor.objname)
            spec.body(site.parent.name).add_site(name=site.name, type=site.type, pos=site.pos, quat=site.quat,
                                                 size=site.size, rgba=site.rgba, group=site.group)
        spec.add_sensor(name=sensor.name, type=sensor.type, objtype=sensor.objtype, objname=sensor.objname)


def load_scene(scene: str = "reach.xml", edit: Callable[[mujoco.MjSpec], None] | None = None,
               physics: PhysicsSettings = GYM_PHYSICS, prune_contacts: bool = True,
               sensors: tuple[mujoco.mjtSensor, ...] | None = (), cameras: tuple[str, ...] = ()) -> mujoco.MjModel:
    """Compile a Gym hand scene (`reach.xml`, `manipulate_block.xml`, ...) with our MJX preparations and `physics`.

    Args:
        scene: the Gym scene's file name.
        edit: changes the prepared `MjSpec` in place before compiling (a task's own scene changes).
        physics: the simulation settings.
        prune_contacts: take `UNTOUCHED_GEOMS` out of collision (False keeps the Gym scene's contacts, for
            comparisons).
        sensors: the sensor types to keep (None: all of the Gym scene's). MJX evaluates every sensor at every physics
            step, and the Gym scenes' joint-position sensors only repeat `qpos`: a task keeps only what it reads.
        cameras: `rendering.CAMERAS` names to add as fixed model cameras `vision_<name>` looking at the palm where it
            is at the scene's start (`rendering.add_cameras`; what camera vision renders).
    """
    if cameras:
        start = load_scene(scene, edit, physics, prune_contacts, sensors)
        data = mujoco.MjData(start)
        mujoco.mj_forward(start, data)
        palm = data.body(PALM_BODY).xpos.copy()

        def edit_with_cameras(spec: mujoco.MjSpec) -> None:
            if edit is not None:
                edit(spec)
            add_cameras(spec, palm, cameras)

        return load_scene(scene, edit_with_cameras, physics, prune_contacts, sensors)
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
    if prune_contacts:
        remove_from_collision(spec, UNTOUCHED_GEOMS)
    for sensor in [] if sensors is None else list(spec.sensors):
        if sensor.type not in sensors:
            spec.delete(sensor)
    physics.apply(spec)
    if edit is not None:
        edit(spec)
    return spec.compile()
