"""Tests of mosd.arl: EWMA ARL by integral equation / Markov chain, and Monte Carlo ARL.

References are independent of the code under test: closed forms (λ = 1 is the
Shewhart chart), the other numerical method, published tables, and simulation.
"""
from __future__ import annotations

import math
import time

import numpy as np
import pytest
from scipy import signal, stats

from mosd import arl as arl_module
from mosd.arl import ArlEstimate, ewma_arl, monte_carlo_arl
from mosd.validation import ConfigError


# --------------------------------------------------------------------------------------
# charts defined here, independent of mosd.detectors
# --------------------------------------------------------------------------------------
class ShewhartMeanChart:
    """Alarms when |√n·mean| > L; its ARL is 1/p, p = P(|N(√n a, b²)| > L)."""

    def __init__(self, L):
        self.L = L

    def alarms(self, z):
        return np.abs(math.sqrt(z.shape[-1]) * z.mean(axis=-1)) > self.L

    def exact_arl(self, a, b, n):
        centre = math.sqrt(n) * a
        p = stats.norm.sf(self.L, loc=centre, scale=b) + stats.norm.cdf(-self.L, loc=centre, scale=b)
        return 1.0 / p


class EwmaMeanChart:
    """EWMA of U_k = √n·mean_k with fixed asymptotic limits; U_k ~ N(√n a, 1) when b = 1."""

    def __init__(self, lam, L):
        self.lam, self.L = lam, L

    def alarms(self, z):
        u = math.sqrt(z.shape[-1]) * z.mean(axis=-1)
        e = signal.lfilter([self.lam], [1.0, -(1.0 - self.lam)], u, axis=-1)
        return np.abs(e) > self.L * math.sqrt(self.lam / (2.0 - self.lam))


class AlarmAtChart:
    """Deterministic: alarms at every sample index ≥ ``index`` (run length index + 1)."""

    def __init__(self, index):
        self.index = index

    def alarms(self, z):
        alarm = np.zeros(z.shape[:-1], dtype=bool)
        alarm[..., self.index:] = True
        return alarm


def shewhart_arl(L, shift):
    return 1.0 / (stats.norm.sf(L - shift) + stats.norm.cdf(-L - shift))


# --------------------------------------------------------------------------------------
# ewma_arl
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize("method", ["integral", "markov"])
@pytest.mark.parametrize("L, shift", [(3.0, 0.0), (2.5, 0.5), (3.0, 1.0), (2.0, -1.5), (3.5, 3.0)])
def test_lambda_one_is_shewhart(method, L, shift):
    # With λ = 1 the kernel does not depend on the current state, so both methods
    # are exact up to rounding: Gauss–Legendre integrates the smooth normal density
    # to machine precision, and the Markov cells tile [−h, h] exactly (measured:
    # both within ~1e-13 relative of the closed form).
    assert ewma_arl(1.0, L, shift, method=method) == pytest.approx(shewhart_arl(L, shift), rel=1e-8)


def test_integral_and_markov_agree_on_grid():
    lam = np.array([0.05, 0.1, 0.25, 0.5])[:, None, None]
    L = np.array([2.5, 2.7, 3.0])[None, :, None]
    shift = np.array([0.0, 0.5, 1.0, 2.0])[None, None, :]
    integral = ewma_arl(lam, L, shift, method="integral")
    markov = ewma_arl(lam, L, shift, method="markov")
    assert integral.shape == markov.shape == (4, 3, 4)
    relative = np.abs(markov - integral) / integral
    assert relative.max() < 5e-3, relative.max()


def test_markov_error_falls_like_inverse_square_of_states():
    exact = ewma_arl(0.25, 3.0, 0.0, nodes=300)
    error_coarse = ewma_arl(0.25, 3.0, 0.0, method="markov", nodes=101) - exact
    error_fine = ewma_arl(0.25, 3.0, 0.0, method="markov", nodes=303) - exact
    assert abs(error_coarse / error_fine) == pytest.approx(9.0, rel=0.15)


