"""One experiment, end to end, as plain Python (no Hydra, no MLflow).

train the estimator if it needs it (own seed stream) → calibrate (fault-free
runs) → simulate training runs → tune the detector (pymoo) → choose a design
from the archive → evaluate it on fresh test runs. Estimator training,
calibration, training and test replications come from disjoint seed streams
(docs/DECISIONS.md §5; :data:`mosd.scenario.STREAMS`).

The same four verbs serve the app (``python -m mosd``) and the paper reports
(``python -m mosd.paper``): :meth:`Experiment.prepare`, :meth:`Experiment.test_data`,
:meth:`Experiment.evaluate`, :meth:`Experiment.tune` / :meth:`Experiment.run`.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from typing import Any, Callable, Sequence

import numpy as np

from .metrics import DEFAULT_METRICS, DetectionReport, Estimate, check_objectives
from .scenario import Scenario, training_rng
from .types import Residuals, Subgroups
from .validation import ConfigError, check_int


@dataclass(frozen=True)
class Budget:
    """Replication counts of each seed stream (paper-000 scale by default).

    ``n_estimator`` are the runs a trainable estimator learns from (its own
    stream; unused when the estimator needs no training).
    """

    n_calibration: int = 10
    n_train: int = 10
    n_test: int = 100
    n_estimator: int = 10

    def __post_init__(self):
        for name in ("n_calibration", "n_train", "n_test", "n_estimator"):
            check_int(f"budget.{name}", getattr(self, name), 1)


@dataclass
class PreparedData:
    """Everything before the detector: cached for the whole optimisation.

    ``sigma`` is the unit of relative faults (σ of the faulty channel's
    calibration residual; 1 for absolute faults).
    """

    sigma: float
    phase1: Subgroups
    train: Subgroups
    phase1_residuals: Residuals
    train_residuals: Residuals


@dataclass
class Tuned:
    """An optimiser's archive on the training runs and the design chosen from it."""

    params: dict[str, float]
    X: np.ndarray
    F: np.ndarray
    index: int
    objectives: tuple[str, ...]
    history: list[dict[str, float]] = field(default_factory=list)
    seconds: float = 0.0

    @property
    def train_objectives(self) -> dict[str, float]:
        return {name: float(v) for name, v in zip(self.objectives, self.F[self.index])}


@dataclass
class ExperimentResult:
    """What one run produced (the app logs it, the reports read it back)."""

    params: dict[str, float]
    detector: Any
    archive_X: np.ndarray
    archive_F: np.ndarray
    chosen_index: int
    objectives: tuple[str, ...]
    train_objectives: dict[str, float]
    test: DetectionReport
    sigma: float
    history: list[dict[str, float]] = field(default_factory=list)
    timings: dict[str, float] = field(default_factory=dict)
    example: dict[str, Any] = field(default_factory=dict)

    def summary(self) -> dict[str, Estimate]:
        return self.test.summary()


def first_replication(outputs: Residuals) -> Residuals:
    """The first replication of an estimator's outputs (every per-replication array cut to R = 1)."""
    def first(value):
        return value[:1] if isinstance(value, np.ndarray) and value.ndim >= 2 else value

    return replace(outputs, r=outputs.r[:1], fault_mask=outputs.fault_mask[:1], cov=first(outputs.cov),
                   extra={k: first(v) for k, v in outputs.extra.items()}, fault_label=first(outputs.fault_label))


def concatenate_replications(parts: Sequence[Residuals]) -> Residuals:
    """One :class:`Residuals` from consecutive blocks of replications (every per-replication array joined on R).

    The inverse of cutting replications into blocks: what :meth:`Experiment.residuals`
    computes block by block on ``n_jobs`` threads is the array one call would give.
    """
    if len(parts) == 1:
        return parts[0]
    first = parts[0]

    def joined(values):
        head = values[0]
        return np.concatenate(values, axis=0) if isinstance(head, np.ndarray) and head.ndim >= 2 else head

    return replace(first, r=np.concatenate([p.r for p in parts], axis=0),
                   fault_mask=np.concatenate([p.fault_mask for p in parts], axis=0),
                   cov=None if first.cov is None else np.concatenate([p.cov for p in parts], axis=0),
                   extra={k: joined([p.extra[k] for p in parts]) for k in first.extra},
                   fault_label=joined([p.fault_label for p in parts]))


