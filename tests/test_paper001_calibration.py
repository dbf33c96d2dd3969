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
    # a bin with too few values is left out of the gap
    few = paper001.reliability(np.array([0.05, 0.95]), np.array([True, False]), min_steps=2)
    assert np.isnan(few["max_gap"]) and few["steps"].sum() == 2


def test_mode_calibration_draws_faults_from_lambda_and_bins_every_step():
    experiment = cli.preset("paper001", ["seed=4"]).experiment
    cal = paper001.mode_calibration(experiment, 60)
    assert cal["hazard"] == pytest.approx(1 / 40)
    assert cal["steps"].sum() == 60 * 40  # every fusion step t_1 ... t_40 of every run
    # faulty runs: binomial(60, 1 - 0.975**40 = 0.637), within 4 standard deviations
    assert abs(cal["faulty_runs"] - 60 * 0.637) < 4 * np.sqrt(60 * 0.637 * 0.363)
    assert 0.0 <= cal["max_gap"] <= 1.0
    again = paper001.mode_calibration(experiment, 60)
    np.testing.assert_array_equal(cal["steps"], again["steps"])  # seeded
