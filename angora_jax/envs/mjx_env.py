"""`MjxEnv`: a `MujocoTask` simulated with MuJoCo MJX, pure and batched (the training path).

MJX has two implementations behind one API: "jax" (MJX's own, any JAX device) and "warp" (MuJoCo Warp kernels called
from JAX, CUDA GPUs or the CPU). A scene picks one with `PhysicsSettings.impl` (`physics.impl` in an env's options;
the default "auto" is Warp on a GPU when warp-lang is installed, else JAX); it travels in the compiled model
(`mujoco_task.mjx_impl`).
"""

from __future__ import annotations

import contextlib
import functools
import importlib.util
import inspect
import io
from typing import TYPE_CHECKING, Any

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from angora_jax.envs.cameras import HostCameras, WarpCameras
from angora_jax.envs.core import Sensation, State
from angora_jax.envs.mujoco_task import MujocoEnv, MujocoTask, mjx_impl, mjx_impl_why, start_physics
from angora_jax.envs.randomization import INFO_KEY

if TYPE_CHECKING:
    from mujoco import mjx

_WARP_ABSENT = importlib.util.find_spec("warp") is None


@functools.cache
def mjx_module() -> Any:
    """`mujoco.mjx`, imported when first needed: it is most of `import angora_jax` (about 5 of 7 s on 2 CPU cores,
    MuJoCo Warp's import included when warp-lang is installed), which tasks without MuJoCo (CartPole, `make run`) and
    the command's help never need. Without the optional warp-lang it prints "Failed to import warp" (twice): nothing
    failed for the default JAX implementation, so that output is dropped then (impl="warp" still raises
    `require_warp`'s error)."""
    with contextlib.redirect_stdout(io.StringIO()) if _WARP_ABSENT else contextlib.nullcontext():
        from mujoco import mjx
    return mjx


# MuJoCo Warp keeps one contact buffer for all environments of a batch, sized when the data is made (before the
# batch size is known): it holds this many environments' worst case. Larger batches can run out of contact slots
# (Warp then prints an overflow warning and drops contacts).
WARP_MAX_ENVS = 32768
WARP_GRAPHS_PER_DEVICE = 32  # warp-lang's default bound for one device (`size_warp_graph_cache`)
# The warp-lang version that mujoco-mjx 3.17's `warp` extra pins (its MuJoCo Warp is vendored inside mujoco-mjx).
WARP_REQUIREMENT = "warp-lang==1.18.0"


def resolve_impl(impl: str) -> str:
    """`impl` with "auto" decided: "warp" when JAX runs on a GPU and warp-lang is importable (measured on one H100:
    the cube trains 4.6x faster on Warp at 4,096 envs), otherwise "jax" (the CPU default and the fallback)."""
    return choose_impl(impl)[0]


def on_gpu() -> bool:
    """Whether JAX runs on a GPU in this process."""
    return any(device.platform == "gpu" for device in jax.local_devices())


def choose_impl(impl: str, jax_lacks: str = "") -> tuple[str, str]:
    """`resolve_impl(impl)` and why, as a phrase for logs and `angora-jax doctor` (with what to install when
    a faster choice is missing).

    Args:
        impl: "jax", "warp" or "auto".
        jax_lacks: what MJX's JAX implementation cannot step in the scene ("" when it steps all of it): "auto" then
            picks Warp wherever warp-lang is importable, on the CPU too (without it `MjxEnv` names the install).
    """
    if impl != "auto":
        return impl, f"physics.impl is set to {impl!r}"
    if jax_lacks and importlib.util.find_spec("warp") is not None:
        return "warp", f"physics.impl auto: MJX's JAX implementation lacks {jax_lacks}; warp-lang is importable"
    if not on_gpu():
        return "jax", "physics.impl auto: JAX runs on the CPU (MuJoCo Warp needs an NVIDIA GPU)"
    if importlib.util.find_spec("warp") is None:
        return "jax", (f"physics.impl auto: JAX runs on a GPU but warp-lang is not installed; pip install "
                       f"{WARP_REQUIREMENT} (or the cuda extra: make gpu in the clone) for MuJoCo Warp, 4.6x faster "
                       "on the cube")
    return "warp", "physics.impl auto: JAX runs on a GPU and warp-lang is importable"


