"""The example notebooks run top to bottom on the CPU."""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from quick_compile import QUICK_SUBPROCESS_NO_FUSION_EMITTERS

# Each notebook trains and probes an agent: all of them are in the slow tier.
pytestmark = pytest.mark.slow


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


# A cube run of the brain-area model as small as it trains: 1 cycle of 4 environments x 8 steps, areas of 16 units, and
# episodes of one goal with 0.4 s (5 steps) to reach it. The physics run on MuJoCo Warp, whose kernels are compiled
# once and cached on disk, leaving XLA little to compile: measured on 2 CPU cores with goals of 0.8 s, MJX's JAX
# implementation took 158 s to train the cycle and 142 s to record 4 episodes, Warp with quick compiles 22 s and 14 s.
# Goals of 0.4 s instead of 0.8 s halve the 7 ablation runs (18 s to 10 s of the notebook's 90 s to 75 s).
TINY_CUBE_AREAS = "{SSC_1: 16, SSC_2: 16, SPL: 16, IPL: 16, IPS: 16, MCC: 16, LPFC: 16, PMC_in: 16, PMC: 16, M1: 16}"
TINY_CUBE = [
    "env.options.physics={impl: warp}", "env.options.max_goals=1", "env.options.goal_timeout=0.4",
    "ppo.num_cycles=1", "ppo.num_envs=4", "ppo.rollout_length=8", "ppo.chunk_length=8", "ppo.minibatch_size=32",
    "ppo.num_epochs=1", "ppo.network.width=16", f"ppo.network.areas={TINY_CUBE_AREAS}",
    "checkpoint.every=1", "checkpoint.snapshot_every=0", "logging.progress=none", "logging.report=false",
]

# What the cube notebook found, printed as one JSON line after its cells have run.
CUBE_FINDINGS = """
import json
def labels(result):
    return [list(map(str, result["layer"].values)), list(map(str, result["variable"].values))]
values = ablation["outcome_values"]
print("FINDINGS", json.dumps({
    "alive": recording["alive"].values.tolist(), "lengths": outcomes["episode_length"].tolist(),
    "decoding": labels(decoding), "control": labels(control), "learned": labels(learned),
    "lesions": list(map(str, ablation["lesion"].values)),
    "none_equals_intact": bool((values.sel(lesion="-none") == values.sel(lesion="intact")).all()),
    "rsa": list(map(str, rsa["model_similarity"]["variable"].values)),
}))
"""


def test_cube_probing_notebook_runs_every_analysis_on_a_tiny_cube_run(tmp_path, quick_compiles):
    """The cube notebook top to bottom on a cube run of the brain-area model trained for one tiny cycle, on 5
    episodes (decoding's 5 folds need 5): `alive` is 1 through each episode's length as a run without recording
    counts it and 0 after; decoding (trained and random weights, and their difference) is labelled with the probe's
    areas x variables; the lesions are the probe's and the empty one equals the intact agent exactly; RSA compares
    with the two model variables; every figure is a PNG. Every check is gathered first, so a failure names all that
    failed."""
    import angora_jax as aj
    from angora_jax.analysis import PROBES

    run = aj.train("shadow_ihom_cortical", [*TINY_CUBE, f"logging.run_root={tmp_path}", "logging.run_name=cube"])
    result = run_notebook("probe_a_cube_hand.ipynb", tmp_path, epilogue=CUBE_FINDINGS, ANGORA_RUN=str(run.run_dir),
                          ANGORA_EPISODES="5", **QUICK_SUBPROCESS_NO_FUSION_EMITTERS)
    found = json.loads(result.stdout.split("FINDINGS ", 1)[1].splitlines()[0])
    probe = PROBES["ShadowHandCube"]
    alive, lengths = found["alive"], found["lengths"]
    labels = [list(probe.layers), list(probe.variables)]
    figures = ["decoding", "decoding_random_weights", "decoding_learned", "ablation_goals_reached", "ablation_dropped",
               "timescales", "dynamics", "similarity"]
    checks = {
        "alive is 1 for each episode's length, then 0": all(
            row == [1.0] * int(length) + [0.0] * (len(row) - int(length)) for row, length in zip(alive, lengths,
                                                                                              strict=True)),
        "the recording ends with the longest episode": len(alive[0]) == max(lengths),
        "decoding is areas x variables": found["decoding"] == labels,
        "the random-weights control is areas x variables": found["control"] == labels,
        "trained minus random is areas x variables": found["learned"] == labels,
        "the lesions are the probe's": found["lesions"] == ["intact", "-SSC", "-touch input", "-goal input",
                                                            "-10% M1", "-50% M1", "-none"],
        "the empty lesion equals the intact agent": found["none_equals_intact"],
        "RSA has the two model variables": found["rsa"] == ["task_cube_rotation", "task_rotation_to_goal"],
        "every figure is a PNG": all((tmp_path / f"{name}.png").exists()
                                     and (tmp_path / f"{name}.png").read_bytes()[:4] == b"\x89PNG" for name in figures),
    }
    failed = [name for name, holds in checks.items() if not holds]
    assert not failed, "failed: " + "; ".join(failed) + f"\nfound: {found}"


