"""Tests for mosd.denoisers: MATLAB-style wavelet denoising of chart statistics."""
from __future__ import annotations

import math

import numpy as np
import pytest
import pywt

import mosd.denoisers.wavelet as denoise_module
from mosd.denoisers import (
    NoDenoiser,
    WaveletDenoiser,
    select_threshold,
    threshold_coefficients,
)
from mosd.validation import ConfigError


def sure_risk(x: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Stein's unbiased risk of soft thresholding at each t, unit noise (brute force).

    SURE(t) = n − 2·#{|x| ≤ t} + Σ min(x², t²), evaluated directly for every t.
    """
    x = np.asarray(x)[None, :]
    t = np.asarray(t)[:, None]
    return x.size - 2 * np.sum(np.abs(x) <= t, axis=1) + np.sum(np.minimum(x**2, t**2), axis=1)


def piecewise_smooth(n: int) -> np.ndarray:
    """A sine with jumps (HeaviSine-like), amplitude a few noise σ."""
    t = np.arange(n) / n
    return 4 * np.sin(4 * np.pi * t) - np.sign(t - 0.3) - np.sign(0.72 - t) + 3 * (t > 0.5)


# --- threshold rules -------------------------------------------------------------

def test_rigrsure_hand_checked_vector():
    # x = [0.1, -0.2, 0.3, 3, -4], n = 5. Sorted squares s = [0.01, 0.04, 0.09, 9, 16],
    # cumsum = [0.01, 0.05, 0.14, 9.14, 25.14]. n·risk_i = n − 2i + cumsum_i + (n − i)·s_i:
    #   i=1: 5 − 2 + 0.01 + 4·0.01 =  3.05
    #   i=2: 5 − 4 + 0.05 + 3·0.04 =  1.17
    #   i=3: 5 − 6 + 0.14 + 2·0.09 = −0.68   <- minimum
    #   i=4: 5 − 8 + 9.14 + 1·9    = 15.14
    #   i=5: 5 − 10 + 25.14        = 20.14
    # so the threshold is sqrt(0.09) = 0.3.
    x = np.array([0.1, -0.2, 0.3, 3.0, -4.0])
    assert select_threshold(x, "rigrsure") == pytest.approx(0.3)
    # Order and sign of the coefficients must not matter.
    assert select_threshold(-x[::-1], "rigrsure") == pytest.approx(0.3)


def test_heursure_switches_between_sure_and_universal():
    # Hand vector above: energy excess (25.14 − 5)/5 = 4.028 exceeds
    # log2(5)^1.5/sqrt(5) = 1.582, so heursure = min(rigrsure 0.3, sqrt(2 ln 5) = 1.794) = 0.3.
    x = np.array([0.1, -0.2, 0.3, 3.0, -4.0])
    assert select_threshold(x, "heursure") == pytest.approx(0.3)
    # All-small vector: energy excess (0.05 − 4)/4 < 0 -> universal threshold sqrt(2 ln 4).
    small = np.array([0.1, -0.1, 0.1, -0.1, 0.1])[:4]
    assert select_threshold(small, "heursure") == pytest.approx(math.sqrt(2 * math.log(4)))


def test_fixed_form_rules_match_matlab_documentation():
    # MATLAB's thselect page, x = randn(1,1000): sqtwolog 3.7169, minimaxi 2.2163
    # (both depend on n only).
    x = np.random.default_rng(0).standard_normal(1000)
    assert select_threshold(x, "sqtwolog") == pytest.approx(3.7169, abs=1e-4)
    assert select_threshold(x, "minimaxi") == pytest.approx(2.2163, abs=1e-4)
    # minimaxi is 0 for n <= 32.
    assert select_threshold(x[:32], "minimaxi") == 0.0
    assert select_threshold(x[:33], "minimaxi") > 0.0


def test_rigrsure_attains_brute_force_sure_minimum():
    rng = np.random.default_rng(42)
    n_vectors, n = 40, 64
    # Mix of pure noise and sparse signals of varying strength.
    signal = np.zeros((n_vectors, n))
    spikes = rng.random((n_vectors, n)) < 0.15
    signal[spikes] = rng.normal(0.0, 1.0, spikes.sum()) * np.repeat(np.linspace(0, 8, n_vectors), n).reshape(
        n_vectors, n)[spikes]
    x = signal + rng.standard_normal((n_vectors, n))
    chosen = select_threshold(x, "rigrsure")  # one batched call
    assert chosen.shape == (n_vectors,)
    for row, t in zip(x, chosen):
        magnitudes = np.abs(row)
        grid = np.linspace(magnitudes.min(), magnitudes.max(), 4001)
        candidates = np.concatenate([magnitudes, grid])
        risk_all = sure_risk(row, candidates)
        risk_chosen = sure_risk(row, np.array([t]))[0]
        assert risk_chosen <= risk_all.min() + 1e-9
        assert np.any(np.isclose(t, magnitudes))  # the threshold is one of the |x_i|


def test_rigrsure_batched_any_leading_shape():
    x = np.random.default_rng(1).standard_normal((3, 4, 50))
    batched = select_threshold(x, "rigrsure")
    assert batched.shape == (3, 4)
    rowwise = np.array([[select_threshold(x[i, j], "rigrsure") for j in range(4)] for i in range(3)])
    np.testing.assert_array_equal(batched, rowwise)


# --- thresholding functions -----------------------------------------------------------

def test_hard_threshold_zeroes_values_equal_to_threshold():
    x = np.array([-2.0, -1.0, -0.5, 0.0, 0.5, 1.0, 1.5])
    out = threshold_coefficients(x, 1.0, "hard")
    np.testing.assert_array_equal(out, [-2.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.5])
    # pywt keeps |x| == t, which is exactly the difference MATLAB's wthresh does not have.
    assert pywt.threshold(x, 1.0, "hard")[5] == 1.0


def test_soft_threshold_shrinks_by_t():
    x = np.random.default_rng(2).normal(0, 3, 200)
    t = 1.25
    out = threshold_coefficients(x, t, "soft")
    big = np.abs(x) > t
    np.testing.assert_allclose(np.abs(out[big]), np.abs(x[big]) - t)
    assert np.all(np.sign(out[big]) == np.sign(x[big]))
    assert np.all(out[~big] == 0.0)
    np.testing.assert_allclose(out, pywt.threshold(x, t, "soft"))


def test_thresholds_broadcast_per_row():
    x = np.array([[1.0, 2.0, 3.0], [1.0, 2.0, 3.0]])
    out = threshold_coefficients(x, np.array([[1.5], [2.5]]), "hard")
    np.testing.assert_array_equal(out, [[0.0, 2.0, 3.0], [0.0, 0.0, 3.0]])


# --- whole-series denoising ----------------------------------------------------------------

@pytest.mark.parametrize("n", [40, 41, 57, 58])
def test_zero_threshold_reconstructs_exactly_short_series(n):
    # minimaxi gives 0 for <= 32 coefficients: every level of these short series qualifies
    # (cD1 has floor((n + 5)/2) <= 31 coefficients for n <= 58).
    x = np.random.default_rng(n).standard_normal((3, n))
    d = WaveletDenoiser(threshold="minimaxi", scope="level")
    out = d.denoise(x)
    assert out.shape == x.shape
    np.testing.assert_allclose(out, x, atol=1e-12)


@pytest.mark.parametrize("n", [999, 1000, 1001, 1024])
def test_zero_threshold_reconstructs_exactly_odd_and_even(monkeypatch, n):
    monkeypatch.setattr(denoise_module, "select_threshold", lambda c, rule: np.zeros(c.shape[:-1]))
    x = np.random.default_rng(n).standard_normal((2, 3, n))
    out = WaveletDenoiser().denoise(x)
    assert out.shape == x.shape
    np.testing.assert_allclose(out, x, atol=1e-12)


def test_one_dimensional_input_keeps_shape():
    x = np.random.default_rng(5).standard_normal(101)
    out = WaveletDenoiser().denoise(x)
    assert out.shape == (101,)


def test_tiny_statistic_without_rescaling_keeps_only_the_approximation():
    # With scaling='one' the rules assume unit noise: details of a signal of amplitude
    # 1e-3 are all below the threshold, so the output is the level-3 approximation.
    rng = np.random.default_rng(6)
    x = 1e-3 * rng.standard_normal((4, 300))
    out = WaveletDenoiser(scaling="one", global_source="all").denoise(x)
    coeffs = pywt.wavedec(x, "db3", mode="symmetric", level=3, axis=-1)
    approx_only = pywt.waverec([coeffs[0]] + [np.zeros_like(c) for c in coeffs[1:]], "db3",
                               mode="symmetric", axis=-1)[:, :300]
    np.testing.assert_allclose(out, approx_only, atol=1e-15)
    assert not np.allclose(out, x)


def test_matches_a_pywt_reference_pipeline():
    # sln, global threshold from the finest details, soft: rebuild it by hand with pywt.
    rng = np.random.default_rng(7)
    x = piecewise_smooth(500) + 0.5 * rng.standard_normal(500)
    out = WaveletDenoiser(scaling="sln", global_source="finest").denoise(x)
    coeffs = pywt.wavedec(x, "db3", mode="symmetric", level=3)
    sigma = np.median(np.abs(coeffs[-1])) / 0.6745
    t = sigma * select_threshold(coeffs[-1] / sigma, "rigrsure")
    shrunk = [coeffs[0]] + [pywt.threshold(c, t, "soft") for c in coeffs[1:]]
    expected = pywt.waverec(shrunk, "db3", mode="symmetric")[:500]
    np.testing.assert_allclose(out, expected, atol=1e-12)


@pytest.mark.parametrize("scaling", ["one", "sln", "mln"])
@pytest.mark.parametrize("scope", ["global", "level"])
def test_denoising_reduces_mse(scaling, scope):
    n = 1024
    clean = piecewise_smooth(n)
    noisy = clean + np.random.default_rng(8).standard_normal((10, n))
    out = WaveletDenoiser(scaling=scaling, scope=scope).denoise(noisy)
    mse_before = np.mean((noisy - clean) ** 2)
    mse_after = np.mean((out - clean) ** 2)
    assert mse_after < 0.5 * mse_before


@pytest.mark.parametrize("scaling", ["sln", "mln"])
def test_rescaled_denoising_is_scale_equivariant(scaling):
    # With a noise estimate the threshold scales with the data; without one it would not.
    x = piecewise_smooth(256) + np.random.default_rng(9).standard_normal((3, 256))
    d = WaveletDenoiser(scaling=scaling)
    np.testing.assert_allclose(d.denoise(0.01 * x), 0.01 * d.denoise(x), rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("scaling", ["sln", "mln"])
@pytest.mark.parametrize("scope", ["global", "level"])
def test_zero_noise_estimate_keeps_details(scaling, scope):
    # A clean step: only the few coefficients overlapping the jump are non-zero, so the
    # median-based sigma-hat is 0 at every level. wden's guard then keeps the details
    # (threshold 0) instead of dividing by zero, and the step comes back unchanged.
    x = np.zeros((2, 128))
    x[:, 64:] = 1.0
    out = WaveletDenoiser(scaling=scaling, scope=scope).denoise(x)
    np.testing.assert_allclose(out, x, atol=1e-12)


@pytest.mark.parametrize("kwargs", [
    {},
    {"scope": "level", "scaling": "mln", "mode": "hard"},
    {"threshold": "heursure", "global_source": "coarsest"},
    {"window": 50},
])
def test_batched_equals_row_by_row(kwargs):
    rng = np.random.default_rng(10)
    x = np.cumsum(rng.standard_normal((6, 200)), axis=-1) + rng.standard_normal((6, 200))
    d = WaveletDenoiser(**kwargs)
    batched = d.denoise(x)
    rowwise = np.stack([d.denoise(row) for row in x])
    np.testing.assert_allclose(batched, rowwise, rtol=0, atol=1e-12)


# --- causal mode ---------------------------------------------------------------------------

def test_causal_output_ignores_future_samples():
    rng = np.random.default_rng(11)
    x = rng.standard_normal((3, 300))
    d = WaveletDenoiser(window=64)
    base = d.denoise(x)
    for k in (10, 45, 63, 64, 150, 298):
        changed = x.copy()
        changed[:, k + 1:] += rng.normal(0, 5, changed[:, k + 1:].shape)
        out = d.denoise(changed)
        np.testing.assert_array_equal(out[:, :k + 1], base[:, :k + 1])
        assert not np.allclose(out[:, k + 1:], base[:, k + 1:])
    # The whole-series mode, by contrast, looks ahead.
    whole = WaveletDenoiser()
    changed = x.copy()
    changed[:, 151:] += 5.0
    assert not np.allclose(whole.denoise(changed)[:, :151], whole.denoise(x)[:, :151])


def test_causal_output_is_last_value_of_denoised_window():
    rng = np.random.default_rng(12)
    x = rng.standard_normal(200)
    w = 60
    causal = WaveletDenoiser(window=w)
    whole = WaveletDenoiser()
    out = causal.denoise(x)
    m = causal.min_length
    assert m == 40  # (dec_len 6 − 1) · 2**3 for db3, level 3
    np.testing.assert_array_equal(out[:m - 1], x[:m - 1])  # too short: passed through
    for k in (m - 1, 50, w - 2):  # growing prefix
        assert out[k] == pytest.approx(whole.denoise(x[:k + 1])[-1], abs=1e-12)
    for k in (w - 1, 100, 199):  # full sliding window
        assert out[k] == pytest.approx(whole.denoise(x[k - w + 1:k + 1])[-1], abs=1e-12)


def test_describe_says_causal_or_not():
    assert WaveletDenoiser().describe()["causal"] is False
    assert "non-causal" in repr(WaveletDenoiser())
    d = WaveletDenoiser(window=100)
    assert d.describe()["causal"] is True and d.describe()["window"] == 100
    assert "causal sliding window" in repr(d)


def test_no_denoiser_is_identity_and_causal():
    x = np.random.default_rng(13).standard_normal((4, 7))
    d = NoDenoiser()
    out = d.denoise(x)
    np.testing.assert_array_equal(out, x)
    assert out is not x
    assert d.describe()["causal"] is True


# --- validation ------------------------------------------------------------------------------

@pytest.mark.parametrize("kwargs, name", [
    ({"wavelet": "db99"}, "denoise.wavelet"),
    ({"wavelet": "morl"}, "denoise.wavelet"),  # continuous wavelet: no DWT
    ({"level": 0}, "denoise.level"),
    ({"level": 2.5}, "denoise.level"),
    ({"threshold": "bayes"}, "denoise.threshold"),
    ({"mode": "garrote"}, "denoise.mode"),
    ({"scaling": "mad"}, "denoise.scaling"),
    ({"scope": "lvd"}, "denoise.scope"),
    ({"global_source": "middle"}, "denoise.global_source"),
    ({"window": 39}, "denoise.window"),  # below min_length 40 for db3, level 3
    ({"window": 64.5}, "denoise.window"),
])
def test_invalid_parameters_raise_config_error(kwargs, name):
    with pytest.raises(ConfigError, match=name):
        WaveletDenoiser(**kwargs)


def test_window_minimum_follows_wavelet_and_level():
    WaveletDenoiser(wavelet="haar", level=2, window=4)  # (2 − 1) · 2**2 = 4
    with pytest.raises(ConfigError, match="denoise.window"):
        WaveletDenoiser(wavelet="haar", level=2, window=3)


def test_invalid_inputs_raise():
    d = WaveletDenoiser()
    with pytest.raises(ValueError, match="non-finite"):
        d.denoise(np.array([1.0, np.nan] * 30))
    with pytest.raises(ValueError, match="at least 40"):
        d.denoise(np.zeros(39))
