"""Paper 002 (reconstruction): entropy-optimal isolation filter, fixed-gain baseline, threshold detector."""
import math

import numpy as np
import pytest
from scipy import stats

from mosd.detectors.threshold import ThresholdDetector
from mosd.estimators.entropy_filter import (EntropyIsolationFilter, FixedGainFilter, information_potential,
                                            renyi_quadratic, silverman_bandwidth)
from mosd.faults.base import FaultSet
from mosd.faults.random_amplitude import RandomAmplitudeFault
from mosd.noise.bounded import BoundedNoise
from mosd.plants.scalar_nonlinear import ScalarNonlinearPlant
from mosd.scenario import Scenario
from mosd.validation import ConfigError


def affine_errors(seed=0, n=300):
    rng = np.random.default_rng(seed)
    b = rng.normal(0.0, 1.0, n)
    a = 0.3 * b + rng.uniform(-0.5, 0.5, n)
    return a, b


def paper_scenario(missing_rate=0.0):
    faults = FaultSet([RandomAmplitudeFault("sine", role="target"), RandomAmplitudeFault("ramp", role="nuisance")])
    return Scenario(ScalarNonlinearPlant(missing_rate=missing_rate), BoundedNoise(), faults, duration=10.0)


@pytest.fixture(scope="module")
def designed():
    sc = paper_scenario()
    template = sc.simulate(0, 1, "estimator")
    est = EntropyIsolationFilter(n_particles=200).fit(template, sc.plant.model(sc.noise), np.random.default_rng(9))
    return est, sc


def test_information_potential_equals_the_double_sum_of_gaussians():
    a, b = affine_errors(n=40)
    s, U = 0.2, 0.7
    e = a - U * b
    direct = np.mean([stats.norm.pdf(ei - ej, scale=math.sqrt(2) * s) for ei in e for ej in e])
    V, _, _ = information_potential(a, b, U, s)
    assert V == pytest.approx(direct, rel=1e-12)


@pytest.mark.parametrize("U", [-0.4, 0.1, 0.8])
def test_closed_form_derivatives_match_finite_differences(U):
    a, b = affine_errors()
    s, h = silverman_bandwidth(a - U * b), 1e-5
    V, dV, d2V = information_potential(a, b, U, s)
    Vp, dVp, _ = information_potential(a, b, U + h, s)
    Vm, dVm, _ = information_potential(a, b, U - h, s)
    assert dV == pytest.approx((Vp - Vm) / (2 * h), rel=1e-6)
    assert d2V == pytest.approx((dVp - dVm) / (2 * h), rel=1e-6)
    H, dH, d2H = renyi_quadratic(a, b, U, s)
    Hp, dHp, _ = renyi_quadratic(a, b, U + h, s)
    Hm, dHm, _ = renyi_quadratic(a, b, U - h, s)
    assert H == pytest.approx(-math.log(V))
    assert dH == pytest.approx((Hp - Hm) / (2 * h), rel=1e-6)
    assert d2H == pytest.approx((dHp - dHm) / (2 * h), rel=1e-6)
    est = EntropyIsolationFilter(n_particles=50)
    a2, b2 = affine_errors(seed=1)
    J, dJ, d2J = est.cost(a, b, a2, b2, U, s, 0.15)
    Jp, _, _ = est.cost(a, b, a2, b2, U + h, s, 0.15)
    Jm, _, _ = est.cost(a, b, a2, b2, U - h, s, 0.15)
    assert dJ == pytest.approx((Jp - Jm) / (2 * h), rel=1e-6)
    assert d2J == pytest.approx((Jp - 2 * J + Jm) / h**2, rel=1e-3)


def test_renyi_entropy_is_shift_invariant_and_grows_with_spread():
    a, b = affine_errors()
    H = renyi_quadratic(a, b, 0.2, 0.1)[0]
    assert renyi_quadratic(a + 3.0, b, 0.2, 0.1)[0] == pytest.approx(H, abs=1e-12)
    assert renyi_quadratic(2 * a, 2 * b, 0.2, 0.1)[0] > H + 0.5


def test_newton_step_reaches_the_minimum_of_a_convex_cost():
    # one ensemble only (R1 = 0): the minimum of H₂(e²) is near the least-squares gain cov(a, b)/var(b)
    a, b = affine_errors(n=400)
    est = EntropyIsolationFilter(n_particles=50, R1=0.0, R2=1.0, gain_low=-2, gain_high=2, newton_steps=20)
    gain = est._step(a, b, a, b, 0.0)
    assert gain == pytest.approx(np.cov(a, b)[0, 1] / np.var(b, ddof=1), abs=0.05)


def test_design_is_seeded_bounded_and_raises_the_gain_after_the_onset(designed):
    est, sc = designed
    assert est.gain_.shape == (100,)
    assert est.gain_.min() >= 0.0 and est.gain_.max() <= 1.0
    again = EntropyIsolationFilter(n_particles=200).fit(sc.simulate(0, 1, "estimator"), sc.plant.model(sc.noise),
                                                        np.random.default_rng(9))
    np.testing.assert_array_equal(again.gain_, est.gain_)
    assert est.gain_[10:50].mean() < 0.15 < 0.3 < est.gain_[60:].mean()
    target, nuisance = est.design_["target_error"], est.design_["nuisance_error"]
    assert target[60:].mean() > 1.5 * nuisance[60:].mean()


