"""The analyses on data with known answers: RDMs (symmetric, zero diagonal, the right model RDM wins), fixed points
of a hand-built linear RNN and of Elman areas of brain-area graphs (against fixed-point iteration in numpy),
timescales of AR(1) units (only from alive steps), tuning strength, PCA dimensionality, held-out decoding of noise
and of a code, lagged decoding and cross-correlation of a layer that another follows by 3 steps."""

import re

import jax.numpy as jnp
import numpy as np
import pytest
import xarray as xr
from sklearn.metrics import r2_score
from sklearn.model_selection import GroupKFold

from angora_jax.analysis import (
    cross_correlation,
    decode,
    find_fixed_points,
    principal_components,
    similarity,
    timescales,
    tuning_curves,
)
from angora_jax.analysis.decoding import cross_validated_r2
from angora_jax.analysis.timescales import autocorrelation
from angora_jax.envs import list_tasks, register
from angora_jax.envs.classic import Pendulum
from angora_jax.envs.core import ActionSpec
from angora_jax.experiment import ConfigError

DT = 0.02

# Every program here runs once on small synthetic data (tests/quick_compile.py).
pytestmark = pytest.mark.usefixtures("quick_file_compiles")


def synthetic(episodes=20, steps=50, seed=0):
    """A recording with a variable x per step, a layer `code` whose 6 units are linear in x and a layer `noise` of
    pure noise."""
    rng = np.random.default_rng(seed)
    x = rng.uniform(-1, 1, (episodes, steps))
    code = x[..., None] * rng.standard_normal(6) + 0.01 * rng.standard_normal((episodes, steps, 6))
    alive = np.ones((episodes, steps))
    alive[0, 40:] = 0  # one episode ends early: its last steps are masked
    data = {"metric_x": (("episode", "time"), x), "alive": (("episode", "time"), alive),
            "activity_code": (("episode", "time", "code_unit"), code),
            "activity_noise": (("episode", "time", "noise_unit"), rng.standard_normal((episodes, steps, 5)))}
    return xr.Dataset(data, coords={"time": np.arange(steps) * DT}, attrs={"policy_step_s": DT})


def test_rdms_are_symmetric_with_zero_diagonal_and_match_the_encoded_variable():
    result = similarity(synthetic(), "metric_x", layers=["code", "noise"], variables=["metric_x"], bins=12,
                        method="euclidean")  # the code layer's condition means are collinear: correlation is +-1
    rdm = result["rdm"].values
    assert rdm.shape == (2, 12, 12)
    np.testing.assert_allclose(rdm, np.swapaxes(rdm, 1, 2), atol=1e-12)
    np.testing.assert_allclose(np.diagonal(rdm, axis1=1, axis2=2), 0.0, atol=1e-12)
    model = result["model_similarity"].sel(variable="metric_x")
    assert model.sel(layer="code") > 0.99 and abs(float(model.sel(layer="noise"))) < 0.5
    np.testing.assert_allclose(np.diag(result["layer_similarity"].values), 1.0)
    with pytest.raises(ValueError, match="No variable 'metric_y'"):
        similarity(synthetic(), "metric_y")


def test_a_one_unit_layer_is_left_out_of_correlation_rsa_unless_named_and_then_refused_in_our_words():
    """The correlation between two conditions' mean patterns of one unit is undefined: such a layer (the value
    output) gave an all-NaN RDM, stored as 0 similarity or ending in rsatoolbox's "different nan positions"."""
    data = synthetic().assign(activity_value=(("episode", "time", "value_unit"), np.ones((20, 50, 1))))
    result = similarity(data, "metric_x", bins=4)
    assert list(result["layer"].values) == ["code", "noise"] and np.isfinite(result["rdm"].values).all()
    with pytest.raises(ValueError, match=r"The correlation RDM of value \(1 unit\) is undefined.*--layers"):
        similarity(data, "metric_x", layers=["code", "value"], bins=4)
    assert "value" in similarity(data, "metric_x", bins=4, method="euclidean")["layer"].values


@pytest.mark.parametrize("method, hint", [
    ("Euclidean", r" Did you mean 'euclidean'\?"), ("cosine", ""),
    ("crossnobis", r" \(crossnobis is cross-validated: it needs repeats of each condition, and similarity compares "
                   r"their mean patterns\)"),
])
def test_an_rdm_method_rsatoolbox_does_not_compute_here_is_refused_naming_the_methods(method, hint):
    """A misspelt method ("Euclidean", "cosine") ended in rsatoolbox's bare NotImplementedError (no message), and its
    cross-validated methods in "AssertionError: cv_descriptor generation failed"."""
    with pytest.raises(ConfigError, match=rf"^method must be one of 'correlation', 'euclidean', 'mahalanobis', "
                                          rf"'poisson' \(rsatoolbox's RDM methods\), got {method!r}\.{hint}$"):
        similarity(synthetic(), "metric_x", bins=4, method=method)


def test_a_poisson_rdm_of_negative_activity_is_refused_naming_the_layer_and_of_rates_computed():
    """rsatoolbox's poisson RDM takes logs of the condition means (plus a prior of 0.1): tanh units' negative means
    gave NaN, which was put down to one-unit or constant patterns, and means in [-0.1, 0) a finite, meaningless
    RDM."""
    data = synthetic()
    with pytest.raises(ValueError, match=r"^The poisson RDM treats activity as firing rates, which are not "
                                         r"negative, but code \(down to -[\d.]+\), noise \(down to -[\d.]+\) hold "
                                         r"negative values \(tanh or linear units\)"):
        similarity(data, "metric_x", bins=4, method="poisson")
    with pytest.raises(ValueError, match=r"but noise \(down to -[\d.]+\) holds negative"):
        similarity(data, "metric_x", layers=["noise"], bins=4, method="poisson")
    rates = data.assign(activity_code=np.abs(data["activity_code"]), activity_noise=np.exp(data["activity_noise"]))
    result = similarity(rates, "metric_x", bins=4, method="poisson")
    assert np.isfinite(result["rdm"].values).all() and (result["rdm"].values >= -1e-12).all()


def test_decoding_with_one_fold_is_refused_in_our_words():
    with pytest.raises(ConfigError, match=r"at least 2 folds \(--folds\), got 1"):
        decode(synthetic(episodes=4, steps=5), ["code"], ["metric_x"], folds=1)


def test_more_folds_than_episodes_are_refused_with_the_two_ways_out():
    """The message named the shortfall (5 folds, 4 episodes) but neither fix."""
    with pytest.raises(ValueError, match=r"needs at least 5 episodes alive at the lags \[0\]; the recording has 4: "
                                         r"decode with fewer folds \(--folds\), or record more episodes"):
        decode(synthetic(episodes=4, steps=5), ["code"], ["metric_x"], folds=5)


def test_an_analysis_writes_into_new_folders_and_refuses_a_file_on_the_way_before_computing(tmp_path, capsys,
                                                                                             monkeypatch):
    """`analyze ... --out new/x.png` computed the analysis, then failed "No such file or directory" where record and
    export make the folders; a file on the way (`--out notes.txt/x.png`) also failed only after the analysis."""
    from angora_jax import analysis, cli
    from angora_jax.analysis import save_activity

    path = save_activity(synthetic(episodes=4, steps=30), tmp_path / "rec.nc")
    out = tmp_path / "new" / "deeper" / "t.png"
    assert cli.main(["analyze", "timescales", str(path), "--out", str(out)]) == 0, capsys.readouterr().err
    assert out.is_file() and out.with_suffix(".nc").is_file()
    (tmp_path / "notes.txt").write_text("mine")
    monkeypatch.setattr(analysis, "timescales", lambda *args: pytest.fail("computed before --out was checked"))
    assert cli.main(["analyze", "timescales", str(path), "--out", str(tmp_path / "notes.txt" / "t.png")]) == 2
    assert f"{tmp_path / 'notes.txt'} is a file, not a folder; give a path in a folder" in capsys.readouterr().err


def test_decoding_options_out_of_range_are_refused_by_name(tmp_path, capsys):
    """Notebook trial: decode(folds=2.5) failed in scikit-learn, folds="3" comparing text with a number, seed=-1 or
    1.5 inside NumPy, max_samples=0 blamed the recording ("needs at least 2 episodes ...; the recording has 0"),
    lags=3 with "'int' object is not iterable", lags=[1.5] with NumPy's "arrays used as indices must be of integer
    type" and lags=[] (`--lags` alone) with "min() arg is an empty sequence". Each is a ConfigError naming the
    argument and its range."""
    data = synthetic(episodes=4, steps=5)
    for options, said in (({"folds": 2.5}, "Decoding needs a whole number of at least 2 folds (--folds), got 2.5: "),
                          ({"folds": "3"}, "Decoding needs a whole number of at least 2 folds (--folds), got '3': "),
                          ({"seed": -1}, "seed must be a whole number from 0 to 4,294,967,295, got -1."),
                          ({"seed": 1.5}, "seed must be a whole number from 0 to 4,294,967,295, got 1.5."),
                          ({"max_samples": 0}, "max_samples must be a whole number of at least 1, got 0."),
                          ({"lags": 3}, "lags must be one or more whole numbers of policy steps (--lags), e.g. [-4, "
                                        "0, 4], got 3."),
                          ({"lags": [1.5]}, "lags must be one or more whole numbers of policy steps"),
                          ({"lags": []}, "lags must be one or more whole numbers of policy steps"),
                          ({"lags": [5]}, "lags must be shorter than the recording's 5 steps, got [5].")):
        with pytest.raises(ConfigError, match="^" + re.escape(said)):
            decode(data, ["code"], ["metric_x"], **options)
    lagged = decode(data, ["code"], ["metric_x"], folds=np.int64(2), lags=np.array([0, 1]))
    assert lagged["lag"].values.tolist() == [0, 1] and lagged.attrs["folds"] == 2
    from angora_jax import cli
    from angora_jax.analysis import save_activity

    path = save_activity(data, tmp_path / "short.nc")
    assert cli.main(["analyze", "decode", str(path), "--lags"]) == 2
    assert "angora-jax analyze decode: lags must be one or more whole numbers" in capsys.readouterr().err


@pytest.mark.parametrize("argv", [["decode", "REC.nc", "--folds", "1"],
                                  ["muscles-or-movements", "REC.nc", "--folds", "1"],
                                  ["similarity", "REC.nc", "--condition", "metric_x", "--bins", "1"],
                                  ["tuning", "REC.nc", "--layer", "code", "--variable", "metric_x", "--bins", "1"]])
