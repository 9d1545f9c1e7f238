"""Inside the visual area (angora_jax.analysis.visual), on a small CORnet-Z with its initial weights: saliency is the
gradient it claims to be, activation maximization raises the unit's activation, and the parts fit together."""

import re
from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import xarray as xr

import angora_jax as aj
from angora_jax.analysis import units as unit_checks
from angora_jax.analysis import visual
from angora_jax.experiment import ConfigError
from angora_jax.nets.visual import make_visual_encoder

# Every program here runs briefly on a small seeing network (tests/quick_compile.py).
pytestmark = pytest.mark.usefixtures("quick_file_compiles")

SIZE = 32


@pytest.fixture(scope="module")
def agent():
    """What the analyses read of an agent: its config (a reach run seeing one 32 x 32 camera through a CORnet-Z of 4
    channels per area and 6 features) and its parameters."""
    config = aj.load_config("shadow_reach", [
        "ppo.network.visual={encoder: cornet_z, widths: [4, 4, 4, 4], features: 6}",
        f"env.options.vision={{cameras: [front], width: {SIZE}, height: {SIZE}}}"])
    encoder = make_visual_encoder("cornet_z", widths=(4, 4, 4, 4), features=6)
    params = encoder.init(jax.random.key(0), jnp.zeros((1, SIZE, SIZE, 3), jnp.uint8))["params"]
    return SimpleNamespace(config=config, params={"visual": params})


@pytest.fixture(scope="module")
def images():
    return np.random.default_rng(0).integers(0, 256, (2, SIZE, SIZE, 3), dtype=np.uint8)


def test_the_saliency_of_a_linear_map_is_its_weights():
    weights = np.random.default_rng(1).normal(size=(SIZE, SIZE, 3)).astype(np.float32)
    images = np.random.default_rng(2).integers(0, 256, (3, SIZE, SIZE, 3), dtype=np.uint8)
    found = visual.gradient_saliency(lambda pixels: (pixels * weights).sum(axis=(1, 2, 3)), images)
    np.testing.assert_allclose(found, np.broadcast_to(np.abs(weights).max(axis=-1), (3, SIZE, SIZE)), rtol=1e-6)


@pytest.mark.slow
def test_saliency_of_a_unit_is_that_of_its_one_hot_readout_and_bad_outputs_are_refused(agent, images):
    unit = visual.saliency(agent, images, unit=2)
    assert unit.shape == (2, SIZE, SIZE) and unit.max() > 0
    np.testing.assert_allclose(visual.saliency(agent, images, readout=np.eye(6)[2]), unit, rtol=1e-6)
    for bad in ({"unit": 6}, {"readout": np.ones(5)}, {}, {"unit": 0, "readout": np.ones(6)}):
        with pytest.raises(ConfigError, match="unit|readout"):
            visual.saliency(agent, images, **bad)


@pytest.mark.slow
def test_activation_maximization_raises_each_units_activation(agent, images):
    """Each unit's preferred image (as the uint8 image returned) drives it well above what random frames do, and the
    optimization's trace rose."""
    found, trace = visual.preferred_stimuli(agent, "V2", [0, 3], steps=48)
    assert found.shape == (2, SIZE, SIZE, 3) and found.dtype == np.uint8 and trace.shape == (2, 48)
    assert (trace[:, -1] > trace[:, 0]).all(), trace[:, [0, -1]]
    own = visual.feature_maps(agent, found)["V2"].mean(axis=(1, 2))[[0, 1], [0, 3]]
    noise = visual.feature_maps(agent, images)["V2"].mean(axis=(1, 2))[:, [0, 3]].max(axis=0)
    assert (own > noise + 0.1).all(), (own, noise)
    with pytest.raises(ConfigError, match=r"No convolution 'V3'.*V1"):
        visual.preferred_stimuli(agent, "V3", [0])
    with pytest.raises(ConfigError, match=r"V1 has 4 units"):
        visual.preferred_stimuli(agent, "V1", [4])


@pytest.mark.slow
def test_filters_maps_and_the_whole_analysis_fit_together(agent, images, tmp_path):
    # A restored checkpoint holds the layers sorted by name: the order is still the one images pass them.
    restored = SimpleNamespace(config=agent.config, params={"visual": dict(sorted(agent.params["visual"].items()))})
    assert visual.conv_layers(agent) == visual.conv_layers(restored) == ["V1", "V2", "V4", "IT"]
    assert visual.first_layer_filters(restored).shape == (4, 7, 7, 3)
    maps = visual.feature_maps(agent, images)
    assert {name: m.shape for name, m in maps.items()} == {
        "V1": (2, 16, 16, 4), "V2": (2, 8, 8, 4), "V4": (2, 4, 4, 4), "IT": (2, 2, 2, 4)}
    result = visual.visual_analysis(agent, images, units=1, steps=4, layers=["V1"])
    assert result["preferred"].shape == (1, 1, SIZE, SIZE, 3) and result["saliency"].shape == (2, 1, SIZE, SIZE)
    np.testing.assert_allclose(result["last_map"].values, maps["IT"].mean(axis=-1))
    visual.plot_visual(result, str(tmp_path / "visual.png"))
    assert (tmp_path / "visual.png").read_bytes()[:4] == b"\x89PNG"
    with pytest.raises(ValueError, match=r"images must be \(N, height, width, 3\) uint8"):
        visual.visual_analysis(agent, images.astype(np.float32))
    blind = SimpleNamespace(config=aj.load_config("shadow_reach"), params={"network": {}})
    with pytest.raises(ValueError, match="has no visual area"):
        visual.first_layer_filters(blind)