def require_warp() -> None:
    """Raise a ModuleNotFoundError naming the fix when MJX's Warp implementation cannot be used."""
    if importlib.util.find_spec("warp") is None:
        raise ModuleNotFoundError(
            f"physics impl 'warp' needs NVIDIA Warp: pip install {WARP_REQUIREMENT} (or mujoco-mjx[warp]); "
            "or use impl 'jax'.")


def local_device(impl: str) -> jax.Device:
    """This process's device for an MJX implementation. MJX's own default is `jax.devices()[0]`, which under
    `jax.distributed` is process 0's: every other process would put its model where it cannot address it."""
    if impl == "warp":
        gpus = [device for device in jax.local_devices() if device.platform == "gpu"]
        return gpus[0] if gpus else jax.local_devices(backend="cpu")[0]
    return jax.local_devices()[0]


def jax_collision_gap(model: mujoco.MjModel) -> str:
    """"" when MJX's JAX implementation has a collision function for every pair of geom types that can touch in
    `model`, else MJX's own message naming the pair it lacks (e.g. ellipsoid (4) against box (6))."""
    try:
        mjx_module()._src.collision_driver.make_condim(model)
    except ValueError as error:
        return " ".join(str(arg) for arg in error.args)
    return ""


def warp_sizes(model: mujoco.MjModel, max_envs: int) -> dict[str, int]:
    """Warp's buffer sizes for `model`: contacts for `max_envs` environments (`naconmax`) and constraint rows per
    environment (`njmax`).

    A scene that states its budget in MuJoCo's own size fields (`MjSpec.nconmax` and `njmax`, MJCF's `<size nconmax
    njmax>`: contacts and constraint rows per environment, which C MuJoCo has ignored since 3.0) gets it; the scene
    says how it was measured. Otherwise each is the worst case MJX's JAX implementation allocates (every candidate
    pair touching), which needs a JAX collision function for every pair of geom types that can touch: a ValueError
    naming the fix when one is missing."""
    if model.nconmax > 0 and model.njmax > 0:
        return {"naconmax": model.nconmax * max_envs, "njmax": model.njmax}
    gap = jax_collision_gap(model)
    if gap:
        raise ValueError(f"MuJoCo Warp's buffers for this scene cannot be sized from MJX's JAX implementation ({gap}): "
                         "state the scene's contacts and constraint rows per environment in MjSpec.nconmax and "
                         "njmax (MJCF <size nconmax=... njmax=...>), e.g. from C MuJoCo rollouts with a margin.")
    data = mjx_module().make_data(model, device=local_device("jax"), impl="jax")
    return {"naconmax": max(1, data._impl.contact.dist.shape[0]) * max_envs, "njmax": data._impl.efc_J.shape[0]}


def quiet_iteration_caps(mjx_model: mjx.Model) -> mjx.Model:
    """A Warp model that does not print when the solver or line search stops at its iteration cap: our caps are
    chosen by measurement (`PhysicsSettings`), and Warp would print for every environment at every physics step.
    Contact and constraint overflow warnings stay on, and so do Warp's warnings; its per-module load times go."""
    import warp  # importable only with warp-lang installed
    from mujoco.mjx.third_party.mujoco_warp import OverflowType

    warp.config.log_level = max(warp.config.log_level, warp.LOG_WARNING)
    quiet = int(mjx_model.opt._impl.warn_overflow) & ~int(OverflowType.ITERATIONS | OverflowType.LS_ITERATIONS)
    return mjx_model.tree_replace({"opt._impl.warn_overflow": quiet})


