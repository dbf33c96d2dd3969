"""The chart-tuning problem (paper 000, eq. 36) as a pymoo ``Problem``.

min over the chart's tunable parameters of (FAR, MDR), each the mean over the
training replications. Everything before the chart — simulation, residuals,
standardisation, the parameter-free subgroup statistics U_k, V_k — is computed
once and cached; a candidate costs only its EWMA recursions, the (batched)
denoising, its limit and the two rates.

Parallelism: a population is split into one chunk per worker of a persistent
loky process pool. The pool's workers receive the cached features once, through
the pool initializer, and keep them between generations; each generation ships
only the candidate vectors. ``n_jobs=1`` evaluates in-process. Results do not
depend on ``n_jobs`` because each candidate's evaluation is independent of the
others in its chunk.
"""
from __future__ import annotations

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
_WORKER_EVALUATOR: CandidateEvaluator | None = None


def _install_evaluator(evaluator: CandidateEvaluator) -> None:
    global _WORKER_EVALUATOR
    _WORKER_EVALUATOR = evaluator


def _evaluate_chunk(X: np.ndarray) -> np.ndarray:
    return _WORKER_EVALUATOR(X)


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
        self._executor = None

    def _evaluate(self, X, out, *args, **kwargs):
        out["F"] = self.evaluate_population(X)

    def evaluate_population(self, X: np.ndarray) -> np.ndarray:
        """(FAR, MDR) for every row of X, over the pool when ``n_jobs > 1``."""
        X = np.atleast_2d(X)
        if self.n_jobs == 1 or X.shape[0] < 2:
            return self.evaluator(X)
        executor = self._pool()
        chunks = np.array_split(X, min(self.n_jobs, X.shape[0]))
        futures = [executor.submit(_evaluate_chunk, chunk) for chunk in chunks]
        return np.concatenate([f.result() for f in futures], axis=0)

    def _pool(self):
        if self._executor is None:
            from joblib.externals.loky import get_reusable_executor

            self._executor = get_reusable_executor(
                max_workers=self.n_jobs, initializer=_install_evaluator, initargs=(self.evaluator,), reuse=True
            )
        return self._executor

    def close(self) -> None:
        """Release the worker pool (it also ends with the process)."""
        if self._executor is not None:
            self._executor.shutdown(wait=True)
            self._executor = None

    def __getstate__(self):
        state = self.__dict__.copy()
        state["_executor"] = None  # pymoo deep-copies problems into res.history
        return state
