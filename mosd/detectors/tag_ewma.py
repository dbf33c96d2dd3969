"""Per-tag EWMA charts: one EWMA per standardised tag, alarm on the largest, limit for the family-wise FAR.

Each tag is standardised on the fit rows, z_i = (x_i − μ_i)/σ_i, and smoothed (Roberts 1959;
Montgomery, Introduction to Statistical Quality Control, 7th ed., eq. 9.22)

    e_{k,i} = λ_t z_{k,i} + (1 − λ_t) e_{k−1,i},   e_{−1,i} = 0,

and the row's statistic is the largest standardised chart, ``ewma`` = max_i |e_{k,i}| / σ_e with
σ_e = √(λ_t / (2 − λ_t)) (the asymptotic standard deviation of e for white unit-variance z).
The theoretical limit holds the family-wise false-alarm rate at α for m independent Gaussian tags
(Šidák): c = Φ⁻¹(1 − α′/2), α′ = 1 − (1 − α)^(1/m); recorded tags are correlated and autocorrelated,
so ``limits: empirical`` (the (1 − α) quantile of the maximum on the held-back calibration runs)
is the default. A missing value enters as 0 (the in-control mean) and its row is not scored. The
deployed stage carries every chart (``tag_ewma_<i>``) as its state.
"""
from __future__ import annotations

import math

import numpy as np
from scipy import special

from ..streaming import FINITE, StateVar
from ..validation import Interval, Param
from .latent import LatentDetector, complete_rows, ewma_from, latent_params, scaling


class TagEwmaDetector(LatentDetector):
    """The largest of per-tag EWMA charts with tunable smoothing, α, EWMA λ and persistence (module docstring)."""

    STATISTICS = ("ewma",)
    params = latent_params({
        "smoothing": Param(Interval(0.0, 1.0, open_low=True), "λ_t of every tag's chart (1: Shewhart).",
                           tunable=True),
    }, STATISTICS)

    def __init__(self, smoothing: float = 0.2, alpha: float = 0.01, lam: float = 1.0, persistence: int = 1,
                 statistic: str = "combined", limits: str = "empirical", fit_runs: int | None = None,
                 persistence_max: int = 10, lam_min: float = 0.0, flatline: float | None = None):
        self._assign(locals())
        self._cache: dict = {}

    def fit(self, X: np.ndarray, design) -> dict:
        mean, scale = scaling(complete_rows(X), "per-tag EWMA")
        return {"mean": mean, "scale": scale}

    def score(self, fitted, X, design, carried=None):
        Z = (np.asarray(X, float) - fitted["mean"]) / fitted["scale"]
        R, K, m = Z.shape
        finite = np.all(np.isfinite(Z), axis=-1)
        Z = np.moveaxis(Z, -1, 1)                                           # (R, m, K): time last
        lam = float(design["smoothing"])
        previous = 0.0
        if carried:
            previous = np.column_stack([np.asarray(carried[f"tag_ewma_{i}"], float).reshape(R)
                                        for i in range(1, m + 1)])[..., None]   # (R, m, 1)
        # the one EWMA of the recorded-data monitors (a missing value enters as 0, the in-control mean)
        e = ewma_from(Z, lam, 0.0, previous=previous)
        sigma = math.sqrt(lam / (2.0 - lam))
        statistic = np.where(finite, np.abs(e).max(axis=1, initial=0.0) / sigma, np.nan)
        return {"ewma": statistic}, {f"tag_ewma_{i}": e[:, i - 1] for i in range(1, m + 1)}

    def state(self, fitted, design):
        return {f"tag_ewma_{i}": (StateVar(f"The EWMA of standardised tag {i} after the last row.", FINITE), 0.0)
                for i in range(1, len(fitted["mean"]) + 1)}

    def limit(self, fitted, name, alpha, design):
        m = len(fitted["mean"])
        per_tag = -math.expm1(math.log1p(-alpha) / m)                        # 1 − (1 − α)^(1/m)
        return float(special.ndtri(1.0 - per_tag / 2.0))
