"""Paper 003's Kalman filter and multi-step neural observer: oracles, rollout feedback, seeds, cache."""
import math
import subprocess
import sys
from dataclasses import replace

import numpy as np
import pytest

from mosd.estimators.ekf import AltitudeKalmanFilter
from mosd.estimators.neural_observer import MultiStepNeuralObserver
from mosd.plants.flapping_wing import FlappingWingModel
from mosd.types import Trace

import torch  # noqa: F401  (a test dependency: a missing one fails, never skips)

NAMES = ("gps_altitude", "down_velocity", "pitch", "throttle", "tail_deflection")
MODEL = FlappingWingModel(dt=0.2, output_names=NAMES, gps_variance=0.05**2, down_velocity_variance=0.05**2,
                          gps_bias_rate=1 / 1100, gps_bias_sigma=0.0)


def synthetic_logs(n_reps, n_samples, seed, gps_sigma=0.05, vd_sigma=0.05, walk_sigma=0.0):
    """Logs whose altitude follows the Kalman filter's own model exactly (known answers for the filter).

    The down velocity is a smooth random climb profile; the true altitude is its
    trapezoidal integral plus a random walk of step σ ``walk_sigma``; GPS and
    velocity noise are white.
    """
    rng = np.random.default_rng(seed)
    t = np.arange(n_samples) * 0.2
    phase = rng.uniform(0, 2 * np.pi, (n_reps, 3))
    v_true = (np.sin(0.05 * t + phase[:, :1]) + 0.5 * np.sin(0.13 * t + phase[:, 1:2])) * 1.5
    steps = 0.1 * (v_true[:, 1:] + v_true[:, :-1]) - walk_sigma * rng.standard_normal((n_reps, n_samples - 1))
    h = 50.0 - np.concatenate([np.zeros((n_reps, 1)), np.cumsum(steps, 1)], 1)
    others = np.stack([0.1 + 0.05 * np.sin(0.07 * t + phase[:, 2:3]) * np.ones((n_reps, 1)),
                       0.7 + 0.02 * v_true, -0.4 + 0.01 * v_true], -1)
    y = np.concatenate([(h + gps_sigma * rng.standard_normal(h.shape))[..., None],
                        (v_true + vd_sigma * rng.standard_normal(h.shape))[..., None], others], -1)
    x = np.zeros((n_reps, n_samples, 6))
    x[..., 4] = h
    return Trace(t=t, u=y[..., 3:], x=x, y=y, fault_mask=np.zeros((n_reps, n_samples), bool))


def small_observer(window, tmp_path=None, **kwargs):
    params = dict(window=window, hidden=4, fusion=4, epochs=3, batch_size=128, patience=2,
                  cache_dir=str(tmp_path) if tmp_path else None, progress=False)
    params.update(kwargs)
    return MultiStepNeuralObserver(**params)


@pytest.fixture(scope="module")
def training():
    return synthetic_logs(2, 200, seed=1)


def test_filter_variance_converges_to_the_riccati_solution():
    trace = synthetic_logs(3, 300, seed=2)
    kf = AltitudeKalmanFilter(model_error=0.02)
    out = kf.filter(trace, MODEL)
    q, r = kf.process_variance(MODEL), MODEL.gps_variance
    assert math.isclose(q, 0.2**2 * 0.05**2 / 2 + 0.02**2, rel_tol=1e-12)
    predicted = (q + math.sqrt(q * q + 4 * q * r)) / 2  # steady-state P_{k|k-1} of the scalar Riccati equation
    np.testing.assert_allclose(out["S"][:, -1], predicted + r, rtol=1e-9)
    assert np.isnan(out["r"][:, 0]).all() and np.isnan(out["chi2"][:, 0]).all()
    np.testing.assert_allclose(out["chi2"], out["r"] ** 2 / out["S"])


def test_filter_chi2_has_unit_mean_when_its_model_holds():
    # exact velocity, a white random walk of σ_m = model_error: the filter's model, so λ ~ χ²(1)
    # (with noisy velocity the trapezoid's errors are MA(1)-correlated and the law holds only roughly)
    trace = synthetic_logs(200, 150, seed=3, vd_sigma=0.0, walk_sigma=0.03)
    kf = AltitudeKalmanFilter(model_error=0.03)
    chi2 = kf.filter(trace, replace(MODEL, down_velocity_variance=0.0))["chi2"][:, 20:]
    assert abs(np.mean(chi2) - 1.0) < 0.05
    assert abs(np.mean(chi2 > 3.841458820694124) - 0.05) < 0.01


def test_filter_skips_missing_gps_samples():
    trace = synthetic_logs(2, 60, seed=4)
    y = trace.y.copy()
    y[0, 30, 0] = np.nan
    out = AltitudeKalmanFilter().filter(replace(trace, y=y), MODEL)
    assert np.isnan(out["r"][0, 30]) and np.isfinite(out["r"][0, 31]) and np.isfinite(out["r"][1, 30])
    assert out["S"][0, 31] > out["S"][1, 31]  # one missed update leaves more uncertainty


def test_same_seed_same_weights_and_predictions(training):
    a = small_observer(3).fit(training, MODEL, np.random.default_rng(11))
    b = small_observer(3).fit(training, MODEL, np.random.default_rng(11))
    c = small_observer(3).fit(training, MODEL, np.random.default_rng(12))
    for name in a.params_:
        np.testing.assert_array_equal(a.params_[name], b.params_[name])
    assert not np.array_equal(a.params_["w1"], c.params_["w1"])
    np.testing.assert_array_equal(a.predict(training.y), b.predict(training.y))
    np.testing.assert_array_equal(a.history_["validation_loss"], b.history_["validation_loss"])


