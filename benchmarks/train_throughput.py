"""Training throughput: environment steps consumed per wall second by the compiled PPO cycle, against the raw
batched env-step rate at the same batch size (random actions, the same `lax.scan` over `vmap(env.step)`).

    python benchmarks/train_throughput.py --task CartPole --num-envs 64 256 --model simple lstm
    python benchmarks/train_throughput.py --task ShadowHandReach --num-envs 4096 --rollout-length 32   # GPU
    python benchmarks/train_throughput.py --task ShadowHandCube --num-envs 4096 --model simple --impls jax,warp  # GPU
    python benchmarks/train_throughput.py --task ShadowHandCube --num-envs 8192 --model simple --impls warp \
        --warp-sized-to-batch --rollout-length 32   # GPU: Warp's buffers for 8,192 envs, not 32,768

`--impls` compares MJX implementations of the Shadow-hand tasks in one run ("warp" needs warp-lang, see
angora_jax/envs/mjx_env.py).

`--vision-sizes` trains the cube from camera images (the task's `vision` option, `--cameras`, square frames of each
size; 0 is the pose input) with a CORnet-Z visual area (`ppo.network.visual`), as configs/shadow_ihom_pixels.yaml
does; on a GPU, Warp renders inside the compiled step, at every step and every auto-reset:

    python benchmarks/train_throughput.py --task ShadowHandCube --num-envs 4096 --model simple --impls warp \
        --warp-sized-to-batch --rollout-length 32 --vision-sizes 0 32 64 --cameras front top   # GPU

`--configs` trains shipped configs (or YAML files) as they are, network, rollout and minibatches included, at each
`--num-envs` (the minibatch keeps its share of the batch), e.g. the brain-area model against the MLP on the cube:

    python benchmarks/train_throughput.py --configs shadow_ihom shadow_ihom_cortical --num-envs 16384   # GPU

Prints a Markdown table and writes JSON (device, versions, config, numbers) under
benchmarks/results/env_train_throughput/. Compile time is measured separately (ahead-of-time lowering and
compilation) and excluded from the rates.
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import json
import os
import subprocess
import sys
import tempfile

from common import env_step_rate, markdown_table, peak_memory_bytes, train_rate, write_results

from angora_jax.envs.registry import make
from angora_jax.experiment.config import load_config, validate
from angora_jax.ppo import NetworkConfig, PPOConfig, VisualConfig


def config_rows(names: list[str], num_envs: list[int], repeats: int) -> list[dict]:
    """One row per shipped config (or YAML path) and batch size, each trained as its config says; with several, each
    in a fresh process of this script (`config_row_in_subprocess`)."""
    combinations = list(itertools.product(names, num_envs))
    if len(combinations) > 1:
        return [config_row_in_subprocess(name, envs, repeats) for name, envs in combinations]
    ((name, envs),) = combinations
    shipped = load_config(name)
    share = shipped.ppo.minibatch_size / shipped.ppo.num_envs
    config = load_config(name, [f"ppo.num_envs={envs}", f"ppo.minibatch_size={round(envs * share)}"])
    env = validate(config)
    raw = env_step_rate(env, envs, config.ppo.rollout_length, repeats)
    trained = train_rate(env, config.ppo, repeats)
    print(f"{name} @ {envs} envs: {trained['env_steps_per_s']:,.0f} train steps/s", flush=True)
    return [row(config.env.task, name, env, config.ppo, getattr(env, "impl", None), raw, trained)]


def config_row_in_subprocess(name: str, envs: int, repeats: int) -> dict:
    """`config_rows` of one config and batch size, measured by this script in a fresh process on the same device, as
    a training run has the device to itself. In one process, MuJoCo Warp could not allocate its buffers for a second
    cube config at 16,384 envs on an H100 (721 MB, with most of the memory free: three times, also with the first
    config's environment freed and without XLA's preallocation)."""
    with tempfile.TemporaryDirectory() as folder:
        out = os.path.join(folder, "row.json")
        subprocess.run([sys.executable, os.path.abspath(__file__), "--configs", name, "--num-envs", str(envs),
                        "--repeats", str(repeats), "--out", out], check=True)
        with open(out) as f:
            return json.load(f)["results"][0]


def row(task: str, model: str, env, config: PPOConfig, impl: str | None, raw: dict, trained: dict, vision: str = "pose",
        area: str = "-", cameras: int = 0) -> dict:
    """A table row: rates of the compiled cycle (`trained`) and of random-action env steps (`raw`)."""
    return {
        "task": task, "impl": impl or "-", "model": model, "num_envs": config.num_envs,
        "vision": vision, "visual_area": area,
        "train_frames_per_s": trained["env_steps_per_s"] * cameras,
        "raw_env_steps_per_s": raw["env_steps_per_s"],
        "train_env_steps_per_s": trained["env_steps_per_s"],
        "train_sim_s_per_s": trained["env_steps_per_s"] * env.dt, "control_dt_s": env.dt,
        "train_over_raw": trained["env_steps_per_s"] / raw["env_steps_per_s"],
        "raw_compile_s": raw["compile_s"], "train_compile_s": trained["compile_s"],
        "peak_memory_gib": (peak_memory_bytes() or 0) / 2**30 or None,
        "config": dataclasses.asdict(config),
    }


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--task", default="CartPole")
    parser.add_argument("--num-envs", type=int, nargs="+", default=[64])
    parser.add_argument("--model", nargs="+", default=["simple", "lstm"])
    parser.add_argument("--rollout-length", type=int, default=128)
    parser.add_argument("--chunk-length", type=int, default=16)
    parser.add_argument("--epochs", type=int, default=3)
    parser.add_argument("--minibatches", type=int, default=4, help="minibatches per epoch")
    parser.add_argument("--repeats", type=int, default=5, help="timed cycles per configuration")
    parser.add_argument("--impls", default=None, help="comma-separated MJX implementations (jax, warp) of an MJX task")
    parser.add_argument("--warp-sized-to-batch", action="store_true",
                        help="size Warp's contact buffer for each row's envs (physics.warp_max_envs) instead of 32,768")
    parser.add_argument("--vision-sizes", type=int, nargs="+", default=[0],
                        help="ShadowHandCube from camera images of these sizes (pixels; 0: the pose input)")
    parser.add_argument("--cameras", nargs="+", default=["front"], help="cameras for --vision-sizes")
    parser.add_argument("--visual-area", nargs="+", choices=("trained", "frozen"), default=["trained"],
                        help="with --vision-sizes: train the visual area, or keep it frozen (no backward pass)")
    parser.add_argument("--configs", nargs="+", default=None,
                        help="train these configs as they are (configs/ names or YAML) instead of --task/--model")
    parser.add_argument("--out", default=None,
                        help="JSON path (default: results/env_train_throughput/train_throughput_<platform>.json)")
    args = parser.parse_args(argv)

    impls = args.impls.split(",") if args.impls else [None]
    rows = config_rows(args.configs, args.num_envs, args.repeats) if args.configs else []
    combinations = [] if args.configs else itertools.product(impls, args.num_envs, args.vision_sizes)
    for impl, num_envs, size in combinations:
        physics = {"impl": impl} if impl else {}
        # Camera vision on Warp renders batches of a fixed size: the environment is always sized for its batch.
        if impl == "warp" and (args.warp_sized_to_batch or size):
            physics["warp_max_envs"] = num_envs
        options = {"physics": physics} if physics else {}
        visual = None
        if size:
            options |= {"vision": {"cameras": args.cameras, "width": size, "height": size}, "relative_goal": False}
            visual = VisualConfig(widths=(32, 64, 64, 128))
        env = make(args.task, **options)
        raw = env_step_rate(env, num_envs, args.rollout_length, args.repeats)
        for model, area in itertools.product(args.model, args.visual_area if size else ["trained"]):
            config = PPOConfig(
                num_envs=num_envs,
                rollout_length=args.rollout_length,
                chunk_length=args.chunk_length,
                num_epochs=args.epochs,
                minibatch_size=num_envs * args.rollout_length // args.minibatches,
                network=NetworkConfig(name=model, visual=visual, frozen=("visual",) if area == "frozen" else ()),
            ).validate_for(env)
            trained = train_rate(env, config, args.repeats)
            cameras = len(args.cameras) if size else 0
            vision = f"{cameras} x {size}x{size}" if size else "pose"
            rows.append(row(args.task, model, env, config, impl, raw, trained, vision, area if size else "-", cameras))
            print(f"{impl or ''} {model} @ {num_envs} envs, {rows[-1]['vision']} ({area}): "
                  f"{trained['env_steps_per_s']:,.0f} train steps/s", flush=True)

    print(markdown_table(rows, [
        ("task", "task", "s"), ("impl", "MJX", "s"), ("model", "model", "s"), ("num_envs", "envs", "d"),
        ("vision", "vision", "s"), ("visual_area", "visual area", "s"), ("train_frames_per_s", "frames seen/s", ",.0f"),
        ("raw_env_steps_per_s", "raw env steps/s", ",.0f"), ("train_env_steps_per_s", "train env steps/s", ",.0f"),
        ("train_sim_s_per_s", "train sim-s/s", ",.1f"), ("train_over_raw", "train / raw", ".1%"),
        ("train_compile_s", "compile train s", ".1f"), ("raw_compile_s", "compile raw s", ".1f"),
        ("peak_memory_gib", "peak GiB", ".2f"),
    ]))
    path = write_results("train_throughput", {"args": vars(args), "control_dt_s": rows[-1]["control_dt_s"]}, rows,
                         args.out, study="env_train_throughput")
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
