"""Smoke tests of the benchmark scripts at tiny sizes on pure-JAX tasks (no MJX compiles): the Brax adapter, Brax's
PPO and ours side by side, and rungs of the throughput ladder, each in its own process."""

import json
import math
import os
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import yaml
from benchmark_results import BENCHMARKS, results
from brax.envs.wrappers import training as brax_training
from quick_compile import QUICK_SUBPROCESS, QUICK_SUBPROCESS_NO_FUSION_EMITTERS
from scipy import stats

from angora_jax.envs.registry import make
from angora_jax.experiment import load_config, validate
from angora_jax.experiment.config import to_dict

sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "benchmarks"))
import angorapy_ratio  # noqa: E402
import brax_side_by_side as side  # noqa: E402
import checkpoint_cost  # noqa: E402
import head_sampling  # noqa: E402
import ihom_curve  # noqa: E402
import paper_figures  # noqa: E402
import snapshot_evaluations  # noqa: E402
import throughput_ladder  # noqa: E402
import train_past_solve  # noqa: E402

EPISODE = 4
# Pendulum's worst step costs pi^2 + 0.1 * 8^2 + 0.001 * 2^2.
WORST_STEP = math.pi**2 + 6.4 + 0.004

# Every program this file compiles trains or times a few tiny cycles, and so do those of the processes that the ladder
# and time_to_solve start (QUICK_SUBPROCESS; the ladder's and paper_figures' also with XLA's CPU fusion emitters off:
# time_to_solve's learning keeps them): all compile quickly (tests/quick_compile.py).
pytestmark = pytest.mark.usefixtures("quick_file_compiles")


@pytest.fixture(scope="module")
def pendulum():
    return make("Pendulum", max_episode_steps=EPISODE)


def test_adapter_steps_like_the_env_and_leaves_time_limits_to_brax(pendulum):
    wrapped = brax_training.wrap(side.BraxAdapter(pendulum), episode_length=EPISODE)
    keys = jax.random.split(jax.random.PRNGKey(0), 3)
    state = jax.jit(wrapped.reset)(keys)
    ours = jax.vmap(pendulum.reset)(keys)
    first = state.obs["state"]
    np.testing.assert_allclose(first, ours.obs.proprioception)
    assert state.obs["privileged_state"].shape == (3, 3)  # Pendulum has no asymmetric inputs
    assert side.BraxAdapter(pendulum).observation_size == {"state": (3,), "privileged_state": (3,)}
    step = jax.jit(wrapped.step)
    action = jnp.full((3, 1), 5.0)  # beyond the torque bound: clipped to 2 as our Gaussian head would
    for t in range(1, EPISODE + 1):
        state = step(state, action)
        ours, _ = jax.vmap(pendulum.advance)(ours, jnp.full((3, 1), 2.0))
        np.testing.assert_allclose(state.reward, ours.reward, rtol=1e-5)
        # Episodes end at Brax's episode limit as truncations, not terminations (which would stop bootstrapping).
        assert state.done.tolist() == [float(t == EPISODE)] * 3
        assert state.info["truncation"].tolist() == [float(t == EPISODE)] * 3
    np.testing.assert_allclose(state.obs["state"], first)  # Brax's auto-reset returns to the first state


def test_discrete_tasks_are_refused_by_name():
    with pytest.raises(ValueError, match="CartPole has discrete actions"):
        side.BraxAdapter(make("CartPole"))


@pytest.mark.slow
def test_side_by_side_trains_both_for_the_same_env_steps(pendulum):
    settings = side.Settings(num_envs=8, rollout_length=4, minibatches=2, epochs=1, width=16, learning_rate=3e-4,
                             entropy_coef=0.01, init_log_std=-1.0, gamma=0.99, cycles_per_snapshot=1, snapshots=2,
                             seed=0)
    result = side.compare(pendulum, settings.plan(pendulum), eval_envs=4, env_alone=True, target=-1e9)
    assert [row["trainer"] for row in result["rows"]] == ["angora_jax", "brax"]
    for row, curve in zip(result["rows"], result["curves"].values(), strict=True):
        assert row["env_steps"] == settings.env_steps == 64
        assert row["env_steps_per_s"] > 0 and row["train_wall_s"] > 0 and row["env_alone_steps_per_s"] > 0
        assert -WORST_STEP * EPISODE <= row["final_return"] <= 0
        assert row["final_return"] == curve[-1]["episode_return"], "the last snapshot's evaluated return"
        # any return passes -1e9: the first snapshot's time is the time to it (first_snapshot_past is tested alone)
        assert (row["seconds_to_target"], row["env_steps_to_target"]) == (curve[0]["train_wall_s"], 32)
    for curve in result["curves"].values():
        assert [point["env_steps"] for point in curve] == [32, 64]
        assert curve[0]["train_wall_s"] < curve[1]["train_wall_s"]
    ours, brax = result["rows"]
    assert ours["speed_over_brax"] == pytest.approx(ours["env_steps_per_s"] / brax["env_steps_per_s"])


@pytest.mark.slow
def test_own_recipes_train_ours_from_its_config_and_brax_from_its_recipe(pendulum):
    """`--recipes own`: our side as a config says, Brax's with a recipe of its own (here a tiny one: Brax publishes
    none for Pendulum), each to about the same env steps; a target neither reached is reported as None."""
    config = load_config("pendulum", ["ppo.num_envs=8", "ppo.rollout_length=4", "ppo.chunk_length=4",
                                      "ppo.minibatch_size=16", "ppo.num_epochs=1"])
    validate(config)
    recipe = dict(num_envs=8, batch_size=4, num_minibatches=2, unroll_length=4, num_updates_per_batch=1,
                  discounting=0.97, learning_rate=3e-4, entropy_cost=1e-2, reward_scaling=1.0)
    plan = side.own_plan(pendulum, config.ppo, recipe, timesteps=64, snapshots=2)
    assert plan.ours.num_cycles == 2 and plan.brax["num_timesteps"] == 64 and plan.brax["num_evals"] == 3
    assert plan.brax["episode_length"] == EPISODE and plan.brax["reward_scaling"] == 1.0
    result = side.compare(pendulum, plan, eval_envs=4, target=1e9)
    for row, curve in zip(result["rows"], result["curves"].values(), strict=True):
        assert [point["env_steps"] for point in curve] == [32, 64] and row["env_steps"] == 64
        assert -WORST_STEP * EPISODE <= row["final_return"] <= 0
        assert row["seconds_to_target"] is None and row["target"] == 1e9
    assert side.brax_recipe("HalfCheetah")["discounting"] == 0.95
    with pytest.raises(ValueError, match="no PPO recipe for Hopper.*SAC.*HalfCheetah"):
        side.brax_recipe("Hopper")
    assert side.brax_changes(["num_envs=16", "reward_scaling=0.5"]) == {"num_envs": 16, "reward_scaling": 0.5}
    with pytest.raises(ValueError, match="KEY=VALUE.*'num_envs'"):
        side.brax_changes(["num_envs"])
    with pytest.raises(ValueError, match="no argument 'ppo.num_envs'"):
        side.brax_changes(["ppo.num_envs=16"])