def test_one_bin_or_fold_is_refused_by_the_option_s_name_before_the_recording_is_read(argv, capsys):
    """One quantile bin compares nothing and one fold leaves nothing to fit on. `--bins 1` and `--folds 1` passed the
    command's check of a positive count and were refused by the library as `bins` and `folds`; now argparse refuses
    them with the option's own name (exit 2), before the recording (here none) is read."""
    from angora_jax import cli

    with pytest.raises(SystemExit) as stop:
        cli.main(["analyze", *argv])
    err = capsys.readouterr().err
    assert stop.value.code == 2 and f"argument {argv[-2]}: must be a whole number >= 2, got '1'" in err, err


@pytest.mark.parametrize("argv", [["decode", "REC.nc", "--layers"], ["decode", "REC.nc", "--variables"],
                                  ["timescales", "REC.nc", "--layers"], ["dynamics", "REC.nc", "--layers"]])
def test_an_option_that_names_layers_or_variables_is_refused_without_a_name(argv, capsys):
    """`--layers` or `--variables` with no name after it (the names forgotten, or taken by the shell) was an empty
    list: decode wrote an empty heat map and exited 0, timescales ended in xarray's "Could not convert tuple"."""
    from angora_jax import cli

    with pytest.raises(SystemExit) as stop:
        cli.main(["analyze", *argv])
    err = capsys.readouterr().err
    assert stop.value.code == 2 and f"argument {argv[-1]}: expected at least one argument" in err, err


def test_a_feature_is_required_of_a_vector_variable_in_range_and_refused_of_a_scalar():
    """`--feature` on a scalar variable was ignored silently, and one out of range was an IndexError traceback
    (negative ones counted from the end)."""
    data = synthetic()
    assert tuning_curves(data.assign(metric_v=data["activity_code"]), "code", "metric_v", bins=4, feature=5).attrs[
        "feature"] == 5
    for variable, feature, message in (("metric_x", 0, "metric_x is one number per step, with no features: drop "
                                                        "feature=0"),
                                       ("activity_code", None, "activity_code has 6 features; choose one"),
                                       ("activity_code", 6, "feature=6 .* is not a feature of activity_code: give a "
                                                            r"whole number from 0 to 5 \(activity_code has 6 "
                                                            "features"),
                                       ("activity_code", -1, "feature=-1 .* is not a feature")):
        with pytest.raises(ValueError, match=message):
            similarity(data, variable, layers=["code"], bins=4, feature=feature)
    with pytest.raises(ValueError, match="drop feature=2"):
        tuning_curves(data, "code", "metric_x", bins=4, feature=2)


def test_a_feature_that_is_no_whole_number_is_refused_by_name_with_the_range():
    """Notebook trial: feature=1.5 passed the range check (0 <= 1.5 < 6) and failed at NumPy's indexing ("only
    integers, slices ... are valid indices"), and feature=True indexed with a bool; feature errors were plain
    ValueErrors. They are ConfigErrors naming feature, the value and the range; NumPy and JAX integers are features."""
    data = synthetic()
    range_said = r"give a whole number from 0 to 5 \(activity_code has 6 features\)"
    for feature in (1.5, True, "1", 6, -1, np.float64(2.0)):
        said = rf"^feature={re.escape(repr(feature))} \(--feature\) is not a feature of activity_code: {range_said}"
        with pytest.raises(ConfigError, match=said):
            similarity(data, "activity_code", layers=["code"], bins=4, feature=feature)
    for call in (lambda: similarity(data, "activity_code", layers=["code"], bins=4),
                 lambda: similarity(data, "metric_x", layers=["code"], bins=4, feature=0)):
        with pytest.raises(ConfigError):
            call()
    for feature in (np.int64(1), jnp.int32(1)):
        assert type(tuning_curves(data, "code", "activity_code", bins=4, feature=feature).attrs["feature"]) is int


def test_a_bin_count_that_is_no_whole_number_of_at_least_2_is_refused_by_name():
    """Notebook trial: similarity(..., bins=1.5) and tuning_curves(..., bins=1.5) failed inside np.linspace ("'float'
    object cannot be interpreted as an integer"), bins="4" adding text to a number, and bins=1 or 0 gave one
    condition (an RDM of one entry, no tuning) or failed in NumPy's quantiles. bins is checked up front by name."""
    data = synthetic()
    for bins in (1.5, "4", True, 1, 0, -3):
        said = rf"^bins must be a whole number of at least 2, got {re.escape(repr(bins))}\.$"
        with pytest.raises(ConfigError, match=said):
            similarity(data, "metric_x", layers=["code"], bins=bins)
        with pytest.raises(ConfigError, match=said):
            tuning_curves(data, "code", "metric_x", bins=bins)
    assert tuning_curves(data, "code", "metric_x", bins=np.int64(2)).sizes["bin"] == 2