def replication_blocks(n_reps: int, n_jobs: int) -> list[tuple[int, int]]:
    """``(first, count)`` of at most ``n_jobs`` consecutive blocks covering replications ``0 .. n_reps-1``."""
    n_blocks = max(1, min(int(n_jobs), int(n_reps)))
    edges = [n_reps * i // n_blocks for i in range(n_blocks + 1)]
    return [(edges[i], edges[i + 1] - edges[i]) for i in range(n_blocks)]


def _blocks_pay(estimator) -> bool:
    """Whether :meth:`Experiment.residuals` may cut ``estimator``'s replications into blocks.

    Not when a replication's outputs depend on the others in its batch, to the last bit (the
    estimator says ``independent_replications = False``: one block keeps the numbers), nor when
    the estimator's filter already spreads the replications over the cores
    (``splits_replications``: blocks would only add threads).
    """
    parts = (estimator, getattr(estimator, "filter", None))
    return (getattr(estimator, "independent_replications", True)
            and not any(getattr(part, "splits_replications", False) for part in parts))


def _truth(subgroups: Subgroups) -> Subgroups:
    """The fault truth of some points without the points (what workers need to score)."""
    return replace(subgroups, z=np.empty((0,)))


class Experiment:
    """Plant, noise, fault, estimator, monitor and detector, with budgets, seed and objectives.

    Parameters
    ----------
    plant, noise, fault, estimator, monitor, detector :
        Components of :mod:`mosd.plants`, :mod:`mosd.noise`, :mod:`mosd.faults`,
        :mod:`mosd.estimators`, :mod:`mosd.monitors`, :mod:`mosd.detectors`
        (the detector's ``tunable`` parameters are the design variables).
    duration : float
        Simulated seconds per replication.
    budget : Budget
    seed : int
    objectives : sequence of str
        Metrics to minimise (:func:`mosd.metrics.objective_names`), default (FAR, MDR).
    """

    def __init__(self, plant, noise, fault, estimator, monitor, detector, duration: float = 5.2,
                 budget: Budget | None = None, seed: int = 0, objectives: Sequence[str] = ("far", "mdr")):
        if fault is None:
            raise ConfigError("fault is not set; allowed: a fault of conf/fault (e.g. +fault=offset_var)")
        self.plant, self.noise, self.fault = plant, noise, fault
        self.estimator, self.monitor, self.detector = estimator, monitor, detector
        self.duration = duration
        self.budget = budget or Budget()
        self.seed = check_int("seed", seed, 0, 2**63 - 1)
        self.objectives = check_objectives(objectives)
        self.model = plant.model(noise)
        # validates duration, onset and the fault's channel now, before any work
        Scenario(plant, noise, fault, duration)
        if getattr(estimator, "requires_fit", False) and getattr(estimator, "fit_on_faults", False) and fault.relative:
            raise ConfigError("estimator needs faulty training runs but the fault is in units of the calibration σ; "
                              "allowed: an absolute fault with this estimator")

    # -- stages -----------------------------------------------------------------------
    #: the fault-free calibration outputs the unit of relative faults comes from (set by calibrate/prepare)
    _calibration: Residuals | None = None

    def fault_scale(self, fault) -> float:
        """The unit of ``fault``'s magnitudes: σ of the fault-free residual for a relative fault, else 1.

        The experiment owns the scale: a relative fault (``fault.relative``, e.g.
        :class:`~mosd.faults.sensor.SensorFault`) is in units of the in-control σ
        of its channel's calibration residual (:meth:`Monitor.fault_scale`), so
        ``a = 2`` means 2σ whoever simulates it. Calibrates first when
        :meth:`calibrate` has not run yet.
        """
        relative = [m for m in (fault.members if fault is not None else ()) if m.relative]
        if not relative:
            return 1.0
        channels = sorted({m.channel for m in relative})
        if len(channels) > 1:
            raise ConfigError(f"fault.faults: relative faults on channels {channels} share one unit; "
                              "allowed: relative faults on one channel")
        calibration = self._calibration if self._calibration is not None else self.calibrate()
        return self.monitor.fault_scale(calibration, channels[0])

    def simulate(self, fault, n_reps: int, stream: str, first: int = 0):
        """Replications ``first .. first+n_reps-1`` of a seed stream; a relative fault in σ of the fault-free
        residual (:meth:`fault_scale`)."""
        return Scenario(self.plant, self.noise, fault, self.duration).simulate(
            self.seed, n_reps, stream=stream, fault_scale=self.fault_scale(fault), first=first)

    def residuals(self, fault, n_reps: int, stream: str, n_jobs: int = 1) -> Residuals:
        """Simulate a seed stream and run the estimator on it; ``n_jobs`` blocks of replications at once.

        Each replication has its own generator (:func:`mosd.scenario.replication_rngs`) and the
        estimator treats replications independently, so blocks simulated and estimated apart and
        joined (:func:`concatenate_replications`) are bit for bit the arrays of one call, for every
        ``n_jobs`` (``tests/test_scale_prepare.py``). The blocks run on threads of this process: the
        simulation's draws and the compiled estimators release Python's lock, and nothing is pickled.
        One block where blocks would not pay or would change a bit (:func:`_blocks_pay`).
        """
        blocks = replication_blocks(n_reps, n_jobs if _blocks_pay(self.estimator) else 1)
        if len(blocks) == 1:
            return self.estimator.estimate(self.simulate(fault, n_reps, stream), self.model)
        self.fault_scale(fault)  # the calibration a relative fault needs, once, before the blocks share it

        def block(first_count):
            first, count = first_count
            return self.estimator.estimate(self.simulate(fault, count, stream, first=first), self.model)

        from concurrent.futures import ThreadPoolExecutor

        with ThreadPoolExecutor(len(blocks) - 1, thread_name_prefix="mosd-replications") as pool:
            others = pool.map(block, blocks[1:])  # submitted now: they run while this thread computes the first
            head = block(blocks[0])
            return concatenate_replications([head, *others])

    def fit_estimator(self) -> None:
        """Train the estimator on its own seed stream (no-op for estimators without ``fit``)."""
        if not getattr(self.estimator, "requires_fit", False):
            return
        fault = self.fault if self.estimator.fit_on_faults else None
        trace = self.simulate(fault, self.budget.n_estimator, "estimator")
        # the training's own randomness (initial weights, shuffling) also comes from the estimator stream
        self.estimator.fit(trace, self.model, training_rng(self.seed))

    def calibrate(self, n_jobs: int = 1) -> Residuals:
        """Train the estimator (if it needs it), then fit the monitor on fault-free calibration runs."""
        self.fit_estimator()
        phase1_res = self.residuals(None, self.budget.n_calibration, "calibration", n_jobs=n_jobs)
        self.monitor.fit(phase1_res)
        self._calibration = phase1_res
        return phase1_res

    def prepare(self, calibration: Residuals | None = None, fault=None, n_jobs: int = 1) -> PreparedData:
        """Calibration and the training runs of ``fault`` (default: the experiment's): what the optimiser caches.

        ``calibration`` is the output of :meth:`calibrate` when several faults
        share one calibration (the calibration stream is fault-free, so it is
        the same for every fault). ``n_jobs``: blocks of replications simulated at
        once (:meth:`residuals`; the same data for every value).
        """
        fault = fault or self.fault
        phase1_res = self.calibrate(n_jobs=n_jobs) if calibration is None else calibration
        self._calibration = phase1_res
        sigma = self.fault_scale(fault)
        train_res = self.residuals(fault, self.budget.n_train, "training", n_jobs=n_jobs)
        return PreparedData(sigma=sigma, phase1=self.monitor.transform(phase1_res),
                            train=self.monitor.transform(train_res), phase1_residuals=phase1_res,
                            train_residuals=train_res)

    def test_data(self, data: PreparedData, n_test: int | None = None, fault=None,
                  n_jobs: int = 1) -> tuple[Subgroups, Residuals]:
        """Fresh test replications (seed stream ``test``) of ``fault`` (default: the experiment's), ``n_jobs``
        blocks at once (:meth:`residuals`)."""
        test_res = self.residuals(fault or self.fault, n_test or self.budget.n_test, "test", n_jobs=n_jobs)
        return self.monitor.transform(test_res), test_res

    def evaluator(self, data: PreparedData, detector=None):
        """The objectives of a population of designs on the training runs (what the optimiser minimises)."""
        from .optim.problem import CandidateEvaluator

        detector = detector or self.detector
        return CandidateEvaluator(detector, detector.features(data.phase1.z), detector.features(data.train.z),
                                  _truth(data.train), self.objectives)

    def evaluate(self, detector, data: PreparedData, n_test: int | None = None,
                 test: tuple | None = None) -> tuple[DetectionReport, dict]:
        """Calibrate ``detector`` on the calibration runs and score it on the test replications.

        ``test`` is the output of :meth:`test_data` when it was already simulated.
        """
        subgroups, test_res = test if test is not None else self.test_data(data, n_test)
        decided = detector.decide(data.phase1.z, subgroups.z)
        names = tuple(dict.fromkeys((*DEFAULT_METRICS, *self.objectives)))
        report = DetectionReport.of(decided.decision, subgroups, names)
        channel = getattr(self.fault, "channel", 0)
        residual = test_res.r[0, :, channel] if test_res.r.shape[-1] > channel else None
        example = {
            "statistic": decided.statistic[0],
            "ucl": np.broadcast_to(decided.threshold, decided.statistic.shape)[0],
            "fault_mask": subgroups.fault_mask[0],
            "t": subgroups.t,
            "residual": residual,
            "residual_t": test_res.t,
            "residual_fault_mask": test_res.fault_mask[0],
            "dt": self.plant.dt,
            "seconds_per_point": float(np.median(np.diff(subgroups.t))) if subgroups.t is not None
            and len(subgroups.t) > 1 else float(self.plant.dt),
            # what the run's deployed pipeline is built and checked with (mosd.app.model): the monitor's
            # calibration points, the first test replication's estimator outputs and its decisions
            "calibration_z": data.phase1.z,
            "first_outputs": first_replication(test_res),
            "decision": np.asarray(decided.decision[0]),
        }
        return report, example

    def tune(self, data: PreparedData, algorithm, termination, n_jobs: int = 2, bounds: dict | None = None,
             choose: Callable | None = None, callback=None, verbose: bool = False, detector=None,
             backend: str = "loky", dask_address: str | None = None) -> Tuned:
        """Minimise the objectives over the detector's parameters on the training runs.

        ``backend``/``dask_address`` choose where the populations are evaluated
        (:class:`mosd.optim.problem.TuningProblem`); the result does not depend on them.
        """
        from pymoo.optimize import minimize

        from .optim.problem import TuningProblem
        from .optim.selection import choose as default_choose

        t0 = time.perf_counter()
        problem = TuningProblem(self.evaluator(data, detector), bounds=bounds, n_jobs=n_jobs, backend=backend,
                                dask_address=dask_address)
        try:
            extra = {} if callback is None else {"callback": callback}
            res = minimize(problem, algorithm, termination, seed=self.seed, verbose=verbose, **extra)
        finally:
            problem.close()
        X = problem.round(np.atleast_2d(res.opt.get("X")))
        F = np.atleast_2d(res.opt.get("F"))
        index = int((choose or default_choose)(X, F, objectives=self.objectives))
        params = {name: (int(v) if problem.is_integer[i] else float(v))
                  for i, (name, v) in enumerate(zip(problem.names, X[index]))}
        return Tuned(params, X, F, index, self.objectives, list(getattr(callback, "records", []) or []),
                     time.perf_counter() - t0)

    def run(self, algorithm, termination, n_jobs: int = 2, bounds: dict | None = None,
            choose: Callable | None = None, callback=None, verbose: bool = False, backend: str = "loky",
            dask_address: str | None = None) -> ExperimentResult:
        """Prepare, tune and evaluate the chosen design on fresh test runs.

        ``backend="dask"`` evaluates the optimiser's populations on a Dask cluster
        (``dask_address``, or a local one of ``n_jobs`` workers, started before the
        simulation so that it is up when the first generation needs it); see :meth:`tune`.
        """
        from .optim.backends import check_backend
        from .optim.problem import uses_threads, worker_pool

        # a misspelt backend must fail before the simulation, not after it
        backend, dask_address = check_backend(backend, dask_address)
        timings: dict[str, float] = {}
        if n_jobs > 1 and backend == "loky" and not uses_threads(self.detector, self.objectives, n_jobs, backend):
            worker_pool(n_jobs, warm=True)  # workers start while the main process simulates
        if backend == "dask" and dask_address is None:
            from .optim.backends import discard_local_clusters, start_local_cluster

            start_local_cluster(n_jobs)  # the local cluster starts while the main process simulates
            try:
                return self._run(algorithm, termination, n_jobs, bounds, choose, callback, verbose, backend,
                                 dask_address, timings)
            finally:
                discard_local_clusters()  # one the tuning never took (it failed before)
        return self._run(algorithm, termination, n_jobs, bounds, choose, callback, verbose, backend, dask_address,
                         timings)

    def _run(self, algorithm, termination, n_jobs, bounds, choose, callback, verbose, backend, dask_address,
             timings: dict) -> ExperimentResult:
        from concurrent.futures import ThreadPoolExecutor

        t0 = time.perf_counter()
        data = self.prepare(n_jobs=n_jobs)
        timings["prepare_s"] = time.perf_counter() - t0
        # the test runs do not depend on the design: simulate them while the workers optimise
        with ThreadPoolExecutor(max_workers=1) as background:
            test_future = background.submit(self.test_data, data, n_jobs=n_jobs)
            tuned = self.tune(data, algorithm, termination, n_jobs=n_jobs, bounds=bounds, choose=choose,
                              callback=callback, verbose=verbose, backend=backend, dask_address=dask_address)
            timings["optimise_s"] = tuned.seconds
            t0 = time.perf_counter()
            test = test_future.result()
        timings["test_wait_s"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        detector = self.detector.with_params(**tuned.params)
        report, example = self.evaluate(detector, data, test=test)
        timings["test_s"] = time.perf_counter() - t0
        return ExperimentResult(params=tuned.params, detector=detector, archive_X=tuned.X, archive_F=tuned.F,
                                chosen_index=tuned.index, objectives=self.objectives,
                                train_objectives=tuned.train_objectives, test=report, sigma=data.sigma,
                                history=tuned.history, timings=timings, example=example)
