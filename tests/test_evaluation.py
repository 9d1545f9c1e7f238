"""Evaluation on the eager CPU path (statistics, JSON, box plot, clear errors, many episodes at a time, runs copied
from another machine), the MJX/CPU agreement tool, and videos of MuJoCo tasks."""

import json
import os
import re
import shutil
import sys
from dataclasses import replace
from pathlib import Path

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
import xarray as xr
import yaml
from jax_events import jax_events
from quick_compile import quick_compilation
from tiny import TINY_PPO

import angora_jax as aj
from angora_jax.cli import main
from angora_jax.envs.core import Sensation
from angora_jax.envs.cpu_env import CpuEnv, eager
from angora_jax.envs.eager_batch import EagerBatch
from angora_jax.envs.rendering import RenderError
from angora_jax.experiment import ConfigError, evaluation, snapshot_cycles
from angora_jax.experiment.episodes import agent_policy, episode_keys, on_host, random_policy, run_episodes
from angora_jax.experiment.evaluation import agreement, evaluate
from angora_jax.experiment.run_dir import EVALUATIONS
from angora_jax.ppo.cycle import make_cycle

sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "benchmarks"))
import path_agreement  # noqa: E402

PNG_MAGIC = b"\x89PNG"
# The CartPole run's evaluations use few batch sizes (a policy and a physics step compiled per size on the CPU path,
# an evaluation program per episode count on the batched one), so that tests share them: 1, 3 and 48 rows (the
# bit-identity test), EPISODES, and 16 episodes on the batched path (the two paths' agreement).
EPISODES = 4


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    """A short recurrent CartPole run, trained under one folder and then moved to another (the folder it was trained
    in is gone), as a run copied from another machine is. Its 20 cycles compile quickly (tests/quick_compile.py); the
    evaluations compile as usual."""
    root = tmp_path_factory.mktemp("runs")
    overrides = [*TINY_PPO, "ppo.num_cycles=20", "ppo.network.name=lstm", f"logging.run_root={root / 'trained'}",
                 "logging.run_name=cartpole", "logging.report=false", "logging.progress=none",
                 "checkpoint.snapshot_every=10"]
    with quick_compilation():
        trained = aj.train(aj.load_config("cartpole", overrides)).run_dir
    moved = Path(shutil.move(trained, root / "cartpole"))
    shutil.rmtree(root / "trained")
    return moved


@pytest.mark.slow
def test_evaluate_writes_statistics_json_and_box_plot_without_overwriting(run_dir):
    result = aj.evaluate(run_dir, "latest", episodes=EPISODES)
    record = json.loads(result.json_path.read_text())
    returns = np.array(record["per_episode"]["episode_return"])
    assert returns.shape == (EPISODES,) and np.all(returns >= 1)
    # CartPole pays 1 per step, so a return is the episode's length.
    assert record["per_episode"]["episode_length"] == record["per_episode"]["episode_return"]
    assert record["summary"]["episode_return"]["mean"] == pytest.approx(returns.mean())
    assert record["summary"]["episode_return"]["median"] == pytest.approx(np.median(returns))
    assert record["cycle"] == 20 and record["stochastic"] is False
    assert result.plot_path.read_bytes().startswith(PNG_MAGIC) and result.plot_path.stat().st_size > 5000
    first = result.json_path.read_text()
    again = aj.evaluate(run_dir, "latest", episodes=EPISODES, batch=1)
    assert again.json_path != result.json_path and result.json_path.read_text() == first
    # Mode actions from the same keys: the same episodes again, one at a time as all at once.
    assert record["batch"] == EPISODES and again.meta["batch"] == 1
    assert again.episodes["episode_return"].tolist() == returns.tolist()


def test_evaluating_again_compiles_nothing(run_dir):
    """Another call (another checkpoint, seed or path) reuses the compiled policy, task logic and batched program."""
    for path in evaluation.PATHS:
        evaluate(run_dir, "latest", episodes=EPISODES, save=False, path=path)
    # Off: the suite's persistent compilation cache would turn a repeated compile into a read that this misses.
    jax.config.update("jax_enable_compilation_cache", False)
    try:
        with jax_events("backend_compile_duration") as compiles:
            for path in evaluation.PATHS:
                assert evaluate(run_dir, "best", episodes=EPISODES, seed=3, save=False,
                                path=path).meta["episodes"] == EPISODES
    finally:
        jax.config.update("jax_enable_compilation_cache", True)
    assert compiles == []


def test_the_evaluation_loop_leaves_the_arrays_it_hands_the_policy_unchanged(run_dir):
    # JAX on CPU uses a NumPy argument's memory in place when it is 64-byte aligned, and computes after the call has
    # returned: changing the array then changes the call's input. Clearing `starting` thus cancelled the reset of a
    # new episode's recurrent carry when the policy computed late (a loaded machine) and the array happened to be
    # aligned, so episodes one at a time differed from all at once now and then. Compared here whatever the timing.
    agent = aj.load_agent(run_dir, "latest")
    handed = []
    with on_host():
        policy = agent_policy(agent)

        def recording(carry, obs, keys, steps, starting):
            handed.append([(given, given.copy()) for given in (steps, starting)])
            return policy(carry, obs, keys, steps, starting)

        with EagerBatch(agent.env, 1) as batch:
            run_episodes(batch, recording, agent.initial_carry(1), *episode_keys(0, 3))
    assert sum(bool(call[1][1].any()) for call in handed) == 3  # each episode's first step was handed over
    for call in handed:
        for now, then in call:
            np.testing.assert_array_equal(now, then)


