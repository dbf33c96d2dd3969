"""Fault decision from IMM mode probabilities (paper 001, §4, step 3).

The paper declares fault i at fusion instant k when the probability μ_i of
fault model i exceeds a threshold μ_T, and suggests requiring that for L
consecutive steps against false alarms (it gives no value for L; the parameter
is ``persistence`` here). Its example uses μ_T = 0.5.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from .. import kernels
from ..streaming import COUNT, PointDecision, StateVar, points_of, spread
from ..validation import ConfigError, Interval, Param, check_int
from .base import Decisions, Detector, persistent, run_lengths


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

    def online(self, calibration_z, inputs=None) -> "OnlineModeProbability":
        """This design's causal form on M mode probabilities (calibration data are not used)."""
        n = int(np.shape(calibration_z)[-1])
        return OnlineModeProbability(mu_T=float(self.mu_T), persistence=int(self.persistence),
                                     labels=tuple(int(v) for v in self._labels(n - 1)), n=n)

    def population(self, calibration_features: np.ndarray, features: np.ndarray, X: np.ndarray) -> Decisions:
        """Decisions of every design (μ_T, persistence) in X (P, 2) on mode probabilities (R, K, M)."""
        mu = np.asarray(features, float)
        if mu.ndim != 3 or mu.shape[-1] < 2:
            raise ConfigError(f"detector: points of shape {mu.shape} are not mode probabilities; allowed: (R, K, M) "
                              f"with M >= 2 (normal model first), e.g. monitor.outputs=[mode_probabilities]")
        X = np.atleast_2d(np.asarray(X, float))
        threshold = X[:, 0]
        lengths = self.tunable["persistence"].round(X[:, 1], clip=True).astype(int)
        # (R, M−1, K): time last for the persistence rule, copied (a few kB) so that the comparisons over all the
        # designs below read contiguous memory (over the moved view they took 30 times as long)
        faults = np.ascontiguousarray(np.moveaxis(mu[..., 1:], -1, -2))
        labels = self._labels(faults.shape[-2])
        statistic = faults.max(axis=-2)
        if kernels.enabled() and labels.dtype == np.int64:
            from ..kernels.decisions import mode_decisions

            decision = mode_decisions(faults, np.ascontiguousarray(threshold), np.ascontiguousarray(lengths, np.int64),
                                      labels, np.empty((X.shape[0],) + statistic.shape, np.int64))
            return Decisions(statistic=np.broadcast_to(statistic, decision.shape), threshold=threshold[:, None, None],
                             decision=decision)
        above = faults[None] > threshold[:, None, None, None]  # (P, R, M−1, K)
        held = persistent(above, lengths)
        # among the fault models that satisfy the rule, the most probable one is declared: np.argmax over the
        # models (the first of equal scores), one model at a time rather than along a strided axis of a
        # (P, R, M−1, K) score (half of paper 001's candidate evaluation)
        best = np.where(held[:, :, 0], faults[None, :, 0], -1.0)  # (P, R, K)
        winner = np.zeros(best.shape, np.intp)
        declared = held[:, :, 0].copy()
        for model in range(1, faults.shape[-2]):
            score = np.where(held[:, :, model], faults[None, :, model], -1.0)
            better = score > best
            winner[better] = model
            np.maximum(best, score, out=best)
            declared |= held[:, :, model]
        decision = np.where(declared, labels[winner], 0)
        statistic = np.broadcast_to(statistic, decision.shape)
        return Decisions(statistic=statistic, threshold=threshold[:, None, None], decision=decision)


@dataclass
class OnlineModeProbability(PointDecision):
    """:class:`ModeProbabilityDetector`'s causal form: mode probabilities in (``point``, ``z_1`` = normal model,
    ``z_{i+1}`` = fault model i); ``statistic`` (max_i μ_i), ``limit`` (μ_T), ``decision`` (the fault declared,
    0 none) and ``alarm`` out. State: ``run_length_i``, consecutive steps with μ_i > μ_T, per fault model."""

    mu_T: float
    persistence: int
    labels: tuple
    n: int

    def state_vars(self) -> dict[str, StateVar]:
        return {f"run_length_{i}": StateVar(f"Consecutive steps with fault model {i}'s probability above μ_T.", COUNT)
                for i in range(1, self.n)}

    def initial_state(self) -> dict:
        return {name: 0 for name in self.state_vars()}

    def update(self, columns, state) -> dict[str, np.ndarray]:
        rows, at, mu = points_of(columns, self.n)
        faults = mu[:, 1:]                                                  # (k, M−1)
        runs = np.column_stack([run_lengths(faults[:, i - 1] > self.mu_T, int(state[f"run_length_{i}"]))
                                for i in range(1, self.n)]) if self.n > 1 else np.zeros((len(at), 0), np.int64)
        held = runs >= self.persistence
        # among the fault models that satisfy the rule, the most probable one is declared (as population does)
        winner = np.argmax(np.where(held, faults, -1.0), axis=-1) if len(at) else np.zeros(0, np.int64)
        decision = np.where(held.any(axis=-1), np.asarray(self.labels)[winner], 0).astype(np.int64)
        per_point = {"statistic": faults.max(axis=-1) if len(at) else np.empty(0),
                     "limit": np.full(len(at), float(self.mu_T)), "decision": decision, "alarm": decision > 0}
        per_point.update({f"run_length_{i}": runs[:, i - 1] for i in range(1, self.n)})
        return spread(rows, at, per_point, state)
