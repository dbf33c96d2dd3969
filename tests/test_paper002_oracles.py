"""Paper 002 (reconstruction), issue 20: missingness mechanisms, fills and their independent oracles.

* a gap [onset, onset + g) seen through an output-based error (the residual y − h(x̂), NaN
  where y is missing) delays the isolation by exactly g samples;
* on an AR(1)-Gaussian surrogate the Kalman smoother's conditional mean (filterpy's
  ``rts_smoother``, independent of mosd) is the least possible fill error: no fill beats it;
* the Rényi quadratic entropy of a one-step error whose density is known in closed form,
  by numerical convolution of the densities (no particles), against the Parzen estimate.
"""
import math

import numpy as np
import pytest
from scipy import integrate, signal, stats

from mosd.detectors.threshold import ThresholdDetector
from mosd.estimators.entropy_filter import FixedGainFilter, renyi_quadratic, silverman_bandwidth
from mosd.estimators.imputation import EMImputer, hold_last
from mosd.faults.random_amplitude import RandomAmplitudeFault, SineLaw
from mosd.metrics import detection
from mosd.noise.bounded import BoundedNoise, EpanechnikovLaw
from mosd.plants.missingness import missing_mask
from mosd.plants.scalar_nonlinear import ScalarNonlinearPlant
from mosd.validation import ConfigError


def _rngs(n, seed=0):
    return [np.random.default_rng([seed, r]) for r in range(n)]


# -- mechanisms ------------------------------------------------------------------------------------
def test_mcar_is_unchanged_and_each_mechanism_loses_its_share():
    u = np.random.default_rng(0).random((4000, 100))
    np.testing.assert_array_equal(missing_mask(u, 0.1), u < 0.1)   # MCAR: the former rule, bit for bit
    burst = missing_mask(u, 0.2, "burst", 5.0)
    assert abs(burst.mean() - 0.2) < 4 * math.sqrt(0.2 * 0.8 * 5 / burst.size) * 3
    # the chain's transitions: a burst goes on with probability 1 − 1/5 (mean length 5, geometric)
    stay = burst[:, 1:][burst[:, :-1]]
    assert stay.mean() == pytest.approx(0.8, abs=4 * math.sqrt(0.16 / stay.size))
    enter = burst[:, 1:][~burst[:, :-1]]
    assert enter.mean() == pytest.approx(0.2 / (5 * 0.8), abs=4 * math.sqrt(0.05 / enter.size))
    gap = missing_mask(u, 0.2, "gap")
    assert np.all(gap.sum(axis=1) == 20)
    assert np.all(np.diff(gap.astype(int), axis=1).clip(min=0).sum(axis=1) <= 1)   # one contiguous block
    np.testing.assert_array_equal(np.argmax(missing_mask(u[:3], 0.1, "gap", gap_start=50), axis=1), [50] * 3)


def test_plant_keys_are_validated_in_one_line():
    with pytest.raises(ConfigError, match="plant.missing_mechanism='bursts' is not allowed; allowed: mcar, burst, gap"):
        ScalarNonlinearPlant(missing_mechanism="bursts")
    with pytest.raises(ConfigError, match="plant.burst_length"):
        ScalarNonlinearPlant(missing_mechanism="burst", burst_length=0.5)
    with pytest.raises(ConfigError, match="plant.burst_length=1.0 is too short for plant.missing_rate=0.6"):
        ScalarNonlinearPlant(missing_mechanism="burst", missing_rate=0.6, burst_length=1.0)
    with pytest.raises(ConfigError, match="plant.gap_onset"):
        ScalarNonlinearPlant(missing_mechanism="gap", gap_onset=-1.0)
    with pytest.raises(ConfigError, match="estimator.missing='ffill' is not allowed; allowed: em, hold, skip"):
        FixedGainFilter(missing="ffill")


def test_hold_last_repeats_the_last_observed_sample():
    y = np.array([[np.nan, 1.0, np.nan, np.nan, 3.0, np.nan], [2.0, np.nan, 5.0, 6.0, np.nan, np.nan]])
    np.testing.assert_array_equal(hold_last(y), [[np.nan, 1, 1, 1, 3, 3], [2, 2, 5, 6, 6, 6]])


# -- oracle 1: a gap at the onset delays an output-based isolation by exactly its length -----------
@pytest.mark.parametrize("g", [1, 4, 10])
def test_a_gap_at_the_onset_delays_the_output_based_error_by_exactly_its_length(g):
    n, N = 20, 100
    plant = ScalarNonlinearPlant(missing_rate=g / N, missing_mechanism="gap", gap_onset=5.0)
    noise = BoundedNoise(c=1e-3, measurement_std=1e-3)
    fault = RandomAmplitudeFault("sine", onset=5.0, role="target")
    trace = plant.simulate(N, noise, fault, _rngs(n))
    onset = int(np.argmax(trace.fault_mask[0]))
    assert onset == 50 and np.all(np.isnan(trace.y[:, onset:onset + g, 0]))
    assert not np.isnan(trace.y[:, onset + g, 0]).any()
    outputs = FixedGainFilter(gain=0.27, missing="skip").estimate(trace, plant.model(noise))
    residual = outputs.r                       # y − h(x̂): the error a monitor can compute, NaN in the gap
    decisions = ThresholdDetector(threshold=0.3, persistence=1).decide(residual[:1], residual).decision
    delay = detection.detection_delay(decisions, trace.fault_mask)
    np.testing.assert_array_equal(delay, np.full(n, float(g)))