def in_batches(fn, size, *rows):
    """`fn` applied to `rows` (leaves `(N, ...)`, N a multiple of `size`) `size` rows at a time, outputs joined."""
    count = jax.tree.leaves(rows)[0].shape[0]
    parts = [fn(*jax.tree.map(lambda x, i=i: x[i:i + size], rows)) for i in range(0, count, size)]
    return jax.tree.map(lambda *part: np.concatenate(part), *parts)


@pytest.mark.slow
def test_policy_and_env_rows_are_bit_identical_for_any_batch_size(run_dir):
    # Random carries, observations and states rather than whole episodes: a difference in the last bit shows at once,
    # where an episode changes only once it flips an action.
    agent, rows = aj.load_agent(run_dir, "latest"), 48
    rng = np.random.default_rng(0)
    carry = jax.tree.map(lambda x: rng.normal(size=x.shape).astype(np.float32), agent.initial_carry(rows))
    obs = Sensation.make(proprioception=rng.normal(scale=0.5, size=(rows, 4)).astype(np.float32))
    keys, steps = jax.random.split(jax.random.key(0), rows), rng.integers(0, 100, rows).astype(np.int32)
    starting, actions = rng.random(rows) < 0.3, rng.integers(0, 2, rows).astype(np.int32)
    physics = rng.uniform(-0.2, 0.2, (rows, 4)).astype(np.float32)

    def env_rows(size):
        with EagerBatch(agent.env, size) as batch:  # one batch, so that its step compiles once
            for slot in range(size):
                batch.reset(slot, jax.random.key(slot))
            started = batch.states

            def step(physics, actions):
                batch.states = started.replace(physics=jnp.asarray(physics))
                state = batch.step(jnp.asarray(actions), np.ones(size, bool))
                return state.physics, state.obs, state.reward, state.done

            return in_batches(step, size, physics, actions)

    with on_host():
        policy = agent_policy(agent)
        outputs = {size: (in_batches(policy, size, carry, obs, keys, steps, starting), env_rows(size))
                   for size in (1, 3, 48)}
    for size in (3, 48):
        for one, other in zip(jax.tree.leaves(outputs[1]), jax.tree.leaves(outputs[size]), strict=True):
            np.testing.assert_array_equal(other, one, err_msg=f"batch of {size}")


def test_agreement_compares_means_in_standard_errors_of_the_difference():
    rng = np.random.default_rng(0)
    a = rng.normal(0.0, 1.0, 400)
    same = agreement(a, rng.normal(0.0, 1.0, 400))
    assert same["agree"] and same["stderr_diff"] == pytest.approx(np.hypot(same["stderr_a"], same["stderr_b"]))
    shifted = agreement(a, a + 0.5)  # 0.5 apart with a standard error of the difference of about 0.07
    assert not shifted["agree"] and shifted["diff_in_stderr"] < -3 and shifted["stderr_paired"] == pytest.approx(0)
    assert agreement(np.full(8, 100.0), np.full(8, 100.0))["agree"]
    constant = agreement(np.full(8, 100.0), np.full(8, 99.0))
    assert not constant["agree"] and constant["diff_in_stderr"] is None


def test_batched_evaluation_writes_the_same_record_as_the_cpu_path(run_dir, capsys):
    """`--path batched` runs every episode at once on the training path (the GPU's way to evaluate 480 episodes): a
    record of its own name, with the same statistics as the CPU path's for the same episodes (mode actions, same
    reset keys; CartPole's physics are the same JAX functions on both paths)."""
    assert main(["evaluate", str(run_dir), "--checkpoint", "latest", "--episodes", "16", "--path", "batched"]) == 0
    out = capsys.readouterr().out
    assert "16 episodes on batched" in out and "at a time" in out
    batched = json.loads(next((run_dir / EVALUATIONS).glob("latest-cycle20-mode-seed0-batched.json")).read_text())
    cpu = evaluate(run_dir, "latest", episodes=16, save=False, batch=EPISODES)
    assert batched["path"] == "batched" and len(batched["per_episode"]["episode_length"]) == 16
    np.testing.assert_allclose(batched["per_episode"]["episode_length"], cpu.episodes["episode_length"])
    with pytest.raises(ValueError, match="Unknown evaluation path 'gpu'"):
        evaluate(run_dir, "latest", episodes=2, save=False, path="gpu")


@pytest.mark.slow
def test_cpu_and_batched_paths_agree_by_the_path_agreement_tool(run_dir, tmp_path, capsys):
    out = tmp_path / "agreement.json"
    assert path_agreement.main([str(run_dir), "--episodes", "16", "--batch", "3", "--out", str(out)]) == 0
    assert "PASS" in capsys.readouterr().out
    record = json.loads(out.read_text())
    assert record["config"]["verdict"] == "PASS" and record["config"]["cpu_batch"] == 3
    rows = {row["quantity"]: row for row in record["results"]}
    assert list(rows) == ["episode_return", "episode_length"] and all(row["agree"] for row in rows.values())
    # Both paths start episode i from the same key and act with the mode: the means differ by far less than the bound.
    assert abs(rows["episode_return"]["diff"]) < 3 * rows["episode_return"]["stderr_diff"]
    assert rows["episode_return"]["cpu_stderr"] > 0 and rows["episode_return"]["mjx_stderr"] > 0
    # A checkpoint or run that is not there: exit 2 and the cause, as the evaluation page says (it was a traceback).
    for argv in ([str(run_dir), "--checkpoint", "999"], [str(tmp_path / "nope")]):
        assert path_agreement.main([*argv, "--episodes", "2", "--out", str(tmp_path / "x.json")]) == 2
        err = capsys.readouterr().err
        assert err.startswith("path_agreement.py: ") and ("No checkpoint 999" in err or "does not exist" in err), err