def test_preferred_stimuli_options_out_of_range_are_refused_by_name_before_compiling(agent):
    """Notebook trial: preferred_stimuli(steps=2.5) failed inside JAX ("Shapes must be 1D sequences of concrete
    values of integer type"), learning_rate="0.05" with "Only integer scalar arrays can be converted to a scalar
    index", seed=1.5 with "PRNG key seed must be an integer", size=(0, 32) in the convolution and size=32 unpacking;
    a negative learning rate (descent), blur=2, jitter=-1 and steps=0 returned images without a word. Each is a
    ConfigError naming the argument and its range, before anything compiles."""
    whole = "must be a whole number of at least"
    for options, said in (({"steps": 0}, f"steps {whole} 1, got 0"), ({"steps": 2.5}, f"steps {whole} 1, got 2.5"),
                          ({"jitter": -1}, f"jitter {whole} 0, got -1"),
                          ({"jitter": 1.5}, f"jitter {whole} 0, got 1.5"),
                          ({"learning_rate": -0.1}, "learning_rate must be a number above 0, got -0.1"),
                          ({"learning_rate": "0.05"}, "learning_rate must be a number above 0, got '0.05'"),
                          ({"blur": 2}, "blur must be a number from 0 to 1, got 2"),
                          ({"blur": float("nan")}, "blur must be a number from 0 to 1, got nan"),
                          ({"seed": 1.5}, "seed must be a whole number from 0 to 4,294,967,295, got 1.5"),
                          ({"size": (0, SIZE)}, f"size[0] (height) {whole} 1, got 0"),
                          ({"size": SIZE}, f"size must be (height, width) in pixels, e.g. (64, 64), got {SIZE}")):
        with pytest.raises(ConfigError, match=f"^{re.escape(said)}\\.$"):
            visual.preferred_stimuli(agent, "V1", [0], **options)


def test_units_that_are_no_units_of_the_layer_are_refused_by_name_before_anything_is_computed(agent, images):
    """preferred_stimuli(units=[1.5]) cut 1.5 to unit 1 and [True] read as unit 0 without a word;
    visual_analysis(units=...) was not checked at all: 2.5 failed in range(), 0 in np.stack ("need at least one array to
    stack"), and 5 (more than the 4 channels of each layer) only after the feature maps and the saliency of 5 output
    features had been computed. Each is a ConfigError naming units, the value and the range, before anything is
    computed."""
    span = "whole numbers from 0 to 3 (V1 has 4 units)"
    for units, said in (([1.5], f"units must be {span}; got 1.5 in [1.5]"),
                        ([True], f"units must be {span}; got True in [True]"),
                        (np.array([0.0, 1.0]), f"units must be {span}; got 0.0 in [0.0, 1.0]"),
                        ([0, 4], f"units must be {span}; got 4 in [0, 4]"),
                        ([-1], f"units must be {span}; got -1 in [-1]"),
                        ([], f"units must be a list of one or more {span}, e.g. [0, 1]; got []"),
                        (2, f"units must be a list of one or more {span}, e.g. [0, 1]; got 2")):
        with pytest.raises(ConfigError, match=f"^{re.escape(said)}\\.$"):
            visual.preferred_stimuli(agent, "V1", units, steps=1)
    with pytest.raises(ConfigError, match=r"^units must be whole numbers from 0 to 5 \(the output has 6 units\); "):
        visual.preferred_stimuli(agent, "output", [6], steps=1)
    many = ("units must be a whole number from 1 to 4, got 5: the analysis shows that many units of the output and "
            "of each layer (their units: output 6, V1 4, V2 4, V4 4, IT 4).")
    for options, said in (({"units": 2.5}, "units must be a whole number of at least 1, got 2.5."),
                          ({"units": 0}, "units must be a whole number of at least 1, got 0."),
                          ({"units": True}, "units must be a whole number of at least 1, got True."),
                          ({"units": 5}, many),
                          ({"units": 7, "layers": ["output"]}, "units must be a whole number from 1 to 6, got 7: "
                                                               "the analysis shows that many units of the output and "
                                                               "of each layer (their units: output 6)."),
                          ({"units": 1, "layers": ["V3"]}, "No convolution 'V3' in the visual area; choose one of "
                                                           "['V1', 'V2', 'V4', 'IT'] or 'output'."),
                          ({"steps": 0}, "steps must be a whole number of at least 1, got 0.")):
        with pytest.raises(ConfigError, match=f"^{re.escape(said)}$"):
            visual.visual_analysis(agent, images, **options)


