"""The analyses only a muscle model allows (issue 62, item 4): muscle synergies (NMF, variance accounted for),
muscles or movements (decoding of muscle and kinematic variables per layer, against the random-weights control) and
single-muscle lesions (an agent whose excitation of one muscle is 0). Synthetic data with planted answers; the lesion
on the MyoHand's C MuJoCo twin with an untrained policy (no trained MyoHand agent exists yet)."""

import re

import numpy as np
import pytest
import xarray as xr

from angora_jax.analysis import muscles_or_movements, plot_muscles_or_movements, plot_synergies, synergies
from angora_jax.experiment import ConfigError

MUSCLES = 39


def planted_activations(samples=1000, seed=0):
    """Activations of 39 muscles made of 3 planted synergies (each mostly on its own third of the muscles, unit
    norm) with exponential activations, plus noise of 0.01 clipped at 0."""
    rng = np.random.default_rng(seed)
    own = np.arange(MUSCLES) % 3 == np.arange(3)[:, None]
    planted = 0.1 * rng.random((3, MUSCLES)) + own * rng.random((3, MUSCLES))
    planted /= np.linalg.norm(planted, axis=1, keepdims=True)
    activations = rng.exponential(1.0, (samples, 3)) @ planted
    return np.clip(activations + 0.01 * rng.standard_normal(activations.shape), 0, None), planted


@pytest.mark.filterwarnings("ignore:Maximum number of iterations")  # NMF fitting noise past the 3 planted
def test_synergies_find_the_3_planted_ones_and_recover_them(tmp_path):
    activations, planted = planted_activations()
    result = synergies(activations, max_synergies=5)
    assert result.attrs["count"] == 3 and result.attrs["reached"] == 1
    assert result["vaf"].values[1] < 0.9 <= result["vaf"].values[2]
    assert np.all(np.diff(result["vaf"].values) > -1e-3), "more synergies never explain much less"
    # Shuffled apart, the muscles keep their tonic level (the first synergy still explains much) but not the planted
    # co-activation: 3 synergies explain far less.
    shuffled = result["vaf_shuffled"].values
    assert 0.3 < shuffled[0] and shuffled[2] < result["vaf"].values[2] - 0.1, shuffled
    # Without a limit the fits stop at the count that reaches the threshold, the same fits as above.
    until = synergies(activations)
    assert list(until["count"].values) == [1, 2, 3] and until.attrs["count"] == 3
    np.testing.assert_allclose(until["vaf"].values, result["vaf"].values[:3])
    reconstruction = result["activation"].values @ result["muscle_weights"].values
    uncentred = 1 - np.sum((activations - reconstruction) ** 2) / np.sum(activations**2)
    assert result["vaf"].sel(count=3) == pytest.approx(uncentred, abs=1e-9)
    similarity = result["muscle_weights"].values @ planted.T  # both unit norm: cosine similarities
    assert np.all(similarity.max(axis=0) > 0.9) and np.all(similarity.max(axis=1) > 0.9)
    plot_synergies(result, str(tmp_path / "synergies.png"))
    assert (tmp_path / "synergies.png").stat().st_size > 0


@pytest.mark.filterwarnings("ignore:Maximum number of iterations")
def test_synergies_read_a_recording_and_refuse_negative_values():
    activations, _ = planted_activations(samples=120)
    recording = xr.Dataset({"task_muscle_activation": (("episode", "time", "muscle"),
                                                       activations.reshape(4, 30, MUSCLES)),
                            "alive": (("episode", "time"), np.r_[np.ones(20), np.zeros(10)][None].repeat(4, 0))})
    assert synergies(recording, max_synergies=3).attrs["samples"] == 80, "only alive steps"
    with pytest.raises(ValueError, match="non-negative"):
        synergies(activations - 0.5)
    with pytest.raises(ValueError, match="task_muscle_activation"):
        synergies(recording.drop_vars("task_muscle_activation"))


