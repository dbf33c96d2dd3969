"""The fused candidate evaluation of a mean–variance chart (SS-DEWMA and kin), compiled.

For one candidate (λ, K) and the features (U_k, V_k) of the calibration and the
training runs, the reference path (``Chart.population`` then
``objective_values``) computes the smoothed statistic of every run, denoises it,
fits the Phase-I limit E{l} + K·sd{l} on the calibration runs and scores the
training runs' alarms — materialising (P, R, K) statistics, limits and
decisions on the way. Here all of it is one compiled loop per candidate that
keeps only one candidate's (R, K) statistic, and returns per-run alarm counts
(P, R): healthy points that alarm and target-fault points that do not.

Each step reproduces the reference's arithmetic in its order (the recursion of
``ewma_time_major``, PyWavelets' sums via :mod:`mosd.kernels.wavelet`, NumPy's
pairwise summation for the mean and standard deviation of ``fit_statistic``),
so FAR and MDR come out bit-identical; ``tests/test_kernels.py`` checks it.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from . import configure_compiler

configure_compiler()  # before this module's first compile

from .ewma import ewma_step
from .wavelet import denoise_row, work_size

_BLOCK = 128  # NumPy's pairwise-summation block (PW_BLOCKSIZE)

#: a helper called only from compiled code: no CPython or C entry point to build (numba builds both for every
#: function it compiles, called from Python or not: on an empty cache each cost the main command compile time)
_helper = njit(cache=True, nogil=True, no_cpython_wrapper=True, no_cfunc_wrapper=True)


@_helper
def _pairwise_sum(a, start, n):
    """NumPy's pairwise summation of a[start:start + n] (what ``np.add.reduce`` does on a contiguous float64 array).

    NumPy recurses: sum(a[:h]) + sum(a[h:]) with h = n//2 rounded down to a
    multiple of 8, down to blocks of at most 128, each summed with eight
    accumulators, then the rest. The recursion runs here on an explicit stack
    (numba's on-disk cache mishandles recursive functions), and the block's sum
    is written once, in the loop, not as a function of its own (each compiled
    function costs the cold cache its own optimisation and code generation).
    """
    starts = np.empty(128, np.int64)
    sizes = np.empty(128, np.int64)
    combine = np.zeros(128, np.bool_)
    values = np.empty(128)
    top = 1
    starts[0], sizes[0], combine[0] = start, n, False
    depth = 0
    while top > 0:
        top -= 1
        s, m, joining = starts[top], sizes[top], combine[top]
        if joining:
            depth -= 1
            values[depth - 1] = values[depth - 1] + values[depth]
        elif m <= _BLOCK:  # a block: NumPy's eight accumulators, then the rest
            if m < 8:
                res = 0.0
                for i in range(s, s + m):
                    res += a[i]
            else:
                r0, r1, r2, r3 = a[s], a[s + 1], a[s + 2], a[s + 3]
                r4, r5, r6, r7 = a[s + 4], a[s + 5], a[s + 6], a[s + 7]
                i = 8
                stop = m - m % 8
                while i < stop:
                    b = s + i
                    r0 += a[b]
                    r1 += a[b + 1]
                    r2 += a[b + 2]
                    r3 += a[b + 3]
                    r4 += a[b + 4]
                    r5 += a[b + 5]
                    r6 += a[b + 6]
                    r7 += a[b + 7]
                    i += 8
                res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
                while i < m:
                    res += a[s + i]
                    i += 1
            values[depth] = res
            depth += 1
        else:
            half = m // 2
            half -= half % 8
            # popped in reverse: the left half first, then the right, then their sum
            starts[top], sizes[top], combine[top] = s, m, True
            starts[top + 1], sizes[top + 1], combine[top + 1] = s + half, m - half, False
            starts[top + 2], sizes[top + 2], combine[top + 2] = s, half, False
            top += 3
    return values[0]


@njit(cache=True, nogil=True)
def mean_std(values):
    """(np.mean(values), np.std(values, ddof=1)) of a contiguous 1-D array, bit for bit.

    With a CPython entry point: the main command calls it from Python too (the deployed chart's Phase-I
    limit, ``fit_statistic``), so one compile serves both.
    """
    n = values.shape[0]
    center = _pairwise_sum(values, np.int64(0), n) / n  # an int64 start, not Literal[int](0): one compile
    deviations = np.empty(n)
    for i in range(n):
        d = values[i] - center
        deviations[i] = d * d
    return center, math.sqrt(_pairwise_sum(deviations, np.int64(0), n) / (n - 1))


@njit(cache=True, nogil=True)
def pairwise_sum(a, start, n):
    """:func:`_pairwise_sum` from Python (the tests' view)."""
    return _pairwise_sum(a, start, n)


@_helper
def _statistics(u, v, gain, f1, f2, order, combine_max, stat, y):
    """Smoothed-and-combined statistic of every run: u, v time-major (K, C) -> stat (C, K).

    y: scratch (4, C) for the recursion's two past values of both parts, from a zero state. Each value is
    :func:`mosd.kernels.ewma.ewma_step`'s (the one arithmetic of the charts); U and V in one pass.
    """
    n_points, n_columns = u.shape
    u1, u2, v1, v2 = y[0], y[1], y[2], y[3]
    for c in range(n_columns):
        u1[c] = 0.0
        u2[c] = 0.0
        v1[c] = 0.0
        v2[c] = 0.0
    for k in range(n_points):
        uk, vk = u[k], v[k]
        for c in range(n_columns):
            a = ewma_step(uk[c], gain, f1, f2, u1[c], u2[c], order)
            b = ewma_step(vk[c], gain, f1, f2, v1[c], v2[c], order)
            if order == 2:
                u2[c] = u1[c]
                v2[c] = v1[c]
            u1[c] = a
            v1[c] = b
            if combine_max:
                stat[c, k] = max(abs(a), abs(b))
            else:
                s = a * a
                s += b * b
                stat[c, k] = s


@_helper
def _count(plotted, n_calibration, width, faulty, calibration, healthy_alarms, faulty_misses, p):
    """Candidate ``p``'s Phase-I limit, mean + K·sd over every calibration point (``Chart.fit_statistic``),
    and its per-run alarm counts on the training runs (rows ``n_calibration:`` of ``plotted``)."""
    n_points = plotted.shape[1]
    for c in range(n_calibration):
        row = plotted[c]
        base = c * n_points
        for k in range(n_points):
            calibration[base + k] = row[k]
    center, scale = mean_std(calibration)
    limit = center + width * scale
    for r in range(healthy_alarms.shape[1]):
        row = plotted[n_calibration + r]
        truth = faulty[r]
        alarms = 0
        misses = 0
        for k in range(n_points):
            alarm = row[k] > limit
            if truth[k]:
                misses += not alarm
            else:
                alarms += alarm
        healthy_alarms[p, r] = alarms
        faulty_misses[p, r] = misses


@_helper
def _buffers(u, feedback, n_calibration):
    """Both kernels' outputs (zeroed counts (P, R_train)) and scratch: the statistic (C, K), the recursion's
    past values (4, C) and the calibration points."""
    n_points, n_columns = u.shape
    n_candidates = feedback.shape[0]
    n_train = n_columns - n_calibration
    return (np.zeros((n_candidates, n_train), np.int64), np.zeros((n_candidates, n_train), np.int64),
            np.empty((n_columns, n_points)), np.empty((4, n_columns)), np.empty(n_calibration * n_points))


@njit(cache=True, nogil=True)
def alarm_counts(u, v, n_calibration, gains, feedback, widths, combine_max, faulty):
    """Per-run alarm counts of every candidate, fused (module docstring), with no denoiser.

    Parameters
    ----------
    u, v : float64 (K, C), time-major
        U_k and V_k of the calibration runs (first ``n_calibration`` columns) then the training runs.
    gains : (P,); feedback : (P, order); widths : (P,)
        Each candidate's recursion coefficients (as ``ewma_time_major`` computes them) and its K.
    faulty : bool (R_train, K)
        Target-fault truth of the training runs.

    Returns
    -------
    healthy_alarms, faulty_misses : int64 (P, R_train)

    A kernel of its own (not a flag of :func:`alarm_counts_denoised`): numba compiles every function a
    body calls, taken branch or not, so a run without a denoiser never compiles the wavelet.
    """
    healthy_alarms, faulty_misses, raw, y, calibration = _buffers(u, feedback, n_calibration)
    order = feedback.shape[1]
    for p in range(feedback.shape[0]):
        f2 = feedback[p, 1] if order == 2 else 0.0
        _statistics(u, v, gains[p], feedback[p, 0], f2, order, combine_max, raw, y)
        _count(raw, n_calibration, widths[p], faulty, calibration, healthy_alarms, faulty_misses, p)
    return healthy_alarms, faulty_misses


@njit(cache=True, nogil=True)
def alarm_counts_denoised(u, v, n_calibration, gains, feedback, widths, combine_max, faulty,
                          lo, hi, rec_lo, rec_hi, level, per_level, source, rule, fixed, hard):
    """:func:`alarm_counts` with each run's statistic wavelet-denoised before the limit and the counts
    (the remaining arguments: :func:`mosd.kernels.wavelet.denoise_row`)."""
    healthy_alarms, faulty_misses, raw, y, calibration = _buffers(u, feedback, n_calibration)
    order = feedback.shape[1]
    n_points, n_columns = u.shape
    plotted = np.empty((n_columns, n_points))
    work = np.empty(work_size(n_points, lo.shape[0], level))
    for p in range(feedback.shape[0]):
        f2 = feedback[p, 1] if order == 2 else 0.0
        _statistics(u, v, gains[p], feedback[p, 0], f2, order, combine_max, raw, y)
        for c in range(n_columns):
            denoise_row(raw[c], plotted[c], work, lo, hi, rec_lo, rec_hi, level, per_level, source, rule,
                        fixed, hard)
        _count(plotted, n_calibration, widths[p], faulty, calibration, healthy_alarms, faulty_misses, p)
    return healthy_alarms, faulty_misses


def _warm_up_arguments():
    u = np.zeros((64, 3))
    faulty = np.zeros((2, 64), bool)
    # K as the tuning passes it: a column of the population (a strided view, numba's layout 'A'); a contiguous
    # array here would compile a signature the run never calls, and the run would compile its own
    widths = np.ones((2, 2))[:, 1]
    return (u, u, 1, np.ones(2), np.zeros((2, 2)), widths, False, faulty)


def warm_up(denoised: bool = False) -> None:
    """Load (or compile) the kernel without a denoiser, and with ``denoised`` also the wavelet one
    (:func:`warm_up_denoised`)."""
    alarm_counts(*_warm_up_arguments())
    if denoised:
        warm_up_denoised()


def warm_up_denoised() -> None:
    """Load (or compile) the kernel with the wavelet denoiser (db3, three levels, SURE: the paper's wavelet)."""
    import pywt

    from .wavelet import RULE_SURE, SOURCE_COARSEST

    wavelet = pywt.Wavelet("db3")
    filters = [np.asarray(f, float) for f in (wavelet.dec_lo, wavelet.dec_hi, wavelet.rec_lo, wavelet.rec_hi)]
    args = (*filters, 3, False, SOURCE_COARSEST, RULE_SURE, np.zeros(3), False)
    alarm_counts_denoised(*_warm_up_arguments(), *args)


def warm_up_all() -> None:
    """Both kernels (``python -m mosd.kernels``)."""
    warm_up(denoised=True)
