"""benchmarks/myohand_pose_targets.py: the nearest-target distances it reports (about 4 s of CPU)."""

import json
import os
import subprocess
import sys

SCRIPT = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "benchmarks",
                      "myohand_pose_targets.py")


def test_the_script_finds_held_out_targets_near_training_and_myosuites_outside_the_reachable_set(tmp_path):
    out = tmp_path / "targets.json"
    subprocess.run([sys.executable, SCRIPT, "--asl", "64", "--out", str(out)], check=True, capture_output=True,
                   timeout=300, cwd=os.path.dirname(SCRIPT))
    rows = {row["queries"].split()[0]: row for row in json.loads(out.read_text())["results"]}
    assert rows["reachable_held_out"]["count"] == 1024 and rows["asl"]["count"] == 64
    assert rows["reachable_held_out"]["min_rad"] > 0, "held-out rows are not copies of training rows"
    assert rows["reachable_held_out"]["median_rad"] < 1.0 < 2.0 < rows["asl"]["median_rad"]
    assert rows["asl"]["share_within_threshold"] == 0.0