def test_integral_converges_in_nodes():
    # the default node count must already be converged: doubling it changes nothing
    for lam in (0.01, 0.05, 0.3):
        default = ewma_arl(lam, 3.0, 0.5)
        doubled = 2 * int(arl_module._integral_nodes(np.array(lam), np.array(3.0)))
        assert ewma_arl(lam, 3.0, 0.5, nodes=doubled) == pytest.approx(default, rel=1e-8)


# Lucas & Saccucci (1990), Technometrics 32, 1–12, Table 3, as reprinted in
# Montgomery, Introduction to Statistical Quality Control, Table "ARLs for several
# EWMA control schemes": zero-state ARL with asymptotic limits, values rounded.
PUBLISHED = [
    # (λ, L, shift, ARL)
    (0.05, 2.615, 0.0, 500.0),
    (0.10, 2.814, 0.0, 500.0),
    (0.20, 2.962, 0.0, 500.0),
    (0.25, 2.998, 0.0, 500.0),
    (0.40, 3.054, 0.0, 500.0),
    (0.10, 2.814, 0.5, 31.3),
    (0.10, 2.814, 1.0, 10.3),
    (0.10, 2.814, 2.0, 4.4),
    (0.25, 2.998, 0.5, 48.2),
    (0.25, 2.998, 1.0, 11.1),
    (0.25, 2.998, 2.0, 3.6),
]


@pytest.mark.parametrize("method", ["integral", "markov"])
@pytest.mark.parametrize("lam, L, shift, published", PUBLISHED)
def test_published_values(method, lam, L, shift, published):
    assert ewma_arl(lam, L, shift, method=method) == pytest.approx(published, rel=0.02)


def test_shape_properties():
    shifts = np.array([0.0, 0.25, 0.5, 1.0, 2.0, 3.0])
    up = ewma_arl(0.2, 3.0, shifts)
    down = ewma_arl(0.2, 3.0, -shifts)
    np.testing.assert_allclose(up, down, rtol=1e-10)  # symmetric chart, symmetric ARL
    assert np.all(np.diff(up) < 0)  # bigger shift, shorter runs
    widths = np.array([2.0, 2.5, 3.0, 3.5])
    assert np.all(np.diff(ewma_arl(0.2, widths, 0.0)) > 0)  # wider limits, longer runs
    # shift 8 with λ = 0.2, h = 1: E_1 ~ N(1.6, 0.2²) stays inside only when E_1 ≤ h
    # (probability Φ(−3)); then E_2 = 0.8·E_1 + 0.2·X_2 ≈ N(2.36, 0.2²) is outside except
    # with probability ~1e-11, so ARL = 1 + Φ(−3) to ~1e-11
    assert ewma_arl(0.2, 3.0, 8.0) == pytest.approx(1.0 + stats.norm.cdf(-3.0), rel=1e-9)


def test_vectorised_matches_scalar_and_broadcasts():
    lam = np.array([0.05, 0.3, 1.0])
    shift = np.array([[0.0], [1.0]])
    grid = ewma_arl(lam, 2.8, shift)
    assert grid.shape == (2, 3)
    for i in range(2):
        for j in range(3):
            assert grid[i, j] == pytest.approx(ewma_arl(float(lam[j]), 2.8, float(shift[i, 0])), rel=1e-12)
    assert isinstance(ewma_arl(0.2, 3.0), float)


def test_twenty_by_twenty_grid_is_fast():
    lam = np.linspace(0.05, 1.0, 20)[:, None]
    L = np.linspace(2.0, 3.5, 20)[None, :]
    start = time.perf_counter()
    grid = ewma_arl(lam, L, 0.5)
    elapsed = time.perf_counter() - start
    assert grid.shape == (20, 20) and np.all(np.isfinite(grid)) and np.all(grid >= 1.0)
    assert elapsed < 2.0, elapsed


