"""Paper 003's detection definition, the fault-free first-alarm law and the metric formulas (issue 20)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from mosd.systems.paper003 import (CONFIRM, KOFM_K, KOFM_M, detection_summary, first_alarm_law, k_of_m_detection,
                                   rate_gain, relative_range, speedup)


def test_metric_formulas_reproduce_the_papers_identities():
    """Table 2: N = 1 at step 634 (134 after the onset at 500) and 33.4 %; N = 12 at 516 (16) and 65.5 %."""
    assert speedup(134, 16) == pytest.approx(7.375, abs=1e-12)  # the paper's 737.5 %
    assert round(100 * rate_gain(33.4, 65.5), 1) == 96.1
    assert rate_gain(33.4, 65.5) == pytest.approx(65.5 / 33.4 - 1, rel=1e-15)


def test_a_chance_alarm_cannot_make_a_detection():
    assert CONFIRM == 3  # 500·α³ < α at α = 0.01 while 500·α² > α (module docstring)
    decision = np.zeros((4, 20), int)
    decision[0, [10, 14]] = 1            # two isolated chance alarms after the onset: no detection
    decision[1, [10, 11, 12]] = 1        # a run of 3 from the onset: detected at its third alarm
    decision[2, [8, 9, 10, 11]] = 1      # a run from before the onset: not a detection after it ...
    decision[2, [15, 16, 17]] = 1        # ... this one is
    decision[3, [10, 12, 13, 14, 19]] = 1
    summary = detection_summary(decision, onset_step=10, confirm=3)
    np.testing.assert_array_equal(summary["first_alarm"], [-1, 12, 17, 14])
    assert summary["detection_step"] == pytest.approx((12 + 17 + 14) / 3)
    assert summary["run_detection_share"] == 0.75
    # the former definition (confirm = 1) counts the first single alarm at or after the onset
    np.testing.assert_array_equal(detection_summary(decision, 10)["first_alarm"], [10, 10, 10, 10])
    # designs on a leading axis give the same per-design numbers
    stacked = detection_summary(np.stack([decision, decision[::-1]]), onset_step=10, confirm=3)
    np.testing.assert_array_equal(stacked["first_alarm"][0], summary["first_alarm"])


def test_k_of_m_rule_needs_the_statistic_high_not_rising():
    """Issue 30: the rule under which "N = 1 never detects" is tested does not ask for three rises in a row."""
    assert (KOFM_K, KOFM_M) == (3, 8)
    alarm = np.zeros((4, 30), bool)
    alarm[0, [10, 13, 17]] = True            # 3 alarms within 8 points (10..17): detected at the third
    alarm[1, [10, 14, 18]] = True            # 3 alarms spread over 9 points: not within any 8
    alarm[2, [6, 7, 12]] = True              # two alarms before the onset do not count
    alarm[3, 10:] = True                     # the statistic stays above T_D: detected at the third point
    found = k_of_m_detection(alarm, start=10)
    np.testing.assert_array_equal(found["detected"], [True, False, False, True])
    np.testing.assert_array_equal(found["step"], [17, -1, -1, 12])
    # the same alarms need not be consecutive, unlike CONFIRM in a row
    assert detection_summary(alarm[:1].astype(int), onset_step=10, confirm=CONFIRM)["first_alarm"][0] == -1
    # under independent chance alarms at α = 0.01, a 500-point flight rarely holds 3 in 8
    rng = np.random.default_rng(3)
    chance = k_of_m_detection(rng.uniform(size=(2000, 500)) < 0.01, start=0)["detected"].mean()
    assert chance < 0.03


def test_first_alarm_law_is_geometric_for_independent_alarms_and_not_for_bursts():
    rng = np.random.default_rng(20)
    p, n_runs, n = 0.01, 400, 300
    independent = rng.uniform(size=(n_runs, n)) < p
    law = first_alarm_law(independent)
    assert law["rate"] == pytest.approx(p, rel=0.1)
    assert law["geometric_share"] == pytest.approx(1 - (1 - law["rate"]) ** n)
    assert abs(law["alarm_share"] - law["geometric_share"]) < 4 * math.sqrt(0.95 * 0.05 / n_runs)
    assert law["step_mean"] == pytest.approx(law["geometric_step_mean"], rel=0.15)
    assert law["p_value"] > 1e-3
    # the same point rate in bursts of 10 (a Markov chain): far fewer flights alarm, and later
    start = rng.uniform(size=(n_runs, n)) < p / 10
    bursts = np.zeros_like(start)
    for lag in range(10):
        bursts[:, lag:] |= start[:, : n - lag]
    burst_law = first_alarm_law(bursts)
    assert burst_law["rate"] == pytest.approx(p, rel=0.25)
    assert burst_law["alarm_share"] < 0.6 * burst_law["geometric_share"]
    assert burst_law["p_value"] < 1e-6
    # first_valid drops the leading points; no alarm at all gives rate 0 and NaN means
    quiet = first_alarm_law(np.zeros((10, 50), bool), first_valid=5)
    assert quiet["rate"] == 0.0 and math.isnan(quiet["step_mean"]) and math.isnan(quiet["p_value"])


def test_threshold_relative_range_is_the_median_flights_swing_over_t_d():
    threshold = np.array([[6.0, 7.0, 9.0], [6.0, 6.0, 6.6], [np.nan, 6.0, 12.0], [np.nan] * 3])
    assert relative_range(threshold, 6.0) == pytest.approx(np.median([3 / 6, 0.6 / 6, 6 / 6]))
    assert relative_range(np.full((2, 4), 6.63), 6.63) == 0.0


@pytest.mark.slow
def test_fault_free_flights_first_alarm_follows_the_geometric_law(tmp_path):
    """The paper's design on 100 fault-free flights, N = 1 and 12, both readings (about 1 min with training).

    A detection step that counted single alarms would measure this law without any fault: the
    first alarm of a flight is geometric at the measured per-point rate (χ² test, 5 % level per case
    at 1 %); at N = 1 on the observer's residual nearly every flight alarms by chance.
    """
    import torch  # noqa: F401  (a test dependency: a missing one fails, never skips)
    from mosd.scenario import training_rng
    from mosd.systems import cli, paper003

    experiment = cli.preset("paper003", ["seed=0", f"estimator.cache_dir='{tmp_path}'",
                                         "estimator.progress=false"]).experiment
    training = experiment.simulate(None, experiment.budget.n_estimator, "estimator")
    clean = experiment.simulate(None, 100, "test")
    paper = experiment.detector.with_params(alpha=0.01, a=1.0, b=1.0)
    for window in (1, 12):
        estimator = experiment.estimator.with_params(window=window)
        estimator.fit(training, experiment.model, training_rng(experiment.seed))
        free = estimator.estimate(clean, experiment.model)
        for statistic in ("observer_chi2", "chi2"):
            z = np.stack([free.extra[statistic], free.extra[paper003.SCALED_RESIDUAL]], -1)
            law = first_alarm_law(paper.decide(z, z).decision, first_valid=window)
            case = (window, statistic, law)
            assert law["p_value"] > 0.01, case
            assert abs(law["alarm_share"] - law["geometric_share"]) < 4 * math.sqrt(0.25 / 100) + 0.02, case
            if statistic == "observer_chi2":
                assert law["alarm_share"] > 0.9, case  # chance alarms alone would "detect" in nearly every flight
