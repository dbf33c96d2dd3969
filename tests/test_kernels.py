"""The compiled kernels (mosd.kernels) give the NumPy reference's numbers: bit for bit where both run one
arithmetic (the same operations in the same order, correctly rounded on every CPU), within a stated
tolerance where the reference is another library's code (PyWavelets', SciPy's C, which a compiler may fuse
into multiply-adds or vectorise differently on another CPU)."""
import pickle

import numpy as np
import pytest

from mosd import kernels
from mosd.denoisers import NoDenoiser, WaveletDenoiser
from mosd.detectors import MDEWMA, SSDEWMA, SSEWMA, MaxEWMA, ewma_time_major
from mosd.detectors.fused import fused_evaluation
from mosd.kernels.chart import mean_std, pairwise_sum
from mosd.optim.problem import CandidateEvaluator

# numba is a dependency: without it these tests fail, they never skip
assert kernels.available(), "numba is a dependency of mosd"


def _reference(fn, *args, **kwargs):
    with kernels.disabled():
        return fn(*args, **kwargs)


def _assert_wavelet_close(got, ref, x):
    """The compiled wavelet against PyWavelets' C: a level-L transform and its inverse take ~4·L·taps (< 200)
    multiply-adds per value over intermediates bounded by (Σ|h|)^L·max|x| (< 10·max|x| here), each rounding
    within 1.1e-16 of them, in an order (and with fused multiply-adds on ARM) that differs between the two:
    at most ~2e-13·max|x| of each row apart; 1e-12 of the row's scale holds that, while a wrong tap, level
    or threshold moves values by far more. Thresholding is continuous in the coefficients (soft) or jumps only
    at a coefficient within that distance of the threshold (hard), which these data never place."""
    assert got.shape == ref.shape
    scale = np.abs(x).max(axis=-1, keepdims=True)
    assert np.all(np.abs(got - ref) <= 1e-12 * scale + 1e-12 * np.abs(ref)), np.abs(got - ref).max()


def test_switch_selects_the_path():
    assert kernels.enabled()
    with kernels.disabled():
        assert not kernels.enabled()
    assert kernels.enabled()


def _ewma_numpy(x, lams, order):
    """The NumPy oracle of ``ewma_time_major`` (the recursion lives only in mosd.kernels.ewma): y_k = λ·x_k +
    (1 − λ)·y_{k−1}, applied ``order`` times, one NumPy step per time point over every (λ, sequence)."""
    columns = np.asarray(x, float).reshape(-1, x.shape[-1]).T              # (K, M)
    lams = np.asarray(lams, float)[:, None]
    y = np.broadcast_to(columns[:, None, :], (columns.shape[0], lams.shape[0], columns.shape[1]))
    for _ in range(order):
        out = np.empty_like(y)
        previous = np.zeros(y.shape[1:])
        for k in range(y.shape[0]):
            previous = lams * y[k] + (1.0 - lams) * previous
            out[k] = previous
        y = out
    return y


@pytest.mark.parametrize("order", [1, 2])
def test_population_recursion_is_the_numpy_oracle(order):
    x = np.random.default_rng(order).standard_normal((3, 2, 257))
    lams = [1e-6, 0.05, 0.3, 0.999999]
    got = ewma_time_major(x, lams, order=order)
    ref = _ewma_numpy(x, lams, order)
    assert got.shape == ref.shape == (257, 4, 6)
    # the compiled recursion runs the filter's difference equation, the oracle the EWMA applied twice: the same
    # numbers up to rounding (λ = 1e-6 leaves values near 1e-6·|x|: an absolute floor for those)
    np.testing.assert_allclose(got, ref, rtol=1e-10, atol=1e-15)


@pytest.mark.parametrize("order", [1, 2, 3])
def test_recursion_coefficients_are_numpy_polys(order):
    from mosd.detectors.statistics import ewma_coefficients

    lams = np.random.default_rng(order).uniform(1e-9, 1.0, 500)
    gain, feedback = ewma_coefficients(lams, order)
    # exact: the gain is NumPy's lams**order on both sides; orders 1-2 write out np.poly's products (-2p and a
    # single p·p, exact in any order), order 3 calls np.poly itself
    assert np.array_equal(gain, lams**order)
    assert np.array_equal(feedback, np.array([-np.poly(np.full(order, 1.0 - lam))[1:] for lam in lams]))


@pytest.mark.parametrize("settings", [
    {},  # the paper's literal call: db3, level 3, rigrsure, soft, unscaled, coarsest details
    {"global_source": "all"}, {"global_source": "finest", "mode": "hard"}, {"scope": "level"},
    {"threshold": "sqtwolog"}, {"threshold": "minimaxi", "scope": "level"}, {"wavelet": "haar", "level": 5},
    {"wavelet": "sym4", "level": 2},
])
@pytest.mark.parametrize("n", [1000, 999, 64])
def test_wavelet_is_pywavelets(settings, n):
    denoiser = WaveletDenoiser(**settings)
    rng = np.random.default_rng(n)
    # a small in-control statistic (every detail removed), a large one (details survive, SURE sorts), a mix
    x = np.concatenate([0.05 * rng.standard_normal((3, n)) ** 2, 20.0 * rng.standard_normal((3, n)) ** 2,
                        np.linspace(0.0, 40.0, n)[None, :] * rng.random((2, n))])
    got = denoiser.denoise(x)
    assert denoiser._kernel_plan() is not None and denoiser._kernel_plan().fits(n)
    _assert_wavelet_close(got, _reference(denoiser.denoise, x), x)