@pytest.mark.slow
def test_ladder_measures_each_rung_in_its_own_process_and_reports_failures(monkeypatch):
    for name, value in QUICK_SUBPROCESS_NO_FUSION_EMITTERS.items():
        monkeypatch.setenv(name, value)
    settings = {"options": {}, "steps": 2, "rollout_length": 4, "chunk_length": 4, "minibatches": 2, "epochs": 1,
                "model": "simple", "repeats": 1}
    good, bad = throughput_ladder.ladder(["Pendulum", "NoSuchTask"], [4], settings, jobs=2)
    assert good["task"] == "Pendulum" and good["num_envs"] == 4 and "error" not in good
    assert good["raw_env_steps_per_s"] is None  # no MJX physics
    assert good["env_env_steps_per_s"] > 0 and good["train_env_steps_per_s"] > 0
    assert good["train_over_env"] == pytest.approx(good["train_env_steps_per_s"] / good["env_env_steps_per_s"])
    assert good["train_sim_s_per_s"] == pytest.approx(good["train_env_steps_per_s"] * 0.05)
    assert "NoSuchTask" in bad["error"]


def test_angorapy_ratio_divides_our_measured_rate_by_the_papers():
    record = {"benchmark": "train_throughput", "device": {"count": 1, "kind": "GPU"},
              "config": {"args": {"task": "ShadowHandCube"}, "control_dt_s": 0.08},
              "results": [{"model": "simple", "num_envs": 8, "train_env_steps_per_s": 6886.6}]}
    (row,) = angorapy_ratio.ratios(record)
    assert angorapy_ratio.angorapy_samples_per_s() == pytest.approx(1.19e9 / (96 * 3600))
    assert row["ratio"] == pytest.approx(2.0, rel=1e-4)
    assert row["sim_s_per_s"] == pytest.approx(6886.6 * 0.08)
    record["config"]["args"]["task"] = "ShadowHandReach"
    with pytest.raises(ValueError, match="ShadowHandCube"):
        angorapy_ratio.ratios(record)


def test_checkpoint_cost_puts_each_save_in_the_gap_before_the_next_cycle(tmp_path):
    """A record's time is taken before its cycle's saves: here a best save costs 2 s, a latest (every 3 cycles) 1 s,
    and they show in the next record's gap. Cycle 6 starts a resumed piece (it has `compile_seconds`): the gap after
    cycle 5 holds the restart and is left out, though cycle 5's best counts for the bests after it."""
    run = tmp_path / "run"
    run.mkdir()
    (run / "config.yaml").write_text(yaml.safe_dump(to_dict(load_config("cartpole", ["checkpoint.every=3",
                                                                                  "checkpoint.best_metric=episode_return"]))))
    returns = [1.0, 2.0, 2.0, 1.0, 3.0, 1.0, 4.0]  # new bests after cycles 1, 2, 5 and 7
    rows, time = [], 100.0
    for cycle, value in enumerate(returns, start=1):
        if cycle == 6:
            time += 60.0  # a restart before cycle 6: the next gap is no save's
        time += 1.0  # the cycle's own second
        rows.append({"cycle": cycle, "seconds": 1.0, "episode_return": value, "time": time}
                    | ({"compile_seconds": 1.0} if cycle in (1, 6) else {}))
        time += 2.0 * (value == max(returns[:cycle]) and value not in returns[:cycle - 1]) + 1.0 * (cycle % 3 == 0)
    (run / "metrics.jsonl").write_text("".join(json.dumps(row) + "\n" for row in rows))
    out = tmp_path / "cost.json"
    checkpoint_cost.main([f"tiny={run}", "--name", "tiny", "--out", str(out)])
    found = {row["saved"]: row for row in json.loads(out.read_text())["results"]}
    assert {name: row["cycles"] for name, row in found.items()} == {"best": 2, "latest": 2, "none": 1, "any": 4}
    assert found["best"]["median_gap_s"] == pytest.approx(2.0) and found["latest"]["median_gap_s"] == pytest.approx(1.0)
    assert found["none"]["mean_gap_s"] == pytest.approx(0.0, abs=1e-9)
    assert found["any"]["share_of_wall"] == pytest.approx(6.0 / 11.0), "2 + 2 + 1 + 1 s of saves, 5 cycles of 1 s"


@pytest.mark.slow
def test_time_to_solve_reports_each_seed_and_their_spread(tmp_path):
    out = tmp_path / "tts.json"
    script = os.path.join(os.path.dirname(side.__file__), "time_to_solve.py")
    # Random play scores about 22 on CartPole; at learning rate 3e-3 both seeds pass 50 in cycle 5 of 512 env steps
    # (measured: 61.5 and 65.5 there, 38.0 and 36.0 in cycle 4).
    subprocess.run([sys.executable, script, "--seeds", "0", "1", "--target", "episode_return=50", "--minutes", "1",
                    "--out", str(out), "--", "--task", "CartPole", "--cycles", "10", "--width", "16",
                    "--learning-rate", "3e-3"], check=True, env=os.environ | QUICK_SUBPROCESS)
    record = json.loads(out.read_text())
    rows, summary = record["results"], record["config"]["summary"]
    assert [r["seed"] for r in rows] == [0, 1]
    assert summary["seeds"] == 2 and summary["solved"] == sum(r["solved"] for r in rows)
    solved = [r for r in rows if r["solved"]]
    assert len(solved) == 2, "both seeds learn CartPole past a return of 50 within 10 cycles"
    assert all(3 * 512 <= r["env_steps"] <= 10 * 512 for r in solved), "learning, not luck, reached it"
    assert summary["env_steps"]["min"] == min(r["env_steps"] for r in solved)
    assert all(r["wall_seconds"] > 0 and r["env_steps"] <= r["steps_run"] for r in solved)