def test_condition_bins_split_only_the_alive_steps_into_equal_parts():
    """The quantiles that bound the bins are those of the alive steps: steps after an episode ended belong to the
    next episode, whose values (here all 0, below every alive value) would otherwise pull the lower bounds down and
    merge bins. Alive values 1..40 in 4 bins: 1-10, 11-20, 21-30, 31-40."""
    from angora_jax.analysis.similarity import condition_labels

    values = np.zeros((4, 15))
    values[:, :10] = np.arange(1, 41).reshape(4, 10)
    alive = (values > 0).astype(float)
    data = xr.Dataset({"metric_x": (("episode", "time"), values), "alive": (("episode", "time"), alive)})
    labels = condition_labels(data, "metric_x", bins=4)
    np.testing.assert_array_equal(labels[:, :10], np.arange(40).reshape(4, 10) // 10)
    assert (labels[:, 10:] == -1).all()


def test_fixed_point_of_a_linear_rnn_is_found_to_1e_6():
    rng = np.random.default_rng(1)
    a = 0.5 * np.linalg.qr(rng.standard_normal((6, 6)))[0]  # contracting: eigenvalue moduli 0.5
    b = rng.standard_normal(6)
    expected = np.linalg.solve(np.eye(6) - a, b)
    found = find_fixed_points(lambda h: jnp.asarray(a, jnp.float32) @ h + jnp.asarray(b, jnp.float32),
                              rng.standard_normal((4, 6)) * 3, iterations=100)
    assert found["fixed"].all()
    np.testing.assert_allclose(found["points"], np.broadcast_to(expected, (4, 6)), atol=1e-6)
    np.testing.assert_allclose(np.abs(found["eigenvalues"]), 0.5, atol=1e-5)


def test_fixed_points_reached_from_several_starts_are_decomposed_once(monkeypatch):
    """The Jacobian's eigenvalues (the cost on a trained cube: O(n^3) per point) are computed once per distinct
    point, and every start that reached it gets them."""
    a = np.diag([0.5, -0.25, 0.1])
    decomposed, original = [], np.linalg.eigvals

    def eigvals(matrix):
        decomposed.append(matrix.shape)
        return original(matrix)

    monkeypatch.setattr(np.linalg, "eigvals", eigvals)
    found = find_fixed_points(lambda h: jnp.asarray(a, jnp.float32) @ h, np.random.default_rng(2).standard_normal(
        (5, 3)), iterations=50)
    assert found["fixed"].all() and decomposed == [(3, 3)]
    np.testing.assert_allclose(np.abs(found["eigenvalues"]), np.broadcast_to([0.5, 0.25, 0.1], (5, 3)), atol=1e-6)


@pytest.mark.slow
def test_fixed_point_search_stays_among_reachable_states():
    """A point outside the states a cell reaches (h = 0.5 h + 3 has its point at 6) is not reported: within
    (-1, 1) the search ends on the bound, not fixed; with a lower bound only (a ReLU cell's [0, inf)) a point above
    it is found; without bounds the search finds 6."""
    def step(h):
        return 0.5 * h + 3.0

    starts = np.random.default_rng(3).uniform(-1, 1, (4, 2))
    free = find_fixed_points(step, starts, iterations=100)
    np.testing.assert_allclose(free["points"], 6.0, atol=1e-5)
    boxed = find_fixed_points(step, starts, iterations=100, bounds=(-1.0, 1.0))
    assert not boxed["fixed"].any()
    np.testing.assert_allclose(boxed["points"], 1.0)
    half_open = find_fixed_points(step, starts, iterations=100, bounds=(np.zeros(2), np.full(2, np.inf)))
    assert half_open["fixed"].all()
    np.testing.assert_allclose(half_open["points"], 6.0, atol=1e-5)


def test_every_activation_has_a_range_for_the_fixed_point_search():
    from angora_jax.nets.activations import ACTIVATION_RANGES, ACTIVATIONS

    assert set(ACTIVATION_RANGES) == set(ACTIVATIONS)
    for name, (low, high) in ACTIVATION_RANGES.items():
        outputs = np.asarray(ACTIVATIONS[name](jnp.linspace(-50.0, 50.0, 1001)))
        assert low <= min(outputs.min(), 0.0) and max(outputs.max(), 0.0) <= high, name


# The timescale (steps) of AR(1) units of coefficient 0.8: acf(k) = 0.8^k, and 0.8^4 > 1/e > 0.8^5, so the crossing
# interpolated between lags 4 and 5 is at 4.509 steps.
AR1_CROSSING = 4 + (0.8**4 - 1 / np.e) / (0.8**4 - 0.8**5)


def ar1_recording(coefficient, episodes=400, steps=100, units=8, seed=0):
    """A recording whose layer `unit` holds AR(1) units x(t + 1) = coefficient x(t) + noise, stationary from the
    first step (so that the autocorrelation at lag k is coefficient^k at every step)."""
    rng = np.random.default_rng(seed)
    x = np.zeros((episodes, steps, units))
    x[:, 0] = rng.standard_normal((episodes, units)) / np.sqrt(1 - coefficient**2)
    for t in range(1, steps):
        x[:, t] = coefficient * x[:, t - 1] + rng.standard_normal((episodes, units))
    return xr.Dataset({"alive": (("episode", "time"), np.ones((episodes, steps))),
                       "activity_unit": (("episode", "time", "unit"), x)},
                      coords={"time": np.arange(steps) * DT}, attrs={"policy_step_s": DT})


def test_timescales_of_ar1_units_and_white_noise():
    result = timescales(ar1_recording(0.8), max_lag=30)
    # 40,000 steps per unit put the median within 0.06 steps of the crossing (5 seeds); a lag off by one is 1 step away.
    expected = AR1_CROSSING
    assert float(result["timescale_median"].item()) / DT == pytest.approx(expected, abs=0.2)
    assert expected - 0.3 < result["timescale_iqr_low"].item() / DT < result["timescale_iqr_high"].item() / DT < (
        expected + 0.3)
    np.testing.assert_allclose(result["autocorrelation"].values[0, :8], 0.8 ** np.arange(8), atol=0.02)
    # White noise: acf(1) is about 0, so the crossing is (1 - 1/e) / (1 - acf(1)) of a step.
    noise = timescales(ar1_recording(0.0), max_lag=30)
    assert float(noise["timescale_median"].item()) / DT == pytest.approx(1 - 1 / np.e, abs=0.03)


def test_a_recurrent_cell_is_no_dense_layer_and_its_lesion_names_what_to_lesion_instead():
    """A recurrent area's kernels (a GRU's gates `network.PMC.hn`, ...; here an Elman cell's `i` and `h`) were offered
    as lesionable layers, and asking for the area itself named them: zeroing one is no lesion of the area."""
    from angora_jax.analysis import dense_layers, lesion

    agent = graph_agent({"S1": {"size": 3, "inputs": ("proprioception",)},
                         "PMC": {"size": 5, "inputs": ("S1",), "cell": "rnn"}})
    layers = dense_layers(agent)
    assert "network.S1" in layers and not [name for name in layers if name.startswith("network.PMC.")], layers
    with pytest.raises(ValueError, match="'network.PMC' is a recurrent cell: .* Lesion the layers feeding it"):
        lesion(agent, "network.PMC", [0])


def test_analyze_crosscorrelation_prints_every_layer_s_column(tmp_path, capsys, recwarn, monkeypatch):
    """The lag table of many layers was printed through pandas' own repr, which hides the columns past 80 characters
    behind "..." (15 of the reach model's 17 layers). Its plot's legend of 66 pairs squeezed the axes away
    (matplotlib: "Tight layout not applied"); it now stands beside them. Its curves took matplotlib's 10 colours in
    turn, so pairs 1, 11, 21, ... looked alike; each pair now has a colour and line style of its own."""
    from matplotlib.axes import Axes

    from angora_jax import cli
    from angora_jax.analysis import save_activity

    looks = []  # each curve's colour and line style, as asked of matplotlib
    plot = Axes.plot
    monkeypatch.setattr(Axes, "plot", lambda ax, *args, **kwargs: (
        looks.append((tuple(kwargs.get("color", ())), str(kwargs.get("linestyle")))), plot(ax, *args, **kwargs))[1])

    base = synthetic()
    layers = {f"activity_area_with_a_long_name_{i}": base["activity_code"] + i for i in range(12)}
    path = save_activity(base.assign(layers), tmp_path / "many.nc")
    assert cli.main(["analyze", "crosscorrelation", str(path)]) == 0
    said = capsys.readouterr().out
    assert "..." not in said and all(f"area_with_a_long_name_{i}" in said.split("\n")[1] for i in range(12)), said
    assert not [w for w in recwarn if "layout" in str(w.message)], [str(w.message) for w in recwarn]
    assert (tmp_path / "many.crosscorrelation.png").read_bytes()[:4] == b"\x89PNG"
    assert len(looks) == 91 and len(set(looks)) == 91, looks  # 14 layers' pairs: 12 layers here, 2 in synthetic()


def test_analyze_timescales_says_why_a_layer_has_none(tmp_path, capsys):
    """A layer slower than --max-lag and a constant layer have NaN timescales: the summary says which, not "nan"."""
    from angora_jax import cli
    from angora_jax.analysis import save_activity

    fast, slow = ar1_recording(0.5, episodes=40, steps=30), ar1_recording(0.99, episodes=40, steps=30, seed=1)
    recording = fast.assign(activity_slow=slow["activity_unit"], activity_still=xr.zeros_like(fast["activity_unit"]))
    path = save_activity(recording, tmp_path / "rec.nc")
    assert cli.main(["analyze", "timescales", str(path), "--max-lag", "5"]) == 0
    said = capsys.readouterr().out
    assert "unit: timescale median " in said and "nan" not in said, said
    assert f"slow: timescale longer than {5 * DT:.3g} s: no unit's autocorrelation falls below 1/e within 5 steps " \
           "(give a larger --max-lag)" in said
    assert "still: no timescale: its units are constant over the recording" in said


def test_timescales_read_only_the_alive_steps():
    """After its episode ends a unit holds a different process (a random walk a thousand times larger); the dead
    steps must change nothing: every episode dying after 40 steps gives the timescales of its first 40 steps alone,
    and with episodes dying at different steps, zeros in the dead steps give the same as the random walk."""
    recording = ar1_recording(0.8, episodes=100, steps=60, units=4, seed=1)
    units = recording["activity_unit"]
    rng = np.random.default_rng(2)
    walk = 1e3 * np.cumsum(rng.standard_normal(units.shape), axis=1)
    expected = AR1_CROSSING

    def ending(dead, after_death):
        return recording.assign(alive=(("episode", "time"), (~dead).astype(float)),
                                activity_unit=(units.dims, np.where(dead[..., None], after_death, units.values)))

    first_40 = timescales(recording.isel(time=slice(0, 40)), max_lag=20)
    assert float(first_40["timescale_median"].item()) / DT == pytest.approx(expected, abs=0.3)
    at_40 = np.broadcast_to(np.arange(60) >= 40, (100, 60))
    xr.testing.assert_allclose(timescales(ending(at_40, walk), max_lag=20), first_40, rtol=1e-9)

    varied = np.arange(60) >= rng.integers(20, 61, 100)[:, None]
    on_walk, on_zeros = (timescales(ending(varied, after_death), max_lag=20) for after_death in (walk, 0.0))
    xr.testing.assert_allclose(on_walk, on_zeros, rtol=1e-9)
    assert float(on_walk["timescale_median"].item()) / DT == pytest.approx(expected, abs=0.3)


def test_held_out_r2_of_noise_is_chance_even_with_more_units_than_samples():
    """A readout of 400 units of noise explains about half the variance of noise targets on its own 48 training
    samples; held out, it explains none. A code carried by as many units is read out held out almost perfectly."""
    rng = np.random.default_rng(0)
    samples, units = 60, 400
    groups = np.repeat(np.arange(12), 5)
    noise = cross_validated_r2(rng.standard_normal((samples, units)), rng.standard_normal((samples, 1)), groups)
    assert noise.shape == (5,) and noise.mean() <= 0.05, noise
    signal = rng.standard_normal(samples)
    code = signal[:, None] * rng.standard_normal(units) + rng.standard_normal((samples, units))
    assert cross_validated_r2(code, signal[:, None], groups).min() > 0.95


def test_a_layer_that_only_tells_episodes_apart_decodes_no_better_than_the_training_mean():
    """Units holding a per-episode offset (plus noise), and a target with a per-episode level of its own, unrelated to
    the offsets: within the training episodes the offsets identify each episode and so its level, and a penalty
    chosen by leave-one-out over steps (neighbouring steps are near copies) is tiny: on new episodes that readout
    scored R^2 -2.76, where predicting the training mean scores -0.31. Chosen on held-out episodes, the readout
    shrinks to about that mean."""
    rng = np.random.default_rng(1)
    episodes, steps, units = 60, 50, 128
    offsets = rng.standard_normal((episodes, 1, units))
    features = (offsets + 0.1 * rng.standard_normal((episodes, steps, units))).reshape(-1, units)
    levels = rng.standard_normal((episodes, 1))
    target = (levels + 0.03 * np.cumsum(rng.standard_normal((episodes, steps)), axis=1)).reshape(-1, 1)
    groups = np.repeat(np.arange(episodes), steps)
    mean = [r2_score(target[test], np.full(len(test), target[train].mean()))
            for train, test in GroupKFold(n_splits=5).split(target, target, groups)]
    scores = cross_validated_r2(features, target, groups)
    assert scores.mean() > np.mean(mean) - 0.1, (scores, mean)
    with pytest.raises(ValueError, match="at least 2 episodes to fit it on"):  # two folds of two episodes
        cross_validated_r2(features[:2 * steps], target[:2 * steps], groups[:2 * steps], folds=2)


def test_tuning_strength_separates_a_tuned_layer_from_noise():
    data = synthetic()
    tuned, noise = (tuning_curves(data, layer, "metric_x", bins=8) for layer in ("code", "noise"))
    assert tuned["response"].shape == (8, 6) and tuned["strength"].min() > 0.9
    assert noise["strength"].max() < 0.1
    assert np.all(np.diff(tuned["center"].values) > 0), "bins ordered by the variable"


def test_tuning_strength_is_eta_squared_of_each_unit_whatever_its_offset():
    """Variable 1..40 in 2 bins; unit 0 is 10 in the first bin and 12 in the second, unit 1 is -3 throughout, both
    plus alternating +-1. Unit 0: between-bin sum of squares 40 x 1^2, within 40 x 1^2, so eta squared 0.5; unit 1:
    0. Each unit's variance is about its own mean: the units' different offsets (10 and -3) change nothing."""
    x = np.arange(1.0, 41.0).reshape(1, 40)
    jitter = np.where(np.arange(40) % 2, 1.0, -1.0)
    code = np.stack([10.0 + 2.0 * (x[0] > 20) + jitter, -3.0 + jitter], axis=-1)[None]
    data = xr.Dataset({"metric_x": (("episode", "time"), x), "alive": (("episode", "time"), np.ones((1, 40))),
                       "activity_code": (("episode", "time", "code_unit"), code)})
    result = tuning_curves(data, "code", "metric_x", bins=2)
    np.testing.assert_allclose(result["response"].values, [[10.0, -3.0], [12.0, -3.0]], atol=1e-12)
    np.testing.assert_allclose(result["strength"].values, [0.5, 0.0], atol=1e-12)


def test_pca_finds_one_dimension_in_a_rank_one_code():
    result = principal_components(synthetic(), layers=["code", "noise"], components=4)
    assert result["explained"].sel(layer="code", component=0) > 0.99
    assert int(result["dimensionality"].sel(layer="code")) == 1
    assert int(result["dimensionality"].sel(layer="noise")) >= 4
    trajectory = result["trajectory_code"].values
    assert np.isnan(trajectory[0, 45]).all() and np.isfinite(trajectory[1]).all(), "dead steps are not projected"


def test_components_stop_at_the_widest_layer_and_lags_at_the_recordings_length():
    """Asked of a large recording, more would have run out of memory (components x steps) or time (lags)."""
    data = synthetic()
    widest = max(data[name].shape[-1] for name in data.data_vars if name.startswith("activity_"))
    assert principal_components(data, components=1000).sizes["component"] == widest
    steps = data.sizes["time"]
    assert timescales(data, max_lag=steps + 10).sizes["lag"] == steps
    assert cross_correlation(data, max_lag=steps + 10).sizes["lag"] == 2 * steps - 1


def test_participation_ratio_and_dimensionality_of_a_known_spectrum():
    """Three units over mutually orthogonal zero-mean +-1 patterns with standard deviations 2, 1, 1: the covariance's
    eigenvalues are in the ratio 4 : 1 : 1, so the participation ratio (4 + 1 + 1)^2 / (16 + 1 + 1) is 2 and 90% of
    the variance (4/6, 5/6, 6/6 cumulated) takes all 3 components."""
    patterns = np.array([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]], float) * [2.0, 1.0, 1.0]
    activity = np.tile(patterns, (2, 1))[None]
    data = xr.Dataset({"alive": (("episode", "time"), np.ones((1, 8))),
                       "activity_code": (("episode", "time", "code_unit"), activity)},
                      coords={"time": np.arange(8) * DT})
    result = principal_components(data, layers=["code"], components=3)
    np.testing.assert_allclose(result["explained"].sel(layer="code").values, [4 / 6, 1 / 6, 1 / 6], atol=1e-12)
    assert float(result["participation_ratio"].sel(layer="code")) == pytest.approx(2.0, rel=1e-12)
    assert int(result["dimensionality"].sel(layer="code")) == 3