@pytest.mark.filterwarnings("ignore:Maximum number of iterations")
def test_synergies_options_out_of_range_are_refused_by_name_as_the_other_analyses_refuse_theirs(tmp_path, capsys):
    """synergies checked its options by hand: max_synergies=2.5 failed in range() ("'float' object cannot be
    interpreted as an integer"), "3" and threshold="0.9" comparing text with numbers, True fitted one synergy without
    a word and seed=-1 failed inside NumPy; the ranges it did check said "must lie in 1..39" and "(0, 1]", in other
    words than every other analysis. Each is now a ConfigError in the words of check_count, check_number and
    check_seed."""
    activations, _ = planted_activations(samples=120)
    whole = "max_synergies must be a whole number"
    for options, said in (({"max_synergies": 2.5}, f"{whole} of at least 1, got 2.5"),
                          ({"max_synergies": "3"}, f"{whole} of at least 1, got '3'"),
                          ({"max_synergies": True}, f"{whole} of at least 1, got True"),
                          ({"max_synergies": 0}, f"{whole} of at least 1, got 0"),
                          ({"max_synergies": MUSCLES + 1}, f"{whole} from 1 to {MUSCLES} (the muscles), got 40"),
                          ({"threshold": "0.9"}, "threshold must be a number above 0 up to 1, got '0.9'"),
                          ({"threshold": 0}, "threshold must be a number above 0 up to 1, got 0"),
                          ({"threshold": 1.5}, "threshold must be a number above 0 up to 1, got 1.5"),
                          ({"threshold": float("nan")}, "threshold must be a number above 0 up to 1, got nan"),
                          ({"seed": -1}, "seed must be a whole number from 0 to 4,294,967,295, got -1")):
        with pytest.raises(ConfigError, match=f"^{re.escape(said)}\\.$"):
            synergies(activations, **options)
    result = synergies(activations, max_synergies=np.int64(2), threshold=1, seed=np.int64(1), control=False)
    assert result.sizes["count"] == 2 and result.attrs["threshold"] == 1.0
    from angora_jax import cli
    from angora_jax.analysis import save_activity

    recording = xr.Dataset({"task_muscle_activation": (("episode", "time", "muscle"), activations.reshape(4, 30, -1)),
                            "alive": (("episode", "time"), np.ones((4, 30)))})
    path = save_activity(recording, tmp_path / "muscles.nc")
    assert cli.main(["analyze", "synergies", str(path), "--threshold", "1.5"]) == 2
    err = capsys.readouterr().err
    assert err == "angora-jax analyze synergies: threshold must be a number above 0 up to 1, got 1.5.\n", err


@pytest.mark.filterwarnings("ignore:Maximum number of iterations")
def test_the_synergies_summary_counts_one_synergy_in_the_singular(tmp_path, capsys):
    """`analyze synergies` printed "1 synergies reach VAF 0.5" when the first synergy reached the threshold."""
    from angora_jax import cli
    from angora_jax.analysis import save_activity

    activations, _ = planted_activations(samples=120)
    recording = xr.Dataset({"task_muscle_activation": (("episode", "time", "muscle"), activations.reshape(4, 30, -1)),
                            "alive": (("episode", "time"), np.ones((4, 30)))})
    path = save_activity(recording, tmp_path / "muscles.nc")
    assert cli.main(["analyze", "synergies", str(path), "--threshold", "0.5"]) == 0
    assert "\n1 synergy reaches VAF 0.5\n" in capsys.readouterr().out