@pytest.mark.slow
def test_c_mujoco_batch_matches_its_twin_whatever_the_batch_and_threads():
    # The C MuJoCo twin alone (building the MJX environment beside it took about 2 s of CPU), shared, so that its
    # functions compile once.
    twin = aj.make("ShadowHandReach", backend="cpu", max_episode_steps=4)
    assert isinstance(twin, CpuEnv)
    reset_keys, act_keys = episode_keys(0, 3)
    with on_host():
        policy = random_policy(twin)
        runs = []
        for size, workers in ((1, 1), (2, 2)):
            with EagerBatch(twin, size, workers) as batch:
                assert batch.workers == workers
                runs.append(run_episodes(batch, policy, None, reset_keys, act_keys))
        for name, values in runs[0].items():
            np.testing.assert_array_equal(runs[1][name], values, err_msg=name)
        # Episode 0 step by step on the C MuJoCo twin alone, with the same actions, gives the same episode.
        state, total = twin.reset(reset_keys[0]), 0.0
        while not state.done:
            _, action = policy(None, None, act_keys[:1], np.array([state.steps]), np.array([False]))
            state = twin.step(state, action[0])
            total += float(state.reward)
    assert runs[0]["episode_length"][0] == 4
    assert runs[0]["episode_return"][0] == pytest.approx(total, rel=1e-5)
    assert runs[0]["metric/goal_distance"][0] == pytest.approx(float(state.metrics["goal_distance"]), rel=1e-5)


def test_a_run_from_a_bigger_machine_evaluates_here(run_dir, tmp_path, capsys):
    copy = tmp_path / "from-gpu-machine"
    shutil.copytree(run_dir, copy, ignore=shutil.ignore_patterns("evaluation"))
    config = yaml.safe_load((copy / "config.yaml").read_text())
    config["distribution"]["num_devices"] = jax.device_count() + 3  # trained on more devices than this machine has
    config["logging"] |= {"run_root": "/home/someone/runs", "tensorboard": True}
    (copy / "config.yaml").write_text(yaml.safe_dump(config))
    assert main(["evaluate", str(copy), "--checkpoint", "latest", "--episodes", str(EPISODES)]) == 0
    assert len(list((copy / "evaluation").glob("latest-cycle20-*.json"))) == 1
    # Render loads the same way; CartPole then has no scene to draw.
    assert main(["render", str(copy), "--checkpoint", "latest", "--out", str(tmp_path / "cartpole.gif")]) == 2
    assert "no MuJoCo scene" in capsys.readouterr().err


def test_missing_and_corrupt_checkpoints_exit_2_naming_cause_and_fix(run_dir, tmp_path, capsys):
    assert main(["evaluate", str(run_dir), "--checkpoint", "999", "--episodes", "1"]) == 2
    assert "No checkpoint 999" in capsys.readouterr().err
    corrupt = tmp_path / "corrupt"
    shutil.copytree(run_dir, corrupt, ignore=shutil.ignore_patterns("evaluation"))
    for path in (corrupt / "checkpoints" / "latest").rglob("*"):
        if path.is_file() and path.stat().st_size > 0:
            path.write_bytes(b"not a checkpoint")
    assert main(["evaluate", str(corrupt), "--checkpoint", "latest", "--episodes", "1"]) == 2
    err = capsys.readouterr().err
    assert f"Checkpoint {corrupt / 'checkpoints' / 'latest'}" in err and "is damaged: " in err, err
    assert "The newest intact checkpoint is" in err and "--checkpoint" in err, err
    assert not (corrupt / "evaluation").exists()
    shutil.rmtree(corrupt / "checkpoints" / "latest")
    assert main(["evaluate", str(corrupt), "--checkpoint", "latest", "--episodes", "1"]) == 2
    err = capsys.readouterr().err
    assert "No checkpoint 'latest'" in err and "ask for 'best' or a cycle (" in err, "not the kind that is missing"
    shutil.rmtree(corrupt / "checkpoints")
    assert main(["evaluate", str(corrupt), "--episodes", "1"]) == 2
    assert "saved none yet" in capsys.readouterr().err


def test_cli_evaluate_prints_statistics_and_sampled_episodes_do_not_depend_on_the_batch(run_dir, capsys):
    args = ["evaluate", str(run_dir), "--checkpoint", "latest", "--episodes", "7", "--stochastic"]
    assert main([*args, "--batch", "3", "--workers", "2"]) == 0
    out = capsys.readouterr().out
    assert "episode_return" in out and "median" in out and "Written:" in out and "3 at a time" in out
    written = json.loads(Path(out.split("Written: ")[1].split(" and ")[0]).read_text())
    assert written["stochastic"] is True and written["batch"] == 3
    # Each episode samples from its own keys, and the recurrent carry restarts with every episode a slot takes on
    # (CartPole episodes end at different steps, so slots take new ones at different times): one at a time, the same.
    one = aj.evaluate(run_dir, "latest", episodes=7, stochastic=True, save=False, batch=1)
    assert len(set(one.episodes["episode_length"])) > 1
    for name, values in one.episodes.items():
        assert written["per_episode"][name] == values.tolist(), name


