"""The persistence rule of the detectors' decisions, compiled: :func:`persistence`, and paper 001's
mode-probability decisions built on it, :func:`mode_decisions`.

:func:`mosd.detectors.base.persistent` (a design alarms where its condition held at L consecutive
points) on NumPy counts the runs with a cumulative sum, a running maximum and their difference: four
(P, …, K) integer arrays for a boolean answer, the largest part of paper 002's candidate evaluation
(21.7 of 27.5 ms for 40 designs × 400 runs × 90 points) and memory traffic that two processes
evaluating at once shared. Here each row is one pass with a counter: booleans in, booleans out, the
same values as the reference (``tests/test_kernels.py``).
"""
from __future__ import annotations

import numpy as np
from numba import njit

from . import configure_compiler

configure_compiler()  # before this module's first compile


@njit(cache=True, nogil=True)
def persistence(condition, lengths, carried, out, counts):
    """out[p, m, k] = condition held at the L_p points k − L_p + 1 … k, continuing a run of ``carried[p, m]``.

    The one persistence rule of every decision stage, a design population's (tuning, test) and a served
    stream's alike (:func:`mosd.detectors.base.persistent`).

    Parameters
    ----------
    condition : ndarray of bool, shape (P, M, K), C-contiguous
        Per design p, M rows (runs, outputs) of K points.
    lengths : ndarray of int64, shape (P,)
        The persistence L of each design (L <= 0: every point, as the reference's ``run >= L``).
    carried : ndarray of int64, shape (P, M)
        The run of consecutive True before each row's first point (0: a stream's start).
    out : ndarray of bool, shape (P, M, K)
        Written and returned.
    counts : ndarray of int64, shape (P, M, K) or (0, 0, 0)
        The run after each point (the carried state of a stream), written when not empty.
    """
    n_designs, n_rows, n_points = condition.shape
    keep = counts.size > 0
    for p in range(n_designs):
        length = lengths[p]
        for m in range(n_rows):
            run = carried[p, m]
            for k in range(n_points):
                if condition[p, m, k]:
                    run += 1
                else:
                    run = 0
                out[p, m, k] = run >= length
                if keep:
                    counts[p, m, k] = run
    return out


@njit(cache=True, nogil=True)
def mode_decisions(faults, thresholds, lengths, labels, carried, out, counts):  # pragma: no cover - compiled
    """Every design's decisions on mode probabilities: :meth:`mosd.detectors.mode_probability.ModeProbabilityDetector.population`.

    For design p, run r and point k, fault model m satisfies the rule where its probability exceeded
    the threshold μ_T,p at the last L_p points (:func:`persistence`); of those, the one with the largest
    probability is declared (the first of equal ones, as ``np.argmax``), ``labels[m]``, else 0. The
    comparisons are the NumPy code's, so the decisions are the same; a score is a probability that
    exceeded the threshold, or −1, never NaN (a NaN exceeds no threshold), so the NumPy code's running
    maximum is a plain one here. Without its (P, R, M, K) temporaries, whose allocation (tens of MB per
    population, mapped and unmapped by the C library at every call) was most of a fresh process's time.

    Parameters
    ----------
    faults : ndarray of float64, shape (R, M, K), C-contiguous
        The fault models' probabilities (model m of run r at point k).
    thresholds : ndarray of float64, shape (P,)
    lengths : ndarray of int64, shape (P,)
    labels : ndarray of int64, shape (M,)
    carried : ndarray of int64, shape (P, R, M)
        Each model's run above the threshold before the first point (0: a stream's start).
    out : ndarray of int64, shape (P, R, K)
        Written and returned.
    counts : ndarray of int64, shape (P, R, M, K) or (0, 0, 0, 0)
        Each model's run after each point (a stream's carried state), written when not empty.
    """
    n_designs = thresholds.shape[0]
    n_runs, n_models, n_points = faults.shape
    runs = np.zeros(n_models, np.int64)
    keep = counts.size > 0
    for p in range(n_designs):
        threshold, length = thresholds[p], lengths[p]
        for r in range(n_runs):
            runs[:] = carried[p, r]
            for k in range(n_points):
                declared = False
                winner = 0
                best = -1.0
                for m in range(n_models):
                    value = faults[r, m, k]
                    if value > threshold:
                        runs[m] += 1
                    else:
                        runs[m] = 0
                    held = runs[m] >= length
                    if keep:
                        counts[p, r, m, k] = runs[m]
                    declared = declared or held
                    score = value if held else -1.0
                    if m == 0:
                        best = score
                    elif score > best:
                        winner, best = m, score
                out[p, r, k] = labels[winner] if declared else 0
    return out


def warm_up() -> None:
    """Load (or compile) the kernels."""
    persistence(np.zeros((1, 1, 2), np.bool_), np.ones(1, np.int64), np.zeros((1, 1), np.int64),
                np.empty((1, 1, 2), np.bool_), np.empty((0, 0, 0), np.int64))
    mode_decisions(np.zeros((1, 2, 2)), np.zeros(1), np.ones(1, np.int64), np.arange(1, 3, dtype=np.int64),
                   np.zeros((1, 1, 2), np.int64), np.empty((1, 1, 2), np.int64), np.empty((0, 0, 0, 0), np.int64))