def test_second_fit_loads_from_the_cache_without_training(training, tmp_path, monkeypatch):
    first = small_observer(2, tmp_path).fit(training, MODEL, np.random.default_rng(5))
    assert not first.loaded_from_cache_
    assert len(list(tmp_path.glob("*.npz"))) == 1

    def no_training(*args, **kwargs):
        raise AssertionError("retrained although the cache holds this training")

    monkeypatch.setattr(MultiStepNeuralObserver, "_train", no_training)
    second = small_observer(2, tmp_path).fit(training, MODEL, np.random.default_rng(5))
    assert second.loaded_from_cache_
    for name in first.params_:
        np.testing.assert_array_equal(first.params_[name], second.params_[name])
    # another seed, window or training set is another entry, hence a training
    with pytest.raises(AssertionError, match="retrained"):
        small_observer(2, tmp_path).fit(training, MODEL, np.random.default_rng(6))
    with pytest.raises(AssertionError, match="retrained"):
        small_observer(3, tmp_path).fit(training, MODEL, np.random.default_rng(5))
    with pytest.raises(AssertionError, match="retrained"):
        small_observer(2, tmp_path).fit(synthetic_logs(2, 200, seed=9), MODEL, np.random.default_rng(5))


@pytest.mark.parametrize("window", [1, 4])
def test_rollout_feeds_back_its_own_predictions(training, window):
    observer = small_observer(window).fit(training, MODEL, np.random.default_rng(3))
    test = synthetic_logs(2, 80, seed=7)
    onset = 40
    y = test.y.copy()
    y[:, onset:, 0] += 0.5 + 0.1 * np.arange(80 - onset)  # a drift present from step 40 on
    clean, faulty = observer.predict(test.y), observer.predict(y)
    # ĥ_k starts from the measured h_{k−N}: blind to the drift for N−1 steps after the onset
    np.testing.assert_array_equal(faulty[:, : onset + window], clean[:, : onset + window])
    assert np.all(faulty[:, onset + window] != clean[:, onset + window])
    assert np.isnan(clean[:, :window]).all() and np.isfinite(clean[:, window:]).all()


def test_prediction_matches_a_hand_rollout(training):
    observer = small_observer(3).fit(training, MODEL, np.random.default_rng(4))
    p, s = observer.params_, observer.scaling_
    y = training.y[0]
    k = 50
    h = y[k - 3, 0]
    for j in range(3):
        x = (np.r_[h, y[k - 3 + j, 1:]] - s["input_mean"]) / s["input_std"]
        a1 = np.maximum(x @ p["w1"][j] + p["b1"][j], 0)
        a2 = np.maximum(a1 @ p["w2"][j] + p["b2"][j], 0)
        h = h + s["step_mean"] + s["step_std"] * (a2 @ p["w3"][j] + p["b3"][j])[0]
    assert math.isclose(observer.predict(training.y)[0, k], float(h), rel_tol=1e-12)


def test_estimate_outputs(training):
    observer = small_observer(2).fit(training, MODEL, np.random.default_rng(4))
    out = observer.estimate(training, MODEL)
    assert out.r.shape == (2, 200, 1) and out.cov.shape == (2, 200, 1, 1) and out.channels == ("gps_altitude",)
    for name in ("chi2", "observer_residual", "observer_chi2", "h_hat"):
        assert out.extra[name].shape == (2, 200)
    np.testing.assert_allclose(out.extra["observer_residual"], np.abs(training.y[..., 0] - out.extra["h_hat"]))
    np.testing.assert_allclose(out.extra["chi2"], AltitudeKalmanFilter().filter(training, MODEL)["chi2"])
    weights = observer.step_weights()
    assert math.isclose(weights.sum(), 1.0) and weights[0] > weights[-1]
    assert observer.requires_fit and not observer.fit_on_faults


def test_estimate_before_fit_and_bad_config():
    from mosd.validation import ConfigError

    with pytest.raises(RuntimeError, match="before fit"):
        small_observer(2).estimate(synthetic_logs(1, 30, seed=0), MODEL)
    with pytest.raises(ConfigError, match="estimator.window"):
        MultiStepNeuralObserver(window=0)
    with pytest.raises(ConfigError, match="estimator.weighting"):
        MultiStepNeuralObserver(weighting="cubic")
    with pytest.raises(ConfigError, match="estimator.window"):
        small_observer(60).fit(synthetic_logs(1, 100, seed=0), MODEL, np.random.default_rng(0))


def test_module_imports_without_torch():
    code = ("import sys, importlib.util; sys.modules['torch'] = None; "
            "spec = importlib.util.spec_from_file_location('x', 'mosd/estimators/neural_observer.py'); "
            "import mosd.estimators.neural_observer as m; print('ok')")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=".")
    assert done.returncode == 0 and "ok" in done.stdout, done.stderr


def test_missing_pytorch_is_one_line_at_construction(monkeypatch):
    import importlib.util

    from mosd.estimators.neural_observer import MultiStepNeuralObserver
    from mosd.validation import ConfigError

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "torch" else real(name, *a))
    with pytest.raises(ConfigError, match=r"estimator=neural_observer needs PyTorch.*pip install"):
        MultiStepNeuralObserver()
