"""One experiment, end to end, as plain Python (no Hydra, no MLflow).

calibrate (Phase I) → simulate training runs → tune the chart (pymoo) → choose a
design from the archive → evaluate it on fresh test runs (DESIGN.md decision 5:
calibration, training and test replications come from disjoint seed streams).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from .chart import Chart
from .fault import SensorFault
from .metrics import DetectionReport, Estimate
from .monitor import Monitor
from .scenario import Scenario
from .types import Residuals, Subgroups
from .validation import ConfigError, check_int


@dataclass(frozen=True)
class Budget:
    """Replication counts of each seed stream (paper scale by default)."""

    n_calibration: int = 10
    n_train: int = 10
    n_test: int = 100

    def __post_init__(self):
        for name in ("n_calibration", "n_train", "n_test"):
            check_int(f"budget.{name}", getattr(self, name), 1)


@dataclass
class PreparedData:
    """Everything before the chart: cached for the whole optimisation."""

    sigma: float
    phase1: Subgroups
    train: Subgroups
    phase1_residuals: Residuals
    train_residuals: Residuals


@dataclass
class ExperimentResult:
    """What one run produced (the app logs it, the report reads it back)."""

    params: dict[str, float]
    chart: Chart
    archive_X: np.ndarray
    archive_F: np.ndarray
    chosen_index: int
    train_objectives: tuple[float, float]
    test: DetectionReport
    sigma: float
    history: list[dict[str, float]] = field(default_factory=list)
    timings: dict[str, float] = field(default_factory=dict)
    example: dict[str, Any] = field(default_factory=dict)

    def summary(self) -> dict[str, Estimate]:
        return self.test.summary()


class Experiment:
    """Plant, noise, fault, residual generator, monitor and chart, with budgets and seed.

    Parameters
    ----------
    plant, noise : components of :mod:`mosd.plant` and :mod:`mosd.noise`
    fault : SensorFault
    estimator : residual generator with ``residuals(trace, model) -> Residuals``
    monitor : Monitor
    chart : Chart (its tunable parameters are the design variables)
    duration : float
        Simulated seconds per replication.
    budget : Budget
    seed : int
    """

    def __init__(
        self,
        plant,
        noise,
        fault: SensorFault,
        estimator,
        monitor: Monitor,
        chart: Chart,
        duration: float = 5.2,
        budget: Budget | None = None,
        seed: int = 0,
    ):
        if fault is None:
            raise ConfigError("fault is not set; allowed: offset, variance, offset_var, drift")
        self.plant, self.noise, self.fault = plant, noise, fault
        self.estimator, self.monitor, self.chart = estimator, monitor, chart
        self.duration = duration
        self.budget = budget or Budget()
        self.seed = check_int("seed", seed, 0, 2**63 - 1)
        self.model = plant.model(noise.process_cov, noise.measurement_cov)
        # Validates duration and fault channel now, before any work.
        Scenario(plant, noise, fault, duration)

    # -- stages -----------------------------------------------------------------------
    def residuals(self, fault: SensorFault | None, n_reps: int, stream: str, fault_scale: float = 1.0) -> Residuals:
        trace = Scenario(self.plant, self.noise, fault, self.duration).simulate(
            self.seed, n_reps, stream=stream, fault_scale=fault_scale
        )
        return self.estimator.residuals(trace, self.model)

    def prepare(self) -> PreparedData:
        """Phase-I calibration and the training runs (everything the optimiser caches)."""
        phase1_res = self.residuals(None, self.budget.n_calibration, "calibration")
        self.monitor.fit(phase1_res)
        sigma = self.monitor.channel_std(self.fault.channel) if self.fault.channel in self.monitor.channels else float(
            np.nanstd(phase1_res.r[:, self.monitor.burn_in :, self.fault.channel], ddof=1)
        )
        train_res = self.residuals(self.fault, self.budget.n_train, "training", fault_scale=sigma)
        return PreparedData(
            sigma=sigma,
            phase1=self.monitor.transform(phase1_res),
            train=self.monitor.transform(train_res),
            phase1_residuals=phase1_res,
            train_residuals=train_res,
        )

    def test_data(self, data: PreparedData, n_test: int | None = None) -> tuple[Subgroups, Residuals]:
        """Fresh faulty test replications (seed stream ``test``), as subgroups and residuals."""
        test_res = self.residuals(self.fault, n_test or self.budget.n_test, "test", fault_scale=data.sigma)
        return self.monitor.transform(test_res), test_res

    def evaluate(
        self, chart: Chart, data: PreparedData, n_test: int | None = None, test: tuple | None = None
    ) -> tuple[DetectionReport, dict]:
        """Fit ``chart`` on Phase I and score it on the test replications.

        ``test`` is the output of :meth:`test_data` when it was already simulated.
        """
        fitted = chart.with_params(**chart.get_params()).fit(data.phase1.z)
        subgroups, test_res = test if test is not None else self.test_data(data, n_test)
        statistic = fitted.statistic(subgroups.z)
        ucl = fitted.control_limit(statistic.shape[-1])
        report = DetectionReport.of(statistic > ucl, subgroups.fault_mask)
        example = {
            "statistic": statistic[0],
            "ucl": ucl,
            "fault_mask": subgroups.fault_mask[0],
            "residual": test_res.r[0, :, self.fault.channel],
            "residual_fault_mask": test_res.fault_mask[0],
            "dt": self.plant.dt,
            "subgroup_size": self.monitor.subgroup_size,
        }
        return report, example

    def run(
        self,
        algorithm,
        termination,
        n_jobs: int = 2,
        bounds: dict | None = None,
        choose: Callable[[np.ndarray, np.ndarray], int] | None = None,
        callback=None,
        verbose: bool = False,
    ) -> ExperimentResult:
        """Tune the chart with a pymoo ``algorithm`` and evaluate the chosen design."""
        from pymoo.optimize import minimize

        from .optim.problem import CandidateEvaluator, ChartTuningProblem
        from .optim.selection import choose as default_choose

        from concurrent.futures import ThreadPoolExecutor

        from .optim.problem import worker_pool

        timings: dict[str, float] = {}
        if n_jobs > 1:
            worker_pool(n_jobs, warm=True)  # workers start while the main process simulates
        t0 = time.perf_counter()
        data = self.prepare()
        timings["prepare_s"] = time.perf_counter() - t0

        t0 = time.perf_counter()
        evaluator = CandidateEvaluator(
            self.chart, self.chart.features(data.phase1.z), self.chart.features(data.train.z), data.train.fault_mask
        )
        problem = ChartTuningProblem(evaluator, bounds=bounds, n_jobs=n_jobs)
        # The test runs do not depend on the design: simulate them while the workers optimise.
        with ThreadPoolExecutor(max_workers=1) as background:
            test_future = background.submit(self.test_data, data)
            try:
                extra = {} if callback is None else {"callback": callback}
                res = minimize(problem, algorithm, termination, seed=self.seed, verbose=verbose, **extra)
            finally:
                problem.close()
            timings["optimise_s"] = time.perf_counter() - t0
            t0 = time.perf_counter()
            test = test_future.result()
        timings["test_wait_s"] = time.perf_counter() - t0
        X = np.atleast_2d(res.opt.get("X"))
        F = np.atleast_2d(res.opt.get("F"))
        index = int((choose or default_choose)(X, F))
        params = dict(zip(problem.names, map(float, X[index])))

        t0 = time.perf_counter()
        chart = self.chart.with_params(**params)
        report, example = self.evaluate(chart, data, test=test)
        timings["test_s"] = time.perf_counter() - t0
        history = list(getattr(callback, "records", []) or [])
        return ExperimentResult(
            params=params,
            chart=chart,
            archive_X=X,
            archive_F=F,
            chosen_index=index,
            train_objectives=(float(F[index, 0]), float(F[index, 1])),
            test=report,
            sigma=data.sigma,
            history=history,
            timings=timings,
            example=example,
        )
