"""Slow feature analysis (SFA) monitoring (Shang, Huang, Yang & Huang 2015, AIChE J. 61, 3666-3682).

With the rows standardised on the fit rows (z) and their first differences ż_k = z_k − z_{k−1}, the
slow features s = Wᵀ z solve the generalised symmetric eigenproblem (Shang et al., eqs. 6-8)

    A w = ω B w,   A = Cov(ż),  B = Cov(z),   Wᵀ B W = I,

by :func:`scipy.linalg.eigh` (ω ascending: the slowest features first; ω_j = Var(ṡ_j)). The
``n_slow`` slowest features s_d are the process's operating condition, the others s_e the fast part;
per row (eqs. 14-17)

    T² = s_dᵀ s_d,   T²ₑ = s_eᵀ s_e,   S² = ṡ_dᵀ Ω_d⁻¹ ṡ_d,   S²ₑ = ṡ_eᵀ Ω_e⁻¹ ṡ_e,

Ω = diag(ω). T² and T²ₑ flag a departure from the operating point, S² and S²ₑ a change of the
dynamics (faster or slower variation). Limits: χ² with M and m − M degrees of freedom for T² and
T²ₑ (s has identity covariance), and Shang et al.'s F-based limit for S² and S²ₑ
(:func:`~mosd.detectors.pca.t2_limit` with M and m − M dimensions on the N differenced fit rows).
ṡ_k needs the previous row: the deployed stage carries it (``prev_<i>``) as its state.

``drop_unjudged``: a feature's lag-1 autocorrelation is ρ_j = 1 − ω_j/2 (Var(s_j) = 1, Var(ṡ_j) = ω_j), the memory
(1 + ρ)/(1 − ρ) of an EWMA of weight ω_j/2. The slowest features can have memories of hundreds of rows (TE's
slowest: about 950 rows), which held-back calibration runs of K rows see as one level per run: an empirical limit
on them rests on the one run whose level is highest. With ``drop_unjudged`` the features slower than the base's
λ floor allows, ω_j/2 < :func:`~mosd.detectors.latent.lam_floor` (K) (the same rule: a memory of at most a tenth of
a held-back run), are left out of every statistic; the slow block is then features d+1 … M (d dropped, at least
one kept), the fast block M+1 … m as before. Nothing is dropped without held-back runs (``fit_runs`` None).
"""
from __future__ import annotations

import numpy as np
from scipy import linalg, special

from ..validation import ConfigError, Interval, Param
from .latent import LatentDetector, complete_rows, lag_state, lagged, latent_params, scaling
from .pca import _one_blas_thread, project, t2_limit