def size_warp_graph_cache() -> None:
    """Let MuJoCo Warp keep `WARP_GRAPHS_PER_DEVICE` captured CUDA graphs per Warp call for each local device,
    instead of warp-lang's 32 per call whatever the device count.

    Why: Warp replays a captured graph for each (device, call, buffer addresses) it has seen, and each graph holds
    the memory its call allocated while it was captured (the cube's contact pass: 38 MB for 16,384 envs). One
    process driving several GPUs needs a set per GPU: on 4 H100s the cube's two Warp calls held 16 graphs each for
    4 GPUs on top of a 1-GPU run's 4 and 9 (benchmarks/results/scaling/scaling_ShadowHandCube_weak_one_4xh100.json). A
    benchmark process that had run 1 and 2 GPUs before 4, by these counts past 32 for one call and so evicting
    graphs, hung after 3 cycles on 4 GPUs. No bound is no cure where XLA keeps placing buffers at new addresses (as
    it did while the checkpointer held a best cycle's arrays for a later save): 4 processes of one GPU each then ran
    out of GPU memory inside Warp after 58 cycles of the fast cube and 28 of the paper's setup
    (benchmarks/results/cube_multi_gpu/ihom_4gpu_warp_graphs_4xh100.md). So the bound scales with the devices, and
    one process per GPU keeps Warp's default. MJX creates its Warp calls with warp-lang's default bound, so the
    default is changed here (warp-lang 1.18's `jax_callable`; a version without the setting is left as it is)."""
    from warp._src.jax import ffi  # importable only with warp-lang installed

    names = list(inspect.signature(ffi.jax_callable).parameters)[1:]  # __defaults__ covers all but `func`
    if "graph_cache_max" in names and len(ffi.jax_callable.__defaults__) == len(names):
        defaults = list(ffi.jax_callable.__defaults__)
        defaults[names.index("graph_cache_max")] = WARP_GRAPHS_PER_DEVICE * len(jax.local_devices())
        ffi.jax_callable.__defaults__ = tuple(defaults)


