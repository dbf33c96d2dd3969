"""Operating-characteristic machinery (mosd.systems.oc_curves): matched limits that hit their target.

The ARL0 calibration is checked against Crowder's integral equation (mosd.arl.ewma_arl), an
implementation that shares no code with it; the FAR calibration against fresh in-control data.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from mosd.arl import ewma_arl
from mosd.detectors import EWMA, SSDEWMA
from mosd.systems import oc_curves as oc
from mosd.validation import ConfigError


def test_run_lengths_are_first_exceedances_and_censored_at_the_horizon():
    stat = np.array([[0.0, 2.0, 5.0], [3.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    np.testing.assert_array_equal(oc.run_lengths(stat, 1.0), [2, 1, 4])
    np.testing.assert_array_equal(oc.run_lengths(stat, 2.0), [3, 1, 4])


def test_arl_limit_is_the_smallest_limit_reaching_the_target():
    rng = np.random.default_rng(41)
    stat = rng.exponential(size=(300, 400))
    h = oc.arl_limit(stat, 50.0)
    assert oc.run_lengths(stat, h).mean() >= 50.0
    smaller = np.nextafter(h, -np.inf)
    assert oc.run_lengths(stat, smaller).mean() < 50.0
    # i.i.d. Exp(1) points: geometric run length with p = e^{−h}, ARL = e^{h}
    assert math.exp(h) == pytest.approx(50.0, rel=0.15)
    with pytest.raises(ConfigError, match="^arl0=400 "):
        oc.arl_limit(stat, 400.0)


def test_arl0_matched_ewma_limit_agrees_with_the_integral_equation():
    lam, reps, target = 0.2, 2000, 100.0
    z = np.random.default_rng(42).standard_normal((reps, 1000, 5))
    chart = EWMA(lam=lam, limit="phase1")
    h = oc.arl_limit(chart.statistic(z), target)
    L = h / math.sqrt(lam / (2.0 - lam))
    exact = ewma_arl(lam, L)
    # the in-sample calibration carries the Monte Carlo error of the mean run length (~ARL/√reps)
    assert abs(exact - target) < 4.0 * target / math.sqrt(reps), (exact, L)


def test_far_matched_limit_gives_that_alarm_rate_on_fresh_in_control_data():
    rng = np.random.default_rng(43)
    chart = SSDEWMA(lam=0.3)
    phase1, fresh = chart.statistic(rng.standard_normal((100, 400, 5))), chart.statistic(rng.standard_normal((100, 400, 5)))
    h = oc.far_limit(phase1, 0.01)
    assert (phase1 > h).mean() == pytest.approx(0.01, abs=1e-4)
    per_run = (fresh > h).mean(axis=1)
    se = per_run.std(ddof=1) / math.sqrt(per_run.size)
    assert abs(per_run.mean() - 0.01) < 4 * math.hypot(se, se), (per_run.mean(), se)


def test_faulty_subgroups_inject_the_sensor_faults_of_the_plant():
    """The study's faulty subgroups against the plant's own injection (mosd.faults.sensor_fault_signals).

    The plant's samples after an onset at t = 0, in subgroups of n consecutive samples, σ = 1: the
    offset and the drift are the plant's g sample for sample; the variance fault, whose extra noise the
    plant draws itself, has the plant's spread (b·e and e + √(b² − 1)·e' agree in distribution).
    """
    from mosd.faults import SensorFault, sensor_fault_signals

    dt, (R, T, n) = 1e-3, (2, 10, 5)
    base = np.random.default_rng(44).standard_normal((R, T, n))
    t = dt * np.arange(1, T * n + 1)
    for kind, size in (("offset", 0.5), ("drift", 2.0)):
        g, active = sensor_fault_signals(SensorFault(kind, onset=0.0, a=size), t,
                                         [np.random.default_rng(r) for r in range(R)], n_outputs=1,
                                         scale=1.0)  # standardised points: σ = 1
        assert active.all()
        np.testing.assert_allclose(oc.faulty_subgroups(base, kind, size, dt), base + g[..., 0].reshape(R, T, n),
                                   rtol=1e-12, atol=1e-15, err_msg=kind)
    wide = np.random.default_rng(45).standard_normal((4, 5000, n))
    t = dt * np.arange(1, 5000 * n + 1)
    g, _ = sensor_fault_signals(SensorFault("variance", onset=0.0, b=1.5), t,
                                [np.random.default_rng(100 + r) for r in range(4)], n_outputs=1, scale=1.0)
    plant = (wide + g[..., 0].reshape(wide.shape)).std()
    study = oc.faulty_subgroups(wide, "variance", 1.5, dt).std()
    se = 1.5 / math.sqrt(2 * wide.size)  # standard error of a normal sample's standard deviation
    assert abs(plant - study) < 5 * math.sqrt(2) * se and abs(plant - 1.5) < 5 * se, (plant, study)


def test_charts_compared_are_labelled_causal_or_not():
    specs = {s.name: s for s in oc.chart_specs("offset", 0.35)}
    assert specs["SS-DEWMA tuned"].lam == 0.35
    assert specs["SS-DEWMA + causal wavelet"].causal and specs["MS-OEWMA (causal prefilter)"].causal
    assert not specs["SS-DEWMA + wavelet (whole series)"].causal
    assert not specs["MS-OEWMA (whole-series prefilter)"].causal
    assert set(oc.SIZES["offset"]) == {0.25, 0.5, 1.0, 2.0} and set(oc.SIZES["variance"]) == {1.1, 1.25, 1.5, 2.0}


@pytest.mark.parametrize("argv,key", [(["--budget", "huge"], "budget"), (["--far", "0"], "far"),
                                      (["--kinds", "offset,spikes"], "kinds"), (["--arl0", "5000"], "arl0")])
def test_bad_options_stop_with_one_line_and_exit_2(argv, key, capsys, tmp_path):
    assert oc.main(argv + ["--out", str(tmp_path / "oc")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"error: {key}"), err
    assert not (tmp_path / "oc").exists()


@pytest.mark.slow
def test_tiny_study_end_to_end(tmp_path):
    """Every kind's files, matched in-control numbers, and causal charts' FAR independent of the fault size."""
    assert oc.main(["--budget", "tiny", "--arl0", "100", "--kinds", "offset", "--n-jobs", "1",
                    "--out", str(tmp_path)]) == 0
    assert (tmp_path / "oc_offset.png").stat().st_size > 10_000
    import csv

    rows = list(csv.DictReader((tmp_path / "oc_offset.csv").open()))
    assert len(rows) == 8 * 4
    for name in {r["chart"] for r in rows}:
        mine = [r for r in rows if r["chart"] == name]
        fars = {float(r["far"]) for r in mine}
        if mine[0]["causal"] == "1":
            # same seeds for every size and a causal chart: the points before the onset decide the same
            assert len(fars) == 1, (name, fars)
        if mine[0]["arl0"] != "nan":
            assert abs(float(mine[0]["arl0"]) - 100.0) < 25.0
