"""Estimation metrics: how well an estimator tracks the truth (paper 001's RMSE)."""
from __future__ import annotations

import numpy as np


def rmse_over_runs(estimate: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Root-mean-square error at each time over replications: sqrt(mean_r ||x̂_r,k − x_r,k||²).

    Parameters
    ----------
    estimate, truth : ndarray, shape (R, N, n) or (R, N)

    Returns
    -------
    ndarray, shape (N,)
        The Monte Carlo RMSE curve of paper 001's Figs. 4–5 (NaN entries ignored).
    """
    err = np.asarray(estimate, float) - np.asarray(truth, float)
    if err.ndim == 2:
        err = err[..., None]
    return np.sqrt(np.nanmean(np.sum(err**2, axis=-1), axis=0))


def rmse(estimate: np.ndarray, truth: np.ndarray) -> float:
    """One number: the RMSE over replications and time (NaN entries ignored)."""
    err = np.asarray(estimate, float) - np.asarray(truth, float)
    if err.ndim == 2:
        err = err[..., None]
    return float(np.sqrt(np.nanmean(np.sum(err**2, axis=-1))))