@pytest.mark.slow
def test_profile_splits_a_cycles_device_time_by_phase(tmp_path):
    out = tmp_path / "profile.json"
    script = os.path.join(os.path.dirname(side.__file__), "profile_cycle.py")
    settings = ["ppo.num_envs=4", "ppo.rollout_length=8", "ppo.chunk_length=8", "ppo.minibatch_size=16",
                "ppo.num_epochs=1", "distribution.num_devices=2"]  # the data-parallel cycle, which covers D = 1's code
    subprocess.run([sys.executable, script, "pendulum", *settings, "--cycles", "1", "--trace-dir",
                    str(tmp_path / "trace"), "--out", str(out)], check=True,
                   env=os.environ | {"XLA_FLAGS": "--xla_force_host_platform_device_count=2"})
    record = json.loads(out.read_text())
    assert record["config"]["summary"]["devices"] == 2
    phases = {row["phase"]: row for row in record["results"]}
    assert phases["collectives"]["kernels"] > 0  # the all-reduces, apart from the phase they serve
    # Every phase of the cycle ran kernels, and the ops XLA adds without a scope inherit their loop's phase.
    assert {"env step", "acting", "updates"} <= set(phases)
    assert all(phases[p]["device_s"] > 0 for p in ("env step", "acting", "updates"))
    assert "unattributed" not in phases
    assert sum(row["share"] for row in record["results"]) == pytest.approx(1.0)
    summary = record["config"]["summary"]
    assert summary["device_busy_s_per_cycle"] == pytest.approx(sum(row["device_s"] for row in record["results"]))
    assert os.path.exists(summary["trace"]) and summary["top_kernels"]


def test_ihom_curve_joins_pieces_by_cycle_and_finds_the_milestones(tmp_path, monkeypatch):
    """Two pieces of one run: the second recomputed cycle 3 after resuming from cycle 2's checkpoint and replaces it.
    Wall time counts the gap between a piece's cycles, training time only the cycles' own seconds."""
    def row(cycle, cgr, time, compile=None):
        record = {"cycle": cycle, "env_steps": 100 * cycle, "seconds": 2.0, "time": time, "episode_return": cgr,
                  "metric/goals_reached": cgr, "metric/dropped": 0.1, "metric/goal_distance": 1.0}
        return record | ({"compile_seconds": compile} if compile else {})

    first = [row(1, 0.5, 100.0, compile=1.5), row(2, 4.0, 103.0), row(3, 99.0, 106.0)]
    second = [row(3, 6.0, 500.0, compile=1.5), row(4, 12.0, 504.0)]
    for name, rows in (("a.jsonl", first), ("b.jsonl", second)):
        (tmp_path / name).write_text("".join(json.dumps(r) + "\n" for r in rows))
    rows = ihom_curve.read_pieces([str(tmp_path / "a.jsonl"), str(tmp_path / "b.jsonl")])
    assert [r["metric/goals_reached"] for r in rows] == [0.5, 4.0, 6.0, 12.0]
    assert [r["train_seconds"] for r in rows] == [2.0, 4.0, 6.0, 8.0]
    assert [r["wall_seconds"] for r in rows] == [2.0, 5.0, 7.0, 11.0]
    found = {m["cgr"]: m for m in ihom_curve.milestones(rows)}
    assert found[1]["cycle"] == 2 and found[5]["cycle"] == 3 and found[10]["env_steps"] == 400
    assert found[20]["cycle"] is None and found[30]["cycle"] is None
    monkeypatch.setattr(ihom_curve, "study_folder", lambda study: str(tmp_path))
    pieces = f"run={tmp_path / 'a.jsonl'},{tmp_path / 'b.jsonl'}"
    assert ihom_curve.main([pieces, "--device", "cpu", "--name", "t"]) == 0
    record = json.loads((tmp_path / "ihom_curve_t.json").read_text())
    (curve,) = record["curves"]["run"]  # one list of rows per run of the label
    assert record["training_device"] == "cpu" and len(curve) == 4
    assert (tmp_path / "ihom_curve_t.png").read_bytes()[:4] == b"\x89PNG"
    # Run again by another process (a committed result is there): a new name for the JSON and its figure together.
    import common

    monkeypatch.setattr(common, "_CHOSEN", {})
    written = {path: path.read_bytes() for path in tmp_path.glob("ihom_curve_t.*")}
    assert ihom_curve.main([pieces, "--device", "cpu", "--name", "t"]) == 0
    assert {path: path.read_bytes() for path in tmp_path.glob("ihom_curve_t.*")} == written
    assert (tmp_path / "ihom_curve_t-2.png").exists() and json.loads((tmp_path / "ihom_curve_t-2.json").read_text())
    # A fine-tuned run continues its base's curve; time its route spent elsewhere first goes on its wall clock.
    tuned = tmp_path / "tuned.jsonl"
    tuned.write_text(json.dumps(row(1, 20.0, 900.0, compile=1.5)) + "\n")
    assert ihom_curve.main([pieces, f"tuned={tuned}", "--continues", "tuned=run", "--before", "tuned=0.5",
                            "--device", "cpu", "--name", "t2"]) == 0
    record = json.loads((tmp_path / "ihom_curve_t2.json").read_text())
    ((point,),) = record["curves"]["tuned"]
    assert point["env_steps"] == 500 and point["train_seconds"] == 10.0 and point["wall_seconds"] == 11.0 + 2.0 + 30.0
    assert record["before_minutes"] == {"tuned": 0.5} and record["continues"] == {"tuned": "run"}
    with pytest.raises(SystemExit, match="LABEL=MINUTES"):
        ihom_curve.main([pieces, "--before", "run=soon", "--device", "cpu", "--name", "t3"])
    with pytest.raises(SystemExit, match="the label ends at the first '='"):  # a label "blocks.count=2"
        ihom_curve.main([f"blocks.count=2={tmp_path / 'a.jsonl'}", "--device", "cpu", "--name", "t4"])