def kinematic_recording(episodes=10, steps=60, seed=0):
    """A recording where layer `network.M1` is a linear readout (with noise) of 6 "muscle force" variables and
    `network.SPL` one of 4 "joint angle" variables, independent random walks; its random-weights control is noise
    of the same shapes."""
    rng = np.random.default_rng(seed)

    def walk(size):
        return np.cumsum(rng.standard_normal((episodes, steps, size)), axis=1)

    muscles, joints = walk(6), walk(4)
    dims = ("episode", "time")
    data = {"task_muscle_force": ((*dims, "m"), muscles), "task_joint_angles": ((*dims, "j"), joints),
            "activity_network.M1": ((*dims, "u1"), muscles @ rng.standard_normal((6, 16))
                                    + 0.1 * rng.standard_normal((episodes, steps, 16))),
            "activity_network.SPL": ((*dims, "u2"), joints @ rng.standard_normal((4, 16))
                                     + 0.1 * rng.standard_normal((episodes, steps, 16))),
            "alive": (dims, np.ones((episodes, steps)))}
    recording = xr.Dataset(data)
    control = recording.assign({name: (recording[name].dims, rng.standard_normal(recording[name].shape))
                                for name in ("activity_network.M1", "activity_network.SPL")})
    return recording, control


def test_each_layer_decodes_its_own_kind_of_variable_better_than_the_other_and_than_the_control(tmp_path):
    recording, control = kinematic_recording()
    result = muscles_or_movements(recording, control, muscles=["task_muscle_force"],
                                  movements=["task_joint_angles"], folds=3)
    r2 = result["r2"]
    assert r2.sel(layer="network.M1", variable="task_muscle_force") > 0.9
    assert r2.sel(layer="network.SPL", variable="task_joint_angles") > 0.9
    assert r2.sel(layer="network.M1", variable="task_joint_angles") < 0.5
    assert r2.sel(layer="network.SPL", variable="task_muscle_force") < 0.5
    assert result["preference"].sel(layer="network.M1") > 0.5 > -0.5 > result["preference"].sel(layer="network.SPL")
    assert np.all(result["control_r2"].values < 0.2), "noise decodes nothing"
    assert list(result["kind"].values) == ["muscle", "movement"]
    plot_muscles_or_movements(result, str(tmp_path / "mm.png"))
    with pytest.raises(ValueError, match="replay_activity"):
        muscles_or_movements(recording, control.isel(episode=slice(5)), muscles=["task_muscle_force"],
                             movements=["task_joint_angles"], folds=3)


@pytest.fixture(scope="module")
def cpu_hand():
    """The MyoHandPose C MuJoCo twin (skipped without myo-sim)."""
    pytest.importorskip("myo_sim")
    import angora_jax as aj

    return aj.make("MyoHandPose", backend="cpu")


def test_a_silenced_muscle_gets_no_excitation_on_the_c_mujoco_path_of_videos_and_the_others_theirs(cpu_hand,
                                                                                                   monkeypatch):
    """An untrained hand policy on the C MuJoCo twin, as a video (and `evaluate`'s CPU path) plays it: with muscle 7
    silenced, its ctrl stays 0 at every step while the other muscles get what the intact policy sends them. (The
    silenced agent once wrapped its task, which the eager path could not step on C MuJoCo: its video failed.)"""
    import jax
    import jax.numpy as jnp

    from angora_jax.analysis import silence_actions
    from angora_jax.experiment import video
    from angora_jax.experiment.agent import Agent
    from angora_jax.experiment.config import load_config
    from angora_jax.nets import ActorCritic, make_network
    from angora_jax.ppo.cycle import build_head
    from angora_jax.ppo.evaluate import PolicyState
    from angora_jax.ppo.normalization import observation_stats

    config = load_config("myohand_pose", ["ppo.network.width=8"])
    network, head = make_network(config.ppo.network), build_head(cpu_hand, config.ppo)
    obs = cpu_hand.reset(jax.random.key(0)).obs
    params = ActorCritic(network, head).init(jax.random.key(0), network.initial_carry(1),
                                         jax.tree.map(lambda x: x[None], obs))["params"]
    state = PolicyState(params, observation_stats(obs), jnp.asarray(0, jnp.int32))
    agent = Agent(config, cpu_hand, network, head, state, 0)
    ctrls = []

    class Renderer:  # what the video would draw: each step's MjData, its ctrl kept
        def __init__(self, model, body, camera, width, height):
            self.frame = np.zeros((height, width, 3), np.uint8)

        def render(self, data):
            ctrls.append(np.array(data.ctrl))
            return self.frame

        def close(self):
            pass

    monkeypatch.setattr(video, "SceneRenderer", Renderer)
    sent = {}
    for name, acting in (("intact", agent), ("silenced", silence_actions(agent, [7]))):
        ctrls.clear()
        video.render_episodes(acting, None, max_steps=2, width=8, height=8)
        sent[name] = np.array(ctrls[1:])  # the reset's frame shows ctrl 0 everywhere
    assert np.all(sent["silenced"][:, 7] == 0.0) and np.all(sent["intact"][:, 7] > 0.0)
    np.testing.assert_array_equal(np.delete(sent["silenced"][0], 7), np.delete(sent["intact"][0], 7))


