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

``drop_unjudged`` (the same rule as :class:`~mosd.detectors.sfa.SFADetector`'s): the first canonical variates are
the past's most predictable directions, and the most predictable are the slowest. A variate with lag-1
autocorrelation ρ_i on the fit rows has the memory of an EWMA of weight 1 − ρ_i; TE's first three states have
ρ 0.96-0.996 on ``d00.dat`` (memories of about 25-280 rows), which the 160-row held-back calibration runs see as one
level per run (their mean of c_i² ranges 0.3-4.5 over the lead-ins): an empirical limit on T²ₛ then rests on the one
run whose level is highest. With ``drop_unjudged`` the variates slower than the base's λ floor allows,
1 − ρ_i < :func:`~mosd.detectors.latent.lam_floor` (K) (a memory of at most a tenth of a held-back run of K rows),
are left out of T²ₛ and T²ᵣ (and out of their F limits' dimensions); they stay in the state-space model, so Q's
one-step residual still uses them. Should every one of the n states be dropped, the state block is widened to the
first kept variate (at least one kept state and one kept residual variate). Nothing is dropped without held-back
runs (``fit_runs`` None).
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
        "drop_unjudged": Param((False, True), "Leave out of T²ₛ and T²ᵣ the canonical variates slower than the "
                               "held-back calibration runs can judge (1 − ρ below λ's floor; module docstring)."),
    }, STATISTICS)

    def __init__(self, past: int = 2, future: int = 2, n_states: int = 25, alpha: float = 0.01, lam: float = 1.0,
                 persistence: int = 1, statistic: str = "combined", limits: str = "theoretical",
                 fit_runs: int | None = None, max_lags: int = 5, max_states: int = 100,
                 persistence_max: int = 10, lam_min: float = 0.0, flatline: float | None = None,
                 drop_unjudged: bool = False):
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

    def fitted(self, calibration_z: np.ndarray, design=None) -> dict:
        """The base's model, with ``unjudged`` (0/1 per canonical variate) under ``drop_unjudged``: the variates whose
        lag-1 autocorrelation ρ on the fit rows leaves 1 − ρ below λ's floor of the held-back runs."""
        fitted = super().fitted(calibration_z, design)
        held_back = self.fit_runs is not None and np.shape(calibration_z)[0] > self.fit_runs
        if not held_back or not (self.drop_unjudged if design is None else design.get("drop_unjudged",
                                                                                      self.drop_unjudged)):
            return fitted
        floor = self.lam_floor_of(calibration_z)
        fit, _ = self._split(calibration_z)
        return self._remember(("unjudged", id(fitted)), (fitted, fit), lambda: {
            **fitted, "unjudged": (1.0 - self.autocorrelation(fitted, fit) < floor).astype(np.int8)})

    def autocorrelation(self, fitted, X: np.ndarray) -> np.ndarray:
        """Lag-1 autocorrelation of each canonical variate (pm,) within the runs X (R, K, m): pairs of consecutive
        scored rows of one run, about the variates' mean over the scored rows."""
        c = self._variates(fitted, X, None)[0]
        scored = np.all(np.isfinite(c), axis=-1)
        mean = c[scored].mean(axis=0)
        centred = c - mean
        pairs = scored[:, 1:] & scored[:, :-1]
        lagged_products = (centred[:, 1:] * centred[:, :-1])[pairs].sum(axis=0)
        return lagged_products / (centred[scored] ** 2).sum(axis=0)

    def _blocks(self, fitted, design) -> tuple[np.ndarray, np.ndarray, int]:
        """(kept states, kept residual variates, n'): indices of the canonical variates in T²ₛ and T²ᵣ, and the
        state order n' the model uses (n, or larger when every one of the first n variates is unjudged)."""
        q = len(fitted["J"])
        n = int(min(int(design["n_states"]), q - 1))
        unjudged = np.asarray(fitted.get("unjudged", np.zeros(q)), bool).copy()
        if np.count_nonzero(~unjudged) < 2:
            # T²ₛ and T²ᵣ each need a variate: the last two in the canonical order (the past's least predictable)
            unjudged[-2:] = False
        kept = np.flatnonzero(~unjudged)
        n = int(min(max(n, kept[0] + 1), kept[-1]))        # a kept state below n', a kept residual from n' on
        return kept[kept < n], kept[kept >= n], n

    def _states(self, fitted, design) -> int:
        return self._blocks(fitted, design)[2]

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
        states, rest, n = self._blocks(fitted, design)
        squares = c**2
        residual = z - project(c[..., :n], np.asarray(fitted["C"])[:, :n].T)
        if len(states) + len(rest) == squares.shape[-1]:       # nothing dropped: contiguous slices (the old bits)
            return {"t2s": squares[..., :n].sum(-1), "t2r": squares[..., n:].sum(-1),
                    "q": (residual**2).sum(-1)}, after
        return {"t2s": squares[..., states].sum(-1), "t2r": squares[..., rest].sum(-1),
                "q": (residual**2).sum(-1)}, after

    def state(self, fitted, design):
        return lag_state(len(fitted["mean"]), int(fitted["past"]), prefix="past")

    def limit(self, fitted, name, alpha, design):
        states, rest, _ = self._blocks(fitted, design)
        if name == "t2s":
            return t2_limit(int(fitted["n"]), len(states), alpha)
        if name == "t2r":
            return t2_limit(int(fitted["n"]), len(rest), alpha)
        return None