def test_wavelet_settings_outside_the_kernel_use_the_reference():
    assert WaveletDenoiser(scaling="sln")._kernel_plan() is None
    assert WaveletDenoiser(threshold="heursure")._kernel_plan() is None
    causal = WaveletDenoiser(window=48)  # its windows run through the kernel
    x = np.random.default_rng(0).standard_normal((2, 120)) ** 2
    _assert_wavelet_close(causal.denoise(x), _reference(causal.denoise, x), x)


@pytest.mark.parametrize("n", [1, 7, 8, 9, 127, 128, 129, 1000, 8192, 8193, 10000, 123457])
def test_pairwise_summation_matches_numpy(n):
    x = np.random.default_rng(n).standard_normal(n) * 10.0 ** np.random.default_rng(n + 1).uniform(-3, 3, n)
    # exact on purpose: the kernel replays NumPy's summation order (its 8 accumulators are vectorised without
    # reordering on any CPU), and additions, squares, a division and a sqrt round correctly everywhere
    assert pairwise_sum(x, 0, n) == np.sum(x)
    if n > 1:
        assert mean_std(x) == (np.mean(x), np.std(x, ddof=1))


def _workload(n_cal=4, n_train=5, n_subgroups=300, seed=0):
    rng = np.random.default_rng(seed)
    phase1 = rng.standard_normal((n_cal, n_subgroups, 5))
    train = rng.standard_normal((n_train, n_subgroups, 5))
    onset = n_subgroups // 2
    train[:, onset:] = 0.6 + 1.3 * train[:, onset:]  # a moderate fault: FAR and MDR both away from 0
    mask = np.zeros((n_train, n_subgroups), bool)
    mask[:, onset:] = True
    return phase1, train, mask


def _population(size=40, seed=3):
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.uniform(1e-3, 0.999, size), rng.uniform(0.0, 5.0, size)])


@pytest.mark.parametrize("chart_type", [SSDEWMA, SSEWMA, MDEWMA, MaxEWMA])
@pytest.mark.parametrize("denoiser", [WaveletDenoiser(), NoDenoiser()], ids=["wavelet", "none"])
def test_fused_evaluation_gives_the_reference_objectives_exactly(chart_type, denoiser):
    chart = chart_type(limit="phase1", denoiser=denoiser)
    phase1, train, mask = _workload()
    evaluator = CandidateEvaluator(chart, chart.features(phase1), chart.features(train), mask)
    X = _population()
    assert evaluator.fused() is not None
    got = evaluator(X)
    ref = evaluator.reference(X)
    # exact on purpose: the reference (kernels on) takes every value from the same compiled steps (ewma_step,
    # combine_step, denoise_row, NumPy's pairwise order for the limit), adds, multiplies and square roots that
    # numba never fuses (no fastmath), so the same statistics, limits and counts on any CPU
    assert np.array_equal(got, ref)
    assert 0 < got[:, 0].max() and 0 < got[:, 1].max()  # the workload separates candidates on both objectives
    # a candidate's objectives do not depend on its neighbours, nor on the process (pickled, as a worker gets it)
    assert np.array_equal(evaluator(X[7:8]), got[7:8])
    assert np.array_equal(pickle.loads(pickle.dumps(evaluator))(X[:5]), got[:5])


def test_fused_evaluation_declines_what_it_does_not_reproduce():
    phase1, train, mask = _workload(n_subgroups=120)
    theoretical = SSDEWMA(limit="theoretical")
    assert fused_evaluation(theoretical, theoretical.features(phase1), theoretical.features(train),
                            CandidateEvaluator(theoretical, None, None, mask).truth, ("far", "mdr")) is None
    chart = SSDEWMA(denoiser=WaveletDenoiser(scaling="sln"))
    evaluator = CandidateEvaluator(chart, chart.features(phase1), chart.features(train), mask)
    assert evaluator.fused() is None
    delay = CandidateEvaluator(SSDEWMA(), chart.features(phase1), chart.features(train), mask,
                               objectives=("far", "delay_censored"))
    assert delay.fused() is None
    assert np.isfinite(delay(_population(4))).all()

    class Tighter(SSDEWMA):  # a subclass with its own limit rule keeps the reference path
        def fit_statistic(self, l_phase1):
            super().fit_statistic(l_phase1)
            self.scale_ *= 0.5
            return self

    tighter = Tighter()
    assert CandidateEvaluator(tighter, chart.features(phase1), chart.features(train), mask).fused() is None


