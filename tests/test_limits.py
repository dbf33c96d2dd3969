"""Every limit mode holds its in-control claim (issue 15, item 3; docs/DECISIONS.md §10).

* Model limits (SS/M charts' ``theoretical``, the EWMA's ``asymptotic`` and ``time_varying``)
  state the law of the raw statistic of i.i.d. N(0, 1) subgroups: their point alarm rate (or
  ARL0, tests/test_baselines.py) matches the closed form. After denoising that law no longer
  holds (measured here), so those combinations are refused with one line naming both keys.
* Phase-I limits (``phase1``, ``normalised``) claim that fresh in-control data exceed them as
  often as the Phase-I data they were fitted on: checked with and without denoisers, whole-series
  and causal, through the same ``Detector.decide`` the optimiser and the reports use.

Monte Carlo errors are run-level (runs are independent, points within a run are not), and a
check passes within 4 standard errors.
"""
from __future__ import annotations

import math
import os
import subprocess
import sys

import numpy as np
import pytest
from scipy import special

from mosd.detectors import EWMA, MDEWMA, MSOEWMA, SSDEWMA, SSEWMA, MaxEWMA
from mosd.denoisers import NoDenoiser, WaveletDenoiser
from mosd.validation import ConfigError

MAX_MEAN = 2.0 / math.sqrt(math.pi)
MAX_SD = math.sqrt(1.0 - 2.0 / math.pi)


def _run_level(alarms: np.ndarray) -> tuple[float, float]:
    """Alarm rate and its standard error from per-run rates (R, K) → (mean, se)."""
    per_run = alarms.mean(axis=-1)
    return float(per_run.mean()), float(per_run.std(ddof=1) / math.sqrt(per_run.size))


# ------------------------------------------------------------------------------------------
# model limits: refused after denoising, exact without
# ------------------------------------------------------------------------------------------
@pytest.mark.parametrize("cls,limit", [(SSDEWMA, "theoretical"), (SSEWMA, "theoretical"), (MDEWMA, "theoretical"),
                                       (MaxEWMA, "theoretical"), (EWMA, "asymptotic"), (EWMA, "time_varying")])
@pytest.mark.parametrize("window", [None, 128])
def test_model_limit_on_a_denoised_statistic_is_refused_naming_both_keys(cls, limit, window):
    with pytest.raises(ConfigError, match=rf"^detector\.limit={limit} .*denoise=WaveletDenoiser; allowed: "
                                          rf"detector\.limit=[a-z1|]+ with denoise, or denoise=none$"):
        cls(limit=limit, denoiser=WaveletDenoiser(window=window))
    cls(limit=limit, denoiser=NoDenoiser())  # the raw statistic keeps its law
    cls(limit="phase1", denoiser=WaveletDenoiser(window=window))  # a Phase-I limit holds after denoising


@pytest.mark.parametrize("limit", ["asymptotic", "time_varying"])
def test_ms_oewma_model_limit_needs_an_identity_prefilter(limit):
    with pytest.raises(ConfigError, match=rf"^detector\.limit={limit} .*detector\.prefilter=WaveletDenoiser"):
        MSOEWMA(limit=limit)
    assert MSOEWMA(limit=limit, prefilter=NoDenoiser()).limit == limit


def test_the_app_refuses_the_combination_in_one_line_with_exit_2(tmp_path):
    env = {**os.environ, "MOSD_OUTPUTS": str(tmp_path)}
    done = subprocess.run([sys.executable, "-m", "mosd", "+fault=offset_var", "detector.limit=theoretical",
                           "denoise=wavelet_causal", "tracking=none"], capture_output=True, text=True, env=env,
                          timeout=120)
    assert done.returncode == 2, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and "detector.limit=theoretical" in lines[0] and "denoise=" in lines[0], done.stderr
    assert "Traceback" not in done.stderr
    assert not (tmp_path / "runs").exists() or not any((tmp_path / "runs").iterdir())


def test_theoretical_limit_holds_on_the_raw_statistic_and_fails_after_denoising():
    # the case: SS-DEWMA, λ = 0.3, K = 2, nominal e^{-3} = 0.0498 per point
    lam, K = 0.3, 2.0
    z = np.random.default_rng(21).standard_normal((120, 600, 5))
    chart = SSDEWMA(lam=lam, K=K, limit="theoretical")
    raw = chart.raw_statistic(chart.features(z))
    ucl = chart.control_limit(raw.shape[-1])
    nominal = math.exp(-(1.0 + K))
    rate, se = _run_level(raw > ucl)
    assert abs(rate - nominal) < 4 * se, (rate, se, nominal)
    # the paper's whole-series wavelet smooths the statistic: far fewer points exceed eq. 35
    # (measured 0.028 ± 0.001 here), the law the limit rests on is gone
    denoised = WaveletDenoiser().denoise(raw)
    rate_d, se_d = _run_level((denoised > ucl)[:, 50:])
    assert rate_d < nominal - 8 * se_d, (rate_d, se_d, nominal)


def test_time_varying_ewma_limit_gives_its_normal_tail_at_every_k():
    lam, L = 0.2, 2.0
    reps = 20000
    z = np.random.default_rng(22).standard_normal((reps, 25, 5))
    rate = EWMA(lam=lam, L=L, limit="time_varying").alarms(z).mean(axis=0)
    p = 2.0 * special.ndtr(-L)  # |E_k|/σ_k is |N(0, 1)| at every k
    assert np.all(np.abs(rate - p) < 4.5 * math.sqrt(p * (1 - p) / reps)), (rate, p)


