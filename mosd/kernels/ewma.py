"""The population EWMA recursion of :func:`mosd.detectors.statistics.ewma_time_major`, compiled.

The reference runs one Python iteration per time step over all (candidate,
column) pairs; here the whole recursion is one compiled loop. The arithmetic is
the reference's, in its order — y_k = g·x_k, then y_k += y_{k−lag}·f_lag for
lag = 1..order — so the results are bit-identical.
"""
from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def ewma_population(columns, gain, feedback):
    """out[k, p, m] = gain[p]·columns[k, m] + Σ_lag out[k−lag, p, m]·feedback[p, lag−1].

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
    for k in range(n_points):
        for p in range(n_candidates):
            g = gain[p]
            row = out[k, p]
            x = columns[k]
            for m in range(n_columns):
                row[m] = g * x[m]
            for lag in range(1, order + 1):
                if k >= lag:
                    f = feedback[p, lag - 1]
                    past = out[k - lag, p]
                    for m in range(n_columns):
                        row[m] += past[m] * f
    return out


def warm_up() -> None:
    """Load (or compile) the kernel."""
    ewma_population(np.zeros((3, 2)), np.ones(1), np.zeros((1, 2)))
