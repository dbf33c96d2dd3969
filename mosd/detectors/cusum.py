"""A two-sided CUSUM chart (Page 1954): the worked example of docs/ADD_A_SYSTEM.md.

On standardised points x_k (in control N(0, 1): the mean of a monitor's subgroup
times √n), S⁺_k = max(0, S⁺_{k−1} + x_k − k_ref), S⁻_k = max(0, S⁻_{k−1} − x_k − k_ref),
S_0 = 0; an alarm where max(S⁺_k, S⁻_k) > h at ``persistence`` consecutive
points (Montgomery, *Introduction to Statistical Quality Control*, §9.1). The
reference value k_ref is half the shift, in σ, the chart is tuned to find
fastest. A NaN point leaves the sums where they were.
"""
from __future__ import annotations

import numpy as np

from ..validation import Interval, Param
from .base import Decisions, Detector, persistent


class Cusum(Detector):
    """Two-sided CUSUM of the standardised subgroup mean with a persistence rule (module docstring)."""

    params = {
        "k": Param(Interval(0.0, 5.0), "Reference value (allowance) k_ref, in σ of the points.", tunable=True),
        "h": Param(Interval(0.0, 50.0, open_low=True), "Decision interval h, in σ of the points.", tunable=True),
        "persistence": Param(Interval(1, 10, integer=True), "Consecutive points above h for an alarm.",
                             tunable=True),
    }

    def __init__(self, k: float = 0.5, h: float = 5.0, persistence: int = 1):
        self._assign(locals())

    def features(self, z: np.ndarray) -> np.ndarray:
        """x_k = √n · mean of the point's n values, (R, K, n) -> (R, K): N(0, 1) in control."""
        z = np.asarray(z, float)
        return z.mean(axis=-1) * np.sqrt(z.shape[-1])

    def population(self, calibration_features: np.ndarray, features: np.ndarray, X: np.ndarray) -> Decisions:
        """Decisions of every design in X (P, 3) = (k, h, persistence); calibration data are not used."""
        X = np.atleast_2d(np.asarray(X, float))
        reference = X[:, 0].reshape(-1, 1)
        limit = X[:, 1].reshape(-1, 1, 1)
        lengths = self.tunable["persistence"].round(X[:, 2], clip=True).astype(int)
        x = np.asarray(features, float)
        upper = np.zeros((X.shape[0], x.shape[0]))
        lower = np.zeros_like(upper)
        statistic = np.empty((X.shape[0],) + x.shape)
        for k in range(x.shape[1]):
            point = x[:, k]
            missing = np.isnan(point)
            upper = np.where(missing, upper, np.maximum(0.0, upper + point - reference))
            lower = np.where(missing, lower, np.maximum(0.0, lower - point - reference))
            statistic[:, :, k] = np.maximum(upper, lower)
        decision = persistent(statistic > limit, lengths).astype(np.int8)
        return Decisions(statistic=statistic, threshold=limit, decision=decision)
