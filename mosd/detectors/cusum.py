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

from ..streaming import COUNT, StateVar
from ..validation import Interval, Param
from .base import persistent
from .step import StepDetector


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


class Cusum(StepDetector):
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

    # -- the one step (mosd.detectors.step) -------------------------------------------------
    def step_params(self, X: np.ndarray, calibration_features=None) -> dict[str, np.ndarray]:
        """(k, h, persistence) per design of X (P, 3); calibration data are not used."""
        X = np.atleast_2d(np.asarray(X, float))
        return {"k": X[:, 0], "h": X[:, 1], "persistence": self.tunable["persistence"].round(X[:, 2], clip=True)}

    def step_state(self, n: int) -> dict:
        return {"cusum_upper": (StateVar("S⁺ after the last point.", Interval(0.0, 1e150)), 0.0),
                "cusum_lower": (StateVar("S⁻ after the last point.", Interval(0.0, 1e150)), 0.0),
                "run_length": (StateVar("Consecutive points above h.", COUNT), 0)}

    def scan(self, params, state, features, trajectory=False) -> dict[str, np.ndarray]:
        """S⁺, S⁻ from the carried sums (:func:`cusum_step` per point), max(S⁺, S⁻) > h at ``persistence``
        consecutive points."""
        reference = np.asarray(params["k"], float).reshape(-1, 1)
        limit = np.asarray(params["h"], float).reshape(-1, 1, 1)
        x = np.asarray(features, float)
        batch = (reference.shape[0], x.shape[0])
        upper = np.array(np.broadcast_to(state["cusum_upper"], batch), float)
        lower = np.array(np.broadcast_to(state["cusum_lower"], batch), float)
        statistic = np.empty(batch + x.shape[1:])
        uppers = np.empty_like(statistic) if trajectory else None
        lowers = np.empty_like(statistic) if trajectory else None
        for k in range(x.shape[1]):
            upper, lower = cusum_step(upper, lower, x[:, k], reference)
            statistic[:, :, k] = np.maximum(upper, lower)
            if trajectory:
                uppers[:, :, k], lowers[:, :, k] = upper, lower
        held = persistent(statistic > limit, np.asarray(params["persistence"]).astype(int), state["run_length"],
                          trajectory)
        decision, run = held if trajectory else (held, None)
        out = {"statistic": statistic, "limit": limit, "decision": decision.astype(np.int8)}
        if trajectory:
            out.update(cusum_upper=uppers, cusum_lower=lowers, run_length=run)
        return out
