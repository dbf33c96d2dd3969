"""Per-tag CUSUM charts: one two-sided tabular CUSUM per tag, alarm on the largest (the baseline engineers try first).

Each tag is standardised on the fit rows, z_i = (x_i − μ_i)/σ_i, and charted by Page's tabular
CUSUM (Montgomery, Introduction to Statistical Quality Control, 7th ed., eqs. 9.2-9.3) with allowance κ:

    C⁺_{k,i} = max(0, C⁺_{k−1,i} + z_{k,i} − κ),   C⁻_{k,i} = max(0, C⁻_{k−1,i} − z_{k,i} − κ),   C_{−1} = 0,

and the row's statistic is the largest chart, ``cusum`` = max_i max(C⁺_{k,i}, C⁻_{k,i}). The limit is
set for the family-wise false-alarm rate: the (1 − α) quantile of that maximum on the held-back
calibration runs (no closed form for the maximum of m dependent CUSUMs), so one limit serves all
tags. A missing value enters as 0 (the in-control mean) and its row is not scored. The deployed
stage carries every chart (``cusum_hi_<i>``, ``cusum_lo_<i>``) as its state.
"""
from __future__ import annotations

import numpy as np

from ..streaming import StateVar
from ..validation import Interval, Param
from .latent import LatentDetector, complete_rows, latent_params, scaling

#: a chart's state: a non-negative sum, bounded far below overflow
CHART = Interval(0.0, 1e150)


class TagCusumDetector(LatentDetector):
    """The largest of per-tag two-sided CUSUMs with tunable allowance, α, EWMA λ and persistence (module docstring)."""

    STATISTICS = ("cusum",)
    params = latent_params({
        "allowance": Param(Interval(0.0, 5.0), "Allowance κ of every chart, in standard deviations (half the "
                           "shift to detect fastest).", tunable=True),
    }, STATISTICS)

    def __init__(self, allowance: float = 0.5, alpha: float = 0.01, lam: float = 1.0, persistence: int = 1,
                 statistic: str = "combined", limits: str = "empirical", fit_runs: int | None = None,
                 persistence_max: int = 10, lam_min: float = 0.0, flatline: float | None = None):
        self._assign(locals())
        self._cache: dict = {}

    def fit(self, X: np.ndarray, design) -> dict:
        mean, scale = scaling(complete_rows(X), "per-tag CUSUM")
        return {"mean": mean, "scale": scale}

    def score(self, fitted, X, design, carried=None):
        Z = (np.asarray(X, float) - fitted["mean"]) / fitted["scale"]
        R, K, m = Z.shape
        finite = np.all(np.isfinite(Z), axis=-1)
        Z = np.where(np.isfinite(Z), Z, 0.0)
        kappa = float(design["allowance"])
        hi, lo = np.zeros((R, m)), np.zeros((R, m))
        if carried:
            hi = np.column_stack([np.asarray(carried[f"cusum_hi_{i}"], float).reshape(R) for i in range(1, m + 1)])
            lo = np.column_stack([np.asarray(carried[f"cusum_lo_{i}"], float).reshape(R) for i in range(1, m + 1)])
        his, los = np.empty((R, K, m)), np.empty((R, K, m))
        for k in range(K):  # a recursion in time: vectorised over runs and tags
            hi = np.maximum(0.0, hi + Z[:, k] - kappa)
            lo = np.maximum(0.0, lo - Z[:, k] - kappa)
            his[:, k], los[:, k] = hi, lo
        statistic = np.where(finite, np.maximum(his, los).max(axis=-1, initial=0.0), np.nan)
        after = {**{f"cusum_hi_{i}": his[..., i - 1] for i in range(1, m + 1)},
                 **{f"cusum_lo_{i}": los[..., i - 1] for i in range(1, m + 1)}}
        return {"cusum": statistic}, after

    def state(self, fitted, design):
        m = len(fitted["mean"])
        return {f"cusum_{side}_{i}": (StateVar(f"The {word} CUSUM of tag {i} after the last row.", CHART), 0.0)
                for side, word in (("hi", "upper"), ("lo", "lower")) for i in range(1, m + 1)}
