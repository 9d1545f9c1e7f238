"""Batched camera rendering inside the compiled physics loop (MuJoCo Warp, `mjx.render`): frames per second and
simulated seconds per wall second, with and without rendering, per resolution. Needs a GPU with warp-lang.

The in-hand cube scene with the fixed vision cameras (`load_cube_scene(cameras=...)`: `vision_front`, `vision_side`,
`vision_top`), `num_envs` worlds on MuJoCo Warp; one policy step = fresh uniform random joint targets, `frame_skip`
physics steps (`vmap(mjx.step)`), then (when rendering) `refit_bvh` and `render` of every camera, RGB unpacked to
uint8 `(envs, cameras, H, W, 3)` as a policy would receive it. Frames per second count one image per camera per
environment per policy step. The last rendered batch is compared with C MuJoCo's `mujoco.Renderer` of the same
states through the same model cameras (needs MUJOCO_GL=egl with a driver's EGL; skipped otherwise): the share of
pixels that differ by more than 16 of 255 in any channel, and the mean absolute difference; `--save-frames` keeps a
few worlds' states and frames to make that comparison on another machine (`python benchmarks/render_throughput.py
--compare FILE`, with MUJOCO_GL=egl).

    python benchmarks/render_throughput.py --envs 4096 --sizes 32 64 96 --steps 20
"""

from __future__ import annotations

import argparse
import time

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from common import markdown_table, write_results
from mujoco import mjx

from angora_jax.envs.mjx_env import quiet_iteration_caps, warp_sizes
from angora_jax.envs.rendering import VISION_PREFIX
from angora_jax.envs.shadow_hand.cube import CUBE_PHYSICS, load_cube_scene


def measure(model: mujoco.MjModel, num_envs: int, size: int | None, steps: int, frame_skip: int, cameras: int,
            seed: int = 0) -> tuple[dict, np.ndarray | None, mjx.Data]:
    """One timed rollout (after a compiling one): rates, the last frames (uint8) and the last physics."""
    mx = quiet_iteration_caps(mjx.put_model(model, impl="warp"))
    start_data = mjx.make_data(model, impl="warp", **warp_sizes(model, num_envs))  # Warp's buffers for the batch
    data = jax.jit(jax.vmap(lambda _: start_data))(jnp.arange(num_envs))
    low, high = (jnp.asarray(x, jnp.float32) for x in model.actuator_ctrlrange.T)
    context = None
    if size is not None:
        context = mjx.create_render_context(mjm=model, nworld=num_envs, cam_res=(size, size), use_textures=True,
                                            use_shadows=False, render_rgb=[True] * cameras,
                                            render_depth=[False] * cameras, enabled_geom_groups=[0, 1, 2])
        handle = context.pytree()

    def images(data):
        data = jax.vmap(mjx.refit_bvh, in_axes=(None, 0, None))(mx, data, handle)
        rgb, _, data = jax.vmap(mjx.render, in_axes=(None, 0, None))(mx, data, handle)
        frames = jnp.stack([mjx.get_rgb(handle, camera, rgb) for camera in range(cameras)], axis=1)
        return (frames * 255.0 + 0.5).astype(jnp.uint8), data

    def policy_step(carry, key):
        data, _ = carry
        data = data.replace(ctrl=jax.random.uniform(key, (num_envs, model.nu), minval=low, maxval=high))
        data = jax.lax.fori_loop(0, frame_skip, lambda _, d: jax.vmap(mjx.step, (None, 0))(mx, d), data)
        if context is None:
            return (data, carry[1]), None
        frames, data = images(data)
        return (data, frames), None

    empty = jnp.zeros((num_envs, cameras, size or 1, size or 1, 3), jnp.uint8)

    @jax.jit
    def rollout(data, key):
        return jax.lax.scan(policy_step, (data, empty), jax.random.split(key, steps))[0]

    compile_start = time.perf_counter()
    jax.block_until_ready(rollout(data, jax.random.key(seed)))
    compile_seconds = time.perf_counter() - compile_start
    start = time.perf_counter()
    data, frames = jax.block_until_ready(rollout(data, jax.random.key(seed + 1)))
    seconds = time.perf_counter() - start
    policy_steps = num_envs * steps
    row = {"envs": num_envs, "size": size or 0, "render": context is not None, "seconds": seconds,
           "compile_and_first_s": compile_seconds, "policy_steps_per_s": policy_steps / seconds,
           "sim_s_per_s": policy_steps * frame_skip * model.opt.timestep / seconds,
           "frames_per_s": policy_steps * cameras / seconds if context is not None else 0.0}
    return row, (np.asarray(frames) if context is not None else None), data