@pytest.mark.parametrize("kwargs, name", [
    ({"lam": 0.0, "L": 3.0}, "lam"),
    ({"lam": 1.5, "L": 3.0}, "lam"),
    ({"lam": [0.2, -0.1], "L": 3.0}, "lam"),
    ({"lam": float("nan"), "L": 3.0}, "lam"),
    ({"lam": 0.2, "L": 0.0}, "L"),
    ({"lam": 0.2, "L": [3.0, -2.0]}, "L"),
    ({"lam": 0.2, "L": 3.0, "shift": float("inf")}, "shift"),
    ({"lam": 0.2, "L": 3.0, "method": "simpson"}, "method"),
    ({"lam": 0.2, "L": 3.0, "method": "markov", "nodes": 300}, "nodes"),
    ({"lam": 0.2, "L": 3.0, "nodes": 0}, "nodes"),
])
def test_ewma_arl_rejects_bad_parameters(kwargs, name):
    with pytest.raises(ConfigError, match=rf"^{name}\b"):
        ewma_arl(**kwargs)


# --------------------------------------------------------------------------------------
# monte_carlo_arl
# --------------------------------------------------------------------------------------
def assert_within_three_se(estimate, exact):
    assert isinstance(estimate, ArlEstimate)
    assert estimate.stderr > 0
    assert abs(estimate.mean - exact) < 3.0 * estimate.stderr, (estimate, exact)


@pytest.mark.parametrize("L, a, b, n", [
    (2.5, 0.0, 1.0, 5),    # ARL ≈ 80
    (3.5, 0.0, 1.0, 4),    # ARL ≈ 2150: most runs outlive several horizon doublings
    (3.0, 0.3, 1.0, 5),
    (3.0, 0.0, 1.5, 3),    # variance increase
    (3.0, -0.2, 1.2, 1),
])
def test_monte_carlo_shewhart_matches_closed_form(L, a, b, n):
    chart = ShewhartMeanChart(L)
    assert_within_three_se(monte_carlo_arl(chart, a=a, b=b, n=n, reps=2000, seed=11), chart.exact_arl(a, b, n))


@pytest.mark.parametrize("lam, L, a, n", [
    (0.2, 2.7, 0.0, 5),
    (0.1, 2.814, 0.0, 4),
    (0.3, 3.0, 0.25, 5),
])
def test_monte_carlo_ewma_matches_ewma_arl(lam, L, a, n):
    chart = EwmaMeanChart(lam, L)
    estimate = monte_carlo_arl(chart, a=a, n=n, reps=2000, seed=5)
    assert_within_three_se(estimate, ewma_arl(lam, L, math.sqrt(n) * a))


def test_monte_carlo_with_package_ewma_chart():
    from mosd.detectors import EWMA

    chart = EWMA(lam=0.2, L=2.8, limit="asymptotic")
    estimate = monte_carlo_arl(chart, a=0.2, n=5, reps=2000, seed=3)
    assert_within_three_se(estimate, ewma_arl(0.2, 2.8, math.sqrt(5) * 0.2))


def test_run_length_is_first_alarm_index_plus_one():
    # 300 is beyond the first horizon, so this also exercises the re-simulation
    for index in (0, 9, 300):
        assert monte_carlo_arl(AlarmAtChart(index), reps=10, seed=0) == (index + 1.0, 0.0)


def test_same_seed_same_result_and_seed_matters():
    chart = EwmaMeanChart(0.2, 2.7)
    first = monte_carlo_arl(chart, reps=400, seed=42)
    assert monte_carlo_arl(chart, reps=400, seed=42) == first
    assert monte_carlo_arl(chart, reps=400, seed=43) != first


def test_result_independent_of_batch():
    chart = EwmaMeanChart(0.2, 2.7)
    reference = monte_carlo_arl(chart, reps=300, seed=7)
    for batch in (1, 13, 300, 5000):
        assert monte_carlo_arl(chart, reps=300, seed=7, batch=batch) == reference