# -- oracle 2: the Kalman smoother's conditional mean is the least possible fill error --------------
PHI, Q, R_NOISE = 0.8, 0.36, 0.04     # x_{k+1} = φ x_k + w, y = x + v: an AR(1)-Gaussian surrogate


def _ar1(n_runs, N, seed):
    rng = np.random.default_rng(seed)
    x = np.empty((n_runs, N))
    x[:, 0] = rng.normal(0.0, math.sqrt(Q / (1 - PHI**2)), n_runs)
    for k in range(N - 1):
        x[:, k + 1] = PHI * x[:, k] + rng.normal(0.0, math.sqrt(Q), n_runs)
    return x, x + rng.normal(0.0, math.sqrt(R_NOISE), x.shape), rng.random(x.shape)


def _smoothed(y):
    """filterpy's Kalman filter + RTS smoother on one run, missing samples passed as None (no update)."""
    from filterpy.kalman import KalmanFilter

    kf = KalmanFilter(dim_x=1, dim_z=1)
    kf.F, kf.H, kf.Q, kf.R = np.array([[PHI]]), np.array([[1.0]]), np.array([[Q]]), np.array([[R_NOISE]])
    kf.x, kf.P = np.zeros((1, 1)), np.array([[Q / (1 - PHI**2)]])   # x_0's stationary law
    zs = [None if np.isnan(v) else np.array([[v]]) for v in y]
    # update then predict: the stored means are x_k | y_0..y_k, which rts_smoother expects
    means, covs, _, _ = kf.batch_filter(zs, update_first=True)
    xs, Ps, _, _ = kf.rts_smoother(means, covs)
    return xs[:, 0, 0], Ps[:, 0, 0]


@pytest.mark.parametrize("mechanism", ["mcar", "burst", "gap"])
def test_no_fill_beats_the_kalman_smoothers_conditional_mean(mechanism):
    n_runs, N = 60, 100
    x, y, u = _ar1(n_runs, N, seed=11)
    gap = missing_mask(u, 0.2, mechanism, 5.0)
    y_obs = np.where(gap, np.nan, y)
    smooth, var = map(np.array, zip(*(_smoothed(row) for row in y_obs)))
    rmse = {"smoother": math.sqrt(np.mean((smooth - x)[gap] ** 2))}
    # the smoother's error is what its own posterior variance says (the oracle is calibrated)
    assert rmse["smoother"] == pytest.approx(math.sqrt(np.mean(var[gap])), rel=0.1)
    for name, filled in (("em", EMImputer().impute(y_obs)), ("hold", hold_last(y_obs))):
        ok = gap & np.isfinite(filled)
        rmse[name] = math.sqrt(np.mean((filled - x)[ok] ** 2))
        # E[x_k | all observed y] minimises the mean squared fill error: a fill can only tie it
        assert rmse[name] >= 0.98 * rmse["smoother"], rmse
    if mechanism != "mcar":   # long gaps: holding a value up to g steps old is clearly worse
        assert rmse["hold"] > 1.2 * rmse["smoother"], rmse


# -- oracle 3: error entropy by numerical convolution of the known densities -----------------------
def test_parzen_entropy_matches_the_convolved_densities():
    """e = δ + ω − U σ_v v (a particle whose estimate was exact a step before): its density is the
    convolution of the sine law of δ, the Epanechnikov law of ω and N(0, (U σ_v)²)."""
    U, sd_v, c = 0.3, 0.2, 0.1
    sine, epan = SineLaw(), EpanechnikovLaw(c)
    h = 1e-4
    grid = np.arange(-1.0, 3.0, h)
    p_delta = np.where((grid >= 0.5) & (grid <= 1.5), math.pi / 2 * np.sin(math.pi * (grid - 0.5)), 0.0)
    k = np.arange(-c, c + h / 2, h)
    p_omega = 3 / (4 * c) * (1 - (k / c) ** 2)
    g = np.arange(-6 * U * sd_v, 6 * U * sd_v + h / 2, h)
    p_v = stats.norm.pdf(g, scale=U * sd_v)
    p_e = signal.fftconvolve(signal.fftconvolve(p_delta, p_omega * h, "same"), p_v * h, "same")
    assert integrate.trapezoid(p_e, grid) == pytest.approx(1.0, abs=1e-3)
    H_exact = -math.log(integrate.trapezoid(p_e**2, grid))

    rng = np.random.default_rng(2013)
    n = 3000
    a = sine.sample(rng, n) + epan.sample(rng, n)
    b = sd_v * rng.standard_normal(n)
    s = silverman_bandwidth(a - U * b)
    H_parzen, _, _ = renyi_quadratic(a, b, U, s)
    # the Parzen estimate is the entropy of p_e smoothed by the kernel N(0, s²): exact up to Monte Carlo error
    p_smooth = signal.fftconvolve(p_e, stats.norm.pdf(np.arange(-6 * s, 6 * s + h / 2, h), scale=s) * h, "same")
    H_smooth = -math.log(integrate.trapezoid(p_smooth**2, grid))
    assert H_parzen == pytest.approx(H_smooth, abs=0.03)
    # and within the smoothing bias of the exact entropy (the kernel only widens the density)
    assert H_exact < H_smooth < H_exact + 0.1
    assert H_parzen == pytest.approx(H_exact, abs=0.1)
