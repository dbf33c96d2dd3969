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

from dataclasses import dataclass

import numpy as np

from ..streaming import COUNT, PointDecision, StateVar, points_of, spread
from ..validation import Interval, Param
from .base import Decisions, Detector, persistent, run_lengths


def largest_magnitude(z: np.ndarray) -> np.ndarray:
    """max_j |z_j| of points z (..., n) -> (...)."""
    z = np.abs(np.asarray(z, float))
    return z[..., 0] if z.shape[-1] == 1 else np.max(z, axis=-1)


class ThresholdDetector(Detector):
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

    def online(self, calibration_z, inputs=None) -> "OnlineThreshold":
        """This design's causal form on points of ``calibration_z``'s width (calibration data are not used)."""
        return OnlineThreshold(threshold=float(self.threshold), persistence=int(self.persistence),
                               n=int(np.shape(calibration_z)[-1]))

    def features(self, z: np.ndarray) -> np.ndarray:
        """max_j |z_j| of points z (R, K, n) -> (R, K)."""
        return largest_magnitude(z)

    def population(self, calibration_features: np.ndarray, features: np.ndarray, X: np.ndarray) -> Decisions:
        """Decisions of every design in X (P, 2) = (threshold, persistence); calibration data are not used."""
        X = np.atleast_2d(np.asarray(X, float))
        threshold = X[:, 0].reshape(-1, 1, 1)
        lengths = self.tunable["persistence"].round(X[:, 1], clip=True).astype(int)
        statistic = np.broadcast_to(features, (X.shape[0],) + features.shape)
        with np.errstate(invalid="ignore"):
            exceeds = statistic > threshold
        decision = persistent(exceeds, lengths).astype(np.int8)
        return Decisions(statistic=statistic, threshold=threshold, decision=decision)


@dataclass
class OnlineThreshold(PointDecision):
    """:class:`ThresholdDetector`'s causal form: points in (``point``, ``z_1`` ... ``z_n``); ``statistic``
    (max_j |z_j|), ``limit`` (the threshold), ``decision`` and ``alarm`` out. State: ``run_length`` (consecutive exceedances)."""

    threshold: float
    persistence: int
    n: int

    def state_vars(self) -> dict[str, StateVar]:
        return {"run_length": StateVar("Consecutive points above the threshold.", COUNT)}

    def initial_state(self) -> dict:
        return {"run_length": 0}

    def update(self, columns, state) -> dict[str, np.ndarray]:
        rows, at, Z = points_of(columns, self.n)
        statistic = largest_magnitude(Z) if len(Z) else np.empty(0)
        with np.errstate(invalid="ignore"):
            exceeds = statistic > self.threshold
        run = run_lengths(exceeds, int(state["run_length"]))
        alarm = run >= self.persistence
        return spread(rows, at, {"statistic": statistic, "limit": np.full(len(at), float(self.threshold)),
                                 "decision": alarm.astype(np.int64), "alarm": alarm, "run_length": run}, state)
