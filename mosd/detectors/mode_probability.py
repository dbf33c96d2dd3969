"""Fault decision from IMM mode probabilities (paper 001, §4, step 3).

The paper declares fault i at fusion instant k when the probability μ_i of
fault model i exceeds a threshold μ_T, and suggests requiring that for L
consecutive steps against false alarms (it gives no value for L; the parameter
is ``persistence`` here). Its example uses μ_T = 0.5.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from .. import kernels
from ..streaming import COUNT, StateVar
from ..validation import ConfigError, Interval, Param, check_int
from .base import persistent
from .step import StepDetector


def _labels(key: str, value, detector):
    if isinstance(value, (str, bytes)) or not hasattr(value, "__len__") or not len(value):
        raise ConfigError(f"{key}={value!r} is not allowed; allowed: null or one integer >= 1 per fault model")
    return tuple(check_int(key, v, 1) for v in value)


class ModeProbabilityDetector(StepDetector):
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

    # -- the one step (mosd.detectors.step) -------------------------------------------------
    def step_params(self, X: np.ndarray, calibration_features=None) -> dict[str, np.ndarray]:
        """(μ_T, persistence) per design of X (P, 2); calibration data are not used."""
        X = np.atleast_2d(np.asarray(X, float))
        return {"mu_T": X[:, 0], "persistence": self.tunable["persistence"].round(X[:, 1], clip=True)}

    def step_state(self, n: int) -> dict:
        return {f"run_length_{i}": (StateVar(f"Consecutive steps with fault model {i}'s probability above μ_T.",
                                             COUNT), 0) for i in range(1, n)}

    def scan(self, params, state, features, trajectory=False) -> dict[str, np.ndarray]:
        """Fault i where μ_i > μ_T at ``persistence`` consecutive points (each model's run carried), the most
        probable of those declared, on mode probabilities (R, K, M)."""
        mu = np.asarray(features, float)
        if mu.ndim != 3 or mu.shape[-1] < 2:
            raise ConfigError(f"detector: points of shape {mu.shape} are not mode probabilities; allowed: (R, K, M) "
                              f"with M >= 2 (normal model first), e.g. monitor.outputs=[mode_probabilities]")
        threshold = np.asarray(params["mu_T"], float)
        lengths = np.asarray(params["persistence"]).astype(np.int64)
        # (R, M−1, K): time last for the persistence rule, copied (a few kB) so that the comparisons over all the
        # designs below read contiguous memory (over the moved view they took 30 times as long)
        faults = np.ascontiguousarray(np.moveaxis(mu[..., 1:], -1, -2))
        n_designs, (n_runs, n_models, n_points) = threshold.shape[0], faults.shape
        labels = self._labels(n_models)
        carried = np.stack([np.broadcast_to(np.asarray(state[f"run_length_{i}"], np.int64), (n_designs, n_runs))
                            for i in range(1, n_models + 1)], axis=-1)                      # (P, R, M−1)
        statistic = faults.max(axis=-2) if n_models else np.zeros((n_runs, n_points))
        if kernels.enabled() and labels.dtype == np.int64:
            from ..kernels.decisions import mode_decisions

            runs = np.empty((n_designs, n_runs, n_models, n_points) if trajectory else (0, 0, 0, 0), np.int64)
            decision = mode_decisions(faults, np.ascontiguousarray(threshold), np.ascontiguousarray(lengths), labels,
                                      np.ascontiguousarray(carried), np.empty((n_designs, n_runs, n_points), np.int64),
                                      runs)
        else:
            decision, runs = self._decide(faults, threshold, lengths, labels, carried)
        out = {"statistic": np.broadcast_to(statistic, decision.shape), "limit": threshold[:, None, None],
               "decision": decision}
        if trajectory:
            out.update({f"run_length_{i}": runs[:, :, i - 1] for i in range(1, n_models + 1)})
        return out

    @staticmethod
    def _decide(faults, threshold, lengths, labels, carried):
        """The NumPy form of :func:`mosd.kernels.decisions.mode_decisions` (the kernels off): decisions (P, R, K)
        and each model's runs (P, R, M−1, K)."""
        above = faults[None] > threshold[:, None, None, None]  # (P, R, M−1, K)
        held, runs = persistent(above, lengths, carried, counts=True)
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
        return np.where(declared, labels[winner], 0), runs
