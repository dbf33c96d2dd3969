"""A fixed threshold on |z| with a persistence rule (paper 002's isolation decision, generic).

Paper 002 declares the target fault when the filter's estimation error is large
(its figures and tables compare error amplitudes); a fixed threshold on the
monitored output with L consecutive exceedances is the simplest decision of
that kind, and works for any scalar residual an
:class:`~mosd.monitors.outputs.OutputMonitor` selects. Where the monitor hands
several outputs (n > 1) the statistic is the largest |z_j|. A NaN point (a
missing residual) does not exceed the threshold and so breaks a run of
exceedances.
"""
from __future__ import annotations

import numpy as np

from ..validation import Interval, check_in
from .base import Decisions, Detector, persistent


class ThresholdDetector(Detector):
    """Alarm (decision 1) where max_j |z_j| > ``threshold`` at L consecutive points.

    Parameters
    ----------
    threshold : float
        The threshold on |z|, in (0, threshold_max] (tunable).
    L : int
        Consecutive exceedances required, in [1, L_max] (tunable, integer).
    threshold_max : float
        Upper end of the threshold's search range, > 0 (default 10: set it to a
        few times the monitored output's fault-free spread).
    L_max : int
        Upper end of L's search range, >= 1.
    """

    tunable = {"threshold": Interval(0.0, 10.0, open_low=True), "L": Interval(1, 20, integer=True)}

    def __init__(self, threshold: float = 1.0, L: int = 1, threshold_max: float = 10.0, L_max: int = 20):
        threshold_max = check_in("detector.threshold_max", threshold_max, Interval(0.0, 1e12, open_low=True))
        L_max = check_in("detector.L_max", L_max, Interval(1, 1e6, integer=True))
        # the search ranges are per instance: what a sensible threshold is depends on the monitored output
        self.tunable = {"threshold": Interval(0.0, threshold_max, open_low=True),
                        "L": Interval(1, L_max, integer=True)}
        self.threshold_max, self.L_max = threshold_max, L_max
        self.threshold = check_in("detector.threshold", threshold, self.tunable["threshold"])
        self.L = check_in("detector.L", L, self.tunable["L"])

    def features(self, z: np.ndarray) -> np.ndarray:
        """max_j |z_j| of points z (R, K, n) -> (R, K)."""
        z = np.abs(np.asarray(z, float))
        return z[..., 0] if z.shape[-1] == 1 else np.max(z, axis=-1)

    def population(self, calibration_features: np.ndarray, features: np.ndarray, X: np.ndarray) -> Decisions:
        """Decisions of every design in X (P, 2) = (threshold, L); calibration data are not used."""
        X = np.atleast_2d(np.asarray(X, float))
        threshold = X[:, 0].reshape(-1, 1, 1)
        L = self.tunable["L"].round(X[:, 1], clip=True).astype(int)
        statistic = np.broadcast_to(features, (X.shape[0],) + features.shape)
        with np.errstate(invalid="ignore"):
            exceeds = statistic > threshold
        decision = persistent(exceeds, L).astype(np.int8)
        return Decisions(statistic=statistic, threshold=threshold, decision=decision)