def leader_and_follower(episodes=16, steps=60, delay=3, seed=0):
    """A layer `lead` whose units carry one white-noise signal, a layer `follow` that repeats it `delay` steps later
    (mixed, plus a little noise), and `metric_echo`, lead's first unit `delay` steps later: the variable at t + delay
    is the activity at t, while the activity at t says nothing of the variable at t."""
    rng = np.random.default_rng(seed)
    signal = rng.standard_normal((episodes, steps + delay))
    full = signal[..., None] * rng.standard_normal(5) + 0.1 * rng.standard_normal((episodes, steps + delay, 5))
    lead = full[:, delay:]
    follow = full[:, :steps] @ rng.standard_normal((5, 4)) + 0.05 * rng.standard_normal((episodes, steps, 4))
    data = {"alive": (("episode", "time"), np.ones((episodes, steps))),
            "metric_echo": (("episode", "time"), full[:, :steps, 0]),
            "activity_lead": (("episode", "time", "lead_unit"), lead),
            "activity_follow": (("episode", "time", "follow_unit"), follow)}
    return xr.Dataset(data, coords={"time": np.arange(steps) * DT}, attrs={"policy_step_s": DT})


def test_lagged_decoding_finds_what_a_layer_tells_of_the_future():
    result = decode(leader_and_follower(), layers=["lead"], variables=["metric_echo"], lags=[0, 3])
    r2 = result["r2"].sel(layer="lead", variable="metric_echo")
    assert r2.sel(lag=3) > 0.95 and r2.sel(lag=0) < 0.2, r2.values  # metric_echo(t + 3) = lead(t)
    assert float(result["baseline"].max()) < 0.1 and result["lag_s"].values.tolist() == [0.0, 3 * DT]
    assert result.attrs["samples"] == [16 * 57] * 2, "every lag reads the steps with a step 3 later"
    # A lag costs one more output of the same readout: the lag-0 column equals a decoding of those steps alone.
    alone = decode(leader_and_follower().isel(time=slice(0, 57)), layers=["lead"], variables=["metric_echo"])
    np.testing.assert_allclose(r2.sel(lag=0), alone["r2"].sel(layer="lead", variable="metric_echo"), rtol=1e-9)
    unmeasured = decode(leader_and_follower(), layers=["lead"], variables=["metric_echo"], lags=[3], baseline=False)
    assert np.isnan(unmeasured["baseline"]).all() and unmeasured["r2"].equals(result["r2"].sel(lag=[3]))
    # A stride over the steps keeps what they tell: a fifth of them finds the same echo.
    fewer = decode(leader_and_follower(), layers=["lead"], variables=["metric_echo"], lags=[3], max_samples=180)
    assert fewer.attrs["samples"] == [180] and fewer["r2"].sel(lag=3, layer="lead", variable="metric_echo") > 0.95
    with pytest.raises(ValueError, match="lags must be shorter than the recording's 60 steps"):
        decode(leader_and_follower(), layers=["lead"], variables=["metric_echo"], lags=[60])


def test_cross_correlation_peaks_where_one_layer_follows_another():
    result = cross_correlation(leader_and_follower(), max_lag=6)
    assert float(result["peak_lag"].sel(layer="lead", other="follow")) == pytest.approx(3 * DT)
    assert float(result["peak_lag"].sel(layer="follow", other="lead")) == pytest.approx(-3 * DT)
    peak = result["cross_correlation"].sel(layer="lead", other="follow").sel(lag=3 * DT, method="nearest")
    assert abs(float(peak)) > 0.95
    np.testing.assert_allclose(result["cross_correlation"].sel(layer="lead", other="lead").sel(lag=0.0), 1.0, atol=1e-9)



def test_a_layer_correlates_best_with_itself_at_lag_0_when_its_episodes_start_and_end_at_rest():
    """A movement-like layer: at rest for each episode's first and last 6 steps, a smooth bump between them, of a
    different size and sign per episode (a reach from rest to a hold). The pairs at a lag leave out rest steps, so
    a mean of products scaled once over all steps gave 1.016 at lags 1 and 2 against 1 at 0 (a trained reach agent's
    M1 peaked at -0.08 s against itself); each lag's correlation is scaled over its own pairs."""
    rng = np.random.default_rng(2)
    episodes, steps = 30, 40
    t = np.arange(steps)
    bump = np.where((t >= 6) & (t < 34), np.sin(np.pi * (t - 6) / 28) ** 2, 0.0)
    moving = bump[None, :, None] * rng.standard_normal((episodes, 1, 3)) + 1e-3 * rng.standard_normal((episodes,
                                                                                                       steps, 3))
    data = xr.Dataset({"alive": (("episode", "time"), np.ones((episodes, steps))),
                       "activity_moving": (("episode", "time", "unit"), moving)},
                      coords={"time": np.arange(steps) * DT}, attrs={"policy_step_s": DT})
    result = cross_correlation(data, max_lag=8)
    curve = result["cross_correlation"].sel(layer="moving", other="moving")
    assert float(np.abs(curve).max()) <= 1 + 1e-9 and float(curve.sel(lag=0.0)) == pytest.approx(1.0)
    assert float(result["peak_lag"].sel(layer="moving", other="moving")) == 0.0
    acf = autocorrelation(data, "moving", max_lag=8)
    assert np.all(np.abs(acf) <= 1 + 1e-9) and np.all(acf[1] < acf[0]), acf[:3]
    # Units that change only at the last step: over the pairs (t, t + k) with k > 0, their earlier side is constant.
    last_step = np.zeros((episodes, steps, 3)) + [0.7, -3.0, 1e-3]
    last_step[:, -1] = rng.standard_normal((episodes, 3))
    acf = autocorrelation(data.assign(activity_moving=(data["activity_moving"].dims, last_step)), "moving", max_lag=4)
    assert np.isfinite(acf[0]).all() and np.isnan(acf[1:]).all(), acf


def graph_agent(areas):
    """An untrained CartPole agent (proprioception: 4 features) whose network is the graph of `areas` (area -> spec
    keyword arguments), read by the policy from the last area; recurrent kernels scaled by 0.5 so that each cell's
    map contracts (one fixed point, which iterating the map finds), and normaliser statistics that move the inputs."""
    from dataclasses import replace

    import jax

    from angora_jax.experiment.agent import Agent, acting_parts
    from angora_jax.experiment.config import load_config
    from angora_jax.nets import ActorCritic, AreaGraph, AreaSpec, ValueSpec
    from angora_jax.ppo.normalization import RunningMeanStd

    config = load_config("cartpole", ["ppo.network.name=areas", "ppo.network.width=null"])
    graph = AreaGraph({name: AreaSpec(**spec) for name, spec in areas.items()}, policy=list(areas)[-1],
                      value=ValueSpec(inputs=("proprioception",), sizes=(2,)))
    config = replace(config, ppo=replace(config.ppo, network=replace(config.ppo.network, graph=graph)))
    env, network, head, template, _ = acting_parts(config)
    obs = jax.vmap(env.reset)(jax.random.split(jax.random.key(1), 1)).obs
    params = ActorCritic(network, head).init(jax.random.key(0), network.initial_carry(1), obs)["params"]
    for name, spec in areas.items():
        if spec.get("cell"):
            params["network"][name]["h"]["kernel"] *= 0.5
    stats = template.obs_stats.replace(proprioception=RunningMeanStd(
        jnp.asarray([0.5, -1.0, 0.0, 2.0]), jnp.asarray([4.0, 0.25, 1.0, 9.0]), jnp.asarray(10.0)))
    state = template.replace(params=params, obs_stats=stats, cycle=jnp.asarray(0))
    return Agent(config, env, network, head, state, 0)


def graph_recording(layers, episodes=3, steps=6, seed=0):
    """A hand-built recording: raw proprioception and each of `layers` (name -> units) random, with a trend over
    time (so that a mean over steps shifted by one differs from the mean over steps); episode 0 ends after 3 steps."""
    rng = np.random.default_rng(seed)
    trend = np.linspace(0.0, 2.0, steps)[None, :, None]
    alive = np.ones((episodes, steps))
    alive[0, 3:] = 0
    data = {"alive": (("episode", "time"), alive),
            "input_proprioception": (("episode", "time", "proprioception_feature"),
                                     3 * rng.standard_normal((episodes, steps, 4)))}
    for name, units in layers.items():
        data[f"activity_{name}"] = (("episode", "time", f"{name}_unit"),
                                    (rng.standard_normal((episodes, steps, units)) + trend).astype(np.float32))
    return xr.Dataset(data, coords={"time": np.arange(steps) * DT}, attrs={"policy_step_s": DT})


def elman_fixed_point(params, constant, activation, own=False):
    """The fixed point of the Elman cell `params` (flax SimpleCell: h' = act(h Wh + x Wi + b)) under the input
    `constant`, followed by h itself when the cell reads its own output (`own`), by iterating the map (float64)."""
    wh, wi, b = (np.asarray(a, np.float64) for a in (params["h"]["kernel"], params["i"]["kernel"], params["i"]["bias"]))
    h = np.zeros(wh.shape[0])
    for _ in range(2000):
        x = np.concatenate([constant, h]) if own else constant
        h = np.asarray(activation(h @ wh + x @ wi + b), np.float64)
    return h


def normalised(recording, alive):
    raw = recording["input_proprioception"].values
    mean, var = np.array([0.5, -1.0, 0.0, 2.0]), np.array([4.0, 0.25, 1.0, 9.0])
    return np.clip((raw - mean) / np.sqrt(var + 1e-8), -10.0, 10.0)[alive].mean(0)


def test_a_cell_of_one_s_own_is_refused_for_fixed_points_naming_the_cells_searched_and_the_pca_without_them():
    """A user's leaky-integrator cell (parameters `input`, `recurrent`) got only 'is not a recurrent cell'."""
    from angora_jax.analysis.dynamics import _cell_kind

    with pytest.raises(ValueError, match=r"^'network.M1' is not a recurrent cell of angora_jax's \(its parameters: "
                                         r"\['input', 'recurrent'\]\): fixed points are searched in an LSTM, GRU or "
                                         r"Elman \(rnn\) cell's update.*Without --run and --recurrent, analyze "
                                         r"dynamics gives the PCA of every layer"):
        _cell_kind({"input": {}, "recurrent": {}}, "network.M1")


