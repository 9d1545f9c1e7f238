"""The analyses on data with known answers: RDMs (symmetric, zero diagonal, the right model RDM wins), fixed points
of a hand-built linear RNN, timescales of AR(1) units, tuning strength, PCA dimensionality, lagged decoding and
cross-correlation of a layer that another follows by 3 steps."""

import jax.numpy as jnp
import numpy as np
import pytest
import xarray as xr

from angora_jax.analysis import (
    cross_correlation,
    decode,
    find_fixed_points,
    principal_components,
    similarity,
    timescales,
    tuning_curves,
)

DT = 0.02


def synthetic(episodes=20, steps=50, seed=0):
    """A recording with a variable x per step, a layer `code` whose 6 units are linear in x, a layer `noise` of pure
    noise and a layer `slow` of AR(1) units with coefficient 0.9 (timescale -1/ln 0.9 steps)."""
    rng = np.random.default_rng(seed)
    x = rng.uniform(-1, 1, (episodes, steps))
    code = x[..., None] * rng.standard_normal(6) + 0.01 * rng.standard_normal((episodes, steps, 6))
    slow = np.zeros((episodes, steps, 4))
    for t in range(1, steps):
        slow[:, t] = 0.9 * slow[:, t - 1] + rng.standard_normal((episodes, 4))
    alive = np.ones((episodes, steps))
    alive[0, 40:] = 0  # one episode ends early: its last steps are masked
    data = {"metric_x": (("episode", "time"), x), "alive": (("episode", "time"), alive),
            "activity_code": (("episode", "time", "code_unit"), code),
            "activity_noise": (("episode", "time", "noise_unit"), rng.standard_normal((episodes, steps, 5))),
            "activity_slow": (("episode", "time", "slow_unit"), slow)}
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

    def eigvals(matrices):
        decomposed.append(len(matrices))
        return original(matrices)

    monkeypatch.setattr(np.linalg, "eigvals", eigvals)
    found = find_fixed_points(lambda h: jnp.asarray(a, jnp.float32) @ h, np.random.default_rng(2).standard_normal(
        (5, 3)), iterations=50)
    assert found["fixed"].all() and decomposed == [1]
    np.testing.assert_allclose(np.abs(found["eigenvalues"]), np.broadcast_to([0.5, 0.25, 0.1], (5, 3)), atol=1e-6)


def test_timescales_of_ar1_units_and_white_noise():
    result = timescales(synthetic(episodes=200), layers=["slow", "noise"], max_lag=30)
    expected = -1 / np.log(0.9) * DT  # acf(k) = 0.9^k crosses 1/e at k = -1 / ln 0.9
    assert result["timescale_median"].sel(layer="slow") == pytest.approx(expected, rel=0.15)
    assert result["timescale_median"].sel(layer="noise") < DT  # uncorrelated: below 1/e at the first lag
    np.testing.assert_allclose(result["autocorrelation"].sel(layer="slow").values[:4], 0.9 ** np.arange(4), atol=0.05)


def test_tuning_strength_separates_a_tuned_layer_from_noise():
    data = synthetic()
    tuned, noise = (tuning_curves(data, layer, "metric_x", bins=8) for layer in ("code", "noise"))
    assert tuned["response"].shape == (8, 6) and tuned["strength"].min() > 0.9
    assert noise["strength"].max() < 0.1
    assert np.all(np.diff(tuned["center"].values) > 0), "bins ordered by the variable"


def test_pca_finds_one_dimension_in_a_rank_one_code():
    result = principal_components(synthetic(), layers=["code", "noise"], components=4)
    assert result["explained"].sel(layer="code", component=0) > 0.99
    assert int(result["dimensionality"].sel(layer="code")) == 1
    assert int(result["dimensionality"].sel(layer="noise")) >= 4
    trajectory = result["trajectory_code"].values
    assert np.isnan(trajectory[0, 45]).all() and np.isfinite(trajectory[1]).all(), "dead steps are not projected"


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
    with pytest.raises(ValueError, match="lags must be shorter than the recording's 60 steps"):
        decode(leader_and_follower(), layers=["lead"], variables=["metric_echo"], lags=[60])


def test_cross_correlation_peaks_where_one_layer_follows_another():
    result = cross_correlation(leader_and_follower(), max_lag=6)
    assert float(result["peak_lag"].sel(layer="lead", other="follow")) == pytest.approx(3 * DT)
    assert float(result["peak_lag"].sel(layer="follow", other="lead")) == pytest.approx(-3 * DT)
    peak = result["cross_correlation"].sel(layer="lead", other="follow").sel(lag=3 * DT, method="nearest")
    assert abs(float(peak)) > 0.95
    np.testing.assert_allclose(result["cross_correlation"].sel(layer="lead", other="lead").sel(lag=0.0), 1.0, atol=1e-9)