def test_evaluation_in_a_changed_task_records_the_change(run_dir, tmp_path, capsys):
    """`--env-option` evaluates the policy in a task with other options (e.g. the cube seen through a pose estimator;
    here CartPole's episodes cut at 20 steps): recorded in the JSON, named apart from plain evaluations."""
    args = ["evaluate", str(run_dir), "--checkpoint", "latest", "--episodes", "4",
            "--env-option", "max_episode_steps=20"]
    assert main(args) == 0
    path = Path(capsys.readouterr().out.split("Written: ")[1].split(" and ")[0])
    written = json.loads(path.read_text())
    assert path.name.endswith("-changed.json") and written["env_overrides"] == ["max_episode_steps=20"]
    assert written["task_options"]["max_episode_steps"] == 20, "the options evaluated with, not only the change"
    assert max(written["per_episode"]["episode_length"]) <= 20
    assert main([*args[:-1], "max_episode_steps"]) == 2
    assert "A task option is given as KEY=VALUE, e.g. max_episode_steps=20" in capsys.readouterr().err, \
        "not the config's 'env.options.max_episode_steps=VALUE', which --env-option refused"
    # Recordings take changed options too (e.g. the estimated pose beside the true one).
    out = tmp_path / "changed.nc"
    assert main(["record", str(run_dir), "--checkpoint", "latest", "--episodes", "2", "--steps", "30",
                 "--env-option", "max_episode_steps=20", "--out", str(out)]) == 0
    recording = xr.open_dataset(out)
    assert recording.attrs["env_overrides"] == "max_episode_steps=20"
    capsys.readouterr()
    assert main(["record", str(run_dir), "--episodes", "2", "--out", str(tmp_path / "act.png")]) == 2
    assert "give --out a name ending in .nc (e.g. " in capsys.readouterr().err, "NetCDF under another name"
    assert not (tmp_path / "act.png").exists()
    assert recording["alive"].values[:, 20:].sum() == 0, "no episode outlives its changed limit"


@pytest.mark.slow
def test_a_new_run_fine_tunes_a_saved_policy_in_a_changed_task(run_dir, tmp_path, quick_compiles):
    """`ppo.init_from`: a run that starts from a saved run's network and observation statistics (e.g. the cube's
    pose-input policy, fine-tuned reading a pose estimator; here CartPole's with shorter episodes) and trains on; a
    network that does not fit, or no such run, is refused naming the cause."""
    saved = aj.load_agent(run_dir, "latest").state
    overrides = [*TINY_PPO, "ppo.network.name=lstm", "ppo.num_cycles=2", f"ppo.init_from={run_dir}:latest",
                 "env.options.max_episode_steps=50", f"logging.run_root={tmp_path}", "logging.run_name=tuned",
                 "logging.report=false", "logging.progress=none", "checkpoint.every=1"]
    config = aj.load_config("cartpole", overrides)
    env = aj.make("CartPole", max_episode_steps=50)
    init, _ = make_cycle(env, None, config.ppo)
    start = init(jax.random.key(0))
    for ours, theirs in ((start.params, saved.params), (start.obs_stats, saved.obs_stats)):
        jax.tree.map(np.testing.assert_array_equal, ours, theirs)
    run = aj.train(config)
    assert [row["cycle"] for row in run.history] == [1, 2]
    tuned = aj.load_agent(run.run_dir, "latest").state
    assert not np.array_equal(tuned.params["policy_head"]["kernel"], saved.params["policy_head"]["kernel"]), "trained"
    with pytest.raises(ValueError, match="init_from .*network parameters do not fit.*policy_cell"):
        make_cycle(env, None, config.ppo.replace(network=replace(config.ppo.network, width=8)))[0](jax.random.key(0))
    with pytest.raises(FileNotFoundError, match="is neither a file nor a run directory"):
        make_cycle(env, None, config.ppo.replace(init_from=str(tmp_path / "gone")))[0](jax.random.key(0))


def test_render_frames_of_random_actions_differ(opengl):
    frames = aj.render_frames(task="ShadowHandReach", task_options={"max_episode_steps": 4}, camera="side")
    assert len(frames) == 5 and frames[0].shape == (240, 320, 3) and frames[0].dtype == np.uint8
    assert frames[0].std() > 10  # a scene, not a blank image
    assert not np.array_equal(frames[0], frames[-1])


@pytest.mark.slow
def test_cli_render_writes_a_video_and_refuses_to_overwrite(run_dir, tmp_path, capsys, opengl):
    out = tmp_path / "reach.mp4"
    assert main(["render", "--task", "ShadowHandReach", "--out", str(out), "--width", "160", "--height", "120"]) == 0
    size = out.stat().st_size
    assert size > 1000
    assert main(["render", "--task", "ShadowHandReach", "--out", str(out)]) == 2
    assert "exists already" in capsys.readouterr().err and out.stat().st_size == size
    assert main(["render", str(run_dir), "--checkpoint", "latest", "--out", str(tmp_path / "cartpole.gif")]) == 2
    assert "no MuJoCo scene" in capsys.readouterr().err


def never_renders(*args, **kwargs):
    raise AssertionError("rendered, although the arguments were refusable before")


