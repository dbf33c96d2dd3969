"""Which output samples go missing: MCAR, Markov bursts, one contiguous gap (paper 002, a reconstruction).

Paper 002 loses 5, 10 and 20 % of its outputs without saying how they are lost.
The three mechanisms here span the cases that matter for a repair step
(docs/systems/paper002.md, "Missing data"):

* ``mcar`` — each sample missing independently with probability ``rate``
  (missing completely at random): isolated gaps, which a smoother bridges from
  both neighbours;
* ``burst`` — a two-state Markov chain (observed ↔ missing) whose stationary
  missing share is ``rate`` and whose bursts last ``burst_length`` samples on
  average (geometric lengths; Gilbert's channel model, Gilbert 1960): long gaps
  with no neighbour inside;
* ``gap`` — one contiguous gap of round(rate · N) samples, starting at
  ``gap_start`` or, if that is None, at a position drawn uniformly among those
  that fit in the run.

Every mechanism is a function of the same N uniforms per run (the plant draws
them in one place), so MCAR with a fixed seed keeps its nested missing sets
across rates (common random numbers) and the other mechanisms reuse the stream.
"""
from __future__ import annotations

import numpy as np

MECHANISMS = ("mcar", "burst", "gap")


def burst_switch_probability(rate: float, burst_length: float) -> float:
    """P(observed → missing) of the Markov chain with stationary missing share ``rate``.

    With P(missing → observed) = 1 / burst_length (mean burst length
    ``burst_length``), stationarity π_m · (1/B) = (1 − π_m) · p gives
    p = rate / (B (1 − rate)). A value above 1 has no chain: the caller rejects it.
    """
    if rate <= 0.0:
        return 0.0
    return rate / (burst_length * (1.0 - rate))


def missing_mask(u: np.ndarray, rate: float, mechanism: str = "mcar", burst_length: float = 5.0,
                 gap_start: int | None = None) -> np.ndarray:
    """The missing samples (bool, shape of ``u``) of runs driven by uniforms ``u`` (R, N).

    Parameters
    ----------
    u : ndarray, shape (R, N)
        U[0, 1) draws, one per sample and run.
    rate : float
        Share of samples missing: the probability (``mcar``), the stationary share
        (``burst``), or the gap's length over N (``gap``).
    mechanism : {"mcar", "burst", "gap"}
        Module docstring.
    burst_length : float
        Mean burst length in samples (``burst``), >= rate / (1 − rate).
    gap_start : int, optional
        First missing sample of the ``gap``; None draws it from ``u[:, 0]``.
    """
    u = np.asarray(u, float)
    if mechanism == "mcar":
        return u < rate
    R, N = u.shape
    missing = np.zeros((R, N), dtype=bool)
    if rate <= 0.0:
        return missing
    if mechanism == "burst":
        enter, leave = burst_switch_probability(rate, burst_length), 1.0 / burst_length
        missing[:, 0] = u[:, 0] < rate            # the chain starts in its stationary law
        for k in range(1, N):
            missing[:, k] = np.where(missing[:, k - 1], u[:, k] >= leave, u[:, k] < enter)
        return missing
    if mechanism == "gap":
        length = min(int(round(rate * N)), N)
        if gap_start is None:
            start = np.floor(u[:, 0] * (N - length + 1)).astype(int)
        else:
            start = np.full(R, min(int(gap_start), N - length))
        k = np.arange(N)
        return (k >= start[:, None]) & (k < start[:, None] + length)
    raise ValueError(f"unknown missingness mechanism {mechanism!r}; allowed: {', '.join(MECHANISMS)}")
