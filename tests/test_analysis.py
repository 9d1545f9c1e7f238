"""Probing a trained agent: the recorded dataset's shapes and labels, decoding against known readouts and noise,
and lesions (an empty lesion changes nothing, bit for bit)."""

import jax
import numpy as np
import pytest
import xarray as xr
from tiny import TINY_PPO

import angora_jax as aj
from angora_jax.analysis import decode, dense_layers, lesion, lesion_fraction, record_activity, save_activity
from angora_jax.analysis.decoding import cross_validated_r2
from angora_jax.cli import main
from angora_jax.envs.core import Sensation

LAYER = "network.policy_trunk.Dense_1"


@pytest.fixture(scope="module")
def agent(tmp_path_factory):
    root = tmp_path_factory.mktemp("runs")
    run = aj.train("cartpole", [*TINY_PPO, "ppo.num_cycles=3", f"logging.run_root={root}", "logging.run_name=r",
                                "logging.progress=none", "logging.report=false"])
    return aj.load_agent(run.run_dir, "latest")


@pytest.fixture(scope="module")
def recording(agent):
    return record_activity(agent, episodes=10, steps=40)


def test_recording_is_labelled_episode_by_time_by_unit(agent, recording):
    assert recording.sizes["episode"] == 10 and recording.sizes["time"] == 40
    activity = recording[f"activity_{LAYER}"]
    assert activity.dims == ("episode", "time", f"{LAYER}_unit") and activity.shape[-1] == dense_layers(agent)[LAYER]
    assert recording["input_proprioception"].shape == (10, 40, 4) and recording["action"].dtype.kind == "i"
    np.testing.assert_allclose(recording["time"].values[:3], [0.0, 0.02, 0.04])
    alive = recording["alive"].values
    assert np.all(np.diff(alive, axis=1) <= 0) and alive[:, 0].all(), "alive until the first episode ends"
    assert recording.attrs["task"] == "CartPole" and recording["time"].attrs["units"] == "s"
    # What the network saw: the layer applied again to the recorded inputs of step 5 gives the recorded activity.
    obs = Sensation.make(proprioception=jax.numpy.asarray(recording["input_proprioception"].values[:, 5]))
    _, _, _, layers = record_layers(agent, obs)
    np.testing.assert_allclose(layers[LAYER], activity.values[:, 5], rtol=1e-5, atol=1e-6)


def test_recording_round_trips_through_netcdf_and_is_never_overwritten(recording, tmp_path):
    path = save_activity(recording, tmp_path / "act.nc")
    opened = xr.open_dataset(path)
    np.testing.assert_array_equal(opened[f"activity_{LAYER}"].values, recording[f"activity_{LAYER}"].values)
    with pytest.raises(FileExistsError, match="never overwritten"):
        save_activity(recording, path)


def test_decoding_finds_a_linear_readout_and_not_noise():
    rng = np.random.default_rng(0)
    units, groups = rng.standard_normal((2000, 20)), np.repeat(np.arange(20), 100)
    readout = units @ rng.standard_normal((20, 3))
    assert cross_validated_r2(units, readout, groups).mean() > 0.99
    assert abs(cross_validated_r2(units, rng.standard_normal((2000, 3)), groups).mean()) < 0.05


def test_decode_reports_layer_by_variable_with_a_noise_baseline(recording, tmp_path):
    result = decode(recording, layers=["network.policy_trunk.Dense_0", LAYER], variables=["input_proprioception"])
    r2, baseline = result["r2"].values, result["baseline"].values
    assert r2.shape == (2, 1) and np.all(result["r2_low"].values <= r2) and np.all(r2 <= result["r2_high"].values)
    assert r2[0, 0] > 0.99, "the first layer is a linear map of the (normalised) observation"
    assert np.all(r2 > baseline + 0.5) and np.all(np.abs(baseline) < 0.2)
    with pytest.raises(ValueError, match="Not in the recording"):
        decode(recording, layers=["no.such.layer"])
    path = tmp_path / "act.nc"
    save_activity(recording, path)
    assert main(["analyze", "decode", str(path), "--layers", LAYER, "--variables", "input_proprioception"]) == 0
    assert (tmp_path / "act.decoding.png").read_bytes()[:4] == b"\x89PNG"


def test_an_empty_lesion_changes_nothing_and_a_full_one_silences_the_layer(agent):
    assert lesion(agent, LAYER, []) is agent
    silenced = lesion(agent, LAYER, np.arange(dense_layers(agent)[LAYER]))
    obs = jax.vmap(agent.env.reset)(jax.random.split(jax.random.key(1), 8)).obs
    _, _, _, layers = record_layers(silenced, obs)
    assert np.all(np.asarray(layers[LAYER]) == 0)
    half = lesion_fraction(agent, LAYER, 0.5)
    _, _, _, layers = record_layers(half, obs)
    assert (np.asarray(layers[LAYER]) == 0).all(axis=0).sum() == dense_layers(agent)[LAYER] // 2
    with pytest.raises(ValueError, match="No dense layer 'cortex'.*policy_trunk"):
        lesion(agent, "cortex", [0])


def record_layers(agent, obs):
    from angora_jax.analysis.recording import layer_activity

    return layer_activity(agent, agent.initial_carry(obs.proprioception.shape[0]), obs)
