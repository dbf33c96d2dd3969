"""Paper 001's transition matrix from the fault hazard and the mode-probability calibration check (issue 20).

Λ is not in the paper; the preset's is derived from the scenario (one fault per
run, its onset equally likely in each fusion interval, faults permanent), and the
check asks whether the fused filter's mode probabilities behave as probabilities
when faults start as Λ itself says (docs/systems/paper001.md, "Choosing Λ").
"""
from __future__ import annotations

import numpy as np
import pytest

from mosd.systems import cli, paper001
from mosd.validation import ConfigError


def test_hazard_transition_is_one_fault_per_run_and_permanent():
    trans = paper001.hazard_transition(40, 2)
    np.testing.assert_allclose(trans.sum(axis=1), 1.0, atol=1e-15)
    assert trans[0, 0] == pytest.approx(1 - 1 / 40)
    np.testing.assert_allclose(trans[0, 1:], [1 / 80, 1 / 80])
    np.testing.assert_array_equal(trans[1:, :], np.eye(3)[1:])  # a fault neither ends nor changes direction
    # the chance of a fault within the run's 40 intervals under this hazard
    assert 1 - trans[0, 0] ** 40 == pytest.approx(0.6368, abs=1e-4)
    with pytest.raises(ConfigError, match="n_intervals"):
        paper001.hazard_transition(0, 2)
    # a prior's mean time to a fault need not be whole intervals: the paper's onset at 16.5 s
    assert paper001.hazard_transition(16.5, 2)[0, 0] == pytest.approx(1 - 1 / 16.5)


def test_preset_transition_is_the_scenario_hazard():
    """conf/experiment/paper001.yaml's Λ is hazard_transition of the preset's own scenario, not a tuned constant."""
    experiment = cli.preset("paper001", ["seed=0"]).experiment
    n_intervals = int(round(experiment.duration / experiment.plant.dt)) - 1
    n_faults = np.asarray(experiment.model.fault_directions).shape[1]
    np.testing.assert_allclose(experiment.estimator.transition, paper001.hazard_transition(n_intervals, n_faults),
                               atol=1e-12)


def test_reliability_curve_separates_a_calibrated_forecast_from_an_overconfident_one():
    rng = np.random.default_rng(5)
    p = rng.uniform(size=40_000)
    calibrated = paper001.reliability(p, rng.uniform(size=p.size) < p)
    overconfident = paper001.reliability(p, rng.uniform(size=p.size) < p**2)  # the event is rarer than forecast
    assert calibrated["steps"].sum() == p.size
    np.testing.assert_allclose(calibrated["mean_probability"], np.arange(10) / 10 + 0.05, atol=0.01)
    assert calibrated["max_gap"] < 0.03  # binomial error of ~4,000 per bin: 0.008
    assert overconfident["max_gap"] == pytest.approx(0.25, abs=0.03)  # max of p - p² at p = 0.5
    assert calibrated["ece"] < 0.02
    assert overconfident["ece"] == pytest.approx(1 / 6, abs=0.02)  # the mean of p - p² over uniform p
    # a bin with too small a share of the values is left out of the largest gap
    few = paper001.reliability(np.array([0.05] * 300 + [0.95]), np.array([False] * 300 + [True]), min_share=0.01)
    assert few["max_gap"] == pytest.approx(0.05) and few["steps"].sum() == 301


def test_calibration_metrics_do_not_depend_on_the_number_of_runs():
    """Issue 30: the largest gap kept bins by a count of 50 steps, so a sparse bin entered as the runs grew.

    Here 0.4 % of the forecasts fall in the 0.4-0.5 bin and are badly over-confident; the rest are
    calibrated. The bins kept by share, and the step-weighted ECE, read the same at 5,000 and at
    50,000 forecasts (a count of 50 would keep the sparse bin at 50,000 only: a gap of about 0.45).
    """
    def forecasts(n, seed):
        rng = np.random.default_rng(seed)
        middle = rng.uniform(size=n) < 0.004
        p = np.where(middle, rng.uniform(0.4, 0.5, n), np.where(rng.uniform(size=n) < 0.5, rng.uniform(0, 0.1, n),
                                                                 rng.uniform(0.9, 1.0, n)))
        outcome = np.where(middle, rng.uniform(size=n) < 0.9, rng.uniform(size=n) < p)
        return paper001.reliability(p, outcome)

    small, large = forecasts(5_000, 1), forecasts(50_000, 2)
    assert small["steps"][4] < 50 <= large["steps"][4]
    assert abs(small["max_gap"] - large["max_gap"]) < 0.03 and large["max_gap"] < 0.05
    assert abs(small["ece"] - large["ece"]) < 0.01
    # over the unsure bins alone, the sparse over-confident bin dominates at every size
    assert min(small["ece_middle"], large["ece_middle"]) > 0.3  # 20 and 200 values: binomial noise of 0.07, 0.02


def test_mode_calibration_draws_faults_from_lambda_and_bins_every_step():
    experiment = cli.preset("paper001", ["seed=4"]).experiment
    cal = paper001.mode_calibration(experiment, 60)
    assert cal["hazard"] == pytest.approx(1 / 40)
    assert cal["steps"].sum() == 60 * 40  # every fusion step t_1 ... t_40 of every run
    # faulty runs: binomial(60, 1 - 0.975**40 = 0.637), within 4 standard deviations
    assert abs(cal["faulty_runs"] - 60 * 0.637) < 4 * np.sqrt(60 * 0.637 * 0.363)
    assert 0.0 <= cal["max_gap"] <= 1.0 and 0.0 <= cal["ece"] <= cal["max_gap"]
    again = paper001.mode_calibration(experiment, 60)
    np.testing.assert_array_equal(cal["steps"], again["steps"])  # seeded