@pytest.mark.slow
def test_fixed_point_of_a_graph_area_reading_two_inputs_with_tanh():
    """An Elman area reading a dense area and a modality: the inputs come from the recording, in the order the graph
    lists them (the modality normalised as the network saw it), and the point solves h = tanh(h Wh + x Wi + b)."""
    from angora_jax.analysis import agent_fixed_points

    agent = graph_agent({"S1": {"size": 3, "inputs": ("proprioception",)},
                         "PMC": {"size": 5, "inputs": ("S1", "proprioception"), "cell": "rnn"}})
    recording = graph_recording({"network.S1": 3, "network.PMC.0": 5, "network.PMC.1": 5})
    alive = recording["alive"].values > 0
    x = np.concatenate([recording["activity_network.S1"].values[alive].mean(0), normalised(recording, alive)])
    found = agent_fixed_points(agent, recording, "network.PMC", starts=4, iterations=300)
    np.testing.assert_allclose(found["input"], x, rtol=1e-5)
    expected = elman_fixed_point(agent.params["network"]["PMC"], x, np.tanh)
    assert found["fixed"].all()
    np.testing.assert_allclose(found["points"], np.broadcast_to(expected, (4, 5)), atol=1e-4)


@pytest.mark.slow
def test_fixed_point_of_a_lif_graph_area_with_feedback_and_its_own_output():
    """A LiF Elman area reading a modality, a dense area, a recurrent area that depends on it (feedback: its output
    of the previous step, 0 at an episode's start) and itself (its state, not a constant): the point solves
    h = lif(h Wh + [x, h] Wi + b) with x the mean of what the area read."""
    from angora_jax.analysis import agent_fixed_points
    from angora_jax.nets.activations import ACTIVATIONS

    agent = graph_agent({"S1": {"size": 3, "inputs": ("proprioception",)},
                         "PMC": {"size": 4, "inputs": ("proprioception", "S1", "FB", "PMC"), "cell": "rnn",
                                 "activation": "lif"},
                         "FB": {"size": 2, "inputs": ("PMC",), "cell": "rnn"}})
    recording = graph_recording({"network.S1": 3, "network.PMC.0": 4, "network.PMC.1": 4, "network.FB.1": 2})
    alive = recording["alive"].values > 0
    feedback = recording["activity_network.FB.1"].values
    previous = np.concatenate([np.zeros_like(feedback[:, :1]), feedback[:, :-1]], axis=1)[alive].mean(0)
    x = np.concatenate([normalised(recording, alive), recording["activity_network.S1"].values[alive].mean(0),
                        previous])
    found = agent_fixed_points(agent, recording, "network.PMC", starts=4, iterations=300)
    np.testing.assert_allclose(found["input"], x, rtol=1e-5)
    expected = elman_fixed_point(agent.params["network"]["PMC"], x, ACTIVATIONS["lif"], own=True)
    assert found["fixed"].all()
    np.testing.assert_allclose(found["points"], np.broadcast_to(expected, (4, 4)), atol=1e-4)
    with pytest.raises(ValueError, match="'network.S1' is a dense area.*recurrent areas: network.FB, network.PMC"):
        agent_fixed_points(agent, recording, "network.S1")


@pytest.mark.slow
def test_fixed_point_of_a_relu_graph_area_given_its_input_layers_explicitly():
    """A ReLU Elman area reading two dense areas: naming its input layers (concatenated in the order given) finds the
    point that the graph's inputs give, the one that solves h = relu(h Wh + x Wi + b)."""
    from angora_jax.analysis import agent_fixed_points

    agent = graph_agent({"S1": {"size": 3, "inputs": ("proprioception",)},
                         "S2": {"size": 2, "inputs": ("proprioception",)},
                         "PMC": {"size": 4, "inputs": ("S2", "S1"), "cell": "rnn", "activation": "relu"}})
    recording = graph_recording({"network.S1": 3, "network.S2": 2, "network.PMC.0": 4, "network.PMC.1": 4})
    alive = recording["alive"].values > 0
    x = np.concatenate([recording[f"activity_network.{name}"].values[alive].mean(0) for name in ("S2", "S1")])
    expected = elman_fixed_point(agent.params["network"]["PMC"], x, lambda a: np.maximum(a, 0.0))
    for inputs in (None, ["network.S2", "network.S1"]):
        found = agent_fixed_points(agent, recording, "network.PMC", inputs, starts=4, iterations=300)
        assert found["fixed"].all(), inputs
        np.testing.assert_allclose(found["points"], np.broadcast_to(expected, (4, 4)), atol=1e-4)


@pytest.mark.slow
def test_analyze_dynamics_finds_a_graph_area_s_fixed_points_without_inputs(tmp_path, monkeypatch, capsys):
    """`angora-jax analyze dynamics --run RUN --recurrent network.PMC`: the area's inputs come from the graph, and
    the point is the tanh area's (the run is the agent above: loading a run is not under test); the weights are those
    of the recorded cycle."""
    from angora_jax import cli
    from angora_jax.analysis import save_activity

    agent = graph_agent({"S1": {"size": 3, "inputs": ("proprioception",)},
                         "PMC": {"size": 5, "inputs": ("S1", "proprioception"), "cell": "rnn"}})
    recording = graph_recording({"network.S1": 3, "network.PMC.0": 5, "network.PMC.1": 5})
    path = save_activity(recording, tmp_path / "graph.nc")
    asked = []
    monkeypatch.setattr(cli.analysis, "load_agent",
                        lambda run, checkpoint, options=(): asked.append(checkpoint) or agent)
    monkeypatch.setattr(cli.analysis, "read_run_config", lambda run: agent.config)
    assert cli.main(["analyze", "dynamics", str(path), "--run", "RUN", "--recurrent", "network.PMC"]) == 0
    assert "network.PMC: 15 of 15 starts reached a fixed point" in capsys.readouterr().out
    assert asked == ["best"], "a recording that names no cycle: the best checkpoint"
    # A recording names its cycle: its weights are loaded by default, and others are refused.
    recording.attrs["cycle"] = agent.cycle
    path = save_activity(recording, tmp_path / "graph-cycle0.nc")
    assert cli.main(["analyze", "dynamics", str(path), "--run", "RUN", "--recurrent", "network.PMC"]) == 0
    assert asked[-1] == 0
    recording.attrs["cycle"] = 7
    path = save_activity(recording, tmp_path / "graph-cycle7.nc")
    capsys.readouterr()
    assert cli.main(["analyze", "dynamics", str(path), "--run", "RUN", "--recurrent", "network.PMC",
                     "--checkpoint", "best"]) == 2
    assert "The recording was made from cycle 7, and --checkpoint best of RUN is cycle 0" in capsys.readouterr().err
    # A recording of another run: its cycle has no checkpoint there ("No checkpoint 7" said only that), or another task.
    monkeypatch.setattr(cli.analysis, "load_agent", lambda run, checkpoint, options=(): (_ for _ in ()).throw(
        FileNotFoundError("No checkpoint 7. Saved: latest of cycle 2")))
    assert cli.main(["analyze", "dynamics", str(path), "--run", "RUN", "--recurrent", "network.PMC"]) == 2
    assert "The recording was made from the network at cycle 7, and RUN keeps no checkpoint of that cycle (No " \
           "checkpoint 7. Saved: latest of cycle 2): give --run the run it was recorded from" in capsys.readouterr().err
    recording.attrs["task"] = "MyoHandPose"
    path = save_activity(recording, tmp_path / "graph-myo.nc")
    assert cli.main(["analyze", "dynamics", str(path), "--run", "RUN", "--recurrent", "network.PMC"]) == 2
    assert f"The recording is of MyoHandPose, and RUN was trained on {agent.config.env.task}: give --run the run it " \
           "was recorded from" in capsys.readouterr().err
    assert cli.main(["analyze", "dynamics", str(path), "--inputs", "network.S1"]) == 2
    assert "need --run and --recurrent together, and --inputs only with them" in capsys.readouterr().err


def test_a_recurrent_area_named_without_its_module_path_is_suggested_with_it():
    """`--recurrent PMC` said only "no carry of 'PMC'", not that the recording names it network.PMC."""
    from angora_jax.analysis.dynamics import agent_fixed_points

    recording = graph_recording({"network.S1": 3, "network.PMC.0": 5, "network.PMC.1": 5})
    with pytest.raises(ValueError, match=r"no carry of 'PMC' .*; did you mean 'network.PMC'\? Recurrent modules "
                                         r"recorded: network.PMC\."):
        agent_fixed_points(graph_agent({"S1": {"size": 3, "inputs": ("proprioception",)},
                                        "PMC": {"size": 5, "inputs": ("S1",), "cell": "rnn"}}),
                           recording, "PMC", inputs=["network.S1"])


def test_a_layer_or_variable_the_recording_lacks_is_named_with_the_nearest_and_a_single_name_is_one_layer():
    """timescales, cross_correlation and similarity's variables raised xarray's KeyError deep inside; decode listed
    every variable with the activity_ prefix the user never typed; layers="network.M1" was read letter by letter."""
    data = graph_recording({"network.M1": 3, "network.PMC.0": 4, "network.PMC.1": 4})
    for analysis in (timescales, cross_correlation, principal_components, decode):
        with pytest.raises(ValueError, match=r"^Not in the recording: no layer 'network.m1' \(did you mean "
                                             r"'network.M1'\?\)\. Its layers: network.M1, network.PMC.0, "
                                             r"network.PMC.1\. Its variables: alive, input_proprioception\.$"):
            analysis(data, layers=["network.m1"])
    with pytest.raises(ValueError, match=r"no layer 'network.PMC' \(module network.PMC records network.PMC.0, "
                                         r"network.PMC.1: name one of those\)"):
        timescales(data, layers=["network.PMC"])
    with pytest.raises(ValueError, match=r"no layer 'activity_network.M1' \(layers are named without the activity_ "
                                         r"prefix: 'network.M1'\)"):
        timescales(data, layers=["activity_network.M1"])
    assert list(timescales(data, layers="network.M1")["layer"].values) == ["network.M1"], "one name, one layer"
    with pytest.raises(ValueError, match=r"no variable 'input_proprio' \(did you mean 'input_proprioception'\?\)"):
        similarity(data, "input_proprioception", variables="input_proprio")


def test_an_empty_choice_of_layers_is_refused_naming_the_recordings_layers():
    """`layers=[]` (a filter that kept nothing): principal_components failed with "max() arg is an empty sequence",
    the others with messages about something else, and similarity took every layer."""
    data = graph_recording({"network.M1": 3, "network.PMC.0": 4, "network.PMC.1": 4})
    for analysis in (timescales, cross_correlation, principal_components, decode):
        with pytest.raises(ValueError, match=r"^layers=\[\] chooses no layer: name one or more of the recording's "
                                             r"\(network.M1, network.PMC.0, network.PMC.1\), or leave layers out for "
                                             r"all of them\.$"):
            analysis(data, layers=[])
    with pytest.raises(ValueError, match=r"^layers=\[\] chooses no layer"):
        similarity(data, "input_proprioception", layers=[], feature=0)


