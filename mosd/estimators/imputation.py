"""EM imputation of missing outputs on lag windows (paper 002, a reconstruction).

Paper 002 fills the missing outputs y_k "by the EM algorithm" (initialise the
distribution's parameters, iterate E- and M-steps to convergence, fill the gaps
with the estimates) before it designs its filter; its equations were lost. The
reconstruction (docs/systems/paper002.md): the lag windows
w_j = (y_j, ..., y_{j+2h}) of one run (h = 1: (y_{k−1}, y_k, y_{k+1})) are
treated as draws of one Gaussian N(μ, Σ) with missing entries; EM (Dempster,
Laird and Rubin 1977; Little and Rubin, *Statistical Analysis with Missing
Data*, §11.2) estimates μ and Σ, and each gap y_k is filled with its conditional
mean given the observed entries of the window centred on k (the first/last
window at the ends of a run):

    E-step   x̂_M = μ_M + Σ_MO Σ_OO⁻¹ (x_O − μ_O),   C_MM = Σ_MM − Σ_MO Σ_OO⁻¹ Σ_OM
    M-step   μ = mean_j x̂_j,   Σ = mean_j [(x̂_j − μ)(x̂_j − μ)ᵀ + C_j]

(O/M: observed/missing entries of window j; C_j is C_MM padded with zeros).
The fill uses y_{k+1}: it is an offline (smoothing) step, as in the paper,
which treats an offline isolation problem.
"""
from __future__ import annotations

import numpy as np

from ..validation import Interval, check_in, check_int


def _pattern_groups(missing: np.ndarray):
    """(pattern bits, indices) of every distinct missingness pattern of rows (..., d)."""
    d = missing.shape[-1]
    codes = (missing.astype(np.int64) << np.arange(d)).sum(axis=-1)
    for code in np.unique(codes):
        yield np.array([(code >> i) & 1 for i in range(d)], bool), np.nonzero(codes == code)


def conditional_moments(X: np.ndarray, mean: np.ndarray, cov: np.ndarray, groups=None):
    """Conditional means and covariances of the missing entries of Gaussian rows.

    Parameters
    ----------
    X : ndarray, shape (R, n, d)
        Rows with NaN where an entry is missing.
    mean : ndarray, shape (R, d)
    cov : ndarray, shape (R, d, d)
        The Gaussian of each batch (replication) r.
    groups : list, optional
        ``list(_pattern_groups(np.isnan(X)))`` or ``_pattern_plan(X)``, when the caller has it (EM calls this
        with the same X at every iteration).

    Returns
    -------
    filled : ndarray, shape (R, n, d)
        X with each missing entry replaced by E[x_M | x_O] (observed entries unchanged).
    correction : ndarray, shape (R, n, d, d)
        Cov[x_M | x_O] in the missing block, zero elsewhere.
    """
    X = np.asarray(X, float)
    R, n, d = X.shape
    plan = groups if isinstance(groups, _PatternPlan) else _pattern_plan(X, groups)
    filled = X.copy()
    correction = np.zeros((R, n, d, d))
    for pattern, obs, reps, of_row, x_obs, at_missing, at_block in plan.groups:
        # the gain and the conditional covariance depend on the replication and the pattern only: computed once
        # per replication, then taken by every row of it (the same numbers as one solve per row, which repeated
        # each replication's solve for every row: most of the study's EM time)
        mu, S = mean[reps], cov[reps]                  # (r, d), (r, d, d)
        S_mm = S[:, pattern][:, :, pattern]
        if x_obs is not None:
            S_oo = S[:, obs][:, :, obs]
            S_mo = S[:, pattern][:, :, obs]
            mu_rows = mu[of_row]                           # (m, d): each row's replication's mean
            dev = x_obs - mu_rows[:, obs]
            # Σ_MO Σ_OO⁻¹ through a solve with the symmetric Σ_OO: (Σ_OO⁻¹ Σ_OM)ᵀ
            gain = np.swapaxes(np.linalg.solve(S_oo, np.swapaxes(S_mo, 1, 2)), 1, 2)
            x_m = mu_rows[:, pattern] + np.einsum("mij,mj->mi", gain[of_row], dev)
            c_mm = (S_mm - gain @ np.swapaxes(S_mo, 1, 2))[of_row]
        else:
            x_m, c_mm = mu[of_row][:, pattern], S_mm[of_row]
        filled[at_missing] = x_m
        correction[at_block] = c_mm
    return filled, correction


class _PatternPlan:
    """What :func:`conditional_moments` indexes per missingness pattern of one X, worked out once (:func:`_pattern_plan`).

    ``groups``: per pattern with a missing entry, (pattern, observed, the distinct replications of its rows and
    each row's among them, the rows' observed values or None, the index of the rows' missing entries, the index
    of their missing block). EM's iterations change the Gaussian, never X: the plan's sorting,
    gathering and index building were half of each iteration's time.
    """

    def __init__(self, groups):
        self.groups = groups