# A MyoHandPose run of the brain-area model on MuJoCo Warp (on the CPU), 2 cycles of 4 environments: untrained, only
# what the analyses need to run on (no trained MyoHand agent exists yet).
TINY_AREAS = "{SSC_1: 16, SSC_2: 8, SPL: 8, IPL: 8, IPS: 8, MCC: 8, LPFC: 8, PMC_in: 16, PMC: 16, M1: 16}"
TINY_HAND = ["env.options.physics={impl: warp}", "env.options.max_episode_steps=8", "ppo.num_cycles=2",
             "ppo.num_envs=4", "ppo.rollout_length=8", "ppo.chunk_length=8", "ppo.minibatch_size=16",
             "ppo.num_epochs=1", "ppo.network.width=16", f"ppo.network.areas={TINY_AREAS}", "checkpoint.every=2",
             "checkpoint.snapshot_every=0", "logging.progress=none", "logging.report=false"]


@pytest.mark.slow
def test_a_muscles_lesion_zeroes_that_muscles_recorded_excitation_only_and_the_probe_fits(tmp_path, quick_compiles,
                                                                                           capsys):
    """A tiny MyoHand run's recording with muscle 7 silenced, the probe against the recording, the analyze verbs on
    it (muscles-or-movements with its random-weights control) and ablate silencing a muscle (exit 2 for a muscle the
    hand lacks). The fast counterparts: the silenced step on the C MuJoCo twin above, and the analyses on synthetic
    data."""
    pytest.importorskip("myo_sim")
    from jax_events import jax_events

    import angora_jax as aj
    from angora_jax.analysis import PROBES, record_activity, save_activity, silence_actions
    from angora_jax.cli import main

    run = aj.train("myohand_pose_cortical", [*TINY_HAND, f"logging.run_root={tmp_path}", "logging.run_name=hand"])
    agent = aj.load_agent(run.run_dir, "latest")
    intact = record_activity(agent, episodes=4, steps=6)
    lesioned = record_activity(silence_actions(agent, [7]), episodes=4, steps=6)
    # Step 0 shows the reset's ctrl (0 everywhere); from step 1 on, the ctrl the previous action set.
    sent = lesioned["task_muscle_excitation"].values[:, 1:]
    assert np.all(sent[..., 7] == 0.0) and np.all(intact["task_muscle_excitation"].values[:, 1:, 7] > 0)
    np.testing.assert_array_equal(np.delete(sent, 7, axis=-1)[:, 0],
                                  np.delete(intact["task_muscle_excitation"].values[:, 1], 7, axis=-1))
    probe = PROBES["MyoHandPose"]
    assert {f"activity_{layer}" for layer in probe.layers} | set(probe.variables) <= set(intact.data_vars)
    lesions = probe.lesions(agent)
    assert len(lesions) == MUSCLES + 3 and lesions["-none"] is agent
    assert intact["muscle_activation_component"].values[7] == "PQ_r", "the recording names the muscles"
    path = save_activity(intact, tmp_path / "hand.nc")
    assert main(["analyze", "muscles-or-movements", str(path), "--run", str(run.run_dir), "--checkpoint", "latest",
                 "--layers", "network.M1", "network.SSC_1", "--folds", "2"]) == 0
    control = xr.load_dataset(tmp_path / "hand.muscles-or-movements.nc")["control_r2"].values
    assert np.all(np.isfinite(control)), "the random-weights control replayed the recording"
    assert main(["analyze", "synergies", str(path), "--max-synergies", "3"]) == 0
    assert xr.load_dataset(tmp_path / "hand.synergies.nc")["muscle"].values[24] == "FPL_r"
    with jax_events("jaxpr_trace_duration") as traced:  # the intact agent and its three lesions: one program
        assert main(["analyze", "ablate", str(run.run_dir), "--checkpoint", "latest", "--action", "PQ_r", "24", "0",
                     "--episodes", "4", "--out", str(tmp_path / "ablation.png")]) == 0
    assert traced.count("evaluate") == 1, traced
    ablated = xr.load_dataset(tmp_path / "ablation.nc")
    assert list(ablated["lesion"].values) == ["intact", "-action 7 (PQ_r)", "-action 24 (FPL_r)", "-action 0 (ECRL_r)"]
    assert np.all(ablated["outcome_values"].sel(lesion="intact", outcome="episode_return").values !=
                  ablated["outcome_values"].sel(lesion="-action 24 (FPL_r)", outcome="episode_return").values)
    assert main(["analyze", "ablate", str(run.run_dir), "--checkpoint", "latest", "--action", str(MUSCLES)]) == 2
    capsys.readouterr()
    assert main(["analyze", "ablate", str(run.run_dir), "--checkpoint", "latest", "--action", "PQ"]) == 2
    assert "muscle names (ECRL_r, ECRB_r" in capsys.readouterr().err