def test_result_independent_of_horizon_schedule(monkeypatch):
    chart = EwmaMeanChart(0.2, 2.7)
    reference = monte_carlo_arl(chart, reps=300, seed=8)
    for first_horizon in (1, 5, 4096):
        monkeypatch.setattr(arl_module, "_FIRST_HORIZON", first_horizon)
        assert monte_carlo_arl(chart, reps=300, seed=8) == reference


def test_runs_without_alarm_are_censored_with_warning():
    never = AlarmAtChart(10**9)
    with pytest.warns(RuntimeWarning, match="no alarm within max_run=500"):
        estimate = monte_carlo_arl(never, reps=20, max_run=500)
    assert estimate == (500.0, 0.0)


def test_chart_with_wrong_alarm_shape_is_reported():
    class Flat:
        def alarms(self, z):
            return np.zeros(z.shape[0], dtype=bool)

    with pytest.raises(ValueError, match="shape"):
        monte_carlo_arl(Flat(), reps=5)


def test_non_causal_chart_is_rejected():
    from mosd.detectors import SSDEWMA
    from mosd.denoisers import WaveletDenoiser

    with pytest.raises(ConfigError, match="^chart=.*not causal"):
        monte_carlo_arl(SSDEWMA(limit="phase1", denoiser=WaveletDenoiser()), reps=5)

    class WholeSeries:
        class denoiser:
            is_causal = False

        def alarms(self, z):
            return np.zeros(z.shape[:-1], dtype=bool)

    with pytest.raises(ConfigError, match="^chart=.*not causal"):
        monte_carlo_arl(WholeSeries(), reps=5)


def test_unfitted_chart_error_propagates():
    class NeedsPhaseOne:
        def alarms(self, z):
            raise RuntimeError("NeedsPhaseOne is not fitted")

    with pytest.raises(RuntimeError, match="not fitted"):
        monte_carlo_arl(NeedsPhaseOne(), reps=5)


@pytest.mark.parametrize("kwargs, name", [
    ({"a": float("nan")}, "a"),
    ({"b": 0.0}, "b"),
    ({"n": 0}, "n"),
    ({"reps": 1}, "reps"),
    ({"seed": -1}, "seed"),
    ({"max_run": 0}, "max_run"),
    ({"batch": 0}, "batch"),
])
def test_monte_carlo_rejects_bad_parameters(kwargs, name):
    with pytest.raises(ConfigError, match=rf"^{name}\b"):
        monte_carlo_arl(ShewhartMeanChart(3.0), **kwargs)


def test_object_without_alarms_is_rejected():
    with pytest.raises(ConfigError, match="^chart="):
        monte_carlo_arl(object())


# --------------------------------------------------------------------------------------
# bigger statistical checks
# --------------------------------------------------------------------------------------
@pytest.mark.slow
@pytest.mark.parametrize("lam, L", [(0.05, 2.615), (0.1, 3.0), (0.25, 2.998), (0.5, 3.0), (1.0, 3.0)])
@pytest.mark.parametrize("a", [0.0, 0.2, 0.5])
def test_monte_carlo_ewma_matches_ewma_arl_large(lam, L, a):
    n = 4
    estimate = monte_carlo_arl(EwmaMeanChart(lam, L), a=a, n=n, reps=20_000, seed=101)
    assert_within_three_se(estimate, ewma_arl(lam, L, math.sqrt(n) * a))
    # 20 000 runs: the Monte Carlo ARL0 is within ~1.5 % of the integral equation
    assert estimate.stderr / estimate.mean < 0.01


@pytest.mark.slow
def test_monte_carlo_shewhart_large():
    chart = ShewhartMeanChart(3.0)
    for a, b in [(0.0, 1.0), (0.5, 1.0), (0.0, 2.0)]:
        assert_within_three_se(monte_carlo_arl(chart, a=a, b=b, n=5, reps=50_000, seed=202),
                               chart.exact_arl(a, b, 5))
