"""The EWMA of the recorded-data monitors' statistics, compiled: :func:`smooth_rows`.

:func:`mosd.detectors.latent.ewma_from` (S̃_k = λ S_k + (1 − λ) S̃_{k−1}, a missing point entering as the
in-control mean) ran SciPy's ``lfilter`` behind a NumPy fill and, for a decision, a NumPy mask: three
passes and SciPy's argument handling for every statistic of every design, most of the TE preset's
candidate evaluation (one smoothing of the test runs and one of the held-back runs per statistic and
design). Here each row is one pass. The arithmetic is ``lfilter``'s for this filter (b = [λ, 0],
a = [1, −(1 − λ)]: y = z + λ x, then z = x·0 − y·a₁) in its order, so the values are the same bits
(``tests/test_kernels.py`` compares them, signed zeros included).
"""
from __future__ import annotations

import numpy as np
from numba import njit

from . import configure_compiler

configure_compiler()  # before this module's first compile


@njit(cache=True, nogil=True)
def smooth_rows(x, lam, fill, previous, masked, out):
    """The EWMA along each row of ``x``, from the state ``previous``; written into ``out`` and returned.

    Parameters
    ----------
    x : float64 (rows, K), any strides
    lam : float
        λ; λ ≥ 1 is no smoothing (the filled values themselves).
    fill : float
        What a non-finite point enters as (the in-control mean).
    previous : float
        S̃_{−1} of every row.
    masked : bool
        NaN at the non-finite points of ``x`` (a statistic's smoothed value, which does not alarm there)
        instead of the smoothed value the state carries on with.
    out : float64 (rows, K)
    """
    n_rows, n_points = x.shape
    if lam >= 1.0:
        for r in range(n_rows):
            for k in range(n_points):
                value = x[r, k]
                out[r, k] = value if np.isfinite(value) else (np.nan if masked else fill)
        return out
    a1 = -(1.0 - lam)
    state = np.full(n_rows, (1.0 - lam) * previous)
    # point by point across the rows: each row's recursion waits on its previous step, the rows do not wait
    # on each other, so the processor overlaps them (twice as fast as one row after the other)
    for k in range(n_points):
        for r in range(n_rows):
            value = x[r, k]
            finite = np.isfinite(value)
            if not finite:
                value = fill
            smoothed = state[r] + lam * value
            state[r] = value * 0.0 - smoothed * a1
            out[r, k] = smoothed if finite or not masked else np.nan
    return out


def warm_up() -> None:
    """Load (or compile) the kernel: on rows in order and on a strided view (a family's statistic is often one)."""
    smooth_rows(np.zeros((1, 2)), 0.5, 0.0, 0.0, True, np.empty((1, 2)))
    smooth_rows(np.zeros((1, 2, 2))[..., 0], 0.5, 0.0, 0.0, True, np.empty((1, 2)))
