"""Paper 003's χ² test with an adaptive threshold that grows with the neural observer's error.

Wang et al. 2020 (paper 003, §1.2). A residual r with covariance S gives
λ_k = r_kᵀ S_k⁻¹ r_k ~ χ²(n) while the sensor is healthy; the fixed threshold
T_D is the (1 − α) quantile of χ²(n) for a tolerated false-alarm rate α.
Because the neural observer is itself imperfect the paper raises the
threshold with the observer's residual E_k (**reconstruction**, equations lost)::

    T_k = a · T_D + b · E_k,     alarm at k  ⇔  λ_k > T_k

with a = b = 1 in the paper. Which χ² statistic is tested is the monitor's
choice: points z (R, K, 2) = [λ_k, E_k], e.g. ``[chi2, observer_residual]``
(the Kalman filter's innovation test, as the paper's §1.2 reads) or
``[observer_chi2, observer_residual]`` (the observer's own standardised
residual, as its Fig. 7 plots); docs/systems/paper003.md compares both.
The threshold comes from α alone, so calibration data are not used.
"""
from __future__ import annotations

import numpy as np
from scipy import stats

from ..validation import ConfigError, Interval, Param
from .base import Decisions, Detector, persistent


class AdaptiveChi2Detector(Detector):
    """λ_k > a·T_D(α) + b·E_k (module docstring; reconstruction of paper 003 §1.2)."""

    params = {
        "alpha": Param(Interval(0.0, 0.5, open_low=True, open_high=True), "Tolerated false-alarm probability per "
                       "point of the χ² test.", tunable=True),
        "a": Param(Interval(0.0, 5.0), "Weight of the χ² threshold T_D (paper: 1).", tunable=True),
        "b": Param(Interval(0.0, 20.0), "Weight of the observer residual E_k (paper: 1).", tunable=True),
        "dof": Param(Interval(1, 100, integer=True), "Degrees of freedom of λ_k (the residual's dimension)."),
        "persistence": Param(Interval(1, 1000, integer=True), "Consecutive exceedances before an alarm (paper: 1)."),
    }

    def __init__(self, alpha: float = 0.01, a: float = 1.0, b: float = 1.0, dof: int = 1, persistence: int = 1):
        self._assign(locals())

    def chi2_threshold(self, alpha: np.ndarray | float) -> np.ndarray:
        """T_D = F⁻¹_{χ²(dof)}(1 − α)."""
        return stats.chi2.ppf(1.0 - np.asarray(alpha, float), self.dof)

    def population(self, calibration_features: np.ndarray, features: np.ndarray, X: np.ndarray) -> Decisions:
        """Decisions of every design (α, a, b) in X (P, 3) on z (R, K, 2) = [λ_k, E_k].

        NaN points (no prediction yet, a missing sample) never alarm; with b = 0
        a NaN E_k is ignored.
        """
        X = np.atleast_2d(np.asarray(X, float))
        z = np.asarray(features, float)
        if z.ndim != 3 or z.shape[-1] != 2:
            raise ConfigError(f"detector adaptive_chi2 needs points z of shape (R, K, 2) = [chi2, observer_residual], "
                              f"got {z.shape}; allowed: monitor.outputs with two outputs")
        alpha, a, b = X[:, 0], X[:, 1], X[:, 2]
        statistic = np.broadcast_to(z[..., 0], (X.shape[0],) + z.shape[:2])
        weight = b[:, None, None]
        # a design that ignores E_k (b = 0) must not inherit its NaNs (no prediction yet)
        observer_term = np.where(weight > 0, weight * z[None, ..., 1], 0.0)
        threshold = (a * self.chi2_threshold(alpha))[:, None, None] + observer_term
        exceed = statistic > threshold  # False wherever a NaN is involved
        decision = persistent(exceed, self.persistence).astype(np.int8)
        return Decisions(statistic=statistic, threshold=threshold, decision=decision)
