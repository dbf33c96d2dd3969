"""The two-tank system of docs/ADD_A_SYSTEM.md: its components against known answers, its report's one line."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from mosd.detectors import Cusum
from mosd.estimators.luenberger import LuenbergerObserver, jacobian
from mosd.faults import SensorFault
from mosd.noise import GaussianNoise
from mosd.plants.two_tank import GRAVITY, TwoTank
from mosd.systems import cli, two_tank
from mosd.validation import ConfigError

QUIET = GaussianNoise(process_cov=[0.0, 0.0], measurement_cov=[0.0, 0.0], n_x=2, n_y=2)


def _run(plant, n_samples, fault=None, scale=None, reps=1):
    return plant.simulate(n_samples, QUIET, fault, [np.random.default_rng(r) for r in range(reps)], scale)


def test_the_loop_starts_and_stays_at_its_steady_state():
    plant = TwoTank()
    trace = _run(plant, 300)
    q = plant.outlet_lower * math.sqrt(2 * GRAVITY * plant.set_point)
    np.testing.assert_allclose(trace.x[0], plant.set_point, atol=1e-12)  # a_1 = a_2: both levels at 0.3 m
    np.testing.assert_allclose(trace.u[0, :, 0], q, rtol=1e-12)


def test_one_euler_step_is_torricelli_by_hand():
    plant = TwoTank(dt=2.0)
    x, u = np.array([[0.5, 0.2]]), np.array([[1.0e-4]])
    out1 = plant.outlet_upper * math.sqrt(2 * GRAVITY * 0.5)
    out2 = plant.outlet_lower * math.sqrt(2 * GRAVITY * 0.2)
    expected = [0.5 + 2.0 * (1.0e-4 - out1) / plant.area, 0.2 + 2.0 * (out1 - out2) / plant.area]
    np.testing.assert_allclose(plant.f(x, u)[0], expected, rtol=1e-14)


def test_the_controller_integrates_a_sensor_bias_into_the_true_level():
    """A bias b on the h2 sensor: the PI loop zeroes the *measured* error, so the true level settles at h_ref − b."""
    plant, bias = TwoTank(), 0.01
    trace = _run(plant, 3000, SensorFault("offset", channel=1, onset=100.0, a=1.0), scale=bias)
    np.testing.assert_allclose(trace.x[0, -1, 1], plant.set_point - bias, atol=2e-5)
    np.testing.assert_allclose(trace.y[0, -1, 1], plant.set_point, atol=2e-5)


def test_a_pump_too_small_for_the_set_point_is_one_line():
    with pytest.raises(ConfigError, match=r"^plant\.max_flow=0\.0001 cannot hold plant\.set_point=0\.3; allowed: > "):
        TwoTank(max_flow=1e-4)


def test_the_observer_gain_places_its_poles_and_tracks_a_quiet_loop_exactly():
    plant = TwoTank()
    model = plant.model(QUIET)
    trace = _run(plant, 200, reps=2)
    observer = LuenbergerObserver(poles=(0.9, 0.95))
    gain = observer.gain(model, trace.u[:, 0].mean(axis=0))
    a = jacobian(lambda x: model.f(x, trace.u[0, 0]), model.x0)
    np.testing.assert_allclose(np.sort(np.linalg.eigvals(a - gain @ np.eye(2)).real), [0.9, 0.95], atol=1e-9)
    residuals = observer.estimate(trace, model)
    assert residuals.r.shape == (2, 200, 2) and np.abs(residuals.r).max() < 1e-12


def test_the_observer_keeps_the_linear_share_of_a_sensor_bias():
    """Steady residual of a bias b: r = (I − C (I − A + LC)⁻¹ L) b (the error dynamics do not see u)."""
    plant, bias = TwoTank(), 1e-4
    model = plant.model(QUIET)
    trace = _run(plant, 4000, SensorFault("offset", channel=1, onset=100.0, a=1.0), scale=bias)
    observer = LuenbergerObserver()
    gain = observer.gain(model, trace.u[0, 0])
    a = jacobian(lambda x: model.f(x, trace.u[0, 0]), model.x0)
    expected = (np.eye(2) - np.linalg.solve(np.eye(2) - a + gain, gain)) @ np.array([0.0, bias])
    np.testing.assert_allclose(observer.estimate(trace, model).r[0, -1], expected, rtol=2e-3, atol=1e-9)


def test_the_observer_needs_one_pole_per_state():
    with pytest.raises(ConfigError, match=r"^estimator\.poles has 3 values; allowed: 2, one per state \(h1, h2\)"):
        LuenbergerObserver(poles=(0.9, 0.9, 0.9)).gain(TwoTank().model(QUIET), np.array([1e-4]))
    with pytest.raises(ConfigError, match=r"^estimator\.poles=1\.0 is out of range; allowed: \[0, 1\)"):
        LuenbergerObserver(poles=(0.5, 1.0))


def test_the_cusum_recursion_worked_by_hand():
    x = np.array([[0.0, 1.0, 2.0, -3.0, 0.5, np.nan, 0.0]])
    # S+ = 0, .5, 2, 0, 0, 0 (held), 0; S- = 0, 0, 0, 2.5, 1.5, 1.5 (held), 1.0
    decided = Cusum().population(None, x, np.array([[0.5, 1.9, 2], [0.5, 1.9, 1]]))
    np.testing.assert_allclose(decided.statistic[0, 0], [0.0, 0.5, 2.0, 2.5, 1.5, 1.5, 1.0])
    assert decided.decision[0, 0].tolist() == [0, 0, 0, 1, 0, 0, 0]  # two consecutive points above 1.9
    assert decided.decision[1, 0].tolist() == [0, 0, 1, 1, 0, 0, 0]
    z = np.arange(6.0).reshape(1, 2, 3)
    np.testing.assert_allclose(Cusum().features(z), [[1.0 * math.sqrt(3), 4.0 * math.sqrt(3)]])


def test_the_report_says_no_recorded_design_yet_in_one_line(tmp_path, capsys):
    assert two_tank.main(["--n-runs", "2", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and err.startswith("error: no recorded design yet for two_tank: run python -m mosd "
                                                   "+experiment=two_tank")
    assert not list(tmp_path.iterdir())  # nothing written
    assert two_tank.Study().reference_designs(None, Cusum()) == {}  # the app's run needs no designs file


def test_the_report_scores_a_recorded_design(tmp_path, capsys, monkeypatch):
    recorded = {"tuned": {"k": 0.5, "h": 8.0, "persistence": 1}}
    monkeypatch.setattr(cli, "has_recorded_design", lambda system: system == "two_tank")
    monkeypatch.setattr(cli, "recorded_designs", lambda system: recorded)
    assert two_tank.main(["--n-runs", "3", "--h", "9.0", "--out", str(tmp_path)]) == 0
    saved = json.loads((tmp_path / "two_tank_study.json").read_text())
    assert saved["designs"]["tuned"] == {"k": 0.5, "h": 9.0, "persistence": 1.0}
    assert {"far", "mdr", "far_fault_free"} <= set(saved["metrics"])
    assert "| far_fault_free |" in capsys.readouterr().out
