"""A two-sided CUSUM chart (Page 1954): the worked example of docs/ADD_A_SYSTEM.md.

On standardised points x_k (in control N(0, 1): the mean of a monitor's subgroup
times √n), S⁺_k = max(0, S⁺_{k−1} + x_k − k_ref), S⁻_k = max(0, S⁻_{k−1} − x_k − k_ref),
S_0 = 0; an alarm where max(S⁺_k, S⁻_k) > h at ``persistence`` consecutive
points (Montgomery, *Introduction to Statistical Quality Control*, §9.1). The
reference value k_ref is half the shift, in σ, the chart is tuned to find
fastest. A NaN point leaves the sums where they were.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..streaming import COUNT, PointDecision, StateVar, points_of, spread
from ..validation import Interval, Param
from .base import Decisions, Detector, persistent, run_lengths


def scaled_mean(z: np.ndarray) -> np.ndarray:
    """x_k = √n · mean of the point's n values, (..., n) -> (...)."""
    z = np.asarray(z, float)
    return z.mean(axis=-1) * np.sqrt(z.shape[-1])


def cusum_step(upper, lower, point, reference):
    """S⁺, S⁻ after one point (module docstring): the one recursion of the tuning and the deployed chart."""
    missing = np.isnan(point)
    upper = np.where(missing, upper, np.maximum(0.0, upper + point - reference))
    lower = np.where(missing, lower, np.maximum(0.0, lower - point - reference))
    return upper, lower


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
        return scaled_mean(z)

    def online(self, calibration_z=None, inputs=None) -> "OnlineCusum":
        """This design's causal form on points of n values (calibration data are not used)."""
        return OnlineCusum(k=float(self.k), h=float(self.h), persistence=int(self.persistence),
                           n=int(np.shape(calibration_z)[-1]))

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
            upper, lower = cusum_step(upper, lower, x[:, k], reference)
            statistic[:, :, k] = np.maximum(upper, lower)
        decision = persistent(statistic > limit, lengths).astype(np.int8)
        return Decisions(statistic=statistic, threshold=limit, decision=decision)


@dataclass
class OnlineCusum(PointDecision):
    """:class:`Cusum`'s causal form: points in (``point``, ``z_1`` ... ``z_n``); ``statistic`` (max(S⁺, S⁻)),
    ``limit`` (h), ``decision`` and ``alarm`` out. State: ``cusum_upper``, ``cusum_lower``, ``run_length``."""

    k: float
    h: float
    persistence: int
    n: int

    def state_vars(self) -> dict[str, StateVar]:
        return {"cusum_upper": StateVar("S⁺ after the last point.", Interval(0.0, 1e150)),
                "cusum_lower": StateVar("S⁻ after the last point.", Interval(0.0, 1e150)),
                "run_length": StateVar("Consecutive points above h.", COUNT)}

    def initial_state(self) -> dict:
        return {"cusum_upper": 0.0, "cusum_lower": 0.0, "run_length": 0}

    def update(self, columns, state) -> dict[str, np.ndarray]:
        rows, at, z = points_of(columns, self.n)
        x = scaled_mean(z) if len(at) else np.empty(0)
        upper, lower = np.array([float(state["cusum_upper"])]), np.array([float(state["cusum_lower"])])
        uppers, lowers = np.empty(len(at)), np.empty(len(at))
        for i, point in enumerate(x):
            upper, lower = cusum_step(upper, lower, np.array([point]), self.k)
            uppers[i], lowers[i] = upper[0], lower[0]
        statistic = np.maximum(uppers, lowers)
        run = run_lengths(statistic > self.h, int(state["run_length"]))
        alarm = run >= self.persistence
        return spread(rows, at, {"statistic": statistic, "limit": np.full(len(at), self.h),
                                 "decision": alarm.astype(np.int64), "alarm": alarm, "cusum_upper": uppers,
                                 "cusum_lower": lowers, "run_length": run}, state)
