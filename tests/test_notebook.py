"""The example notebooks run top to bottom on the CPU."""

import json
import os
import subprocess
import sys
from pathlib import Path


def run_notebook(name: str, cwd: Path, **env: str) -> subprocess.CompletedProcess:
    """The notebook's code cells, in order, in a fresh interpreter (nbmake/Jupyter are not dependencies: the cells
    are plain Python, so this runs exactly what a reader runs)."""
    notebook = json.loads((Path(__file__).parents[1] / "examples" / name).read_text())
    code = "\n\n".join("".join(c["source"]) for c in notebook["cells"] if c["cell_type"] == "code")
    result = subprocess.run([sys.executable, "-c", code], cwd=cwd, env=os.environ | {"MPLBACKEND": "Agg"} | env,
                            capture_output=True, text=True)
    assert result.returncode == 0, result.stderr[-3000:]
    return result


def test_example_notebook_runs_top_to_bottom(tmp_path):
    result = run_notebook("train_and_probe.ipynb", tmp_path)
    assert "activations: (200, 64)" in result.stdout
    assert len(list((tmp_path / "runs").iterdir())) == 1


def test_probing_notebook_runs_every_analysis_on_the_trained_reach_run(cortical_reach, tmp_path):
    """On the session's reach run of the brain-area model, 32 episodes (the CPU's limit per hand program)."""
    result = run_notebook("probe_a_trained_hand.ipynb", tmp_path, ANGORA_RUN=str(cortical_reach.run_dir),
                          ANGORA_EPISODES="32")
    assert "ShadowHandReach cortical cycle 120" in result.stdout and "premotor fixed points" in result.stdout
    names = ["decoding", "similarity", "dynamics", "timescales", "tuning", "ablation"]
    assert all((tmp_path / f"{name}.png").read_bytes()[:4] == b"\x89PNG" for name in names)