# What the muscle hand notebook found, printed as one JSON line after its cells have run.
MUSCLE_FINDINGS = """
import json
print("FINDINGS", json.dumps({
    "vaf": [float(v) for v in found["vaf"].values], "count": int(found.attrs["count"]),
    "layers": list(map(str, muscles_or_movements["layer"].values)),
    "kinds": list(map(str, muscles_or_movements["kind"].values)),
    "control_finite": bool(np.isfinite(muscles_or_movements["control_r2"].values).all()),
    "silenced_max": float(silenced["task_muscle_excitation"].values[:, 1:, 0].max()),
    "lesions": list(map(str, ablation["lesion"].values)),
    "none_equals_intact": bool((ablation["outcome_values"].sel(lesion="-none")
                                == ablation["outcome_values"].sel(lesion="intact")).all()),
}))
"""


def test_muscle_hand_notebook_trains_a_tiny_run_and_runs_the_three_muscle_analyses(tmp_path):
    """The MyoHand notebook top to bottom with its own tiny run (3 cycles on MuJoCo Warp, on the CPU) and 5 episodes:
    the synergies' VAF for 1 .. 8 (non-decreasing within NMF's tolerance, at most 1), muscles or movements over the
    probe's areas with its random-weights control, muscle 0 silenced in the recording, and the lesions named as the
    probe names them, the empty one equal to the intact agent. Every figure is a PNG."""
    pytest.importorskip("myo_sim")
    result = run_notebook("muscle_hand.ipynb", tmp_path, epilogue=MUSCLE_FINDINGS, ANGORA_EPISODES="5",
                          **QUICK_SUBPROCESS_NO_FUSION_EMITTERS)
    found = json.loads(result.stdout.split("FINDINGS ", 1)[1].splitlines()[0])
    from angora_jax.analysis import PROBES

    probe = PROBES["MyoHandPose"]
    assert len(found["vaf"]) == 8 and max(found["vaf"]) <= 1 and 1 <= found["count"] <= 8, found
    assert found["layers"] == list(probe.layers) and found["control_finite"], found
    assert found["kinds"] == ["muscle", "muscle", "movement", "movement"], found
    assert found["silenced_max"] == 0.0, found
    assert found["lesions"][0] == "intact" and found["lesions"][-3:] == ["-M1", "-muscle sense", "-none"], found
    assert len(found["lesions"]) == 1 + 3 + 3 and found["none_equals_intact"], found
    for name in ("synergies", "muscles_or_movements", "ablation_pose_error"):
        assert (tmp_path / f"{name}.png").read_bytes()[:4] == b"\x89PNG", name