def test_ihom_curve_gives_seed_statistics_and_each_runs_peak_and_fall(tmp_path, monkeypatch):
    """Three seeds under one label: the milestones' mean and Student's t 95% interval over the seeds that reached
    each; every run's 5-cycle peak, last value and time past the peak; --seeds refuses another count."""
    def run(name, cgr):
        rows = [{"cycle": c + 1, "env_steps": 100 * (c + 1), "seconds": 1.0, "time": 1000.0 + c, "metric/goals_reached":
                 value} for c, value in enumerate(cgr)]
        (tmp_path / name).write_text("".join(json.dumps(r) + "\n" for r in rows))
        return f"fast={tmp_path / name}"

    rising = [0, 2, 6, 11, 21, 31, 40, 40, 40, 40, 40, 20, 20, 20, 20, 20]  # peaks at 40, ends at 20
    seeds = [run("a.jsonl", rising), run("b.jsonl", [0, 0, *rising[:-2]]), run("c.jsonl", [0] * 16)]
    monkeypatch.setattr(ihom_curve, "study_folder", lambda study: str(tmp_path))
    assert ihom_curve.main([*seeds, "--seeds", "3", "--device", "cpu", "--name", "s"]) == 0
    record = json.loads((tmp_path / "ihom_curve_s.json").read_text())
    thirty = {row["cgr"]: row for row in record["seed_milestones"]["fast"]}[30]
    assert thirty["reached"] == 2 and thirty["num_seeds"] == 3, "seed c never reaches 30"
    assert thirty["env_steps"]["mean"] == 700 and thirty["env_steps"]["n"] == 2  # cycles 6 and 8
    assert thirty["env_steps"]["ci95"] == pytest.approx(12.706 * 100, rel=1e-3)  # t(0.975, 1) x sem of 600, 800
    first = record["stability"]["fast"][0]
    assert first["peak"] == 40 and first["peak_cycle"] == 11 and first["final"] == 20
    assert first["fraction_of_peak"] == 0.5 and first["cycles_past_peak"] == 5
    assert first["solve_time_multiple"] == pytest.approx(16 / 6)  # 16 wall seconds, CGR 30 first at the 6th
    assert record["stability"]["fast"][2]["peak"] == 0 and record["stability"]["fast"][2]["solve_time_multiple"] is None
    assert (tmp_path / "ihom_curve_s.png").read_bytes()[:4] == b"\x89PNG"
    with pytest.raises(SystemExit, match="'fast' has 3 run"):
        ihom_curve.main([*seeds, "--seeds", "5", "--device", "cpu", "--name", "s2"])


def test_ihom_curve_draws_the_seeds_band_while_all_run_and_each_seed_to_its_own_end():
    """A seed that stops early (here after 3 cycles) ends the band, not the other seeds' lines: each seed's CGR is drawn
    to its last cycle in both CGR panels, so a seed stopped at CGR 30 still shows reaching it."""
    def rows(cycles):
        return [{"env_steps": 100 * c, "wall_seconds": 60.0 * c, ihom_curve.CGR: 10.0 * c}
                for c in range(1, cycles + 1)]

    fig = ihom_curve.figure({"fast": [rows(3), rows(5), rows(4)]}, "t")
    try:
        for ax, scale in ((fig.axes[0], 100), (fig.axes[1], 1)):
            ends = sorted(max(line.get_xdata()) * 100 / scale for line in ax.get_lines())
            assert ends == [300, 300, 400, 500], "the band's mean to the shortest seed, then each seed to its end"
            assert max(max(line.get_ydata()) for line in ax.get_lines()) == 50.0
    finally:
        ihom_curve.plt.close(fig)


def test_ihom_curve_reports_time_to_solve_efficiency_against_the_fewest_devices(tmp_path, monkeypatch):
    """One GPU reaches CGR 30 at wall minute 8 (its first cycle compiles for 60 s), four GPUs at minute 2.5 (the same
    compile): efficiency 8 x 1 / (2.5 x 4) = 0.8 with compiles, 7 / (1.5 x 4) without; a label that never reaches 30
    gets None, and a device count that is not one exits with the fix."""
    def run(name, minutes, cgr_at_end):
        cycles = int(minutes)
        rows = [{"cycle": 1, "env_steps": 100, "seconds": 60.0, "compile_seconds": 60.0, "time": 60.0,
                 "metric/goals_reached": 0.0}]
        step = (minutes * 60 - 60.0) / (cycles - 1)
        rows += [{"cycle": c, "env_steps": 100 * c, "seconds": step, "time": 60.0 + step * (c - 1),
                  "metric/goals_reached": cgr_at_end if c == cycles else 1.0} for c in range(2, cycles + 1)]
        (tmp_path / name).write_text("".join(json.dumps(r) + "\n" for r in rows))
        return str(tmp_path / name)

    monkeypatch.setattr(ihom_curve, "study_folder", lambda study: str(tmp_path))
    runs = [f"one={run('one.jsonl', 8, 31.0)}", f"four={run('four.jsonl', 2.5, 30.0)}",
            f"never={run('never.jsonl', 4, 29.0)}"]
    assert ihom_curve.main([*runs, "--devices", "four=4", "--devices", "one=1", "--devices", "never=2",
                            "--device", "cpu", "--name", "e"]) == 0
    rows = {row["label"]: row for row in json.loads((tmp_path / "ihom_curve_e.json").read_text())["scaling"]}
    assert rows["one"]["devices"] == 1 and rows["one"]["time_to_solve_efficiency"] == pytest.approx(1.0)
    assert rows["four"]["wall_minutes"] == pytest.approx(2.5) and rows["four"]["compiled_minutes"] == pytest.approx(1.5)
    assert rows["four"]["time_to_solve_efficiency"] == pytest.approx(0.8)
    assert rows["four"]["time_to_solve_efficiency_compiled"] == pytest.approx(7 / 6)
    assert rows["never"]["reached"] == 0 and rows["never"]["time_to_solve_efficiency"] is None
    with pytest.raises(SystemExit, match="LABEL=N"):
        ihom_curve.main([*runs, "--devices", "four=many", "--device", "cpu", "--name", "e2"])


