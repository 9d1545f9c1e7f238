"""SINDy of a layer's dynamics (angora_jax.analysis.equations) on systems whose equations are known: a linear RNN
h[k+1] = A h[k] and a damped oscillator (continuous time) recover their terms, and coefficients within 5%; a linear
RNN hidden in a recording's units is found in its principal components, and predicts held-out episodes far better
than next = current; a driven one is predicted from its input layer; bad input gets a message naming the fix; the
probing page's example runs. The trained reach agent is in test_analysis.py."""

import numpy as np
import pytest
import xarray as xr
from scipy.linalg import expm
from test_docs import marked_blocks

from angora_jax.analysis import fit_sindy, sindy
from angora_jax.experiment import ConfigError

# h[k+1] = A h[k]: a decaying rotation in (x, y) that drives z, which decays on its own.
LINEAR_RNN = np.array([[0.9, -0.2, 0.0],
                       [0.2, 0.9, 0.0],
                       [0.0, 0.1, 0.7]])
# x'' + 2 zeta omega x' + omega^2 x = 0 with omega 2/s, zeta 0.1: x' = v, v' = -4 x - 0.4 v.
OSCILLATOR = np.array([[0.0, 1.0],
                       [-4.0, -0.4]])


def linear_trajectories(step: np.ndarray, episodes: int, steps: int, seed: int = 0, noise: float = 0.0):
    """`episodes` arrays `(steps, n)` of x[k+1] = step @ x[k] from standard normal starts, plus measurement noise."""
    rng = np.random.default_rng(seed)
    x = np.empty((episodes, steps, len(step)))
    x[:, 0] = rng.standard_normal((episodes, len(step)))
    for k in range(1, steps):
        x[:, k] = x[:, k - 1] @ step.T
    return list(x + noise * rng.standard_normal(x.shape))


def assert_recovers(model, expected: np.ndarray, names: list[str]):
    """Exactly the linear terms of `expected` (rows: equations, columns: `names`) and no others; each within 5%."""
    terms = model.get_feature_names()
    coefficients = model.coefficients()
    linear = [terms.index(name) for name in names]
    others = [i for i in range(len(terms)) if i not in linear]
    support = coefficients[:, linear] != 0
    np.testing.assert_array_equal(support, expected != 0, err_msg=f"terms found: {model.equations()}")
    assert np.all(coefficients[:, others] == 0), model.equations()
    found = coefficients[:, linear][expected != 0]
    np.testing.assert_allclose(found, expected[expected != 0], rtol=0.05, err_msg=str(model.equations()))


def test_a_linear_rnn_gets_its_matrix_back():
    trajectories = linear_trajectories(LINEAR_RNN, episodes=20, steps=30, noise=1e-3)
    model = fit_sindy(trajectories, dt=0.02, names=["x", "y", "z"], degree=2)
    assert_recovers(model, LINEAR_RNN, ["x", "y", "z"])


def test_a_damped_oscillator_gets_its_equations_back_in_continuous_time():
    dt = 0.01
    trajectories = linear_trajectories(expm(OSCILLATOR * dt), episodes=10, steps=300)  # exact samples of the flow
    model = fit_sindy(trajectories, dt=dt, names=["x", "v"], discrete=False, degree=2)
    assert_recovers(model, OSCILLATOR, ["x", "v"])