@pytest.mark.parametrize("cls,kind", [(SSDEWMA, "ss"), (MDEWMA, "max")])
def test_theoretical_limit_claim_at_the_default_width(cls, kind):
    lam, K = 0.3, 3.0 if kind == "ss" else 2.0
    p = math.exp(-(1.0 + K)) if kind == "ss" else 1.0 - (2.0 * special.ndtr(MAX_MEAN + K * MAX_SD) - 1.0) ** 2
    z = np.random.default_rng(23).standard_normal((400, 400, 5))
    rate, se = _run_level(cls(lam=lam, K=K, limit="theoretical").alarms(z))
    assert abs(rate - p) < 4 * se, (rate, se, p)


# ------------------------------------------------------------------------------------------
# Phase-I limits: fresh in-control data exceed them as often as the Phase-I data
# ------------------------------------------------------------------------------------------
def _phase1_cases():
    whole, causal = WaveletDenoiser(), WaveletDenoiser(window=48)
    for denoiser, label in ((NoDenoiser(), "raw"), (whole, "wavelet"), (causal, "wavelet_causal")):
        yield pytest.param(SSDEWMA(lam=0.3, K=3.0, limit="phase1", denoiser=denoiser), id=f"ss_dewma-phase1-{label}")
        yield pytest.param(SSDEWMA(lam=0.3, K=3.0, limit="normalised", denoiser=denoiser),
                           id=f"ss_dewma-normalised-{label}")
        yield pytest.param(MDEWMA(lam=0.3, K=2.0, limit="phase1", denoiser=denoiser), id=f"m_dewma-phase1-{label}")
        yield pytest.param(EWMA(lam=0.2, L=2.5, limit="phase1", denoiser=denoiser), id=f"ewma-phase1-{label}")
    yield pytest.param(MSOEWMA(lam=0.3388, L=2.5, limit="phase1"), id="ms_oewma-phase1-prefilter")
    yield pytest.param(MSOEWMA(lam=0.3388, L=2.5, limit="phase1", prefilter=WaveletDenoiser(window=48)),
                       id="ms_oewma-phase1-causal-prefilter")


@pytest.mark.parametrize("chart", list(_phase1_cases()))
def test_phase1_limit_alarm_rate_on_fresh_in_control_data_matches_phase1(chart):
    rng = np.random.default_rng(24)
    phase1, fresh = rng.standard_normal((80, 240, 5)), rng.standard_normal((80, 240, 5))
    decided = chart.decide(phase1, fresh)  # the optimiser's and the reports' path
    ucl = np.broadcast_to(decided.threshold, decided.statistic.shape)[0]
    in_sample = chart.statistic(phase1) > ucl
    fresh_rate, fresh_se = _run_level(decided.decision != 0)
    phase1_rate, phase1_se = _run_level(in_sample)
    assert 0.002 < phase1_rate < 0.2, phase1_rate  # a limit that is actually exercised
    assert abs(fresh_rate - phase1_rate) < 4 * math.hypot(fresh_se, phase1_se), (fresh_rate, phase1_rate)


def test_phase1_limit_of_a_causal_chart_gives_the_run_length_it_was_fitted_for():
    # ARL0 version of the claim for a causal chart: the Phase-I runs' own first-exceedance times
    # and fresh runs' agree (run lengths censored at the horizon on both sides)
    chart = SSDEWMA(lam=0.3, K=4.0, limit="phase1", denoiser=WaveletDenoiser(window=48))
    rng = np.random.default_rng(25)
    phase1, fresh = rng.standard_normal((150, 200, 5)), rng.standard_normal((150, 200, 5))
    decided = chart.decide(phase1, fresh)
    ucl = np.broadcast_to(decided.threshold, decided.statistic.shape)[0]

    def first_alarm(alarms):
        return np.where(alarms.any(axis=1), np.argmax(alarms, axis=1) + 1, alarms.shape[1] + 1).astype(float)

    a, b = first_alarm(chart.statistic(phase1) > ucl), first_alarm(decided.decision != 0)
    se = math.hypot(a.std(ddof=1) / math.sqrt(a.size), b.std(ddof=1) / math.sqrt(b.size))
    assert abs(a.mean() - b.mean()) < 4 * se, (a.mean(), b.mean(), se)


@pytest.mark.slow
def test_phase1_limit_holds_on_the_plant_residuals():
    """Fault-free plant runs: Phase-I limit from the calibration stream, alarm rate on the test stream."""
    from mosd.estimators import CESCKF, DedicatedObserverResidual
    from mosd.experiment import Budget, Experiment
    from mosd.faults import SensorFault
    from mosd.monitors import SubgroupMonitor
    from mosd.noise import GaussianNoise
    from mosd.plants import MouldOscillator

    chart = SSDEWMA(lam=0.3, K=3.0, limit="phase1", denoiser=WaveletDenoiser(window=48))
    exp = Experiment(MouldOscillator(), GaussianNoise(), SensorFault("offset", onset=2.0, a=2.0),
                     DedicatedObserverResidual(CESCKF(), monitored=[0]),
                     SubgroupMonitor(subgroup="window", n=5, channels=[0], burn_in=200), chart, duration=2.2,
                     budget=Budget(n_calibration=30, n_train=1, n_test=30), seed=3)
    calibration = exp.calibrate()
    phase1 = exp.monitor.transform(calibration)
    fresh = exp.monitor.transform(exp.residuals(None, 30, "test"))
    decided = chart.decide(phase1.z, fresh.z)
    ucl = np.broadcast_to(decided.threshold, decided.statistic.shape)[0]
    fresh_rate, fresh_se = _run_level(decided.decision != 0)
    phase1_rate, phase1_se = _run_level(chart.statistic(phase1.z) > ucl)
    assert abs(fresh_rate - phase1_rate) < 4 * math.hypot(fresh_se, phase1_se), (fresh_rate, phase1_rate)
