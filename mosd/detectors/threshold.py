"""A fixed threshold on |z| with a persistence rule (paper 002's isolation decision, generic).

Paper 002 declares the target fault when the filter's estimation error is large
(its figures and tables compare error amplitudes); a fixed threshold on the
monitored output with ``persistence`` consecutive exceedances (paper 002's L) is the simplest decision of
that kind, and works for any scalar residual an
:class:`~mosd.monitors.outputs.OutputMonitor` selects. Where the monitor hands
several outputs (n > 1) the statistic is the largest |z_j|. A NaN point (a
missing residual) does not exceed the threshold and so breaks a run of
exceedances.
"""
from __future__ import annotations

import numpy as np

from ..streaming import COUNT, StateVar
from ..validation import Interval, Param
from .base import persistent
from .step import StepDetector


def largest_magnitude(z: np.ndarray) -> np.ndarray:
    """max_j |z_j| of points z (..., n) -> (...)."""
    z = np.abs(np.asarray(z, float))
    return z[..., 0] if z.shape[-1] == 1 else np.max(z, axis=-1)


class ThresholdDetector(StepDetector):
    """Alarm (decision 1) where max_j |z_j| > ``threshold`` at ``persistence`` consecutive points.

    The ranges of the two tunable parameters are per instance (``threshold_max``,
    ``persistence_max``): what a sensible threshold is depends on the monitored output.
    """

    params = {
        "threshold_max": Param(Interval(0.0, 1e12, open_low=True), "Upper end of the threshold's range (set it "
                               "to a few times the monitored output's fault-free spread)."),
        "persistence_max": Param(Interval(1, 1e6, integer=True), "Upper end of the persistence's range."),
        "threshold": Param(Interval(0.0, "threshold_max", open_low=True), "The threshold on |z|.", tunable=True),
        "persistence": Param(Interval(1, "persistence_max", integer=True), "Consecutive exceedances required "
                             "(paper 002's L).", tunable=True),
    }

    def __init__(self, threshold: float = 1.0, persistence: int = 1, threshold_max: float = 10.0,
                 persistence_max: int = 20):
        self._assign(locals())

    def features(self, z: np.ndarray) -> np.ndarray:
        """max_j |z_j| of points z (R, K, n) -> (R, K)."""
        return largest_magnitude(z)

    # -- the one step (mosd.detectors.step) -------------------------------------------------
    def step_params(self, X: np.ndarray, calibration_features=None) -> dict[str, np.ndarray]:
        """(threshold, persistence) per design of X (P, 2); calibration data are not used."""
        X = np.atleast_2d(np.asarray(X, float))
        return {"threshold": X[:, 0], "persistence": self.tunable["persistence"].round(X[:, 1], clip=True)}

    def step_state(self, n: int) -> dict:
        return {"run_length": (StateVar("Consecutive points above the threshold.", COUNT), 0)}

    def scan(self, params, state, features, trajectory=False) -> dict[str, np.ndarray]:
        """max_j |z_j| > threshold at ``persistence`` consecutive points, continuing ``run_length``."""
        threshold = np.asarray(params["threshold"], float).reshape(-1, 1, 1)
        features = np.asarray(features, float)
        statistic = np.broadcast_to(features, (threshold.shape[0],) + features.shape)
        with np.errstate(invalid="ignore"):  # a NaN point exceeds nothing: it breaks a run
            exceeds = statistic > threshold
        held = persistent(exceeds, np.asarray(params["persistence"]).astype(int), state["run_length"], trajectory)
        decision, run = held if trajectory else (held, None)
        out = {"statistic": statistic, "limit": threshold, "decision": decision.astype(np.int8)}
        if trajectory:
            out["run_length"] = run
        return out