def recording(latent: list[np.ndarray], units: int, dt: float = 0.02, seed: int = 1, **layers) -> xr.Dataset:
    """A recording whose layer `rnn` is the latent trajectories embedded in `units` units (an orthonormal map plus an
    offset), and so each of `layers` (name: (episode, time, n) latent). Each episode ends at a different step, and
    the steps after its end hold large garbage, as a recording's next episode would: the analysis must use the
    alive steps only."""
    rng = np.random.default_rng(seed)
    lengths = rng.integers(len(latent[0]) // 2, len(latent[0]) + 1, size=len(latent))
    alive = np.arange(len(latent[0]))[None] < lengths[:, None]
    data = {"alive": (("episode", "time"), alive.astype(np.float32))}
    for name, values in {"rnn": np.stack(latent), **layers}.items():
        embedding = np.linalg.qr(rng.standard_normal((units, values.shape[-1])))[0]
        activity = values @ embedding.T + rng.standard_normal(units)
        activity[~alive] = 100.0 * rng.standard_normal((int((~alive).sum()), units))
        data[f"activity_{name}"] = (("episode", "time", f"{name}_unit"), activity)
    return xr.Dataset(data, coords={"time": np.arange(alive.shape[1]) * dt}, attrs={"policy_step_s": dt})


def test_a_linear_rnn_in_a_recording_is_found_in_its_principal_components_and_predicts_held_out_episodes():
    angle = 0.25
    rotation = 0.95 * np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    data = recording(linear_trajectories(rotation, episodes=16, steps=40), units=6)
    # The components are centred on the mean of the train steps, which is not the map's fixed point (0): the
    # equations have a constant of about 0.03, which the default threshold of 0.05 would drop.
    result = sindy(data, "rnn", components=2, horizon=10, threshold=0.01)
    # The components are the latent plane up to a rotation, reflection and scale: the linear map's eigenvalues stay.
    linear = result["coefficients"].sel(term=["PC1", "PC2"]).values
    eigenvalues = np.linalg.eigvals(linear)
    np.testing.assert_allclose(np.sort(np.abs(eigenvalues)), [0.95, 0.95], rtol=0.05)
    np.testing.assert_allclose(np.sort(np.abs(np.angle(eigenvalues))), [angle, angle], rtol=0.05)
    quadratic = [term for term in result["term"].values if "^" in term or " " in term]
    assert np.all(result["coefficients"].sel(term=quadratic).values == 0), list(result["equation"].values)
    assert result["equation"].values[0].startswith("PC1[k+1] = ")
    assert result.attrs["held_out_episodes"] == 4 and result.attrs["train_episodes"] == 12
    assert float(result["r2_one_step"]) > 0.99 > float(result["baseline_r2_one_step"])
    error, baseline = result["simulation_error"].values, result["baseline_error"].values
    assert error[0] == baseline[0] == 0 and np.all(error[1:] < 1e-6) and np.all(baseline[1:] > 0.2), (error, baseline)


def test_a_driven_rnn_is_predicted_from_its_input_layer_at_the_step_it_enters():
    """h[k+1] = A h[k] + B x[k+1], as a recurrent cell's state follows its input at the same step: with the input
    layer as terms the held-out simulation is exact; without, the model misses what the input drives."""
    rng = np.random.default_rng(2)
    drive = rng.standard_normal((16, 40, 2))
    state = np.zeros((16, 40, 2))
    state[:, 0] = rng.standard_normal((16, 2))
    for k in range(1, 40):
        state[:, k] = state[:, k - 1] @ (0.9 * np.eye(2)).T + drive[:, k] @ np.array([[0.5, 0.0], [0.2, 0.4]]).T
    data = recording(list(state), units=6, rnn_in=drive)
    # The centring leaves constants of about 0.006 (see the test above), which 0.01 would drop.
    driven = sindy(data, "rnn", components=2, inputs="rnn_in", degree=1, threshold=0.001)
    assert set(driven["term"].values) == {"1", "PC1", "PC2", "IN1", "IN2"}
    assert "IN1[k+1]" in " ".join(driven["equation"].values) and "IN1[k]" not in " ".join(driven["equation"].values)
    assert driven.attrs["inputs"] == "rnn_in" and float(driven["r2_one_step"]) > 0.999
    assert np.all(driven["simulation_error"].values < 1e-6), driven["simulation_error"].values
    alone = sindy(data, "rnn", components=2, degree=1, threshold=0.001)
    assert float(alone["r2_one_step"]) < 0.8 and np.all(alone["simulation_error"].values[1:] > 0.1)


def test_bad_input_names_the_cause_and_the_fix():
    data = recording(linear_trajectories(LINEAR_RNN, episodes=4, steps=10), units=5)
    with pytest.raises(ValueError, match=r"Not in the recording: no layer 'cortex'.* Its layers: rnn\. Its "
                                         r"variables: "):
        sindy(data, "cortex")
    with pytest.raises(ValueError, match="6 components of 'rnn', which has 5 units: ask for at most 5"):
        sindy(data, "rnn", components=6, horizon=5)
    with pytest.raises(ValueError, match="2 time steps; the dynamics need at least 3.*--steps"):
        sindy(data.isel(time=slice(0, 2)), "rnn", horizon=1)
    with pytest.raises(ValueError, match=r"1 episode; SINDy needs one to fit and one held out.*--episodes"):
        sindy(data.isel(episode=slice(0, 1)), "rnn", horizon=5)
    with pytest.raises(ValueError, match="transitions for 56 library terms.*fewer --components"):
        sindy(data, "rnn", components=5, degree=3, horizon=5)
    with pytest.raises(ValueError, match=r"horizon must be a whole number from 1 to 9 \(--horizon; the recording "
                                         r"has 10 time steps\), got 10"):
        sindy(data, "rnn", horizon=10)


def test_sindy_options_out_of_range_are_config_errors_naming_them():
    """Notebook trial: sindy(horizon=2.5) failed inside NumPy ("'float' object cannot be interpreted as an integer"),
    components or degree of 1.5 in scikit-learn or math.comb, seed=1.5 in NumPy, held_out="0.3" comparing text with a
    number; the range, components and transitions refusals were plain ValueErrors, which the command still printed but
    a notebook could not tell from a bug. All are ConfigErrors naming the argument, the value and the range."""
    data = recording(linear_trajectories(LINEAR_RNN, episodes=4, steps=10), units=5)
    for options, said in (({"horizon": 2.5}, r"^horizon must be a whole number of at least 1, got 2\.5\.$"),
                          ({"horizon": True}, r"^horizon must be a whole number of at least 1, got True\.$"),
                          ({"horizon": 0}, r"^horizon must be a whole number of at least 1, got 0\.$"),
                          ({"horizon": 10}, r"^horizon must be a whole number from 1 to 9 \(--horizon; the "
                                            r"recording has 10 time steps\), got 10\.$"),
                          ({"components": 1.5}, r"^components must be a whole number of at least 1, got 1\.5\.$"),
                          ({"components": 6}, r"^6 components of 'rnn', which has 5 units: ask for at most 5"),
                          ({"degree": 1.5}, r"^degree must be a whole number of at least 1, got 1\.5\.$"),
                          ({"threshold": -0.1}, r"^threshold must be a number of at least 0, got -0\.1\.$"),
                          ({"seed": 1.5}, r"^seed must be a whole number from 0 to 4,294,967,295, got 1\.5\.$"),
                          ({"held_out": "0.3"}, r"^held_out \(the fraction of the episodes held out, --held-out\) "
                                                r"must be a number above 0 and below 1, got '0\.3'\.$"),
                          ({"held_out": 1}, r"^held_out \(.*\) must be a number above 0 and below 1, got 1\.$"),
                          ({"components": 5, "degree": 3}, r"^The train episodes give \d+ transitions for 56 library")):
        with pytest.raises(ConfigError, match=said):
            sindy(data, "rnn", **{"horizon": 5, **options})


def test_the_probing_page_example_runs_and_finds_its_equations(tmp_path, monkeypatch, capsys):
    """docs/probing.md's marked block, run here in-process (tests/test_docs.py runs other pages' blocks in a fresh
    interpreter, which for this one would spend some 8 s of CPU importing what this file has imported)."""
    _, script = marked_blocks("probing.md")
    monkeypatch.chdir(tmp_path)
    exec(compile(script, "docs/probing.md", "exec"), {})
    out = capsys.readouterr().out
    assert "PC1[k+1] = " in out and "one-step R^2 0.99" in out, out
    assert (tmp_path / "sindy.png").read_bytes()[:4] == b"\x89PNG"