def test_probing_calls_from_python_name_a_wrong_argument_before_numpy_or_jax_fail_on_it():
    """Notebook trial: record_activity(episodes=0) failed inside NumPy, ablation({"SSC": "network.SSC_2"}) with
    "'str' object has no attribute 'compiled_once'", replaying another task's recording with a broadcasting error,
    and a misspelt area of a graph was called no graph area at all."""
    from angora_jax.analysis import ablation, agent_fixed_points, episode_outcomes, record_activity, replay_activity

    agent = graph_agent({"S1": {"size": 3, "inputs": ("proprioception",)},
                         "PMC": {"size": 4, "inputs": ("S1",), "cell": "rnn"}})
    with pytest.raises(ConfigError, match=r"^episodes must be a whole number of at least 1, got 0\.$"):
        record_activity(agent, episodes=0)
    for options in ({"episodes": 0}, {"episodes": 2.5}, {"steps": 0}, {"steps": "9"}):
        (name, bad), = options.items()
        for outcomes, first in ((episode_outcomes, ()), (ablation, ({},))):
            with pytest.raises(ConfigError, match=rf"^{name} must be a whole number of at least 1, got "
                                                  rf"{re.escape(repr(bad))}\.$"):
                outcomes(agent, *first, **options)
    with pytest.raises(ValueError, match=r"lesions must map a name to a lesioned Agent, e.g. .*; got dict holding "
                                         r"\['str'\]\.$"):
        ablation(agent, {"SSC": "network.SSC_2"})
    other = graph_recording({"network.S1": 3}).assign_attrs(task="ShadowHandReach")
    with pytest.raises(ValueError, match=r"^The recording is of ShadowHandReach, and this agent acts in CartPole"):
        replay_activity(agent, other)
    with pytest.raises(ValueError, match=r"^This agent's brain-area graph has no area 'network.PMX' \(did you mean "
                                         r"'network.PMC'\?\); its recurrent areas: network.PMC\.$"):
        agent_fixed_points(agent, graph_recording({"network.S1": 3, "network.PMC.0": 4, "network.PMC.1": 4}),
                           "network.PMX")


def test_a_lesion_fraction_or_seed_out_of_range_is_refused_by_name():
    """Notebook trial: lesion_fraction(agent, layer, "0.5") compared text with a number (TypeError), its seed=1.5 or
    -1 failed inside NumPy ("SeedSequence expects int", "expected non-negative integer"), with_random_weights(agent,
    seed=1.5) inside a compiled program ("PRNG key seed must be an integer") and seed="3" as "not a valid JAX array
    type". Each is a ConfigError naming the argument and its range, as the other seeds given in Python are."""
    from angora_jax.analysis import dense_layers, lesion_fraction, with_random_weights

    agent = graph_agent({"S1": {"size": 4, "inputs": ("proprioception",)}})
    for bad in (1.5, -0.1, float("nan"), "0.5", True):
        with pytest.raises(ConfigError, match=rf"^fraction must be a number from 0 to 1, got {re.escape(repr(bad))}"):
            lesion_fraction(agent, "network.S1", bad)
    for bad in (1.5, -1, 2**32, "3", True):
        said = rf"^seed must be a whole number from 0 to 4,294,967,295, got {re.escape(repr(bad))}\.$"
        with pytest.raises(ConfigError, match=said):
            lesion_fraction(agent, "network.S1", 0.5, seed=bad)
        with pytest.raises(ConfigError, match=said):
            with_random_weights(agent, seed=bad)
    half = lesion_fraction(agent, "network.S1", np.float32(0.5), seed=np.int64(3))
    assert int((np.asarray(half.params["network"]["S1"]["kernel"]) == 0).all(axis=0).sum()) == 2
    assert dense_layers(with_random_weights(agent, seed=np.int64(1))) == dense_layers(agent)


def test_lesion_units_that_are_no_units_of_the_layer_are_refused_by_name():
    """Notebook trial: lesion cast its units with np.asarray(units, int): [1.5] silenced unit 1 and [True] unit 0
    without a word, and "0" failed inside NumPy; its range, unknown-layer and recurrent-cell refusals were plain
    ValueErrors. Units are checked as preferred_stimuli checks them (ConfigError naming units, the value and the
    range); an empty set still leaves the agent as it was, and NumPy and JAX integers are units."""
    from angora_jax.analysis import lesion

    agent = graph_agent({"S1": {"size": 4, "inputs": ("proprioception",)},
                         "PMC": {"size": 5, "inputs": ("S1",), "cell": "rnn"}})
    span = r"whole numbers from 0 to 3 \(network.S1 has 4 units\)"
    for bad, said in (([1.5], rf"units must be {span}; got 1.5 in \[1.5\]"),
                      ([True], rf"units must be {span}; got True in \[True\]"),
                      ([4], rf"units must be {span}; got 4 in \[4\]"),
                      ([-1], rf"units must be {span}; got -1 in \[-1\]"),
                      (np.array([0.0, 1.0]), rf"units must be {span}; got 0.0 in \[0.0, 1.0\]"),
                      ("0", rf"units must be a list of {span}, e.g. \[0, 1\]; got '0'"),
                      (2, rf"units must be a list of {span}, e.g. \[0, 1\]; got 2")):
        with pytest.raises(ConfigError, match=f"^{said}"):
            lesion(agent, "network.S1", bad)
    for layer in ("cortex", "network.PMC"):
        with pytest.raises(ConfigError):
            lesion(agent, layer, [0])
    assert lesion(agent, "network.S1", []) is agent and lesion(agent, "network.S1", np.arange(0)) is agent
    silenced = lesion(agent, "network.S1", [np.int64(1), jnp.int32(2)])
    assert (np.asarray(silenced.params["network"]["S1"]["kernel"]) == 0).all(axis=0).tolist() == [False, True, True,
                                                                                                  False]


def pendulum_agent():
    """An untrained Pendulum agent (continuous actions: one component, Gaussian head) with its template state: what
    silence_actions reads (the task's action spec), nothing trained or initialised."""
    from angora_jax.experiment.agent import Agent, acting_parts
    from angora_jax.experiment.config import load_config

    config = load_config("pendulum")
    env, network, head, template, _ = acting_parts(config)
    return Agent(config, env, network, head, template, 0)


def test_action_components_that_are_none_of_the_action_s_are_refused_by_name():
    """Notebook trial: silence_actions cast its components with np.asarray(components, int): [1.5] would silence
    component 1 and [True] component 0 without a word (here [0.5] silenced Pendulum's only component), and its range
    and discrete-action refusals were plain ValueErrors. Components are checked as lesion checks its units
    (ConfigError naming components, the value and the range); an empty set leaves the agent as it was, and NumPy and
    JAX integers are components."""
    from angora_jax.analysis import silence_actions

    agent = pendulum_agent()
    span = r"whole numbers from 0 to 0 \(Pendulum's action has 1 component\)"
    for bad, said in (([0.5], rf"components must be {span}; got 0.5 in \[0.5\]"),
                      ([True], rf"components must be {span}; got True in \[True\]"),
                      ([1], rf"components must be {span}; got 1 in \[1\]"),
                      ([-1], rf"components must be {span}; got -1 in \[-1\]"),
                      ("0", rf"components must be a list of {span}, e.g. \[0, 1\]; got '0'"),
                      (0, rf"components must be a list of {span}, e.g. \[0, 1\]; got 0")):
        with pytest.raises(ConfigError, match=f"^{said}"):
            silence_actions(agent, bad)
    assert silence_actions(agent, []) is agent and silence_actions(agent, np.arange(0)) is agent
    for given in ([0], [np.int64(0)], jnp.arange(1)):
        silenced = silence_actions(agent, given)
        assert np.asarray(silenced.state.silenced).tolist() == [True]
        assert silenced.env is agent.env and silenced.compiled is agent.compiled, "the task and programs are shared"
    with pytest.raises(ConfigError, match="^Silencing action components forces them to 0"):
        silence_actions(graph_agent({"S1": {"size": 3, "inputs": ("proprioception",)}}), [0])


class ThreeTorques(Pendulum):
    """Pendulum turned by three torques at once (weighted 1, 0.5 and 0.25, so each action component moves it), whose
    metrics `torque_<i>` are the action components it received at the step: what shows whether a path that acts for
    a silenced agent held them at 0."""

    metric_names = ("torque_0", "torque_1", "torque_2")

    def __init__(self, max_episode_steps: int = 6):
        super().__init__(max_episode_steps)
        self.action_spec = ActionSpec(low=jnp.full((3,), -2.0), high=jnp.full((3,), 2.0))

    def _step(self, physics, info, action, key):
        torque = (action @ jnp.asarray([1.0, 0.5, 0.25]))[None]
        physics, obs, reward, terminated, info, _ = super()._step(physics, info, torque, key)
        return physics, obs, reward, terminated, info, {name: action[i] for i, name in enumerate(self.metric_names)}


def three_torques_agent():
    """An untrained agent of ThreeTorques (an MLP, Gaussian head; normaliser statistics of ones) with programs of
    its own (`compiled`: a fresh dict)."""
    from dataclasses import replace

    import jax

    from angora_jax.experiment.agent import Agent, acting_parts
    from angora_jax.experiment.config import load_config
    from angora_jax.nets import ActorCritic

    if "ThreeTorques" not in list_tasks():  # registered when first needed, not when pytest collects this file in
        register("ThreeTorques", ThreeTorques)  # every worker, where the other files' tests would list it as a task
    config = load_config("pendulum", ["env.task=ThreeTorques", "ppo.network.width=8"])
    env, network, head, template, _ = acting_parts(config)
    obs = jax.vmap(env.reset)(jax.random.split(jax.random.key(1), 1)).obs
    params = ActorCritic(network, head).init(jax.random.key(0), network.initial_carry(1), obs)["params"]
    state = jax.tree.map(lambda leaf: jnp.ones(leaf.shape, leaf.dtype), template).replace(params=params)
    return replace(Agent(config, env, network, head, state, 0), compiled={})