@pytest.mark.parametrize("name", ["video.xyz", "video", "video.png", "video.MP4.txt"])
def test_render_refuses_an_out_that_is_not_mp4_or_gif_before_rendering(name, tmp_path, capsys, monkeypatch):
    """An --out of another suffix (or none) reached imageio after every frame was rendered: a TIFF writer's
    TypeError traceback for no suffix or .xyz, one still picture for .png. Refused first, naming the two suffixes."""
    import angora_jax.experiment.video as video

    monkeypatch.setattr(video, "render_episodes", never_renders)
    assert main(["render", "--task", "ShadowHandReach", "--out", str(tmp_path / name)]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and ".mp4" in err and ".gif" in err and name in err, err
    assert list(tmp_path.iterdir()) == [], "nothing written"
    with pytest.raises(ValueError, match="MP4 or GIF"):
        video.write_video([np.zeros((16, 16, 3), np.uint8)], tmp_path / name, fps=10)


@pytest.mark.parametrize("out", ["notes.txt/v.gif", "notes.txt/new/v.mp4", "read-only/v.gif"])
def test_render_refuses_an_out_in_a_file_or_a_folder_it_cannot_write_before_rendering(out, tmp_path, capsys,
                                                                                      monkeypatch):
    """`render --out notes.txt/v.gif` (a file where the folder goes) rendered every frame, minutes for long episodes,
    then said only "[Errno 17] File exists: 'notes.txt'", as if the video existed; a read-only folder was found only
    then too. Refused first now, naming the file in the way or the folder."""
    import angora_jax.experiment.video as video

    monkeypatch.setattr(video, "render_episodes", never_renders)
    monkeypatch.chdir(tmp_path)
    (tmp_path / "notes.txt").write_text("mine")
    (tmp_path / "read-only").mkdir()
    writable = os.access
    monkeypatch.setattr(os, "access", lambda path, mode: "read-only" not in str(path) and writable(path, mode))
    assert main(["render", "--task", "ShadowHandReach", "--out", out]) == 2
    err = capsys.readouterr().err
    why = f"{tmp_path / 'read-only'} is not writable" if "read-only" in out else f"{tmp_path / 'notes.txt'} is a file"
    assert f"--out {out}: {why}" in err and "Traceback" not in err, err
    assert (tmp_path / "notes.txt").read_text() == "mine" and not any((tmp_path / "read-only").iterdir())


@pytest.mark.parametrize("width, height, said", [("33", "240", "not --width 33: give --width 34, or"),
                                                  ("320", "17", "not --height 17: give --height 18, or")])
def test_render_refuses_an_mp4_of_an_odd_frame_size_before_rendering(width, height, said, tmp_path, capsys,
                                                                     monkeypatch):
    """`render --out v.mp4 --width 33` rendered every frame, then ffmpeg refused them ("width not divisible by 2"),
    reported as ffmpeg failing; H.264 needs even sizes. Refused first now, naming the even size; a GIF takes any."""
    import angora_jax.experiment.video as video

    monkeypatch.setattr(video, "render_episodes", never_renders)
    out = tmp_path / "v.mp4"
    assert main(["render", "--task", "ShadowHandReach", "--out", str(out), "--width", width, "--height", height]) == 2
    err = capsys.readouterr().err
    assert "An MP4's frames have an even width and height" in err and said in err and "Traceback" not in err, err
    assert not out.exists()
    video.check_frame_size(tmp_path / "v.gif", int(width), int(height))


@pytest.mark.parametrize("argv, message", [
    (["evaluate", "RUN", "--episodes", "1000000000"], "--episodes/--num-envs: must be a whole number from 1 to "
                                                      "1,000,000, got '1000000000'; run more episodes as several"),
    (["evaluate", "RUN", "--episodes", "-1"], "from 1 to 1,000,000, got '-1'"),
    (["record", "RUN", "--out", "a.nc", "--episodes", "0"], "--episodes: must be a whole number from 1 to"),
    (["render", "RUN", "--out", "v.gif", "--episodes", "10**9"], "got '10**9'"),
    (["analyze", "ablate", "RUN", "--episodes", "1000001"], "from 1 to 1,000,000, got '1000001'"),
    (["render", "--task", "ShadowHandReach", "--out", "v.gif", "--width", "100000"],
     "--width: must be a whole number from 16 to 4,096, got '100000'; a frame that large is 50 MB"),
    (["render", "--task", "ShadowHandReach", "--out", "v.gif", "--height", "0"], "from 16 to 4,096, got '0'"),
])
def test_absurd_episode_counts_and_frame_sizes_are_usage_errors(argv, message, capsys):
    """`evaluate --episodes 1000000000` split a thousand million keys and was killed by the kernel (exit 137, no
    message); `render --width 100000` loaded the task and then blamed the OpenGL backend; 0 and negative counts were
    refused already. Now argparse refuses each (exit 2) before anything is loaded."""
    with pytest.raises(SystemExit) as stop:
        main(argv)
    err = capsys.readouterr().err
    assert stop.value.code == 2 and message in err and "Traceback" not in err, err


def test_counts_given_in_python_that_are_no_whole_number_of_at_least_one_are_refused_by_name(run_dir):
    """Notebook trial: `agent.evaluate(num_envs=0)` returned NaN means as if evaluated, num_envs=-2 and 2.5 failed
    inside JAX ("slice limit_indices must have every element be nonnegative", "Shapes must be 1D sequences of
    concrete values of integer type"), as did `evaluate(run, episodes=2.5)`; episodes="4" and `resume(run,
    num_cycles="4")` compared text with a number (TypeError); `render_frames(run, episodes=0)` returned no frames."""
    agent = aj.load_agent(run_dir, "latest")
    for bad in (0, -2, 2.5, "4", True):
        said = rf"must be a whole number of at least 1, got {bad!r}\.$"
        with pytest.raises(ValueError, match="^num_envs " + said):
            agent.evaluate(num_envs=bad)
        with pytest.raises(ValueError, match="^episodes " + said):
            evaluate(run_dir, episodes=bad, save=False)
        with pytest.raises(ValueError, match="^episodes " + said):
            aj.render_frames(run_dir, episodes=bad)
        with pytest.raises(ValueError, match="^num_cycles " + said):
            aj.resume(run_dir, num_cycles=bad)
    assert evaluate(run_dir, "latest", episodes=np.int64(EPISODES), save=False).meta["episodes"] == EPISODES


def test_seeds_given_in_python_that_are_no_seed_are_refused_by_name(run_dir):
    """Notebook trial: the Python twins of the commands' --seed (which argparse checks), given seed=1.5, failed inside
    a compiled program ("PRNG key seed must be an integer; got JitTracer(~float32[])"), seed="abc" as "is not a
    valid JAX array type". Each is a ConfigError naming `seed` and its range now, as ppo.seed is in a config."""
    from angora_jax.analysis import episode_outcomes, record_activity

    agent = aj.load_agent(run_dir, "latest")
    for bad in (1.5, "abc", -1, 2**32, True):
        said = rf"^seed must be a whole number from 0 to 4,294,967,295, got {re.escape(repr(bad))}\.$"
        for call, first in ((evaluate, dict(run_dir=run_dir, episodes=1, save=False)),
                            (agent.evaluate, dict(num_envs=1)), (aj.render_frames, dict(run_dir=run_dir)),
                            (record_activity, dict(agent=agent, episodes=1)),
                            (episode_outcomes, dict(agent=agent, episodes=1))):
            with pytest.raises(ConfigError, match=said):
                call(**first, seed=bad)
    assert evaluate(run_dir, "latest", episodes=1, seed=np.int64(3), save=False).meta["seed"] == 3


def test_render_refuses_frames_larger_than_memory_before_rendering(tmp_path, capsys, monkeypatch):
    """Every frame is held until the video is written: 100 episodes at 4,096 x 4,096 pixels (5 TB) rendered for
    as long as they took, then were killed by the kernel. Refused first, naming --episodes, --width and --height."""
    import angora_jax.experiment.video as video

    monkeypatch.setattr(video, "SceneRenderer", never_renders)
    out = tmp_path / "v.gif"
    assert main(["render", "--task", "ShadowHandReach", "--out", str(out), "--episodes", "100", "--width", "4096",
                 "--height", "4096"]) == 2
    err = capsys.readouterr().err
    assert "more than this machine's" in err and "(--episodes) or smaller frames (--width, --height)" in err, err
    assert not out.exists()


def test_frames_larger_than_the_models_framebuffer_are_rendered(opengl):
    """MuJoCo draws into the model's offscreen framebuffer (640 x 480 unless its XML says otherwise) and refused
    larger frames, a refusal `render` reported as a missing OpenGL backend; the renderer now enlarges its own copy's
    framebuffer, and the task's model is left as it was."""
    from angora_jax.envs.rendering import CAMERAS, SceneRenderer

    env = eager(aj.make("ShadowHandReach", max_episode_steps=1))
    framebuffer = (env.model.vis.global_.offwidth, env.model.vis.global_.offheight)
    renderer = SceneRenderer(env.model, env.task.camera_body, CAMERAS["front"], framebuffer[0] + 16, 40)
    try:
        data = mujoco.MjData(env.model)
        mujoco.mj_forward(env.model, data)
        frame = renderer.render(data)
    finally:
        renderer.close()
    assert frame.shape == (40, framebuffer[0] + 16, 3) and frame.std() > 10
    assert (env.model.vis.global_.offwidth, env.model.vis.global_.offheight) == framebuffer


def test_no_gl_backend_is_reported_with_the_package_to_install(monkeypatch):
    def fail(*args, **kwargs):
        raise mujoco.FatalError("gladLoadGL error")

    monkeypatch.setattr(mujoco, "Renderer", fail)
    with pytest.raises(RenderError, match="libegl-mesa0.*MUJOCO_GL=egl.*libosmesa6"):
        aj.render_frames(task="ShadowHandReach", task_options={"max_episode_steps": 1})


def test_evaluating_the_snapshots_follows_the_policy_over_training(run_dir, tmp_path, capsys):
    """`--checkpoint snapshots` evaluates each kept snapshot in turn (cycles 10 and 20 here) and sums them up; a run
    that keeps none is refused with the setting that keeps them."""
    assert snapshot_cycles(run_dir) == [10, 20]
    assert main(["evaluate", str(run_dir), "--checkpoint", "snapshots", "--episodes", "3"]) == 0
    out = capsys.readouterr().out
    assert "checkpoint of cycle 10," in out and "checkpoint of cycle 20," in out and "Over the snapshots:" in out
    written = {p.name: json.loads(p.read_text())["cycle"] for p in (run_dir / "evaluation").glob("cycle*.json")}
    assert written == {"cycle10-mode-seed0.json": 10, "cycle20-mode-seed0.json": 20}, \
        "each snapshot's evaluation is written as a single one would be, its cycle named once"
    bare = tmp_path / "bare"
    shutil.copytree(run_dir, bare)
    shutil.rmtree(bare / "checkpoints" / "snapshots")
    assert main(["evaluate", str(bare), "--checkpoint", "snapshots", "--episodes", "1"]) == 2
    err = capsys.readouterr().err
    assert "keeps no snapshots" in err and "checkpoint.snapshot_every=N" in err



def test_evaluate_out_writes_into_another_folder_and_nothing_into_the_run(run_dir, tmp_path, capsys):
    """`evaluate --out FOLDER` (for a run on a share one may not write to) writes its JSON and box plot there, named as
    in the run, adds nothing to the run, and never overwrites an earlier evaluation in that folder."""
    before = sorted(p.relative_to(run_dir) for p in run_dir.rglob("*"))
    elsewhere = tmp_path / "mine" / "evaluations"
    for _ in range(2):
        assert main(["evaluate", str(run_dir), "--checkpoint", "latest", "--episodes", "2",
                     "--out", str(elsewhere)]) == 0
    assert sorted(p.relative_to(run_dir) for p in run_dir.rglob("*")) == before
    assert sorted(p.name for p in elsewhere.iterdir()) == [
        "latest-cycle20-mode-seed0-2.json", "latest-cycle20-mode-seed0-2.png",
        "latest-cycle20-mode-seed0.json", "latest-cycle20-mode-seed0.png"]
    assert str(elsewhere / "latest-cycle20-mode-seed0.json") in capsys.readouterr().out


def test_an_out_that_is_a_file_or_lies_in_one_is_refused_before_any_episode_runs(run_dir, tmp_path, capsys,
                                                                                 monkeypatch):
    """`evaluate --out notes.txt` (or `save=` in Python) ran every episode, then ended in mkdir's FileExistsError
    (a traceback in Python, "a file is in the way ... (logging.run_root, --out)" from the command). Refused first
    now, as a ConfigError naming the file and saying to give a folder; the file is left as it was."""
    def never_loads(*args, **kwargs):
        raise AssertionError("the agent was loaded to evaluate, although the --out was refusable before")

    monkeypatch.setattr(evaluation, "load_agent", never_loads)
    in_the_way = tmp_path / "notes.txt"
    in_the_way.write_text("mine")
    with pytest.raises(ConfigError, match=f"{in_the_way} is a file.*give a folder"):
        evaluate(run_dir, episodes=1, save=in_the_way)
    assert main(["evaluate", str(run_dir), "--episodes", "1", "--out", str(in_the_way)]) == 2
    err = capsys.readouterr().err
    assert f"--out) {in_the_way} is a file" in err and "give a folder" in err and "Traceback" not in err, err
    assert main(["evaluate", str(run_dir), "--episodes", "1", "--out", str(in_the_way / "evaluations")]) == 2
    assert f"{in_the_way} is a file, not a folder; give a folder you can write to" in capsys.readouterr().err
    assert in_the_way.read_text() == "mine"
    # The run directory itself: its JSON and box plot lay among the run's config.yaml and metrics.jsonl, exit 0.
    before = sorted(path.name for path in run_dir.iterdir())
    assert main(["evaluate", str(run_dir), "--episodes", "1", "--out", str(run_dir)]) == 2
    err = capsys.readouterr().err
    assert f"--out) {run_dir} is a run directory itself" in err and f"({run_dir / 'evaluation'}, the default)" in err
    assert sorted(path.name for path in run_dir.iterdir()) == before

def test_render_shows_a_trained_reach_policy_acting(cortical_reach, tmp_path, opengl):
    """`angora-jax render RUN_DIR` on the session's trained reach run (the policy branch of experiment/video.py): the
    episode `evaluate` plays with the same seed, one frame at its reset and one per step, from the start that random
    actions get with that seed, then other frames than random actions make; written as a GIF."""
    played = aj.evaluate(cortical_reach.run_dir, episodes=1, save=False)
    frames = aj.render_frames(cortical_reach.run_dir, width=64, height=48, camera="side")
    assert len(frames) == int(played.episodes["episode_length"][0]) + 1
    random = aj.render_frames(task="ShadowHandReach", task_options={"max_episode_steps": 30}, width=64, height=48,
                              camera="side")
    np.testing.assert_array_equal(frames[0], random[0])
    assert np.abs(frames[-1].astype(int) - random[-1].astype(int)).mean() > 1.0, "the policy moves otherwise"
    out = tmp_path / "policy.gif"
    assert main(["render", str(cortical_reach.run_dir), "--out", str(out), "--width", "64", "--height", "48",
                 "--camera", "side"]) == 0
    import imageio.v3 as iio

    assert iio.imread(out).shape == (len(frames), 48, 64, 3)


def ffmpeg_with_a_full_disk(monkeypatch, size: int) -> None:
    """The ffmpeg that imageio-ffmpeg starts may write no more than `size` bytes to a file (EFBIG past them, as a disk
    that fills up answers ENOSPC): its process's file-size limit, set in the child only."""
    import resource
    import signal

    import imageio_ffmpeg._io as ffmpeg_io

    popen_kwargs = ffmpeg_io._popen_kwargs

    def limited(*args, **kwargs):
        chosen = popen_kwargs(*args, **kwargs)
        before = chosen["preexec_fn"]

        def start():
            if before is not None:
                before()
            signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write past the limit fails instead of killing ffmpeg
            resource.setrlimit(resource.RLIMIT_FSIZE, (size, size))

        return chosen | {"preexec_fn": start}

    monkeypatch.setattr(ffmpeg_io, "_popen_kwargs", limited)


def test_an_mp4_that_ffmpeg_could_not_finish_is_refused_not_written(tmp_path, capsys, monkeypatch):
    """A disk that filled up while ffmpeg wrote an MP4: ffmpeg printed "Error writing trailer: No space left on
    device" and exited with an error, which imageio-ffmpeg ignores; `render` printed "Video: v.mp4" with exit 0 and
    left a file cut short that no player opens. Now it exits 2 naming the cause and the fix, and writes nothing."""
    import angora_jax.experiment.video as video

    frames = list(np.random.default_rng(0).integers(0, 256, (20, 64, 64, 3), dtype=np.uint8))
    monkeypatch.setattr(video, "render_episodes", lambda *args, **kwargs: (frames, 0.1))
    ffmpeg_with_a_full_disk(monkeypatch, 20_000)
    out = tmp_path / "v.mp4"
    assert main(["render", "--task", "ShadowHandReach", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert f"ffmpeg could not finish {out}" in err and "free space on that disk" in err, err
    assert "Traceback" not in err and list(tmp_path.iterdir()) == [], "nothing written, no draft left"


def test_a_gif_that_meets_a_full_disk_is_named_as_asked_with_no_traceback(tmp_path, capsys, monkeypatch):
    """A disk that filled up while a GIF was written: the message named no file ("No space left on device: free
    space on that disk"), and Pillow's plugin met the error again when it was collected, printing "Exception ignored
    in: <function PluginV3.__del__ ...>" and a traceback after it; a read-only folder was named by the hidden draft's
    name (.v.1234.partial.gif). Here this process's file-size limit (EFBIG) stands for the full disk."""
    import gc
    import resource
    import signal

    import angora_jax.experiment.video as video

    frames = list(np.random.default_rng(0).integers(0, 256, (20, 64, 64, 3), dtype=np.uint8))
    monkeypatch.setattr(video, "render_episodes", lambda *args, **kwargs: (frames, 0.1))
    ignored = []
    monkeypatch.setattr(sys, "unraisablehook", ignored.append)
    out = tmp_path / "v.gif"
    limits = resource.getrlimit(resource.RLIMIT_FSIZE)
    handler = signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    resource.setrlimit(resource.RLIMIT_FSIZE, (20_000, limits[1]))
    try:
        code = main(["render", "--task", "ShadowHandReach", "--out", str(out)])
        gc.collect()
    finally:
        resource.setrlimit(resource.RLIMIT_FSIZE, limits)
        signal.signal(signal.SIGXFSZ, handler)
    err = capsys.readouterr().err
    assert code == 2 and f"File too large ({out}):" in err and ".partial" not in err, err
    assert "A run stopped by it" not in err, "render stops no run: told so, users looked for harm to their run"
    assert ignored == [] and list(tmp_path.iterdir()) == [], "no traceback at collection, no draft left"


def test_an_mp4_is_written_without_jaxs_warning_that_forking_will_deadlock(tmp_path):
    """imageio-ffmpeg forks to exec ffmpeg (no Python runs in the child), and JAX warned at every such fork that it
    "will likely lead to a deadlock": on every MP4 `render`, beside a real hang elsewhere, it misled."""
    import warnings

    from angora_jax.experiment.video import write_video

    jnp.ones(3).block_until_ready()  # JAX's threads are running, as in any command that renders a policy
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        write_video([np.zeros((16, 16, 3), np.uint8)] * 4, tmp_path / "v.mp4", fps=10)
    assert (tmp_path / "v.mp4").stat().st_size > 0
    assert not [w for w in caught if "os.fork()" in str(w.message)], [str(w.message) for w in caught]


def test_the_box_plots_titles_write_large_numbers_whole():
    """Three significant digits wrote a cube policy's mean return of 1,316 as "1.32e+03" in the box plot's title, and
    CartPole's 499.9 as 500, a perfect score it did not reach."""
    from angora_jax.experiment.evaluation import _number

    assert [_number(x) for x in (499.9, 1316.3, -365.2, 45.89, 0.4923, 2.5e-4, 0.0, 123456.7)] == [
        "499.9", "1,316.3", "-365.2", "45.89", "0.4923", "0.00025", "0", "123,457"]


@pytest.mark.parametrize("options, message", [
    ({"save": None}, r"^save is True \(into RUN_DIR/evaluation\), False \(nothing written\) or a folder to write into; "
                     r"got None \(NoneType\)\.$"),
    ({"stochastic": "no"}, r"^stochastic must be True or False, got 'no' \(str\): a non-empty string counts as "
                           r"True\.$"),
])
def test_evaluate_refuses_a_save_or_stochastic_of_the_wrong_kind_before_loading_anything(tmp_path, options, message):
    """evaluate(save=None) failed in pathlib ("expected str, bytes or os.PathLike object, not NoneType"), and
    stochastic="no" sampled actions, as "no" is a true value, evaluating the wrong policy without a word."""
    with pytest.raises(TypeError, match=message):
        evaluate(tmp_path / "not-even-a-run", episodes=1, **options)


@pytest.mark.parametrize("size, given", [({"width": "320"}, "'320' x 240"), ({"height": 2.5}, "320 x 2.5"),
                                         ({"width": 0}, "0 x 240")])
def test_frames_of_no_whole_number_of_pixels_are_refused_before_anything_is_made(tmp_path, size, given):
    """render_frames(width="320") failed comparing text with a number ("'<' not supported between instances of 'str'
    and 'int'") once the task was made, and render_video's MP4 check failed on it with "not all arguments converted
    during string formatting"."""
    message = rf"^Frames are whole numbers of pixels, at least 1 x 1: width and height, got {re.escape(given)}\.$"
    with pytest.raises(ValueError, match=message):
        aj.render_frames(task="Reacher", **size)
    with pytest.raises(ValueError, match=message):
        evaluation_video(tmp_path / "v.mp4", size)
    assert list(tmp_path.iterdir()) == []


def evaluation_video(out, size):
    from angora_jax.experiment.video import render_video

    return render_video(out, task="Reacher", **size)