def agreement(model: mujoco.MjModel, data: mjx.Data, frames: np.ndarray, cameras: tuple[str, ...],
              envs: int = 8) -> dict[str, float] | None:
    """Warp's frames of the first `envs` worlds against `mujoco.Renderer` of the same states (None without EGL)."""
    return compare_frames(model, np.asarray(data.qpos[:envs]), frames[:envs], cameras)


def compare_frames(model: mujoco.MjModel, qpos: np.ndarray, frames: np.ndarray,
                   cameras: tuple[str, ...]) -> dict[str, float] | None:
    """Frames `(worlds, cameras, H, W, 3)` of the states `qpos` against `mujoco.Renderer`'s (None without GL)."""
    try:
        renderer = mujoco.Renderer(model, frames.shape[2], frames.shape[3])
    except Exception:  # no GL context on this machine: the comparison is skipped, the throughput stands
        return None
    cpu = mujoco.MjData(model)
    differ, mean = [], []
    for world in range(frames.shape[0]):
        cpu.qpos[:] = qpos[world]
        mujoco.mj_forward(model, cpu)
        for index, name in enumerate(cameras):
            renderer.update_scene(cpu, VISION_PREFIX + name)
            reference = renderer.render().astype(int)
            delta = np.abs(reference - frames[world, index].astype(int))
            differ.append(float((delta.max(-1) > 16).mean()))
            mean.append(float(delta.mean()))
    renderer.close()
    return {"pixels_differing_over_16": float(np.mean(differ)), "mean_abs_difference": float(np.mean(mean))}


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--envs", type=int, nargs="+", default=[4096])
    parser.add_argument("--compare", default=None, help="an .npz of --save-frames: compare it with mujoco.Renderer")
    parser.add_argument("--sizes", type=int, nargs="+", default=[32, 64, 96])
    parser.add_argument("--cameras", nargs="+", default=["front", "side", "top"])
    parser.add_argument("--steps", type=int, default=20, help="policy steps per timed rollout")
    parser.add_argument("--name", default="render_throughput")
    parser.add_argument("--save-frames", default=None,
                        help="an .npz of the first 8 worlds' qpos and frames at each size, to compare elsewhere")
    parser.add_argument("--out", default=None, help="JSON path (default: results/cube_pixels/<name>_<platform>.json)")
    args = parser.parse_args(argv)
    cameras = tuple(args.cameras)
    model = load_cube_scene(touch=False, cameras=cameras)
    if args.compare:
        saved = np.load(args.compare)
        for key in sorted(k for k in saved.files if k.startswith("frames_")):
            frames, qpos = saved[key], saved[key.replace("frames", "qpos")]
            print(key.removeprefix("frames_"), "px:", compare_frames(model, qpos, frames, cameras))
        return
    frame_skip = CUBE_PHYSICS.frame_skip(0.08)
    rows, saved = [], {}
    for envs in args.envs:
        row, _, _ = measure(model, envs, None, args.steps, frame_skip, len(cameras))
        rows.append(row)
        print(row, flush=True)
        for size in args.sizes:
            row, frames, data = measure(model, envs, size, args.steps, frame_skip, len(cameras))
            rows.append(row | (agreement(model, data, frames, cameras) or {}))
            saved[f"qpos_{size}"], saved[f"frames_{size}"] = np.asarray(data.qpos[:8]), frames[:8]
            print(rows[-1], flush=True)
    print(markdown_table(rows, [("envs", "envs", "d"), ("size", "pixels", "d"), ("render", "render", ""),
                                ("frames_per_s", "frames/s", ",.0f"), ("policy_steps_per_s", "steps/s", ",.0f"),
                                ("sim_s_per_s", "sim-s/s", ",.0f"), ("pixels_differing_over_16", "px differ", ".3f")]))
    if args.save_frames:
        np.savez_compressed(args.save_frames, **saved)
    print(write_results(args.name, {"cameras": cameras, "steps": args.steps, "frame_skip": frame_skip,
                                    "timestep": model.opt.timestep}, rows, args.out, study="cube_pixels"))


if __name__ == "__main__":
    main()