def test_silenced_actions_share_one_program_with_the_intact_agent_and_each_reaches_the_task_as_0():
    """A lesion per muscle compiled its own evaluation program (the mask was a constant of the task's step): 39
    compiles for the MyoHand's `muscle_lesions`, tens of seconds each on a GPU. The mask is now data of the program:
    the intact agent and every silenced variant trace it once, and each variant's silenced components reach the task
    as 0 (its metrics torque_<i>) while the others move, so the outcomes differ from the intact agent's."""
    from jax_events import jax_events

    from angora_jax.analysis import ablation, silence_actions

    agent = three_torques_agent()
    lesions = {f"-{i}": silence_actions(agent, [i]) for i in range(3)}
    lesions["-0 -2"] = silence_actions(lesions["-0"], [2])
    with jax_events("jaxpr_trace_duration") as traced:
        result = ablation(agent, lesions, episodes=4)
    assert traced.count("evaluate") == 1, traced
    torques = result["outcome_values"].sel(outcome=["torque_0", "torque_1", "torque_2"]).values  # lesion x i x ep.
    assert np.all(torques[0] != 0), "the intact agent drives every component"
    for row, silenced in enumerate(([0], [1], [2], [0, 2]), start=1):
        moving = [i for i in range(3) if i not in silenced]
        assert np.all(torques[row, silenced] == 0) and np.all(torques[row, moving] != 0), (silenced, torques[row])
    returns = result["outcome_values"].sel(outcome="episode_return").values
    assert np.all(returns[1:] != returns[0]), "each lesion changes what the task does"


def test_silenced_actions_reach_the_task_as_0_on_every_path_that_acts_for_the_agent(tmp_path, monkeypatch):
    """Every way an agent acts holds its silenced components at 0, while the policy (and the recorded `action`) is
    untouched: Agent.act, Agent.evaluate, record_activity, and evaluate's eager path (that of videos too) and
    batched path. A path that took the lesioned agent for the intact one would give the task nonzero torques."""
    import jax

    from angora_jax.analysis import record_activity, silence_actions
    from angora_jax.experiment import evaluation

    agent = three_torques_agent()
    silenced = silence_actions(agent, [1])
    obs = jax.vmap(agent.env.reset)(jax.random.split(jax.random.key(2), 3)).obs
    intact_actions = np.asarray(agent.act(agent.initial_carry(3), obs)[1])
    actions = np.asarray(silenced.act(silenced.initial_carry(3), obs)[1])
    assert np.all(intact_actions != 0) and np.all(actions[:, 1] == 0)
    np.testing.assert_array_equal(np.delete(actions, 1, axis=1), np.delete(intact_actions, 1, axis=1))
    sampled = np.asarray(silenced.act(silenced.initial_carry(3), obs, jax.random.key(0))[1])
    assert np.all(sampled[:, 1] == 0) and np.all(sampled[:, 0] != 0)

    evaluated = silenced.evaluate(num_envs=3)
    assert evaluated["metric/torque_1"] == 0 != evaluated["metric/torque_0"]
    assert agent.evaluate(num_envs=3)["metric/torque_1"] != 0

    recording = record_activity(silenced, episodes=3, steps=4)
    assert np.all(recording["metric_torque_1"].values == 0) and np.all(recording["metric_torque_0"].values != 0)
    assert np.all(recording["action"].values[..., 1] != 0), "the recorded action is the policy's"
    assert np.all(record_activity(agent, episodes=3, steps=4)["metric_torque_1"].values != 0)

    # evaluate() loads its agent from the run directory: here it is handed the lesioned one.
    monkeypatch.setattr(evaluation, "load_agent", lambda *args: silenced)
    for path in evaluation.PATHS:
        episodes = evaluation.evaluate(tmp_path, episodes=3, batch=2, save=False, path=path).episodes
        assert np.all(episodes["metric/torque_1"] == 0) and np.all(episodes["metric/torque_0"] != 0), path
    monkeypatch.setattr(evaluation, "load_agent", lambda *args: agent)
    assert np.all(evaluation.evaluate(tmp_path, episodes=3, save=False).episodes["metric/torque_1"] != 0)


def test_fixed_point_starts_iterations_or_seed_out_of_range_are_refused_by_name():
    """Notebook trial: agent_fixed_points(starts=0) failed with "need at least one array to stack", starts=2.5 inside
    NumPy, iterations=1.5 in jax's fori_loop ("must have equal types") and seed=1.5 in NumPy; iterations=-1 searched
    nothing without a word. Each is a ConfigError naming the argument and its range, before the search compiles."""
    from angora_jax.analysis import agent_fixed_points

    agent = graph_agent({"S1": {"size": 3, "inputs": ("proprioception",)},
                         "PMC": {"size": 4, "inputs": ("S1",), "cell": "rnn"}})
    data = graph_recording({"network.S1": 3, "network.PMC.0": 4, "network.PMC.1": 4})
    for name in ("starts", "iterations"):
        for bad in (0, -1, 2.5, "8", True):
            with pytest.raises(ConfigError, match=rf"^{name} must be a whole number of at least 1, got "
                                                  rf"{re.escape(repr(bad))}\.$"):
                agent_fixed_points(agent, data, "network.PMC", **{name: bad})
    for bad in (1.5, -1, "3"):
        with pytest.raises(ConfigError, match=rf"^seed must be a whole number from 0 to 4,294,967,295, got "
                                              rf"{re.escape(repr(bad))}\.$"):
            agent_fixed_points(agent, data, "network.PMC", seed=bad)


def test_a_recording_or_inputs_that_do_not_fit_the_cell_are_config_errors_naming_them():
    """A recording of another agent (its carry of another size) or inputs of the wrong width were plain ValueErrors
    ("Recorded carry of 'network.PMC' has 5 values, the cell 4."), which a notebook could not tell from a bug. Both
    are ConfigErrors naming what was given, its size and the size the cell takes."""
    from angora_jax.analysis import agent_fixed_points

    agent = graph_agent({"S1": {"size": 3, "inputs": ("proprioception",)},
                         "S2": {"size": 2, "inputs": ("proprioception",)},
                         "PMC": {"size": 4, "inputs": ("S2", "S1"), "cell": "rnn"}})
    other = graph_recording({"network.S1": 3, "network.S2": 2, "network.PMC.0": 5, "network.PMC.1": 5})
    with pytest.raises(ConfigError, match=r"^The recording's carry of 'network.PMC' has 5 values; this agent's cell "
                                          r"holds 4: .*another agent"):
        agent_fixed_points(agent, other, "network.PMC", starts=2, iterations=1)
    data = graph_recording({"network.S1": 3, "network.S2": 2, "network.PMC.0": 4, "network.PMC.1": 4})
    with pytest.raises(ConfigError, match=r"^inputs of 'network.PMC' must give the 5 input features it reads; "
                                          r"those given have 2"):
        agent_fixed_points(agent, data, "network.PMC", ["network.S2"], starts=2, iterations=1)


def test_a_run_directory_file_name_or_agent_given_for_a_recording_is_named_with_what_to_do(tmp_path):
    """Notebook trial: decode(RUN_DIR), timescales("act.nc") or principal_components(agent) in place of the recording
    failed with "'str' object has no attribute 'data_vars'" (replay_activity: no attribute 'attrs', synergies: "could
    not convert string to float", agent_fixed_points: "string indices must be integers")."""
    from angora_jax.analysis import (
        agent_fixed_points,
        muscles_or_movements,
        replay_activity,
        save_activity,
        sindy,
        synergies,
    )

    agent = graph_agent({"S1": {"size": 3, "inputs": ("proprioception",)},
                         "PMC": {"size": 4, "inputs": ("S1",), "cell": "rnn"}})
    run, name = str(tmp_path), str(tmp_path / "act.nc")
    for given, said in ((run, rf"not the folder '{run}': record one first: record_activity\('{run}'\)\.$"),
                        (name, rf"not the name '{name}': read it first: xarray.load_dataset\('{name}'\)\.$"),
                        (agent, r"not an Agent: record one first: record_activity\(agent\)\.$")):
        for analysis in (decode, timescales, cross_correlation, principal_components, synergies, muscles_or_movements,
                         lambda data: similarity(data, "metric_x"), lambda data: tuning_curves(data, "code", "x"),
                         lambda data: sindy(data, "code"), lambda data: replay_activity(agent, data),
                         lambda data: agent_fixed_points(agent, data, "network.PMC"),
                         lambda data: save_activity(data, tmp_path / "out.nc")):
            with pytest.raises(TypeError, match=r"^Analyses read a recording .*" + said):
                analysis(given)


def test_a_run_directory_or_a_policy_given_for_an_agent_is_named_with_what_to_do(tmp_path):
    """Notebook trial: lesion_area(RUN_DIR, ...), dense_layers, silence_modality, silence_actions, with_random_weights,
    ablation, episode_outcomes, replay_activity, area_input and agent_fixed_points given the run directory (which
    record_activity and evaluate take) failed with AttributeError ("'str' object has no attribute 'params'", 'env',
    'compiled_once', 'config', 'network'); an exported Policy likewise."""
    from types import SimpleNamespace

    from angora_jax.analysis import (
        ablation,
        agent_fixed_points,
        area_input,
        dense_layers,
        episode_outcomes,
        lesion,
        lesion_area,
        lesion_fraction,
        reach_lesions,
        replay_activity,
        silence_actions,
        silence_modality,
        with_random_weights,
    )

    agent = graph_agent({"S1": {"size": 3, "inputs": ("proprioception",)},
                         "PMC": {"size": 4, "inputs": ("S1",), "cell": "rnn"}})
    data = graph_recording({"network.S1": 3, "network.PMC.0": 4, "network.PMC.1": 4})
    run = str(tmp_path)
    for given, said in ((run, rf"not the name '{run}': load it first: agent = aj.load_agent\('{run}'\)\.$"),
                        (SimpleNamespace(agent=agent), r"not a SimpleNamespace: give its .agent\.$")):
        for analysis in (dense_layers, reach_lesions, with_random_weights, lambda a: lesion(a, "network.S1", [0]),
                         lambda a: lesion_area(a, "network.S1"), lambda a: lesion_fraction(a, "network.S1", 0.5),
                         lambda a: silence_modality(a, "proprioception"), lambda a: silence_actions(a, [0]),
                         lambda a: ablation(a, {}, episodes=2), lambda a: episode_outcomes(a, episodes=2),
                         lambda a: replay_activity(a, data), lambda a: area_input(a, data, "network.PMC"),
                         lambda a: agent_fixed_points(a, data, "network.PMC")):
            with pytest.raises(TypeError, match=r"^This analysis takes an Agent, " + said):
                analysis(given)


def test_the_similarity_plot_of_many_layers_wraps_its_rdms_into_rows(tmp_path):
    """The brain-area model's 15 layers and the two comparison matrices were 17 panels in one row, a figure 44 inches
    wide in which nothing could be read; the RDMs now wrap at six a row, with the matrices below them."""
    import matplotlib.image

    from angora_jax.analysis import plot_similarity

    layers = [f"network.area_{i}" for i in range(15)]
    rng = np.random.default_rng(0)
    result = xr.Dataset(
        {"rdm": (("layer", "condition", "condition_"), rng.random((15, 8, 8))),
         "layer_similarity": (("layer", "layer_"), rng.uniform(-1, 1, (15, 15))),
         "model_similarity": (("layer", "variable"), rng.uniform(-1, 1, (15, 3)))},
        coords={"layer": layers, "layer_": layers, "variable": ["a", "b", "c"], "condition": np.arange(8),
                "condition_": np.arange(8)}, attrs={"condition": "goal"})
    path = tmp_path / "similarity.png"
    plot_similarity(result, str(path))
    height, width = matplotlib.image.imread(path).shape[:2]
    assert width <= 1600 and width / height < 1.5, (width, height)