def test_fused_evaluation_rejects_bad_designs_like_the_reference():
    chart = SSDEWMA(denoiser=WaveletDenoiser())
    phase1, train, mask = _workload(n_subgroups=120)
    evaluator = CandidateEvaluator(chart, chart.features(phase1), chart.features(train), mask)
    from mosd.validation import ConfigError

    with pytest.raises(ConfigError, match="detector.lam"):
        evaluator(np.array([[1.5, 1.0]]))


@pytest.mark.slow
def test_a_chart_without_a_denoiser_never_compiles_the_wavelet(tmp_path):
    """numba compiles every function a kernel's body calls: the wavelet lives in its own chart kernel, so a
    run with denoise=none does not pay its compilation on a cold cache (issue 31)."""
    import json
    import os
    import subprocess
    import sys
    from pathlib import Path

    import mosd

    env = {k: v for k, v in os.environ.items() if k != "MOSD_KERNELS"}
    env.update(NUMBA_CACHE_DIR=str(tmp_path), PYTHONPATH=str(Path(mosd.__file__).resolve().parents[1]))
    code = ("import json\nfrom mosd import kernels\nfrom mosd.kernels import chart, wavelet\nkernels.warm_up()\n"
            "print(json.dumps([len(chart.alarm_counts.signatures), len(wavelet.denoise_row.signatures)]))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600, env=env)
    assert out.returncode == 0, out.stderr[-2000:]
    assert json.loads(out.stdout.strip().splitlines()[-1]) == [1, 0]


@pytest.mark.parametrize("shape", [(3, 40), (4, 7, 50), (2, 5, 3, 30), (5, 1, 1)])
def test_the_compiled_persistence_rule_is_the_reference(shape):
    """mosd.kernels.decisions.persistence behind detectors.base.persistent gives the NumPy counting's booleans:
    lengths from 1 to beyond the run, any number of leading axes, a strided input."""
    from mosd.detectors.base import persistent

    rng = np.random.default_rng(len(shape))
    condition = rng.random(shape) < rng.uniform(0.2, 0.95)
    condition[0] = True  # one design's every point, then a run of any length
    lengths = rng.integers(1, shape[-1] + 3, shape[0])
    lengths[-1] = 1
    for given, length in ((condition, lengths), (condition[..., ::-1], lengths), (condition, 2)):
        compiled = persistent(given, length)
        with kernels.disabled():
            reference = persistent(given, length)
        assert compiled.dtype == reference.dtype == bool and compiled.shape == reference.shape
        np.testing.assert_array_equal(compiled, reference)


@pytest.mark.parametrize("seed", range(40))
def test_the_compiled_latent_ewma_is_lfilter(seed):
    """mosd.kernels.latent.smooth_rows behind ewma_from and smoothed_values gives SciPy lfilter's numbers (the
    reference with the kernels off): missing and infinite points, zeros (their sign too), λ = 1, tiny λ, a
    carried state, a strided statistic, one and three axes."""
    from mosd.detectors.latent import ewma_from, smoothed_values

    rng = np.random.default_rng(seed)
    shape = [(int(rng.integers(1, 30)), int(rng.integers(1, 200))), (int(rng.integers(1, 300)),),
             (2, 3, int(rng.integers(1, 50)))][seed % 3]
    x = rng.standard_normal(shape) * 10.0 ** rng.uniform(-6, 6)
    if seed % 2:
        x[rng.random(shape) < 0.1] = np.nan
    if seed % 5 == 0:
        x[rng.random(shape) < 0.05] = np.inf
    if seed % 7 == 0:
        x = -np.abs(x)
        x[..., :3] = 0.0
    lam = (float(rng.uniform(0.01, 1.0)), 1.0, 0.5, 1e-3)[seed % 4]
    start = float(rng.standard_normal()) if seed % 3 else 0.0
    previous = None if seed % 4 == 1 else float(rng.standard_normal())
    strided = np.stack([x, x + 1.0], axis=-1)[..., 0]  # a family's statistic: one of several stacked
    for given in (x, strided):
        compiled = (ewma_from(given, lam, start, previous), smoothed_values(given, lam, start))
        with kernels.disabled():
            reference = (ewma_from(given, lam, start, previous), smoothed_values(given, lam, start))
        for a, b in zip(compiled, reference):
            assert a.shape == b.shape == x.shape
            # two implementations of y = λx + (1−λ)y₋₁ (numba's, SciPy lfilter's C, which a compiler may fuse
            # into multiply-adds): each step rounds within ~2 ulp of its terms and the recursion damps an error
            # by (1 − λ), so they stay within ~4e-16/λ·scale (4.4e-13 for λ = 1e-3) of each other; missing and
            # infinite points in the same places (assert_allclose compares those exactly)
            scale = max(np.abs(x[np.isfinite(x)]).max(initial=0.0), abs(start), abs(previous or 0.0))
            np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-11 * scale)
            zero = b == 0  # the zeros' signs: exact zeros on both sides (a zero input stays a zero)
            assert np.array_equal(np.signbit(a[zero]), np.signbit(b[zero]))
    assert np.isnan(smoothed_values(x, lam, start)[~np.isfinite(x)]).all()
