"""Canonical variate analysis (CVA) monitoring: states of the past, their T², the residual states' T² and Q.

As in Russell, Chiang & Braatz (2000, Chemometr. Intell. Lab. Syst. 51, 81-93) and Odiowei & Cao
(2010, IEEE Trans. Ind. Informatics 6, 36-45). With the rows standardised on the fit rows, the past
and future vectors of row k are

    p_k = [z_{k−1}ᵀ, ..., z_{k−p}ᵀ]ᵀ (pm),    f_k = [z_kᵀ, ..., z_{k+f−1}ᵀ]ᵀ (fm).

From the fit rows' covariances Σpp, Σff, Σfp, the scaled Hankel matrix is decomposed,
Σff^(−1/2) Σfp Σpp^(−1/2) = U S Vᵀ (S: the canonical correlations), and J = Vᵀ Σpp^(−1/2) maps
the past to its canonical variates c_k = J p_k (unit variance, uncorrelated on the fit rows). With n
states x_k = c_k[:n]:

    T²ₛ = Σ_{i≤n} c_{k,i}²,     T²ᵣ = Σ_{i>n} c_{k,i}²,     Q = ‖z_k − C xₖ‖²,

C = Cov(z_k, x_k) the least-squares map from the states to the current row (its one-step residual:
what a fault that breaks the fitted dynamics changes first). Limits: T²ₛ and T²ᵣ by the F
distribution (:func:`~mosd.detectors.pca.t2_limit` with n and pm − n dimensions, Russell et al.
2000, eqs. 14-15); Q has none (Odiowei & Cao set every CVA limit by kernel density estimation), so
its limit is empirical on the held-back calibration runs. Only p_k and z_k are needed to score row
k: the deployed stage carries the last p rows (``past<j>_<i>``) as its state.
"""
from __future__ import annotations

import numpy as np
from scipy import linalg

from ..validation import ConfigError, Interval, Param
from .latent import LatentDetector, complete_rows, lag_state, lagged, latent_params, scaling
from .pca import _one_blas_thread, project, t2_limit


def inverse_sqrt(S: np.ndarray, floor: float = 1e-10) -> np.ndarray:
    """S^(−1/2) of a symmetric positive semi-definite S by its eigendecomposition (eigenvalues floored at
    ``floor`` × the largest: a rank-deficient covariance, e.g. more lagged columns than informative ones)."""
    w, V = linalg.eigh(S)
    w = np.maximum(w, floor * max(float(w.max()), 1e-300))
    return (V / np.sqrt(w)) @ V.T


