"""benchmarks/seed_statistics.py on two made-up run directories whose numbers are known (well under a second)."""

import json
import os
import sys

import pytest
import yaml

sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "benchmarks"))
import seed_statistics  # noqa: E402


def make_run(folder, seed, sessions, evaluation):
    """A run directory: `sessions` is a list of (start time in s, [(cycle, success), ...]) with one cycle per 6 s."""
    folder.mkdir()
    config = {"env": {"task": "MyoHandPose"}, "ppo": {"seed": seed, "network": {"name": "simple"}},
              "logging": {"run_name": folder.name}}
    (folder / "config.yaml").write_text(yaml.safe_dump(config))
    rows, starts = [], []
    for start, cycles in sessions:
        starts.append({"time": start, "start_cycle": cycles[0][0] - 1,
                       "devices": [{"device": "cuda:0", "kind": "NVIDIA H200"}]})
        rows += [{"cycle": c, "env_steps": 1000 * c, "metric/success": s, "steps_per_second": 100.0,
                  "time": start + 6.0 * (i + 1)} for i, (c, s) in enumerate(cycles)]
    (folder / "metrics.jsonl").write_text("".join(json.dumps(row) + "\n" for row in rows))
    (folder / "sessions.jsonl").write_text("".join(json.dumps(s) + "\n" for s in starts))
    (folder / "evaluation").mkdir()
    (folder / "evaluation" / "best.json").write_text(json.dumps(
        {"checkpoint": "best", "cycle": 20, "episodes": 480, "env_overrides": ["targets=reachable_held_out"],
         "summary": {"metric/success": {"mean": evaluation, "stderr": 0.01}}}))
    return str(folder)


def test_minutes_leave_out_the_gap_between_sessions_and_the_peak_and_seed_spread_are_found(tmp_path):
    # Seed 0 climbs by 0.05 a cycle to 0.95 (0.9 at cycle 18, 108 s), holds it after a resume an hour later, then
    # falls to 0.85 for its last 5 cycles. Seed 1 never reaches the bar.
    climb = [(c, min(0.95, c / 20)) for c in range(1, 21)]
    after = [(c, 0.95 if c <= 25 else 0.85) for c in range(21, 31)]
    a = make_run(tmp_path / "a", 0, [(1000.0, climb), (5000.0, after)], evaluation=0.9)
    b = make_run(tmp_path / "b", 1, [(1000.0, [(c, 0.5) for c in range(1, 11)])], evaluation=0.7)
    out = tmp_path / "seeds.json"
    assert seed_statistics.main([a, b, "--bar", "0.9", "--smooth", "5", "--out", str(out)]) == 0
    record = json.loads(out.read_text())
    first, second = record["results"]
    assert first["sessions"] == 2 and first["minutes"] == pytest.approx(3.0)  # 2 minutes, then 1: the hour left out
    assert first["bar_cycle"] == 18 and first["bar_minutes"] == pytest.approx(1.8)
    # The first 5-cycle window at 0.95 ends at cycle 23, 18 s into the second session.
    assert (first["peak"], first["peak_cycle"]) == (pytest.approx(0.95), 23)
    assert first["peak_minutes"] == pytest.approx(2.3) and first["minutes_past_peak"] == pytest.approx(0.7)
    assert first["final"] == pytest.approx(0.85) and first["device"] == "NVIDIA H200"
    assert second["bar_minutes"] is None and second["final"] == pytest.approx(0.5)
    [group] = record["groups"]  # the configs differ only in the seed and the run's name
    assert group["seeds"] == [0, 1] and group["reached_bar"] == "1 of 2"
    spread = group["evaluations"]["best targets=reachable_held_out"]
    assert spread["mean"] == pytest.approx(0.8) and spread["std"] == pytest.approx(0.1414, abs=1e-4)
