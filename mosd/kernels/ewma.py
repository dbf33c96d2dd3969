"""The charts' step, compiled: the EWMA update :func:`ewma_step` and the statistic :func:`combine_step`.

They are the one definition of a chart's recursion (issue 50): :func:`ewma_recursion` (``ewma()``, the
population's :func:`ewma_population`) and :func:`chart_recursion` (:meth:`mosd.detectors.chart.Chart.scan`:
the population, the test evaluation, the served chart) run them, and so does the fused tuning kernel
(:mod:`mosd.kernels.chart`). y_k = g·x_k, then y_k += y_{k−lag}·f_lag for lag = 1..order, in that order.
There is no NumPy copy of them: with numba's JIT disabled they run as plain Python (the tests' NumPy oracle
of the EWMA is in ``tests/test_kernels.py``).
"""
from __future__ import annotations

import numpy as np
from numba import njit

from . import configure_compiler

configure_compiler()  # before this module's first compile


@njit(cache=True, nogil=True, inline="always")
def ewma_step(x, gain, f1, f2, p1, p2, order):
    """One step of the (double) EWMA recursion: y = g·x, += y_{k−1}·f_1, (+= y_{k−2}·f_2 for order 2).

    The one arithmetic of every chart: :func:`ewma_recursion` (the population, ``ewma()``, the deployed
    chart) and the fused candidate evaluation's loop (:mod:`mosd.kernels.chart`) both take each value
    from here, in this order, so their results are the same bits.
    """
    y = gain * x
    y += p1 * f1
    if order == 2:
        y += p2 * f2
    return y


#: how a chart combines its smoothed parts (a, b) into its statistic (:func:`combine_step`)
COMBINE_ABS, COMBINE_SS, COMBINE_MAX = 0, 1, 2


@njit(cache=True, nogil=True, inline="always")
def combine_step(a, b, combine):
    """The chart statistic of one point's smoothed parts: |a| (the EWMA chart, eq. 21), a² + b² (the SS charts,
    eq. 25) or max(|a|, |b|) (the max charts), for ``combine`` COMBINE_ABS, COMBINE_SS, COMBINE_MAX.

    The one combination of every chart: the scan (:func:`chart_recursion`, the population and the served
    chart) and the fused candidate evaluation (:mod:`mosd.kernels.chart`) both take each value from here.
    """
    if combine == COMBINE_SS:  # the paper's chart first: one test on the tuning kernel's path
        s = a * a
        s += b * b
        return s
    if combine == COMBINE_MAX:
        return max(abs(a), abs(b))
    return abs(a)


@njit(cache=True, nogil=True)
def ewma_recursion(x, gain, feedback, past, out):
    """The ``order``-fold EWMA recursion with its state: the one implementation of the charts' arithmetic.

    out[k, c] = gain·x[k, c], then += y_{k−lag, c}·feedback[lag−1] for lag = 1..order, in that order
    (the reference's order, so every caller gets the same bits). The tuning's population
    (:func:`ewma_population`), the fused candidate evaluation (:mod:`mosd.kernels.chart`) and the
    served chart (:meth:`mosd.detectors.chart.Chart.scan`, through :func:`chart_recursion`) all run it.

    Parameters
    ----------
    x : float64 (K, C), time-major
    gain : float
    feedback : float64 (order,)
    past : float64 (order, C)
        y_{−1}, y_{−2}, ... of every column on entry (zeros at a stream's start: adding 0·f changes
        no value); the last ``order`` outputs on return.
    out : float64 (K, C), may be a strided view
    """
    n_points, n_columns = x.shape
    order = feedback.shape[0]
    # orders 1 and 2 (EWMA, double EWMA) written out: the generic loops over the lags cost 5x
    if order == 1:
        f1, p1 = feedback[0], past[0]
        for k in range(n_points):
            xk, ok = x[k], out[k]
            for c in range(n_columns):
                y = ewma_step(xk[c], gain, f1, 0.0, p1[c], 0.0, 1)
                p1[c] = y
                ok[c] = y
        return
    if order == 2:
        f1, f2, p1, p2 = feedback[0], feedback[1], past[0], past[1]
        for k in range(n_points):
            xk, ok = x[k], out[k]
            for c in range(n_columns):
                y = ewma_step(xk[c], gain, f1, f2, p1[c], p2[c], 2)
                p2[c] = p1[c]
                p1[c] = y
                ok[c] = y
        return
    for k in range(n_points):
        for c in range(n_columns):
            y = gain * x[k, c]
            for lag in range(order):
                y += past[lag, c] * feedback[lag]
            for lag in range(order - 1, 0, -1):
                past[lag, c] = past[lag - 1, c]
            past[0, c] = y
            out[k, c] = y


@njit(cache=True, nogil=True)
def chart_recursion(x, gain, feedback, past, combine, smoothed, statistic):
    """One chart's steps over time: :func:`ewma_recursion` of every part, then :func:`combine_step` per point.

    Parameters
    ----------
    x : float64 (K, F·M), time-major
        The features, part-major: columns f·M .. f·M + M − 1 are part f of the M runs (F = 1 or 2).
    gain, feedback, past
        As :func:`ewma_recursion` (``past`` continued in place: the chart's carried state).
    combine : int
        COMBINE_ABS, COMBINE_SS or COMBINE_MAX.
    smoothed : float64 (K, F·M)
        The smoothed parts, written.
    statistic : float64 (K, M)
        The raw chart statistic of each run at each point, written.
    """
    ewma_recursion(x, gain, feedback, past, smoothed)
    n_points, n_runs = statistic.shape
    second = n_runs if x.shape[1] > n_runs else 0  # the second part's columns (the first again for one part)
    for k in range(n_points):
        row = smoothed[k]
        for m in range(n_runs):
            statistic[k, m] = combine_step(row[m], row[second + m], combine)


@njit(cache=True, nogil=True)
def ewma_population(columns, gain, feedback):
    """out[k, p, m] = gain[p]·columns[k, m] + Σ_lag out[k−lag, p, m]·feedback[p, lag−1], from a zero state.

    Parameters
    ----------
    columns : float64 (K, M), time-major
    gain : float64 (P,)
    feedback : float64 (P, order)

    Returns
    -------
    float64 (K, P, M)
    """
    n_points, n_columns = columns.shape
    n_candidates, order = feedback.shape
    out = np.empty((n_points, n_candidates, n_columns))
    past = np.empty((order, n_columns))
    # each candidate into a contiguous scratch, then copied: the recursion then takes the contiguous
    # arrays the deployed chart passes (ewma_continue), one compiled specialisation instead of a second
    # one for the strided view out[:, p, :] (about 1 s of compile on a cold cache)
    smoothed = np.empty((n_points, n_columns))
    for p in range(n_candidates):
        for lag in range(order):  # a loop: a slice assignment compiles numba's broadcasting code
            for c in range(n_columns):
                past[lag, c] = 0.0
        ewma_recursion(columns, gain[p], feedback[p], past, smoothed)
        for k in range(n_points):
            for c in range(n_columns):
                out[k, p, c] = smoothed[k, c]
    return out


def warm_up() -> None:
    """Load (or compile) the kernel."""
    ewma_population(np.zeros((3, 2)), np.ones(1), np.zeros((1, 2)))
    ewma_recursion(np.zeros((3, 2)), 1.0, np.zeros(2), np.zeros((2, 2)), np.zeros((3, 2)))
    chart_recursion(np.zeros((3, 2)), 1.0, np.zeros(2), np.zeros((2, 2)), COMBINE_SS, np.zeros((3, 2)), np.zeros((3, 1)))
