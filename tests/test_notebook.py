"""The example notebooks run top to bottom on the CPU."""

import json
import os
import subprocess
import sys
from pathlib import Path


def run_notebook(name: str, cwd: Path, epilogue: str = "", **env: str) -> subprocess.CompletedProcess:
    """The notebook's code cells, in order, in a fresh interpreter (nbmake/Jupyter are not dependencies: the cells
    are plain Python, so this runs exactly what a reader runs), then `epilogue`, code that reads the notebook's
    variables."""
    notebook = json.loads((Path(__file__).parents[1] / "examples" / name).read_text())
    code = "\n\n".join(["".join(c["source"]) for c in notebook["cells"] if c["cell_type"] == "code"] + [epilogue])
    result = subprocess.run([sys.executable, "-c", code], cwd=cwd, env=os.environ | {"MPLBACKEND": "Agg"} | env,
                            capture_output=True, text=True)
    assert result.returncode == 0, result.stderr[-3000:]
    return result


# What the first notebook found, printed as one JSON line after its cells have run.
FINDINGS = """
import json
returns = [r["episode_return"] for r in run.history]
print("FINDINGS", json.dumps({
    "first_returns": float(np.mean(returns[:3])), "last_returns": float(np.mean(returns[-3:])),
    "evaluated": agent.evaluate(num_envs=8)["episode_return"],
    "units_that_vary": float(np.mean(hidden.std(axis=0) > 1e-3)),
    "values": [float(np.min(values)), float(np.max(values))],
}))
"""


def test_example_notebook_trains_evaluates_and_probes_top_to_bottom(tmp_path):
    """As the notebook says: training raises CartPole's return (random play: about 22), the trained agent keeps the
    pole up in evaluation, and the probe records first-layer units that change over the episode beside a value
    estimate of a positive return (CartPole pays 1 per step)."""
    result = run_notebook("train_and_probe.ipynb", tmp_path, epilogue=FINDINGS)
    assert "activations: (200, 64)" in result.stdout
    assert len(list((tmp_path / "runs").iterdir())) == 1
    found = json.loads(result.stdout.split("FINDINGS ", 1)[1].splitlines()[0])
    assert found["last_returns"] > 2 * found["first_returns"] and found["last_returns"] > 60, found
    assert found["evaluated"] > 100, found
    assert found["units_that_vary"] > 0.5, found
    assert 0 < found["values"][0] <= found["values"][1] < 200, found


# What the probing notebook found, printed as one JSON line after its cells have run.
PROBE_FINDINGS = """
import json
distance, sem = (ablation[stat].sel(outcome="goal_distance") for stat in ("mean", "sem"))
goal = decoding.sel(variable="input_goal")
print("FINDINGS", json.dumps({
    "cycle": agent.cycle, "episodes": recording.sizes["episode"],
    "goal_r2_over_baseline": float((goal["r2"] - goal["baseline"]).max()),
    "distance": {str(name): float(distance.sel(lesion=name)) for name in distance["lesion"].values},
    "sem": {str(name): float(sem.sel(lesion=name)) for name in sem["lesion"].values},
    "fixed_points": [int(points["fixed"].sum()), len(points["fixed"])],
}))
"""


def test_probing_notebook_runs_every_analysis_on_the_trained_reach_run(cortical_reach, tmp_path):
    """On the session's reach run of the brain-area model, 32 episodes (the CPU's limit per hand program): the
    recorded areas hold the goal (decoded above the noise baseline), silencing the goal input leaves the hand farther
    from it, and the premotor search finds fixed points."""
    result = run_notebook("probe_a_trained_hand.ipynb", tmp_path, epilogue=PROBE_FINDINGS,
                          ANGORA_RUN=str(cortical_reach.run_dir), ANGORA_EPISODES="32")
    found = json.loads(result.stdout.split("FINDINGS ", 1)[1].splitlines()[0])
    assert (found["cycle"], found["episodes"]) == (120, 32), found
    assert found["goal_r2_over_baseline"] > 0.5, found
    distance, sem = found["distance"], found["sem"]
    assert distance["-goal input"] > distance["intact"] + 3 * sem["-goal input"], found
    assert 2 * found["fixed_points"][0] >= found["fixed_points"][1], "most starts converge"
    names = ["decoding", "similarity", "dynamics", "timescales", "tuning", "ablation"]
    assert all((tmp_path / f"{name}.png").read_bytes()[:4] == b"\x89PNG" for name in names)