class CVADetector(LatentDetector):
    """CVA T²ₛ, T²ᵣ and Q with tunable past/future horizons, state order, α, EWMA λ and persistence (module docstring)."""

    STATISTICS = ("t2s", "t2r", "q")
    fit_keys = ("past", "future")
    params = latent_params({
        "max_lags": Param(Interval(1, 50, integer=True), "Upper end of the horizons' range."),
        "max_states": Param(Interval(1, 10_000, integer=True), "Upper end of n_states' range."),
        "past": Param(Interval(1, "max_lags", integer=True), "Past horizon p (rows before row k).", tunable=True),
        "future": Param(Interval(1, "max_lags", integer=True), "Future horizon f (row k and the f − 1 after it, "
                        "at the fit only).", tunable=True),
        "n_states": Param(Interval(1, "max_states", integer=True), "State order n (at most pm − 1: larger "
                          "values are lowered to it).", tunable=True),
    }, STATISTICS)

    def __init__(self, past: int = 2, future: int = 2, n_states: int = 25, alpha: float = 0.01, lam: float = 1.0,
                 persistence: int = 1, statistic: str = "combined", limits: str = "theoretical",
                 fit_runs: int | None = None, max_lags: int = 5, max_states: int = 100,
                 persistence_max: int = 10, lam_min: float = 0.0, flatline: float | None = None):
        self._assign(locals())
        self._cache: dict = {}

    def data_bounds(self, calibration_z: np.ndarray) -> dict[str, tuple[float, float]]:
        """λ's floor, the horizons h = p = f that leave the fit the 2 h m complete (past, future) rows it needs
        (:meth:`fit`'s rule: any p, f ≤ h then do), and n ≤ h m − 1 states at the largest."""
        fit = np.asarray(self.fit_rows(calibration_z), float)
        m = fit.shape[-1]
        usable = [h for h in range(1, int(self.max_lags) + 1) if self.complete_count(fit, h, h - 1) >= 2 * h * m]
        top = max(usable, default=0)
        return {**super().data_bounds(calibration_z), "past": (1, top), "future": (1, top),
                "n_states": (1, top * m - 1)}

    def fit(self, X: np.ndarray, design) -> dict:
        p, f = int(design["past"]), int(design["future"])
        mean, scale = scaling(complete_rows(X), "CVA")
        Z = (np.asarray(X, float) - mean) / scale
        R, K, m = Z.shape
        rows, _ = lagged(Z, p)                                     # [z_k, z_{k-1}, ..., z_{k-p}]
        ahead = np.full((R, K, f * m), np.nan)                     # [z_k, ..., z_{k+f-1}], within each run
        for j in range(f):
            ahead[:, : K - j, j * m:(j + 1) * m] = Z[:, j:]
        both = complete_rows(np.concatenate([rows, ahead], axis=-1))
        if len(both) < 2 * p * m:
            raise ConfigError(f"the CVA calibration has {len(both)} complete (past, future) rows for past={p} and "
                              f"{m} variables; allowed: at least {2 * p * m} (lower detector.past or add runs)")
        current, past, future = both[:, :m], both[:, m:(p + 1) * m], both[:, (p + 1) * m:]
        n = len(both)
        with _one_blas_thread():
            Spp, Sff, Sfp = past.T @ past / (n - 1), future.T @ future / (n - 1), future.T @ past / (n - 1)
            Pp = inverse_sqrt(Spp)
            _, correlations, Vt = linalg.svd(inverse_sqrt(Sff) @ Sfp @ Pp, full_matrices=True)
            J = Vt @ Pp                                             # (pm, pm): every canonical direction
            C = current.T @ (past @ J.T) / (n - 1)                  # Cov(z_k, c_k), (m, pm)
        return {"mean": mean, "scale": scale, "J": J, "C": C, "correlations": correlations, "n": int(n), "past": p}

    def _states(self, fitted, design) -> int:
        return int(min(int(design["n_states"]), len(fitted["J"]) - 1))

    def _variates(self, fitted, X, carried):
        """(c_k (R, K, pm), z_k (R, K, m), buffer after each row) of the rows X (R, K, m)."""
        Z = (np.asarray(X, float) - fitted["mean"]) / fitted["scale"]
        m = Z.shape[-1]
        rows, after = lagged(Z, int(fitted["past"]), carried, prefix="past")
        # project: each row's sums in one order, the same bits whatever the chunk (the streaming contract)
        c = project(rows[..., m:], np.asarray(fitted["J"]).T)
        return c, rows[..., :m], after

    def score(self, fitted, X, design, carried=None):
        if carried is None:  # the tuning: the variates once per data set, each state order sliced from them
            c, z, after = self._remember(("variates", id(fitted), id(X)), (fitted, X),
                                         lambda: self._variates(fitted, X, None))
        else:
            c, z, after = self._variates(fitted, X, carried)
        n = self._states(fitted, design)
        squares = c**2
        residual = z - project(c[..., :n], np.asarray(fitted["C"])[:, :n].T)
        return {"t2s": squares[..., :n].sum(-1), "t2r": squares[..., n:].sum(-1), "q": (residual**2).sum(-1)}, after

    def state(self, fitted, design):
        return lag_state(len(fitted["mean"]), int(fitted["past"]), prefix="past")

    def limit(self, fitted, name, alpha, design):
        n, q = self._states(fitted, design), len(fitted["J"])
        if name == "t2s":
            return t2_limit(int(fitted["n"]), n, alpha)
        if name == "t2r":
            return t2_limit(int(fitted["n"]), q - n, alpha)
        return None