def test_decodings_printout_says_a_constant_variable_has_nothing_to_decode():
    """`analyze decode` printed "metric_solved nan (noise nan)" for a variable that never changed in the recording,
    with no word of why."""
    from angora_jax.cli.analysis import decoding_lines

    rng = np.random.default_rng(0)
    episodes, steps = 8, 20
    data = xr.Dataset({"activity_trunk": (("episode", "time", "unit"), rng.standard_normal((episodes, steps, 6))),
                       "input_goal": (("episode", "time", "feature"), rng.standard_normal((episodes, steps, 2))),
                       "metric_solved": (("episode", "time"), np.zeros((episodes, steps))),
                       "alive": (("episode", "time"), np.ones((episodes, steps)))})
    (line,) = decoding_lines(decode(data, folds=2))
    assert line.startswith("trunk: input_goal ") and "(noise " in line
    assert "metric_solved - (constant over the steps decoded: nothing to decode)" in line and "nan" not in line


def test_analyze_crosscorrelation_says_when_a_peak_sits_at_the_windows_edge(tmp_path, capsys):
    """A layer that follows another by 8 steps, read with --max-lag 3, had its "peak" at the last lag asked for,
    printed like any other peak: a bound, not a peak. The printout now names the pair and the fix."""
    from angora_jax import cli
    from angora_jax.analysis import save_activity

    lead = ar1_recording(0.9, episodes=60, steps=40)
    follower = lead["activity_unit"].shift(time=8).fillna(0.0)
    path = save_activity(lead.assign(activity_follower=follower), tmp_path / "rec.nc")
    assert cli.main(["analyze", "crosscorrelation", str(path), "--max-lag", "3"]) == 0
    said = capsys.readouterr().out
    assert f"At the window's edge (+-{3 * DT:.3g} s, --max-lag): unit -> follower, follower -> unit." in said, said
    assert "give a larger --max-lag" in said
    assert cli.main(["analyze", "crosscorrelation", str(path), "--max-lag", "12"]) == 0
    assert "At the window's edge" not in capsys.readouterr().out


def test_a_recording_that_lost_its_alive_steps_or_inputs_is_refused_naming_what_it_lacks():
    """A recording with `alive` dropped (rec[["activity_code", "metric_x"]], a notebook's selection) failed in xarray:
    KeyError "No variable named 'alive'"; replaying one without its inputs said the agent's "obs.proprioception has
    shape ()", as if the agent were given the wrong observation."""
    from angora_jax.analysis import replay_activity

    data = synthetic(episodes=4, steps=30)
    lacking = data.drop_vars("alive")
    message = (r"^This recording has no alive \(which steps of each episode ran\), which every analysis reads: give "
               r"the recording as record_activity returns it, or keep alive when selecting its variables\.$")
    for analysis in (decode, timescales, cross_correlation, principal_components,
                     lambda data: similarity(data, "metric_x"), lambda data: tuning_curves(data, "code", "metric_x")):
        with pytest.raises(ValueError, match=message):
            analysis(lacking)
    agent = graph_agent({"S1": {"size": 3, "inputs": ("proprioception",)},
                         "PMC": {"size": 4, "inputs": ("S1",), "cell": "rnn"}})
    recording = graph_recording({"network.S1": 3, "network.PMC.0": 4, "network.PMC.1": 4})
    with pytest.raises(ValueError, match=r"^The recording lacks the inputs this agent reads \(input_proprioception\): "
                                         r"replay a recording as record_activity returns it, with its input_\* "
                                         r"variables\.$"):
        replay_activity(agent, recording.drop_vars("input_proprioception"))


@pytest.mark.parametrize("emptied", ["no episode", "no step", "alive 0"])
def test_a_recording_with_no_step_that_ran_is_refused_naming_how_to_record_one(emptied, tmp_path, capsys):
    """A selection of episodes that kept none (or none alive) replayed as "batch_size must be a whole number of at
    least 1, got 0", or, all dead, returned activity that every analysis leaves out; PCA failed in scikit-learn
    ("Found array with 0 sample(s)") and tuning in NumPy (IndexError), a traceback from `angora-jax analyze`."""
    from angora_jax import cli
    from angora_jax.analysis import replay_activity

    agent = graph_agent({"S1": {"size": 3, "inputs": ("proprioception",)},
                         "PMC": {"size": 4, "inputs": ("S1",), "cell": "rnn"}})
    recording = graph_recording({"network.S1": 3, "network.PMC.0": 4, "network.PMC.1": 4})
    recording = {"no episode": recording.isel(episode=[]), "no step": recording.isel(time=[]),
                 "alive 0": recording.assign(alive=0 * recording["alive"])}[emptied]
    held = {"no episode": "holds no episode", "no step": "holds no step",
            "alive 0": "holds 3 episodes of 6 steps, with alive 0 at every step"}[emptied]
    fix = (rf"{held}: analyses and replays read only the steps that ran \(alive 1\)\. Record one with episodes "
           r"\(angora-jax record RUN_DIR --episodes N; in Python record_activity\(run_dir, episodes=N\)\)")
    for analysis in (lambda data: replay_activity(agent, data), principal_components,
                     lambda data: tuning_curves(data, "network.S1", "input_proprioception", feature=0)):
        with pytest.raises(ValueError, match=rf"^This recording {fix}"):
            analysis(recording)
    if emptied == "no step":  # NetCDF 3 reads a dimension of length 0 back as none: the file is refused as unreadable
        return
    path = tmp_path / "empty.nc"
    recording.to_netcdf(path, engine="scipy")  # as a notebook may save a selection: save_activity refuses it too
    assert cli.main(["analyze", "tuning", str(path), "--layer", "network.S1", "--variable", "input_proprioception",
                     "--feature", "0"]) == 2
    err = capsys.readouterr().err
    assert re.search(rf"^angora-jax analyze tuning: {re.escape(str(path))} {fix}", err) and "Traceback" not in err, err


def test_no_component_and_a_negative_lag_are_refused_by_name():
    """principal_components(components=0) returned an empty result, and cross_correlation(max_lag=-1) failed in numpy:
    "attempt to get argmax of an empty sequence"; timescales(max_lag=0) gave every unit no timescale."""
    data = synthetic(episodes=4, steps=30)
    with pytest.raises(ConfigError, match=r"^components must be a whole number of at least 1, got 0\.$"):
        principal_components(data, components=0)
    with pytest.raises(ConfigError, match=r"^max_lag must be a whole number of at least 0, got -1\.$"):
        cross_correlation(data, max_lag=-1)
    with pytest.raises(ConfigError, match=r"^max_lag must be a whole number of at least 1, got 0\.$"):
        timescales(data, max_lag=0)
    assert cross_correlation(data, max_lag=0).sizes["lag"] == 1


def test_a_plot_given_what_its_analysis_does_not_return_is_refused_and_one_into_a_new_folder_is_drawn(tmp_path):
    """plot_decoding(recording) failed in xarray (KeyError "No variable named 'r2'"), and a plot into a folder not made
    yet failed in PIL ("[Errno 2] No such file or directory"), where save_activity and export_policy make theirs."""
    from angora_jax.analysis import plot_cross_correlation, plot_decoding, plot_dynamics, plot_timescales, plot_tuning

    data = synthetic(episodes=4, steps=30)
    for plot, analysis, needs in ((plot_decoding, "decode", "r2"), (plot_timescales, "timescales", "autocorrelation"),
                                  (plot_cross_correlation, "cross_correlation", "cross_correlation"),
                                  (plot_dynamics, "principal_components", "explained"),
                                  (plot_tuning, "tuning_curves", "response")):
        with pytest.raises(TypeError, match=rf"^{plot.__name__} draws what {analysis} returns \(a Dataset with "
                                            rf"{needs}\), not a recording: give it {analysis}\(recording, \.\.\.\)\.$"):
            plot(data, tmp_path / "x.png")
        with pytest.raises(TypeError, match=rf"^{plot.__name__} draws what {analysis} returns \(a Dataset with "
                                            rf"{needs}\), not a DataArray\.$"):
            plot(data["activity_code"], tmp_path / "x.png")
    assert sorted(tmp_path.iterdir()) == []
    out = tmp_path / "new" / "deeper" / "t.png"
    plot_timescales(timescales(data), out)
    assert out.is_file()
    (tmp_path / "notes.txt").write_text("mine")
    with pytest.raises(ValueError, match=rf"^{tmp_path / 'notes.txt'} is a file, not a folder; give plot_timescales a "
                                         r"path in a folder you can write to\.$"):
        plot_timescales(timescales(data), tmp_path / "notes.txt" / "t.png")


def test_a_recording_of_one_step_is_refused_by_decoding_and_timescales_naming_what_they_need(tmp_path, capsys):
    """A recording of one step per episode (angora-jax record --steps 1) gave an R^2 of NaN when a fold held out one
    step (scikit-learn's R^2 of one sample), and timescales of NaN that the command put down to a --max-lag too
    short; with enough episodes decoding over episodes is defined and still computed."""
    from angora_jax import cli
    from angora_jax.analysis import save_activity

    one_step = synthetic(episodes=5, steps=1)
    with pytest.raises(ValueError, match=r"^Held-out R\^2 needs at least 2 steps in each fold's held-out episodes; 5 "
                                         r"folds over 5 steps of 5 episodes leave 1 step in a fold: record more "
                                         r"episodes or steps \(angora-jax record --episodes, --steps\), or decode "
                                         r"with fewer folds \(--folds\)\.$"):
        decode(one_step, folds=5)
    with pytest.raises(ValueError, match=r"^Timescales need episodes alive for at least 2 consecutive steps .* the "
                                         r"recording has 1 step per episode and none such: record more steps "
                                         r"\(angora-jax record --steps\)\.$"):
        timescales(one_step)
    path = save_activity(one_step, tmp_path / "one_step.nc")
    for argv, said in ((["decode", "--folds", "5"], "Held-out R^2 needs at least 2 steps"),
                       (["timescales"], "Timescales need episodes alive for at least 2 consecutive steps")):
        assert cli.main(["analyze", argv[0], str(path), *argv[1:]]) == 2
        assert said in capsys.readouterr().err
    assert np.isfinite(decode(synthetic(episodes=20, steps=1), folds=5)["r2"].values).all()