def _pattern_plan(X: np.ndarray, groups=None) -> _PatternPlan:
    planned = []
    for pattern, (rep, row) in (_pattern_groups(np.isnan(X)) if groups is None else groups):
        if not pattern.any():
            continue
        obs = ~pattern
        reps, of_row = np.unique(rep, return_inverse=True)
        idx = np.nonzero(pattern)[0]
        x_obs = X[rep, row][:, obs] if obs.any() else None
        at_missing = (rep[:, None], row[:, None], idx[None, :])
        at_block = (rep[:, None, None], row[:, None, None], idx[None, :, None], idx[None, None, :])
        planned.append((pattern, obs, reps, of_row, x_obs, at_missing, at_block))
    return _PatternPlan(planned)


def em_gaussian(X: np.ndarray, max_iter: int = 500, tol: float = 1e-10):
    """Maximum-likelihood mean and covariance of Gaussian rows with missing entries, by EM.

    Parameters
    ----------
    X : ndarray, shape (R, n, d)
        R independent data sets of n rows each; NaN marks a missing entry.
    max_iter : int
        Iteration cap.
    tol : float
        Stop when no mean or covariance entry of any data set moves by more.

    Returns
    -------
    mean : ndarray, shape (R, d)
    cov : ndarray, shape (R, d, d)
        The maximum-likelihood (divide-by-n) estimates; with no missing entry
        they are the sample mean and covariance after one iteration.
    n_iter : int
    """
    X = np.asarray(X, float)
    n = X.shape[1]
    # start from the observed-entry means and variances, no correlation
    mean = np.nan_to_num(np.nanmean(X, axis=1))
    var = np.nan_to_num(np.nanvar(X, axis=1), nan=1.0)
    cov = np.eye(X.shape[-1]) * np.where(var > 0, var, 1.0)[:, None, :]
    n_iter = 0
    plan = _pattern_plan(X)  # the missing entries do not change between iterations
    for n_iter in range(1, max_iter + 1):
        filled, correction = conditional_moments(X, mean, cov, plan)
        new_mean = filled.mean(axis=1)
        dev = filled - new_mean[:, None, :]
        new_cov = (np.einsum("rni,rnj->rij", dev, dev) + correction.sum(axis=1)) / n
        moved = max(np.abs(new_mean - mean).max(), np.abs(new_cov - cov).max())
        mean, cov = new_mean, new_cov
        if moved <= tol:
            break
    return mean, cov, n_iter


def hold_last(y: np.ndarray) -> np.ndarray:
    """``y`` (R, N) with every NaN replaced by the last observed sample of its run (NaN before the first one).

    The zero-order hold of a sample-and-hold acquisition: causal, no model, the
    comparison for the EM fill (a gap of g samples is filled with a value up to g
    steps old).
    """
    y = np.asarray(y, float)
    k = np.arange(y.shape[-1])
    last = np.maximum.accumulate(np.where(np.isnan(y), -1, k), axis=-1)   # index of the last observed sample
    held = np.take_along_axis(y, np.maximum(last, 0), axis=-1)
    return np.where(last >= 0, held, np.nan)


def lag_windows(y: np.ndarray, width: int) -> np.ndarray:
    """Overlapping windows (y_j, ..., y_{j+width−1}) of every run: (R, N) -> (R, N − width + 1, width)."""
    return np.lib.stride_tricks.sliding_window_view(np.asarray(y, float), width, axis=-1)


#: the EM lag windows' allowed half-widths h
HALF_WIDTHS = Interval(1, 5, integer=True)


class EMImputer:
    """Fill missing outputs with EM on lag windows (module docstring; a reconstruction of paper 002).

    Parameters
    ----------
    half_width : int
        h: windows of 2h + 1 consecutive outputs, in [1, 5] (reconstruction: 1,
        i.e. (y_{k−1}, y_k, y_{k+1})).
    max_iter : int
        EM iteration cap, in [1, 10000].
    tol : float
        EM convergence tolerance on the mean and covariance entries, in (0, 1].
    """

    def __init__(self, half_width: int = 1, max_iter: int = 500, tol: float = 1e-10):
        self.half_width = check_int("estimator.imputer.half_width", half_width, HALF_WIDTHS.low, HALF_WIDTHS.high)
        self.max_iter = check_int("estimator.imputer.max_iter", max_iter, 1, 10000)
        self.tol = check_in("estimator.imputer.tol", tol, Interval(0.0, 1.0, open_low=True))

    def impute(self, y: np.ndarray) -> np.ndarray:
        """``y`` (R, N) with every NaN replaced by its EM conditional mean (R, N).

        Each run gets its own μ and Σ (the runs are independent data sets).
        Runs shorter than a window are returned unchanged.
        """
        y = np.asarray(y, float)
        width = 2 * self.half_width + 1
        N = y.shape[-1]
        if N < width or not np.isnan(y).any():
            return y.copy()
        windows = lag_windows(y, width)
        mean, cov, _ = em_gaussian(windows, self.max_iter, self.tol)
        filled, _ = conditional_moments(windows, mean, cov)
        k = np.arange(N)
        row = np.clip(k - self.half_width, 0, N - width)
        out = filled[:, row, k - row]
        return np.where(np.isnan(y), out, y)

    def __repr__(self) -> str:
        return f"EMImputer(half_width={self.half_width}, max_iter={self.max_iter}, tol={self.tol:g})"