@pytest.mark.filterwarnings("ignore:Maximum number of iterations")
def test_the_analyze_verbs_write_plots_and_numbers_and_exit_2_on_a_recording_without_muscles(tmp_path, capsys):
    from angora_jax.cli import main

    activations, _ = planted_activations(samples=200)
    muscles = xr.Dataset({"task_muscle_activation": (("episode", "time", "muscle"), activations.reshape(5, 40, -1)),
                          "alive": (("episode", "time"), np.ones((5, 40)))})
    muscles.to_netcdf(tmp_path / "muscles.nc", engine="scipy")
    assert main(["analyze", "synergies", str(tmp_path / "muscles.nc"), "--max-synergies", "4"]) == 0
    out = capsys.readouterr().out
    assert "3 synergies reach VAF 0.9" in out and "VAF by count (shuffled control): 1 " in out
    assert xr.load_dataset(tmp_path / "muscles.synergies.nc").attrs["count"] == 3
    recording, _ = kinematic_recording()
    recording.to_netcdf(tmp_path / "joints.nc", engine="scipy")
    assert main(["analyze", "muscles-or-movements", str(tmp_path / "joints.nc"), "--muscles", "task_muscle_force",
                 "--movements", "task_joint_angles", "--folds", "3"]) == 0
    assert "network.M1: muscles R^2 1.00" in capsys.readouterr().out
    assert (tmp_path / "joints.muscles-or-movements.png").is_file()
    assert main(["analyze", "muscles-or-movements", str(tmp_path / "joints.nc"), "--folds", "3"]) == 2
    assert "task_muscle_activation" in capsys.readouterr().err
    assert main(["analyze", "synergies", str(tmp_path / "joints.nc")]) == 2
    assert "task_muscle_activation" in capsys.readouterr().err
    # An analysis's numbers are NetCDF too, but no recording; a layer that was not recorded is named with the rest.
    assert main(["analyze", "decode", str(tmp_path / "muscles.synergies.nc")]) == 2
    assert "muscles.synergies.nc is NetCDF but not a recording" in capsys.readouterr().err
    assert main(["analyze", "tuning", str(tmp_path / "joints.nc"), "--layer", "nosuch", "--variable",
                 "task_joint_angles"]) == 2
    assert "Not in the recording: no layer 'nosuch'. Its layers: " in capsys.readouterr().err