class SFADetector(LatentDetector):
    """Slow feature T², T²ₑ, S², S²ₑ with tunable slow features, α, EWMA λ and persistence (module docstring)."""

    STATISTICS = ("t2", "t2e", "s2", "s2e")
    fit_keys = ()
    params = latent_params({
        "max_slow": Param(Interval(1, 10_000, integer=True), "Upper end of n_slow's range."),
        "n_slow": Param(Interval(1, "max_slow", integer=True), "Slow features M (at most m − 1: larger values are "
                        "lowered to it).", tunable=True),
        "drop_unjudged": Param((False, True), "Leave out the features slower than the held-back calibration runs "
                               "can judge (ω/2 below λ's floor; module docstring)."),
    }, STATISTICS)

    def __init__(self, n_slow: int = 10, alpha: float = 0.01, lam: float = 1.0, persistence: int = 1,
                 statistic: str = "combined", limits: str = "theoretical", fit_runs: int | None = None,
                 max_slow: int = 30, persistence_max: int = 10, lam_min: float = 0.0, flatline: float | None = None,
                 drop_unjudged: bool = False):
        self._assign(locals())
        self._cache: dict = {}

    def data_bounds(self, calibration_z: np.ndarray) -> dict[str, tuple[float, float]]:
        """λ's floor and M ≤ m − 1 slow features (the fast part T²ₑ, S²ₑ keeps at least one)."""
        return {**super().data_bounds(calibration_z), "n_slow": (1, np.shape(calibration_z)[-1] - 1)}

    def fit(self, X: np.ndarray, design) -> dict:
        mean, scale = scaling(complete_rows(X), "SFA")
        rows, _ = lagged((np.asarray(X, float) - mean) / scale, 1)
        pairs = complete_rows(rows)
        m = len(mean)
        if len(pairs) < m + 2:
            raise ConfigError(f"the SFA calibration has {len(pairs)} pairs of consecutive complete rows for {m} "
                              f"variables; allowed: at least {m + 2}")
        z, dz = pairs[:, :m], pairs[:, :m] - pairs[:, m:]
        with _one_blas_thread():
            B = np.cov(z, rowvar=False)
            A = np.cov(dz, rowvar=False)
            omega, W = linalg.eigh(A, B)                            # ascending ω; Wᵀ B W = I
        return {"mean": mean, "scale": scale, "W": W, "omega": omega, "n": int(len(pairs))}

    def shang_slow_features(self, calibration_z: np.ndarray) -> int:
        """Shang et al.'s (2015) choice of M on the fit runs of ``calibration_z``: the slow features no faster than
        the fastest standardised input, ω_j ≤ max_i Δ(z_i) with Δ(z_i) = Var(ż_i) / Var(z_i) (a feature faster
        than every measured variable is taken for noise); our reading of their partition rule, within [1, m − 1].
        """
        fit = np.asarray(self.fit_rows(calibration_z), float)
        fitted = self.fit(fit, self.design_values())
        rows, _ = lagged((fit - fitted["mean"]) / fitted["scale"], 1)
        pairs = complete_rows(rows)
        m = len(fitted["mean"])
        z, dz = pairs[:, :m], pairs[:, :m] - pairs[:, m:]
        fastest = float(np.max(dz.var(axis=0, ddof=1) / z.var(axis=0, ddof=1)))
        return int(np.clip(np.count_nonzero(np.asarray(fitted["omega"]) <= fastest), 1, m - 1))

    def fitted(self, calibration_z: np.ndarray, design=None) -> dict:
        """The base's model, with ``dropped``: how many of the slowest features ``drop_unjudged`` leaves out."""
        fitted = super().fitted(calibration_z, design)
        if not self.drop_unjudged:
            return fitted
        floor = self.lam_floor_of(calibration_z)
        return self._remember(("dropped", id(fitted)), (fitted,), lambda: {
            **fitted, "dropped": int(np.count_nonzero(0.5 * np.asarray(fitted["omega"]) < floor))})

    def _blocks(self, fitted, design) -> tuple[int, int]:
        """(d, M'): the slow block is features d … M' − 1, the fast block M' … m − 1 (0-based, each non-empty)."""
        m = len(fitted["omega"])
        dropped = min(int(fitted.get("dropped", 0)), m - 2)
        return dropped, max(int(min(int(design["n_slow"]), m - 1)), dropped + 1)

    def _slow(self, fitted, design) -> int:
        return self._blocks(fitted, design)[1]

    def _features(self, fitted, X, carried):
        Z = (np.asarray(X, float) - fitted["mean"]) / fitted["scale"]
        m = Z.shape[-1]
        rows, after = lagged(Z, 1, carried, prefix="prev")
        W = np.asarray(fitted["W"])
        # project: each row's sums in one order, the same bits whatever the chunk (the streaming contract)
        s = project(rows[..., :m], W)
        ds = project(rows[..., :m] - rows[..., m:], W)
        return s**2, ds**2 / np.asarray(fitted["omega"]), after

    def score(self, fitted, X, design, carried=None):
        if carried is None:
            s2, ds2, after = self._remember(("features", id(fitted), id(X)), (fitted, X),
                                            lambda: self._features(fitted, X, None))
        else:
            s2, ds2, after = self._features(fitted, X, carried)
        d, M = self._blocks(fitted, design)
        return {"t2": s2[..., d:M].sum(-1), "t2e": s2[..., M:].sum(-1), "s2": ds2[..., d:M].sum(-1),
                "s2e": ds2[..., M:].sum(-1)}, after

    def state(self, fitted, design):
        return lag_state(len(fitted["mean"]), 1, prefix="prev")

    def limit(self, fitted, name, alpha, design):
        (d, M), m = self._blocks(fitted, design), len(fitted["omega"])
        dims = M - d if name in ("t2", "s2") else m - M
        if name.startswith("t2"):
            return float(special.chdtri(dims, alpha))
        return t2_limit(int(fitted["n"]), dims, alpha)
