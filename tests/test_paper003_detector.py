"""Paper 003's adaptive χ² detector and the Table-2 bookkeeping, on hand-made arrays."""
import math

import numpy as np
import pytest

from mosd.detectors.adaptive_chi2 import AdaptiveChi2Detector
from mosd.validation import ConfigError


def test_threshold_is_the_chi2_quantile():
    detector = AdaptiveChi2Detector(dof=1)
    assert math.isclose(detector.chi2_threshold(0.05), 3.841458820694124, rel_tol=1e-12)
    # independently of SciPy: the closed-form χ² survival functions of 1, 2 and 3 degrees of freedom
    # give back α at the threshold (P(χ²_k > T) = α defines the (1 − α) quantile)
    survival = {1: lambda x: math.erfc(math.sqrt(x / 2)),
                2: lambda x: math.exp(-x / 2),
                3: lambda x: math.erfc(math.sqrt(x / 2)) + math.sqrt(2 * x / math.pi) * math.exp(-x / 2)}
    alphas = np.array([0.001, 0.01, 0.2])
    for dof, sf in survival.items():
        thresholds = AdaptiveChi2Detector(dof=dof).chi2_threshold(alphas)
        np.testing.assert_allclose([sf(t) for t in thresholds], alphas, rtol=1e-10, err_msg=f"dof={dof}")


def test_decisions_on_hand_made_points():
    """T_k = a·T_D + b·(E_{k−d}/σ_N)² with the default lag d = 1 (issue 20: dimensionless and lagged)."""
    z = np.zeros((2, 5, 2))
    z[0, :, 0] = [0.0, 4.0, 3.0, 10.0, np.nan]   # λ_k
    z[0, :, 1] = [0.0, 0.0, 0.0, 3.0, 0.0]       # E_k/σ_N
    z[1, :, 0] = [5.0, 5.0, 5.0, 5.0, 5.0]
    z[1, :, 1] = [0.0, 0.5, 1.0, 1.5, np.nan]
    X = np.array([[0.05, 1.0, 1.0],     # T = 3.84 + (E_{k-1}/σ)²
                  [0.05, 1.0, 0.0],     # E ignored
                  [0.05, 0.0, 1.0]])    # T = (E_{k-1}/σ)² only
    decided = AdaptiveChi2Detector().population(None, z, X)
    assert decided.statistic.shape == decided.decision.shape == (3, 2, 5)
    # k = 0 has no E_{k-1}: no alarm unless b = 0; run 0's E = 3 at k = 3 raises only k = 4's threshold
    np.testing.assert_array_equal(decided.decision[0], [[0, 1, 0, 1, 0], [0, 1, 1, 1, 0]])
    np.testing.assert_array_equal(decided.decision[1], [[0, 1, 0, 1, 0], [1, 1, 1, 1, 1]])
    np.testing.assert_array_equal(decided.decision[2], [[0, 1, 1, 1, 0], [0, 1, 1, 1, 1]])
    np.testing.assert_allclose(decided.threshold[0, 1, 1:], 3.841458820694124 + z[1, :-1, 1] ** 2)
    # the one design of decide() is the first row of the population
    single = AdaptiveChi2Detector(alpha=0.05).decide(z, z)
    np.testing.assert_array_equal(single.decision, decided.decision[0])


def test_threshold_lag_is_a_parameter():
    z = np.zeros((1, 6, 2))
    z[0, :, 0] = 5.0
    z[0, 2, 1] = 2.0                     # E/σ_N = 2 at k = 2 only: the threshold rises by b·4 d points later
    for lag in (0, 1, 3):
        decided = AdaptiveChi2Detector(alpha=0.05, b=1.0, lag=lag).decide(z, z)
        expected = np.ones(6, int)
        expected[:lag] = 0               # no E_{k-d} yet
        expected[2 + lag] = 0            # 5 < 3.84 + 4
        np.testing.assert_array_equal(decided.decision[0], expected)
    with pytest.raises(ConfigError, match="detector.lag"):
        AdaptiveChi2Detector(lag=-1)


def test_persistence_needs_consecutive_exceedances():
    z = np.zeros((1, 6, 2))
    z[0, :, 0] = [9, 9, 0, 9, 9, 9]
    decided = AdaptiveChi2Detector(alpha=0.01, b=0.0, persistence=2).decide(z, z)
    np.testing.assert_array_equal(decided.decision[0], [0, 1, 0, 0, 1, 1])


def test_false_alarm_rate_is_alpha_under_the_null():
    rng = np.random.default_rng(0)
    z = np.stack([rng.chisquare(2, size=(40, 2500)), np.zeros((40, 2500))], -1)
    X = np.array([[0.01, 1.0, 0.0], [0.1, 1.0, 0.0]])
    decided = AdaptiveChi2Detector(dof=2).population(None, z, X)
    rates = decided.decision.mean(axis=(1, 2))
    np.testing.assert_allclose(rates, [0.01, 0.1], rtol=0.06)


def test_validation_and_tuning():
    with pytest.raises(ConfigError, match="detector.alpha"):
        AdaptiveChi2Detector(alpha=0.0)
    with pytest.raises(ConfigError, match="detector.b"):
        AdaptiveChi2Detector(b=25.0)
    with pytest.raises(ConfigError, match=r"\(R, K, 2\)"):
        AdaptiveChi2Detector().decide(np.zeros((1, 4, 1)), np.zeros((1, 4, 1)))
    assert list(AdaptiveChi2Detector.tunable) == ["alpha", "a", "b"]
    tuned = AdaptiveChi2Detector().with_params(alpha=0.2, b=3.0)
    assert (tuned.alpha, tuned.a, tuned.b) == (0.2, 1.0, 3.0)


def test_detection_summary_definitions():
    from mosd.systems.paper003 import detection_summary

    decision = np.zeros((3, 10), int)
    decision[0, [1, 6]] = 1          # a false alarm, then detection at 6
    decision[1, 5:] = 1              # detection at the onset
    summary = detection_summary(decision, onset_step=5, first_valid=1)
    np.testing.assert_array_equal(summary["first_alarm"], [6, 5, -1])
    assert summary["detection_step"] == 5.5
    assert math.isclose(summary["run_detection_share"], 2 / 3)
    assert math.isclose(summary["detection_rate"], (1 + 5) / 15)
    assert math.isclose(summary["false_alarm_rate"], 1 / 12)