def test_train_past_solve_stops_at_the_first_cycle_past_the_multiple():
    """Reached at wall second 20 (cycle 2, after a 10 s compile); at 2x the run stops at the first cycle whose wall
    clock is 40 s or more, not before, and never without having reached the bar."""
    records = [{"cycle": c, "env_steps": 100 * c, "seconds": 10.0, "time": 10.0 * c,
                "metric/goals_reached": 31.0 if c >= 2 else 5.0}
               for c in range(1, 6)]
    records[0]["compile_seconds"] = 10.0
    clocked = ihom_curve.with_clocks(records)
    assert [r["wall_seconds"] for r in clocked] == [10.0, 20.0, 30.0, 40.0, 50.0]
    stops = [train_past_solve.should_stop(clocked[:n], ihom_curve.CGR, 30, 2.0) for n in range(1, 6)]
    assert stops == [False, False, False, True, True]
    assert not train_past_solve.should_stop(clocked, ihom_curve.CGR, 40, 1.0), "never reached: never stopped"
    # A run that ended (its cycles, --minutes) before any episode did, or at CGR 0 throughout: no ratio, no crash.
    for value in (math.nan, 0.0):
        summary = train_past_solve.summary([{**r, ihom_curve.CGR: value} for r in clocked], ihom_curve.CGR, 30)
        assert summary["reached_cycle"] is None and summary["fraction_of_peak"] is None, summary
        assert summary["stopped_cycle"] == 5 and summary["solve_time_multiple"] is None


@pytest.mark.slow  # a training run and two evaluations; the stopping rule's fast counterpart is the test above
def test_train_past_solve_trains_stops_and_evaluates_best_and_latest(tmp_path, capsys):
    """CartPole's return passes 40 in its first cycles; the run is stopped by its own SIGINT at 1.5 times that wall
    time, with a checkpoint of that cycle, and both checkpoints are evaluated and summarised. The same run name again,
    or a misspelt key, exits 2 with the library's message, the run untouched."""
    out = tmp_path / "summary.json"
    # Cycles to spare: the stop comes at 1.5 times the wall time of the cycle that passed 40, which includes the first
    # cycle's compile; on a loaded machine that compile grew while the cycles after it did not, and 60 cycles ended
    # before the stop (stopped_cycle 60).
    assert train_past_solve.main(["cartpole", "ppo.num_cycles=1000", f"logging.run_root={tmp_path}",
                                  "logging.run_name=a", "--metric", "episode_return", "--bar", "40",
                                  "--multiple", "1.5", "--episodes", "8", "--out", str(out)]) == 0
    (result,) = results(out, "train_past_solve")["results"]
    rows = ihom_curve.read_pieces([str(tmp_path / "a")])
    reached = ihom_curve.first_reaching(rows, 40, "episode_return")
    assert result["reached_cycle"] == reached["cycle"] and result["stopped_cycle"] == rows[-1]["cycle"] < 1000
    assert rows[-1]["wall_seconds"] >= 1.5 * reached["wall_seconds"] > rows[-2]["wall_seconds"], "the first cycle past"
    assert result["solve_time_multiple"] == pytest.approx(rows[-1]["wall_seconds"] / reached["wall_seconds"])
    assert result["evaluations"]["latest"]["cycle"] == rows[-1]["cycle"], "a checkpoint of the cycle it stopped after"
    for evaluation in result["evaluations"].values():
        assert os.path.exists(evaluation["json"]) and evaluation["stderr"] >= 0
    assert 0 < result["fraction_of_peak"] <= 1.0 and result["final"] <= result["peak"]
    saved = (tmp_path / "a" / "metrics.jsonl").read_bytes()
    capsys.readouterr()
    for mistake, said in ((["logging.run_name=a", "--metric", "episode_return"], "exists and is left untouched"),
                          (["logging.run_name=b", "ppo.num_cyles=9"], "Did you mean 'ppo.num_cycles'?"),
                          (["logging.run_name=b", "--metric", "episode_retrun"], "Did you mean 'episode_return'?"),
                          (["logging.run_name=b"], "'metric/goals_reached' is not a training metric of CartPole")):
        assert train_past_solve.main(["cartpole", f"logging.run_root={tmp_path}", *mistake]) == 2
        assert said in capsys.readouterr().err
    assert (tmp_path / "a" / "metrics.jsonl").read_bytes() == saved and not (tmp_path / "b").exists()