def test_estimate_outputs_shapes_and_isolation_on_simulated_runs(designed):
    est, sc = designed
    sc_missing = paper_scenario(0.1)
    trace = sc_missing.simulate(1, 40, "test")
    out = est.estimate(trace, sc.plant.model(sc.noise))
    assert out.r.shape == (40, 100, 1)
    for key in ("error", "gain", "x_hat", "y_filled", "innovation"):
        assert out.extra[key].shape == (40, 100)
    missing = np.isnan(trace.y[..., 0])
    np.testing.assert_array_equal(np.isnan(out.r[..., 0]), missing)
    assert not np.isnan(out.extra["y_filled"]).any()
    np.testing.assert_allclose(out.extra["error"], trace.x[..., 0] - out.extra["x_hat"])
    level = out.extra["error"][:, 60:].mean(axis=1)
    target = trace.fault_mask.any(axis=1)
    assert level[target].mean() > 1.5 * level[~target].mean()


def test_fixed_gain_filter_matches_a_hand_recursion_and_skip_mode():
    sc = paper_scenario(0.2)
    trace = sc.simulate(2, 3, "test")
    model = sc.plant.model(sc.noise)
    out = FixedGainFilter(gain=0.3, missing="skip").estimate(trace, model)
    for r in range(3):
        xh = 0.0
        for k in range(100):
            assert out.extra["x_hat"][r, k] == pytest.approx(xh, abs=1e-12)
            y = trace.y[r, k, 0]
            xh = 0.5 * xh + 0.2 * math.sin(xh) + (0.0 if math.isnan(y) else 0.3 * (y - xh))
    assert np.isnan(out.extra["innovation"][np.isnan(trace.y[..., 0])]).all()
    zero = FixedGainFilter(gain=0.0).estimate(trace, model)
    np.testing.assert_array_equal(zero.extra["x_hat"], 0.0)


def test_filter_validation_and_fit_before_estimate(designed):
    _, sc = designed
    with pytest.raises(ConfigError, match="estimator.gain_high"):
        EntropyIsolationFilter(gain_low=0.5, gain_high=0.5)
    with pytest.raises(ConfigError, match="estimator.R1"):
        EntropyIsolationFilter(R1=0.0, R2=0.0)
    with pytest.raises(ConfigError, match="estimator.missing"):
        FixedGainFilter(missing="mean")
    with pytest.raises(ConfigError, match="before fit"):
        EntropyIsolationFilter().estimate(sc.simulate(0, 2, "test"), sc.plant.model(sc.noise))
    short = Scenario(sc.plant, sc.noise, RandomAmplitudeFault("sine", onset=1.0), duration=2.0)
    est = EntropyIsolationFilter(n_particles=50).fit(short.simulate(0, 1, "estimator"), short.plant.model(short.noise),
                                                     np.random.default_rng(0))
    with pytest.raises(ConfigError, match="longer than the designed"):
        est.estimate(sc.simulate(0, 2, "test"), sc.plant.model(sc.noise))


def test_threshold_detector_persistence_known_answer():
    z = np.array([0.0, 2.0, -2.0, 0.0, 2.0, 2.0, 2.0])[None, :, None]
    det = ThresholdDetector(threshold=1.0, persistence=1)
    X = np.array([[1.0, 1], [1.0, 2], [1.0, 3], [2.5, 1]])
    d = det.population(det.features(z), det.features(z), X)
    assert d.statistic.shape == d.decision.shape == (4, 1, 7)
    np.testing.assert_array_equal(d.decision[:, 0], [[0, 1, 1, 0, 1, 1, 1], [0, 0, 1, 0, 0, 1, 1],
                                                     [0, 0, 0, 0, 0, 0, 1], [0] * 7])
    nan_gap = np.array([2.0, np.nan, 2.0, 2.0])[None, :, None]
    np.testing.assert_array_equal(ThresholdDetector(1.0, 2).decide(nan_gap, nan_gap).decision[0], [0, 0, 0, 1])
    two = np.array([[[0.0, 3.0], [0.5, 0.2]]])
    np.testing.assert_array_equal(ThresholdDetector(1.0, 1).decide(two, two).decision[0], [1, 0])


def test_threshold_detector_parameters():
    det = ThresholdDetector(threshold=0.8, persistence=3, threshold_max=2.0)
    assert det.tunable["threshold"].high == 2.0
    np.testing.assert_array_equal(det.design(), [[0.8, 3.0]])
    assert [c.persistence for c in det.candidates(np.array([[0.5, 2.4], [1.5, 5.0]]))] == [2, 5]
    with pytest.raises(ConfigError, match="detector.threshold"):
        ThresholdDetector(threshold=0.0)
    with pytest.raises(ConfigError, match="detector.persistence=1.5 is not an integer"):
        ThresholdDetector(persistence=1.5)
    with pytest.raises(ConfigError, match="detector.threshold"):
        det.with_params(threshold=3.0)