def test_a_saliency_unit_that_is_no_unit_of_the_output_and_an_unknown_layer_are_refused_by_name(agent, images,
                                                                                                 monkeypatch):
    """saliency(unit=1.5) returned a map of zeros without a word (one_hot of 1.5 is all zeros), unit=True and "1"
    failed inside JAX, and 6 or -1 were a plain ValueError in their own words ("must be in [0, 6)"); each is a
    ConfigError naming unit, the value and the range in preferred_stimuli's words, before any gradient. An unknown
    layer was a plain ValueError from preferred_stimuli and a ConfigError from visual_analysis, with the same text:
    both are ConfigError."""
    def no_gradient(*args, **kwargs):
        raise AssertionError("a gradient was computed")

    monkeypatch.setattr(visual, "gradient_saliency", no_gradient)
    for unit, shown in ((1.5, "1.5"), (True, "True"), ("1", "'1'"), (6, "6"), (-1, "-1"), (np.float64(2.0), "2.0")):
        said = f"unit must be a whole number from 0 to 5 (the output has 6 units), got {shown}."
        with pytest.raises(ConfigError, match=f"^{re.escape(said)}$"):
            visual.saliency(agent, images, unit=unit)
    for readout, got in ((np.ones(5), "shape (5,)"), (["a"] * 6, repr(["a"] * 6))):
        said = f"readout must be numbers shaped (6,), a weight for each of the output's 6 units, got {got}."
        with pytest.raises(ConfigError, match=f"^{re.escape(said)}$"):
            visual.saliency(agent, images, readout=readout)
    with pytest.raises(ConfigError, match="^Give exactly one of unit"):
        visual.saliency(agent, images)
    # NumPy and JAX integer scalars are units (jnp.argmax of a readout, an entry of jnp.arange): the gradient is run.
    for unit in (np.int64(2), jnp.argmax(jnp.arange(3))):
        with pytest.raises(AssertionError, match="a gradient was computed"):
            visual.saliency(agent, images, unit=unit)
    np.testing.assert_array_equal(unit_checks.checked_units(jnp.arange(2), "V1", 4), [0, 1])
    with pytest.raises(ConfigError, match=r"got 0.0 in \[0.0, 1.0\]"):
        unit_checks.checked_units(jnp.arange(2.0), "V1", 4)
    unknown = "No convolution 'V3' in the visual area; choose one of ['V1', 'V2', 'V4', 'IT'] or 'output'."
    for call in (lambda: visual.preferred_stimuli(agent, "V3", [0], steps=1),
                 lambda: visual.visual_analysis(agent, images, units=1, steps=1, layers=["V3"])):
        with pytest.raises(ConfigError, match=f"^{re.escape(unknown)}$"):
            call()


def test_a_run_directory_or_a_recording_given_for_the_seeing_network_is_named_with_what_to_do(agent, images):
    """A notebook gives the visual analyses the run directory (which record_activity takes) or the recording: each
    failed with AttributeError ('str' object has no attribute 'config', 'Dataset' object ...), pose_saliency given an
    agent with "'SimpleNamespace' object has no attribute 'check_frames'". Each is a TypeError saying what to give."""
    run = "runs/pixels"
    for call in (lambda seer: visual.first_layer_filters(seer), lambda seer: visual.conv_layers(seer),
                 lambda seer: visual.feature_maps(seer, images), lambda seer: visual.saliency(seer, images, unit=0),
                 lambda seer: visual.preferred_stimuli(seer, "V1", [0]),
                 lambda seer: visual.visual_analysis(seer, images)):
        with pytest.raises(TypeError, match=rf"not the name '{run}': load it first: agent = aj.load_agent\('{run}'\)"
                                            r"\. A pose estimator's file is read with .*PoseEstimator.load\(FILE\)"):
            call(run)
        with pytest.raises(TypeError, match=r"not a Dataset: load one with aj.load_agent\(run_dir\)"):
            call(xr.Dataset())
    for not_an_estimator in (agent, run):
        with pytest.raises(TypeError, match=r"pose_saliency takes a PoseEstimator .*got (SimpleNamespace|str); for "
                                            r"an agent's visual area: saliency\(agent, images, unit=\.\.\.\)"):
            visual.pose_saliency(not_an_estimator, images[:, None])