@pytest.mark.slow
def test_paper_figures_runs_each_task_and_head_per_seed_and_says_which_head_won(tmp_path):
    script = os.path.join(os.path.dirname(side.__file__), "paper_figures.py")
    # Smoke runs of two cycles: compiling is nearly all of their time, so XLA compiles them quickly, its CPU fusion
    # emitters off (QUICK_SUBPROCESS_NO_FUSION_EMITTERS: the script's processes set no XLA_FLAGS of their own).
    subprocess.run([sys.executable, script, "--figure", "8", "--tasks", "Pendulum", "--seeds", "3", "--parallel", "2",
                    "--smoke", "--evaluate", "3", "--out", str(tmp_path), "--name", "fig8"], check=True,
                   env=os.environ | QUICK_SUBPROCESS_NO_FUSION_EMITTERS)
    record = json.loads((tmp_path / "fig8.json").read_text())
    runs = record["runs"]
    assert sorted((r["head"], r["seed"]) for r in runs) == [("beta", 3), ("gaussian", 3)]
    assert all(r["cycles"] == 2 and len(r["curve"]["episode_return"]) == 2 and r["wall_seconds"] > 0 for r in runs)
    comparison = record["comparison"]["Pendulum"]
    means = {head: stats["mean"] for head, stats in comparison["heads"].items()}
    assert comparison["highest"] == max(means, key=means.get) and comparison["heads"]["beta"]["seeds"] == 1
    assert comparison["better"] is None and comparison["p_value"] is None, "one seed per head: nothing to test"
    assert (tmp_path / "fig8.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert all(len(r["curve"]["seconds"]) == 2 and r["target"] is None for r in runs), "Pendulum has no target"
    assert all(len(r["curve"]["entropy"]) == 2 and r["curve"]["episode_length"][-1] > 0 for r in runs), "diagnostics"
    for run in runs:  # the final policy's mode on 3 whole episodes of Pendulum's 200 steps
        assert run["evaluation"]["episodes"] == 3 and run["evaluation"]["episode_length"] == 200.0
        assert -16.3 * 200 <= run["evaluation"]["return"] <= 0.0, "Pendulum's cost per step lies in [0, 16.3]"

    # runs of separate invocations (here the same runs again, 3 higher, as seed 4) combine into one figure
    later = [{**run["curve"], "episode_return": [x if x is None else x + 3.0 for x in run["curve"]["episode_return"]]}
             for run in runs]
    other = {**record, "runs": [{**run, "seed": 4, "target": {"stale": True}, "curve": curve}
                                for run, curve in zip(runs, later, strict=True)]}
    (tmp_path / "other.json").write_text(json.dumps(other))
    # (in this process: the training above and the --replace merge below go through the command line)
    paper_figures.merge("8", [str(tmp_path / "fig8.json"), str(tmp_path / "other.json")], "merged", str(tmp_path))
    merged = json.loads((tmp_path / "merged.json").read_text())
    assert sorted((r["head"], r["seed"]) for r in merged["runs"]) == [("beta", 3), ("beta", 4), ("gaussian", 3),
                                                                       ("gaussian", 4)]
    assert all(run["target"] is None for run in merged["runs"]), "targets are taken again from the curves"
    pendulum = merged["comparison"]["Pendulum"]
    assert pendulum["heads"]["beta"]["seeds"] == 2 and 0.0 <= pendulum["p_value"] <= 1.0
    # The verdict is Welch's t-test (scipy's, here) between the two heads' seeds at equal env steps.
    at = {head: [paper_figures.return_at(r, pendulum["env_steps"]) for r in merged["runs"] if r["head"] == head]
          for head in ("beta", "gaussian")}
    welch = stats.ttest_ind(at[pendulum["highest"]], at[pendulum["runner_up"]], equal_var=False).pvalue
    assert pendulum["p_value"] == pytest.approx(welch)
    assert pendulum["better"] == (pendulum["highest"] if welch < 0.05 else "level")
    assert pendulum["highest"] == max(at, key=lambda head: np.mean(at[head]))
    assert set(merged["config"]["merged"]) == {"fig8.json", "other.json"}
    # a merge of merges keeps the first outputs' configs; a run given twice is refused
    paper_figures.merge("8", [str(tmp_path / "merged.json")], "again", str(tmp_path))
    assert set(json.loads((tmp_path / "again.json").read_text())["config"]["merged"]) == {"fig8.json", "other.json"}
    with pytest.raises(SystemExit, match="Pendulum .* merged twice"):
        paper_figures.merge("8", [str(tmp_path / "fig8.json"), str(tmp_path / "merged.json")], "twice", str(tmp_path))
    # --replace keeps the later output's run and lists the earlier one; another machine's runs keep their device
    redone = {**record, "device": {**record["device"], "kind": "Other GPU", "host_cpus": 32},
              "versions": {**record["versions"], "brax": "absent"},
              "runs": [{**run, "curve": {**run["curve"], "episode_return": [7.0, 7.0]}} for run in runs
                       if run["head"] == "beta"]}
    for run in redone["runs"]:
        del run["device"]
    (tmp_path / "redone.json").write_text(json.dumps(redone))
    subprocess.run([sys.executable, script, "--figure", "8", "--merge", str(tmp_path / "merged.json"),
                    str(tmp_path / "redone.json"), "--replace", "--out", str(tmp_path), "--name", "replaced"],
                   check=True)
    replaced = json.loads((tmp_path / "replaced.json").read_text())
    by_key = {(r["head"], r["seed"]): r for r in replaced["runs"]}
    assert len(replaced["runs"]) == 4 and by_key["beta", 3]["final_return"] == 7.0
    assert by_key["beta", 3]["device"] == "Other GPU" and by_key["beta", 4]["device"] == record["device"]["kind"]
    assert replaced["device"]["kind"] == [record["device"]["kind"], "Other GPU"]
    assert [(r["head"], r["seed"], r["kept"]) for r in replaced["config"]["replaced"]] == [
        ("beta", 3, str(tmp_path / "redone.json"))]
    # an output already merged from unlike devices merges again: its lists of values join the others
    paper_figures.merge("8", [str(tmp_path / "replaced.json"), str(tmp_path / "redone.json")], "remerged",
                        str(tmp_path), replace=True)
    remerged = json.loads((tmp_path / "remerged.json").read_text())
    assert remerged["device"]["kind"] == [record["device"]["kind"], "Other GPU"]
    assert remerged["device"]["host_cpus"] == replaced["device"]["host_cpus"]
    newer = {**redone, "versions": {**record["versions"], "jax": "0.0.1"}}
    (tmp_path / "newer.json").write_text(json.dumps(newer))
    with pytest.raises(SystemExit, match="one set of versions"):
        paper_figures.merge("8", [str(tmp_path / "merged.json"), str(tmp_path / "newer.json")], "mixed",
                            str(tmp_path), replace=True)
    # results written before warp-lang was recorded (and with "absent" for what was not installed) still merge
    older = {**redone, "versions": {package: "absent" if version is None else version
                                    for package, version in record["versions"].items() if package != "warp-lang"}}
    (tmp_path / "older.json").write_text(json.dumps(older))
    paper_figures.merge("8", [str(tmp_path / "merged.json"), str(tmp_path / "older.json")], "older", str(tmp_path),
                        replace=True)
    # a run that fails in its process is named with the end of its log
    failing = subprocess.run([sys.executable, script, "--figure", "8", "--tasks", "Pendulum", "--seeds", "3",
                              "--parallel", "2", "--smoke", "--out", str(tmp_path), "--name", "bad",
                              "ppo.num_envs=0"], capture_output=True, text=True, env=os.environ | QUICK_SUBPROCESS)
    assert failing.returncode != 0 and "Every run failed" in failing.stderr and "num_envs" in failing.stderr
    assert not (tmp_path / "bad.json").exists()


@pytest.mark.parametrize("figure", ["8", "9"])
def test_every_task_of_the_paper_figures_exists(figure):
    jobs, missing = paper_figures.figure_jobs(figure, None, None, [0])
    assert missing == {}, "every task of the figure is registered (Fig. 8's LunarLander on the host path)"
    assert {task for task, *_ in jobs} == {task for task, _, _ in paper_figures.FIGURES[figure]}
    _, missing = paper_figures.figure_jobs(figure, ["NoSuchTask"], None, [0])
    assert missing == {}, "a task the figure lacks is not asked for"


def test_the_first_snapshot_past_the_target_is_the_time_to_it():
    curve = [{"episode_return": r, "train_wall_s": t, "env_steps": 32 * (t + 1)} for t, r in enumerate([-9, -2, -5, 0])]
    assert side.first_snapshot_past(curve, -2.5)["train_wall_s"] == 1
    assert side.first_snapshot_past(curve, -2.0)["env_steps"] == 64, "reaching the target counts"
    assert side.first_snapshot_past(curve, -1.0)["train_wall_s"] == 3, "the first one past it, not a later dip"
    assert side.first_snapshot_past(curve, 0.5) is None and side.first_snapshot_past(curve, None) is None


def test_paper_figures_curves_keep_the_tasks_own_metrics():
    rows = [{"env_steps": 100, "cycle": 1, "time": 50.0, "seconds": 20.0, "episode_return": 1.0,
             "metric/success": 0.25, "entropy": 3.0},
            {"env_steps": 200, "cycle": 2, "time": 52.0, "seconds": 2.0, "episode_return": float("nan"),
             "metric/success": float("nan"), "entropy": 2.5}]
    curve = paper_figures.curve_of(rows)
    assert curve["seconds"] == [20.0, 22.0], "from the run's start, its first cycle's compile included"
    assert curve["metric/success"] == [0.25, None] and curve["episode_return"] == [1.0, None]
    assert curve["entropy"] == [3.0, 2.5] and curve["value_loss"] == [None, None]


def test_paper_figures_compares_heads_at_equal_env_steps_and_times_the_target():
    curve = {"env_steps": [100, 200, 300, 400], "cycle": [1, 2, 3, 4], "seconds": [30.0, 31.0, 32.0, 33.0],
             "episode_return": [1.0, 2.0, 3.0, 4.0]}
    fast = {"task": "Walker2d", "head": "gaussian", "env_steps": 400, "curve": curve}
    slow = {"task": "Walker2d", "head": "beta", "env_steps": 200,
            "curve": {"env_steps": [100, 200], "episode_return": [2.5, 2.5]}}
    comparison = paper_figures.compare_heads([fast, slow])
    assert comparison["env_steps"] == 200, "the most env steps that every run reached"
    assert comparison["heads"]["gaussian"]["mean"] == 2.0 and comparison["highest"] == "beta"
    assert comparison["better"] is None, "one seed per head: no test"
    assert paper_figures.first_past(curve, 2.5) == {"return": 2.5, "reached": True, "seconds": 32.0,
                                                    "env_steps": 300, "cycle": 3}
    assert paper_figures.first_past(curve, 9.0)["reached"] is False
    assert paper_figures.first_past(curve, None) is None
    assert comparison["gymnasium_threshold"] is None, "Gymnasium registers no threshold for Walker2d-v5"
    assert "mode" not in comparison["heads"]["gaussian"], "no run evaluated its mode"
    evaluated = [{**run, "head": "beta", "evaluation": {"return": value, "metric/success": success}}
                 for run, value, success in ((fast, 1000.0, 1.0), (slow, 900.0, 0.5))]
    modes = paper_figures.compare_heads(evaluated)["heads"]["beta"]["mode"]
    assert modes == {"mean": 950.0, "std": pytest.approx(70.71, abs=0.01), "metric/success": 0.75}
    partly = paper_figures.compare_heads([evaluated[0], {**slow, "head": "beta"}])
    assert "mode" not in partly["heads"]["beta"], "modes are compared only where every run of the head has one"
    assert paper_figures.gymnasium_threshold("Hopper") == 3800.0
    assert paper_figures.gymnasium_threshold("CartPole") == 475.0
    assert paper_figures.gymnasium_threshold("gym:LunarLander-v3") == 200.0
    assert paper_figures.gymnasium_threshold("ShadowHandReach") is None
    passed = paper_figures.compare_heads([{**fast, "task": "Swimmer", "final_return": 400.0},
                                          {**slow, "task": "Swimmer", "final_return": 300.0}])
    assert passed["gymnasium_threshold"] == 360.0
    assert passed["heads"]["gaussian"]["passed"] == 1 and passed["heads"]["beta"]["passed"] == 0
    # Over seeds, a head is better only where Welch's t-test says so; otherwise the heads are level.
    def seeds(head, returns):
        return [{**fast, "head": head, "seed": i, "curve": {**curve, "episode_return": [r] * 4}}
                for i, r in enumerate(returns)]

    apart = paper_figures.compare_heads(seeds("gaussian", [1.0, 1.1, 0.9]) + seeds("beta", [5.0, 5.2, 4.9]))
    assert (apart["better"], apart["runner_up"]) == ("beta", "gaussian") and apart["p_value"] < 0.05
    assert paper_figures.verdict(apart).startswith("beta > gaussian (p=")
    close = paper_figures.compare_heads(seeds("gaussian", [1.0, 2.0, 3.0]) + seeds("beta", [1.5, 2.5, 3.5]))
    assert close["highest"] == "beta" and close["better"] == "level" and close["p_value"] > 0.5
    solved = paper_figures.compare_heads(seeds("gaussian", [500.0] * 3) + seeds("beta", [500.0] * 3))
    assert solved["better"] == "level" and solved["p_value"] == 1.0
    # A solved InvertedPendulum: its episodes all last 1,000 steps and end in the same cycles, none in the others.
    assert paper_figures.tail_mean([10.0, None, 1000.0, float("nan"), None]) == 1000.0
    assert paper_figures.tail_mean([None, float("nan")]) is None


@pytest.mark.slow
def test_head_sampling_times_every_head_and_counts_betas_rejection_loops(tmp_path):
    path = head_sampling.main(["--task", "Pendulum", "--num-envs", "8", "--rollout-length", "2", "--repeats", "1",
                               "--out", str(tmp_path / "heads.json")])
    rows = {row["head"]: row for row in json.loads(open(path).read())["results"]}
    assert set(rows) == set(head_sampling.HEADS) and rows["gaussian"]["over_gaussian"] == 1.0
    assert all(row["seconds"] > 0 and row["draws_per_s"] == 16 / row["seconds"] for row in rows.values())
    assert rows["beta"]["while_loops"] > rows["gaussian"]["while_loops"], "jax.random.gamma rejects in a loop"


def test_paper_figures_spreads_its_processes_over_the_gpus():
    assert paper_figures.gpu_slots(3, [], None) == [None, None, None], "no GPU: nothing to choose"
    assert paper_figures.gpu_slots(5, [0, 1], None) == ["0", "1", "0", "1", "0"]
    # JAX's ids index into this process's own CUDA_VISIBLE_DEVICES, which names the physical GPUs
    assert paper_figures.gpu_slots(3, [0, 1], "2, 5") == ["2", "5", "2"]
    assert paper_figures.gpu_slots(2, [1], "3,7") == ["7", "7"]


def test_snapshot_evaluations_set_each_snapshot_beside_the_training_mean_since_the_previous(tmp_path):
    """Cycles without ended episodes are left out of the window's mean; stochastic evaluations are not snapshots."""
    run = tmp_path / "run"
    (run / "evaluation").mkdir(parents=True)
    rows = [{"cycle": c, "env_steps": 10 * c, "episodes": 0 if c == 2 else 5, "episode_return": float(c),
             "episode_length": 2.0 * c, "entropy": 1.0 / c} for c in range(1, 5)]
    (run / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    (run / "sessions.jsonl").write_text(json.dumps({"devices": [{"kind": "cpu"}], "versions": {}}) + "\n")

    def evaluation(cycle, stochastic=False, value=100.0):
        summary = {"episode_return": {"mean": value, "stderr": 1.0}, "episode_length": {"mean": 50.0}}
        return {"cycle": cycle, "stochastic": stochastic, "task": "Hopper", "episodes": 8, "summary": summary}

    for name, record in (("a.json", evaluation(2)), ("b.json", evaluation(4, value=80.0)),
                         ("c.json", evaluation(3, stochastic=True))):
        (run / "evaluation" / name).write_text(json.dumps(record))
    table = snapshot_evaluations.snapshot_rows("s", *snapshot_evaluations.read_run(run)[:2])
    assert [r["cycle"] for r in table] == [2, 4]
    assert table[0]["training_return"] == 1.0 and table[1]["training_return"] == 3.5  # cycle 2 ended no episode
    assert table[1]["training_length"] == 7.0 and table[1]["entropy"] == 0.25
    assert [r["evaluation_return"] for r in table] == [100.0, 80.0]
    # the command line: a label may hold "=" (an override); the last one splits it from the run directory
    for spec in ("no-label", "=" + str(run), "label="):
        with pytest.raises(SystemExit, match="LABEL=RUN_DIR"):
            snapshot_evaluations.main([spec, "--name", "t", "--out", str(tmp_path)])
    snapshot_evaluations.main([f"lr=1e-4={run}", "--name", "t", "--out", str(tmp_path)])
    record = json.loads((tmp_path / "snapshot_evaluations_t.json").read_text())
    assert record["runs"]["lr=1e-4"]["run_dir"] == str(run)
    (run / "evaluation" / "a.json").unlink()
    (run / "evaluation" / "b.json").unlink()
    with pytest.raises(SystemExit, match="no evaluations"):
        snapshot_evaluations.read_run(run)


@pytest.mark.slow
def test_suite_profile_accounts_every_test_its_compiles_and_its_subprocesses(tmp_path):
    """suite_profile.py on two small test files (one jits GAE, one starts subprocesses), with a compilation cache of
    its own: a row for each test pytest itself reports (its JUnit XML), the XLA compiles found where the test jits and
    the subprocesses' CPU time where it waits for them, and files and suite that add up their tests."""
    import xml.etree.ElementTree as ElementTree

    out, junit = tmp_path / "profile.json", tmp_path / "junit.xml"
    env = {k: v for k, v in os.environ.items() if k != "JAX_COMPILATION_CACHE_DIR"}  # not this suite's, read warm
    subprocess.run([sys.executable, str(BENCHMARKS / "suite_profile.py"), "--out", str(out), "tests/test_gae.py",
                    "tests/test_layering.py", "-n", "0", "-q", "--junitxml", str(junit)], check=True, env=env)
    record = results(out, "suite_profile")
    assert record["config"]["pytest_args"][:2] == ["tests/test_gae.py", "tests/test_layering.py"]
    rows = {(row["scope"], row["name"]): row for row in record["results"]}
    reported = {f"tests/{case.get('classname').split('.')[-1]}.py::{case.get('name')}"
                for case in ElementTree.parse(junit).iter("testcase")}
    assert {name for scope, name in rows if scope == "test"} == reported and len(reported) >= 5
    gae = rows["test", "tests/test_gae.py::test_gae_matches_reference_loop_with_terminations_and_truncations"]
    assert gae["compiles"] > 0 and gae["compile_s"] > 0 and gae["cpu_s"] > 0 and gae["subprocess_cpu_s"] == 0
    layering = "tests/test_layering.py::test_the_package_and_the_command_load_mujoco_mjx_only_when_a_task_needs_it"
    mjx = rows["test", layering]
    assert mjx["subprocess_cpu_s"] > 1.0, "it starts Python with angora_jax imported, twice"
    suite = rows["suite", "all"]
    for measure in ("wall_s", "cpu_s", "subprocess_cpu_s", "compile_s", "compiles"):
        files = sum(row[measure] for (scope, _), row in rows.items() if scope == "file")
        assert suite[measure] == pytest.approx(files, abs=0.05), measure
    assert suite["tests"] == len(reported) and suite["pytest_cpu_s"] >= suite["cpu_s"] + suite["subprocess_cpu_s"]


def test_a_benchmark_never_replaces_an_existing_result(tmp_path, monkeypatch):
    """path_agreement.py, as the evaluation page runs it, replaced the committed
    results/path_agreement/path_agreement_ShadowHandReach_cpu.json with a user's run. A script that saves as it goes
    (probe_trained, time_to_solve, throughput_ladder) rewrites the file it chose, and only that one."""
    import common

    out = tmp_path / "result.json"
    out.write_text("committed")
    monkeypatch.setattr(common, "_CHOSEN", {})
    assert common.write_results("x", {}, [{"run": 1}], str(out), study="test") == str(tmp_path / "result-2.json")
    assert common.write_results("x", {}, [{"run": 1}, {"run": 2}], str(out), study="test") == str(
        tmp_path / "result-2.json")
    assert json.loads((tmp_path / "result-2.json").read_text())["results"] == [{"run": 1}, {"run": 2}]
    monkeypatch.setattr(common, "_CHOSEN", {})  # another process
    assert common.write_results("x", {}, [], str(out), study="test") == str(tmp_path / "result-3.json")
    assert out.read_text() == "committed"
    # An --out with another suffix, or none, is written where asked: not beside it as .json.
    for asked in ("rows.txt", "rows"):
        written = common.write_results("x", {}, [{"run": 1}], str(tmp_path / asked), study="test")
        assert written == str(tmp_path / asked)
        assert json.loads((tmp_path / asked).read_text())["results"] == [{"run": 1}]
