"""Fault decision from IMM mode probabilities (paper 001, §4, step 3).

The paper declares fault i at fusion instant k when the probability μ_i of
fault model i exceeds a threshold μ_T, and suggests requiring that for L
consecutive steps against false alarms (it gives no value for L; the parameter
is ``persistence`` here). Its example uses μ_T = 0.5.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from ..validation import ConfigError, Interval, Param, check_int
from .base import Decisions, Detector, persistent


def _labels(key: str, value, detector):
    if isinstance(value, (str, bytes)) or not hasattr(value, "__len__") or not len(value):
        raise ConfigError(f"{key}={value!r} is not allowed; allowed: null or one integer >= 1 per fault model")
    return tuple(check_int(key, v, 1) for v in value)


class ModeProbabilityDetector(Detector):
    """Fault i when μ_i > μ_T at ``persistence`` consecutive points (paper 001, §4: L).

    Reads points z (R, K, M) — the mode probabilities of an IMM, column 0 the
    normal model, column i fault model i (an
    :class:`~mosd.monitors.outputs.OutputMonitor` with
    ``outputs: [mode_probabilities]``). When several fault models satisfy the
    rule at once (possible only with μ_T < 0.5), the most probable one is
    declared. The plotted statistic is max_{i>=1} μ_i against the threshold μ_T.
    No calibration data are needed: the threshold is a probability.
    """

    params = {
        "mu_T": Param(Interval(0.0, 1.0, open_low=True), "Probability threshold μ_T (paper: 0.5); with μ_T = 1 "
                      "nothing is declared.", tunable=True),
        "persistence": Param(Interval(1, 20, integer=True), "Consecutive fusion steps above μ_T (the paper's L; "
                             "1 = none).", tunable=True),
        "labels": Param(_labels, "The decision value issued for fault model i = 1..M−1 (None: i), e.g. [2, 1] "
                        "when the scenario's only fault (label 1) is the model set's fault 2.", optional=True,
                        kind="sequence of int >= 1"),
    }

    def __init__(self, mu_T: float = 0.5, persistence: int = 1, labels: Sequence[int] | None = None):
        self._assign(locals())

    def _labels(self, n_faults: int) -> np.ndarray:
        if self.labels is None:
            return np.arange(1, n_faults + 1)
        if len(self.labels) != n_faults:
            raise ConfigError(f"detector.labels has {len(self.labels)} entries; allowed: {n_faults} "
                              f"(one per fault model)")
        return np.asarray(self.labels)

    def population(self, calibration_features: np.ndarray, features: np.ndarray, X: np.ndarray) -> Decisions:
        """Decisions of every design (μ_T, persistence) in X (P, 2) on mode probabilities (R, K, M)."""
        mu = np.asarray(features, float)
        if mu.ndim != 3 or mu.shape[-1] < 2:
            raise ConfigError(f"detector: points of shape {mu.shape} are not mode probabilities; allowed: (R, K, M) "
                              f"with M >= 2 (normal model first), e.g. monitor.outputs=[mode_probabilities]")
        X = np.atleast_2d(np.asarray(X, float))
        threshold = X[:, 0]
        lengths = self.tunable["persistence"].round(X[:, 1], clip=True).astype(int)
        faults = np.moveaxis(mu[..., 1:], -1, -2)  # (R, M−1, K): time last for the persistence rule
        above = faults[None] > threshold[:, None, None, None]  # (P, R, M−1, K)
        held = persistent(above, lengths)
        # among the fault models that satisfy the rule, the most probable one is declared
        score = np.where(held, faults[None], -1.0)
        winner = np.argmax(score, axis=-2)  # (P, R, K)
        declared = held.any(axis=-2)
        decision = np.where(declared, self._labels(faults.shape[-2])[winner], 0)
        statistic = np.broadcast_to(faults.max(axis=-2), decision.shape)
        return Decisions(statistic=statistic, threshold=threshold[:, None, None], decision=decision)
