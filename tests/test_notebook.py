"""The example notebook runs top to bottom on the CPU."""

import json
import os
import subprocess
import sys
from pathlib import Path


def test_example_notebook_runs_top_to_bottom(tmp_path):
    """The notebook's code cells, in order, in a fresh interpreter (nbmake/Jupyter are not dependencies: the cells
    are plain Python, so this runs exactly what a reader runs)."""
    notebook = json.loads((Path(__file__).parents[1] / "examples" / "train_and_probe.ipynb").read_text())
    code = "\n\n".join("".join(c["source"]) for c in notebook["cells"] if c["cell_type"] == "code")
    env = os.environ | {"MPLBACKEND": "Agg"}
    result = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=env, capture_output=True, text=True)
    assert result.returncode == 0, result.stderr[-3000:]
    assert "activations: (200, 64)" in result.stdout
    assert len(list((tmp_path / "runs").iterdir())) == 1