class MjxEnv(MujocoEnv):
    """Run `task` in MJX: each policy step applies `task.control(action)` and advances `frame_skip` physics
    steps of `task.model.opt.timestep` seconds. Actions are float32 in [-1, 1] (shape `(nu,)`).

    The MJX implementation is the model's (`mjx_impl`); with "warp", `warp_max_envs` bounds the batch size whose
    contacts fit Warp's shared contact buffer. None sizes it for `WARP_MAX_ENVS` until a trainer or evaluator calls
    `sized_for(batch)`, which sizes it for the batch it runs."""

    def __init__(self, task: MujocoTask, frame_skip: int, max_episode_steps: int, warp_max_envs: int | None = None):
        super().__init__(task, frame_skip, max_episode_steps)
        self.impl = mjx_impl(task.model)
        self.warp_max_envs = warp_max_envs
        sizes = {}
        gap = jax_collision_gap(task.model) if self.impl == "jax" else ""
        if gap:
            raise ValueError(f"MJX's JAX implementation cannot step this scene ({gap}): set physics.impl to 'warp' "
                             f"or 'auto' with warp-lang installed (pip install {WARP_REQUIREMENT}).")
        if self.impl == "warp":
            require_warp()
            size_warp_graph_cache()
            sizes = warp_sizes(task.model, warp_max_envs or WARP_MAX_ENVS)
        device = local_device(self.impl)
        self.mjx_model = mjx_module().put_model(task.model, device=device, impl=self.impl)
        if self.impl == "warp":
            self.mjx_model = quiet_iteration_caps(self.mjx_model)
            if task.body_dynamics:  # each step's forward then ends with rne_postconstraint (cfrc_ext), see `_step`
                self.mjx_model = self.mjx_model.tree_replace({"opt._impl.run_rne_postconstraint": True})
        # A fixed start is computed once on the CPU: it spares the compiled step (with its auto-reset) a forward pass.
        fixed_qpos = None if task.random_initial_qpos else np.asarray(task.initial_qpos(jax.random.key(0)))
        self._start = None
        if fixed_qpos is not None:
            self._start = mjx_module().put_data(task.model, start_physics(task, fixed_qpos), device=device,
                                                impl=self.impl, **sizes)
        self._data0 = mjx_module().make_data(task.model, device=device, impl=self.impl, **sizes)
        self._cameras = self._make_cameras()
        self._sized: dict[int, MjxEnv] = {}

    def _make_cameras(self) -> tuple[Any, Any] | None:
        """Renderers of the task's camera vision for (`reset`, `step`): on Warp one render context each, for the
        sized batch (two, so that a program that resets and steps cannot interleave their renders); on MJX's JAX
        implementation one OpenGL renderer on the host, called back from the program."""
        vision = self.task.vision
        if vision is None:
            return None
        if self.impl != "warp":
            cameras = HostCameras(self.task.model, vision)
            return cameras, cameras
        if self.warp_max_envs is None:
            return None  # sized by `sized_for`; `_frames` names the fix if a program renders before
        return WarpCameras(self.task.model, vision, self.warp_max_envs), WarpCameras(
            self.task.model, vision, self.warp_max_envs)

    def _frames(self, data: mjx.Data, which: int) -> jax.Array:
        """The camera frames of `data`, `(cameras, height, width, channels)` uint8 (renderer 0: resets, 1: steps)."""
        if self._cameras is None:
            raise RuntimeError("Camera vision on MuJoCo Warp renders batches of a fixed size: get the environment "
                               "with env.sized_for(num_envs) and vmap reset and step over exactly num_envs.")
        cameras = self._cameras[which]
        if isinstance(cameras, HostCameras):
            return cameras.traced_frames(data.qpos, data.mocap_pos, data.mocap_quat)
        return cameras.frames(self.mjx_model, data)

    def _unseen(self, obs: Sensation) -> Sensation:
        """`obs` with a blank `vision` of the perceived shape (with camera vision), so that the auto-reset's branches
        agree; `reset` and `step` perceive the rendered frames once per call."""
        if self.task.vision is None:
            return obs
        return obs.replace(vision=jnp.zeros(self._seen.shape, self._seen.dtype))

    @functools.cached_property
    def _seen(self) -> jax.ShapeDtypeStruct:
        """Shape and dtype of the perceived vision modality."""
        return self.observation_shapes().vision

    def reset(self, key: jax.Array) -> State:
        state = super().reset(key)
        if self.task.vision is None:
            return state
        obs = self.task.perceive(state.obs, self._frames(state.physics, 0), state.info)
        return state.replace(obs=obs, final_obs=obs)

    def step(self, state: State, action: jax.Array) -> State:
        """As `Env.step`. With camera vision the frames are rendered once per step, of the physics after the
        auto-reset: `obs` shows exactly what it should. `final_obs` of an episode that ended at this step shows the
        frames of the step before (0.08 s earlier for the cube), its other modalities are exact: it only feeds the
        value bootstrap of truncated episodes (for the cube the value function also reads the exact pose).
        Rendering the ended state as well would double the rendering, the largest cost of a pixel step."""
        stepped = super().step(state, action)
        if self.task.vision is None:
            return stepped
        obs = self.task.perceive(stepped.obs, self._frames(stepped.physics, 1), stepped.info)
        # An ended episode's final observation keeps what was seen a step before (`final_obs` = `obs` otherwise).
        ended = stepped.final_obs.replace(vision=state.obs.vision)
        final_obs = jax.tree.map(lambda e, o: jnp.where(stepped.done > 0, e, o), ended, obs)
        return stepped.replace(obs=obs, final_obs=final_obs)

    def data_parallel_problem(self) -> str | None:
        if self.impl == "warp" and self.task.vision is not None and not on_gpu():
            # Warp's CPU backend is one device: the devices' shares would render into one context's buffers at once.
            return "Camera vision on MuJoCo Warp renders on the CPU into one render context for all devices"
        return None

    def physics_info(self, num_envs: int | None = None) -> dict[str, Any]:
        info = super().physics_info() | {
            "engine": f"MuJoCo MJX ({'MuJoCo Warp' if self.impl == 'warp' else 'JAX'} implementation)",
            "impl": self.impl, "why": mjx_impl_why(self.task.model) or "set in the model",
            "device": str(local_device(self.impl))}
        if self.impl == "warp":
            info["warp_max_envs"] = self.warp_max_envs or num_envs or WARP_MAX_ENVS
        return info

    def sized_for(self, num_envs: int) -> MjxEnv:
        """This environment with Warp's buffers sized for batches of `num_envs` (itself unless it runs on Warp with
        no `warp_max_envs` of its own): an unsized buffer costs GPU memory for 32,768 environments (the cube ran out
        of memory at 8,192 envs on one H100 unsized, and trained at 16,384 sized to its batch)."""
        if self.impl != "warp" or self.warp_max_envs is not None:
            return self
        # Kept for this environment's life: a compiled program names a Warp render context by its key only, and the
        # context frees its buffers when collected, so a program compiled ahead of time (evaluate's) would outlive it.
        if num_envs not in self._sized:
            self._sized[num_envs] = MjxEnv(self.task, self.frame_skip, self.max_episode_steps, warp_max_envs=num_envs)
        return self._sized[num_envs]

    def state_shapes(self) -> State:
        """As `Env.state_shapes`. Camera frames on Warp render only in an environment sized for its batch, so an
        unsized one with cameras gives those of `sized_for(1)` (its physics sized for one); any other is traced as it
        is, since sizing builds the environment again (seconds on a CPU: Warp's buffers put on the device anew)."""
        if self.task.vision is not None and self._cameras is None:
            return self.sized_for(1).state_shapes()
        return super().state_shapes()

    def _reset(self, key: jax.Array) -> tuple[mjx.Data, Sensation, dict[str, jax.Array]]:
        pose_key, task_key = jax.random.split(key)
        randomizer = self.task.randomizer
        factors = {} if randomizer is None else randomizer.draw(key)
        if self._start is None:
            qpos = self.task.start_qpos(pose_key, task_key)
            qvel = self.task.initial_qvel(jax.random.fold_in(pose_key, 1))
            model = self.mjx_model if randomizer is None else randomizer.apply(self.mjx_model, factors)
            data = mjx_module().forward(model, self._data0.replace(qpos=qpos, qvel=qvel))
            # MJX's forward writes free joints' quaternions back normalised, C MuJoCo's (the twin, Gymnasium) does not:
            # the start keeps the drawn qpos as C MuJoCo does (Ant's start draws unnormalised ones).
            data = data.replace(qpos=qpos, ctrl=self.task.initial_control(self.task.snapshot(data)))
        else:
            data = self._start
        # The drawn factors ride in the episode's info: the auto-reset replaces them with the next episode's.
        info, obs = self._begin_task(key, task_key, self.task.snapshot(data), factors)
        return data, self._unseen(obs), info

    def _step(self, physics: mjx.Data, info: dict[str, jax.Array], action: jax.Array, key: jax.Array):
        model, randomizer = self.mjx_model, self.task.randomizer
        if randomizer is not None:
            model = randomizer.apply(model, info[INFO_KEY])
        prev = self.task.snapshot(physics)
        ctrl, info = self._control_task(action, key, prev, info)
        data = physics.replace(ctrl=ctrl)
        data = jax.lax.fori_loop(0, self.frame_skip, lambda _, d: mjx_module().step(model, d), data)
        # C MuJoCo's `step_physics` calls rne_postconstraint after the last physics step: from the state that step's
        # forward pass left, which is where Warp computed it (`run_rne_postconstraint`); MJX's JAX step does not.
        if self.task.body_dynamics and self.impl == "jax":
            data = mjx_module().rne_postconstraint(model, data)
        obs, reward, terminated, info, metrics = self._advance_task(key, prev, self.task.snapshot(data), info)
        return data, self._unseen(obs), reward, terminated, info, metrics

    def _select_physics(self, done: jax.Array, fresh: mjx.Data, ended: mjx.Data) -> mjx.Data:
        # Warp's contact buffer is shared by the batch: `Data.where` selects per environment only what is its own.
        return ended.where(done, fresh)
