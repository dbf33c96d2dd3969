"""The chart-tuning problem (paper 000, eq. 36) as a pymoo ``Problem``.

min over the chart's tunable parameters of (FAR, MDR), each the mean over the
training replications. Everything before the chart — simulation, residuals,
standardisation, the parameter-free subgroup statistics U_k, V_k — is computed
once and cached; a candidate costs only its EWMA recursions, the (batched)
denoising, its limit and the two rates.

Parallelism: a population is split into one chunk per worker of a persistent
loky process pool. Each worker loads the cached features once (from a file the
main process writes at the first pooled generation) and keeps them between
generations; each generation ships only the candidate vectors. The pool can be
started early (:func:`worker_pool` with ``warm=True``) so that process start-up
overlaps with the simulation. ``n_jobs=1`` evaluates in-process. Results do not
depend on ``n_jobs`` because each candidate's evaluation is independent of the
others in its chunk.
"""
from __future__ import annotations

import os
import pickle
import tempfile
import time

import numpy as np
from pymoo.core.problem import Problem

from ..metrics import false_alarm_rate, missed_detection_rate
from ..validation import ConfigError, check_int

_OPEN_BOUND_MARGIN = 1e-6


class CandidateEvaluator:
    """Maps a population of chart parameters X (P, d) to objectives (P, 2) = (FAR, MDR).

    Parameters
    ----------
    chart : mosd.chart.Chart
        Template chart; its tunable parameters are set from each row of X in the
        order of ``chart.tunable``.
    phase1_features, train_features : ndarray
        ``chart.features`` of the Phase-I (fault-free) and training subgroups.
    train_fault_mask : ndarray of bool, shape (R, K)
    """

    def __init__(self, chart, phase1_features, train_features, train_fault_mask):
        self.chart = chart
        self.n_phase1 = phase1_features.shape[0]
        self.features = np.concatenate([phase1_features, train_features], axis=0)
        self.fault_mask = np.asarray(train_fault_mask, bool)

    def __call__(self, X: np.ndarray) -> np.ndarray:
        X = np.atleast_2d(np.asarray(X, float))
        if X.shape[0] == 0:
            return np.empty((0, 2))
        stats = self.chart.population_statistics(self.features, X)  # (P, R1 + R, K)
        limits = self.chart.population_limits(stats[:, : self.n_phase1], X)  # (P, K)
        alarms = stats[:, self.n_phase1 :] > limits[:, None, :]
        return np.column_stack([
            false_alarm_rate(alarms, self.fault_mask).mean(axis=-1),
            missed_detection_rate(alarms, self.fault_mask).mean(axis=-1),
        ])


# -- the worker side of the persistent pool -------------------------------------------
# Each worker loads the evaluator (cached features) once from a file the main process
# writes, and keeps it between generations; a task then carries only its candidates.
_WORKER_CACHE: dict = {"path": None, "evaluator": None}


def _warm_up(delay: float) -> int:
    """Import the evaluation stack in a worker before the first generation needs it."""
    from .. import chart, denoise, metrics  # noqa: F401

    time.sleep(delay)  # hold this worker so that the next warm-up task lands on another
    return os.getpid()


def _evaluate_chunk(path: str, X: np.ndarray) -> np.ndarray:
    if _WORKER_CACHE["path"] != path:
        with open(path, "rb") as fh:
            _WORKER_CACHE.update(path=path, evaluator=pickle.load(fh))
    return _WORKER_CACHE["evaluator"](X)


def worker_pool(n_jobs: int, warm: bool = False):
    """The persistent loky pool of ``n_jobs`` workers (started on first use).

    ``warm=True`` also sends every worker an import task, without waiting for it,
    so that process start-up overlaps with the caller's own work (simulation).
    """
    from joblib.externals.loky import get_reusable_executor

    executor = get_reusable_executor(max_workers=n_jobs, timeout=600)
    if warm:
        for _ in range(n_jobs):
            executor.submit(_warm_up, 0.05)
    return executor


class ChartTuningProblem(Problem):
    """Eq. 36: minimise (FAR, MDR) of a chart over its tunable parameters.

    Parameters
    ----------
    evaluator : CandidateEvaluator
    bounds : dict name -> (low, high), optional
        Overrides the chart's declared bounds (e.g. K_SD in (0, 5) as in Table 2).
        Open bounds are moved inside by 1e-6.
    n_jobs : int
        Worker processes (1 = in-process).
    """

    def __init__(self, evaluator: CandidateEvaluator, bounds: dict | None = None, n_jobs: int = 2):
        self.evaluator = evaluator
        self.n_jobs = check_int("optimizer.n_jobs", n_jobs, 1, 64)
        self.names = list(evaluator.chart.tunable)
        xl, xu = [], []
        bounds = dict(bounds or {})
        unknown = set(bounds) - set(self.names)
        if unknown:
            raise ConfigError(f"bounds key {sorted(unknown)[0]!r} is unknown; allowed: {', '.join(self.names)}")
        for name in self.names:
            interval = evaluator.chart.tunable[name]
            lo, hi = bounds.get(name, (interval.low, interval.high))
            if not interval.low <= lo < hi <= interval.high:
                raise ConfigError(f"bounds.{name}=[{lo}, {hi}] is not allowed; allowed: low < high within {interval}")
            xl.append(lo + (_OPEN_BOUND_MARGIN if interval.open_low and lo == interval.low else 0.0))
            xu.append(hi - (_OPEN_BOUND_MARGIN if interval.open_high and hi == interval.high else 0.0))
        super().__init__(n_var=len(self.names), n_obj=2, xl=np.array(xl), xu=np.array(xu))
        self._payload: str | None = None

    def _evaluate(self, X, out, *args, **kwargs):
        out["F"] = self.evaluate_population(X)

    def evaluate_population(self, X: np.ndarray) -> np.ndarray:
        """(FAR, MDR) for every row of X, over the pool when ``n_jobs > 1``."""
        X = np.atleast_2d(X)
        if self.n_jobs == 1 or X.shape[0] < 2:
            return self.evaluator(X)
        if self._payload is None:
            fd, self._payload = tempfile.mkstemp(prefix="mosd-evaluator-", suffix=".pkl")
            with os.fdopen(fd, "wb") as fh:
                pickle.dump(self.evaluator, fh, protocol=pickle.HIGHEST_PROTOCOL)
        executor = worker_pool(self.n_jobs)
        chunks = np.array_split(X, min(self.n_jobs, X.shape[0]))
        futures = [executor.submit(_evaluate_chunk, self._payload, chunk) for chunk in chunks]
        return np.concatenate([f.result() for f in futures], axis=0)

    def close(self) -> None:
        """Delete the evaluator file the workers load; the pool itself stays up for reuse."""
        if self._payload is not None:
            try:
                os.remove(self._payload)
            except OSError:
                pass
            self._payload = None

    def __getstate__(self):
        state = self.__dict__.copy()
        state["_payload"] = None  # pymoo deep-copies problems into res.history
        return state
