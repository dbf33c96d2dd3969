"""The detector-tuning problem (paper 000, eq. 36, generalised) as a pymoo ``Problem``.

min over the detector's tunable parameters of the named objectives (default FAR
and MDR), each the mean over the training replications. Everything before the
detector — simulation, estimation, the monitor's points, the detector's
parameter-free features — is computed once and cached; a candidate costs only
the detector's parameter-dependent part (for a chart: its EWMA recursions, the
batched denoising, its limit) and the metrics.

Integer parameters (``Interval(integer=True)``, e.g. the L of a persistence
rule) are declared by the detector; the problem exposes them as
``is_integer`` and rounds them before every evaluation, so any pymoo algorithm
sees a piecewise-constant objective in those coordinates and the reported
designs are integral.

Parallelism: a population is split into at most ``n_jobs`` chunks (fewer when
the previous population's measured cost would not pay for a round trip per
chunk, :meth:`TuningProblem.n_chunks`); the main process evaluates the first and
``n_jobs − 1`` workers the others. :attr:`TuningProblem.clock` (an
:class:`EvaluationClock`) sums where the evaluation time went, for
``python -m mosd.bench --only scale``. When the compiled
fused chart evaluation applies (:mod:`mosd.kernels.chart`), the workers are
threads of this process: the kernel releases the GIL for all its work, so
threads compute in parallel with no process to start, no evaluator to copy and
no pipe per generation. Otherwise they are processes of a persistent loky
pool. Each worker pins BLAS/OpenMP to one thread, loads the cached
evaluator once (from a file the main process writes at the first pooled
generation) and keeps it between generations, serving the problem's
generations on a socket of its own (:mod:`mosd.optim.pipes`): a generation
writes each worker its candidate vectors and reads its objectives, from the
main thread, with no pool task and no thread hand-over. The pool can be started early (:func:`worker_pool` with
``warm=True``) so that process start-up and loading the compiled kernels
overlap with the simulation. ``n_jobs=1`` evaluates in-process. Results do not
depend on ``n_jobs`` because each candidate's evaluation is independent of the
others in its chunk.

``backend="dask"`` evaluates on a Dask cluster instead (:mod:`mosd.optim.backends`):
a local one of ``n_jobs`` workers started for the problem, or the scheduler at
``dask_address``; the results are the same as loky's (docs/SCALING.md).
"""
from __future__ import annotations

import functools
import os
import pickle
import tempfile
import time

import numpy as np
from pymoo.core.problem import Problem

from ..metrics.registry import as_truth, objective_values
from ..timing import timed_call
from ..validation import ConfigError, Interval, check_int
from .backends import check_backend
from .workers import memmapping_executor, pin_threads as _pin_threads

_OPEN_BOUND_MARGIN = 1e-6


class CandidateEvaluator:
    """Maps a population of detector parameters X (P, d) to objectives (P, n_obj).

    Parameters
    ----------
    detector : mosd.detectors.base.Detector
        Template; its tunable parameters are set from each row of X in the order
        of ``detector.tunable``.
    calibration_features, train_features : ndarray
        ``detector.features`` of the fault-free calibration and of the training points.
    truth : mosd.types.Subgroups or ndarray of bool
        Fault truth of the training points (``z`` may be empty), or just the target-fault mask (R, K).
    objectives : sequence of str
        Metric names (:mod:`mosd.metrics.registry`), all minimised.
    """

    def __init__(self, detector, calibration_features, train_features, truth, objectives=("far", "mdr")):
        self.detector = detector
        self.calibration_features = calibration_features
        self.features = train_features
        self.truth = as_truth(truth)
        self.objectives = tuple(objectives)

    def __call__(self, X: np.ndarray) -> np.ndarray:
        X = np.atleast_2d(np.asarray(X, float))
        if X.shape[0] == 0:
            return np.empty((0, len(self.objectives)))
        fused = self.fused()
        if fused is not None:
            return fused(X)
        return self.reference(X)

    def reference(self, X: np.ndarray) -> np.ndarray:
        """The NumPy path: ``Detector.population`` then ``objective_values`` (what the fused kernel reproduces)."""
        X = np.atleast_2d(np.asarray(X, float))
        decided = self.detector.population(self.calibration_features, self.features, X)
        return objective_values(self.objectives, decided.decision, self.truth)

    def fused(self):
        """The compiled fused evaluation (:func:`mosd.detectors.fused.fused_evaluation`) when it applies, else None.

        Whether it applies is asked on every call (kernels may be switched off
        for a comparison); the plan on this evaluator's data is built once.
        """
        from ..detectors.fused import applies, fused_evaluation

        if not applies(self.detector, self.objectives):
            return None
        if "_fused" not in self.__dict__:
            self.__dict__["_fused"] = fused_evaluation(self.detector, self.calibration_features, self.features,
                                                       self.truth, self.objectives)
        return self.__dict__["_fused"]

    def __getstate__(self):
        # the fused plan is rebuilt where it is used (a worker), not shipped
        state = dict(self.__dict__)
        state.pop("_fused", None)
        return state


# -- the worker side of the persistent pool -------------------------------------------
# Each worker loads the evaluator (cached features) once from a file the main process
# writes, and keeps it between generations; a task then carries only its candidates.
_WORKER_CACHE: dict = {"path": None, "evaluator": None}


def _warm_up(delay: float) -> int:
    """Prepare a worker before the first generation needs it: imports, compiled kernels, thread pinning."""
    from .. import denoisers, detectors, kernels, metrics  # noqa: F401

    _pin_threads()
    kernels.warm_up()
    time.sleep(delay)  # hold this worker so that the next warm-up task lands on another
    return os.getpid()


def _resident_evaluation(path: str):
    """A worker's handler for :class:`~mosd.optim.pipes.WorkerPipes`: chunk -> (objectives, seconds taken),
    with the evaluator loaded from ``path`` once and kept while the path is the same."""
    if _WORKER_CACHE["path"] != path:
        _pin_threads()
        with open(path, "rb") as fh:
            _WORKER_CACHE.update(path=path, evaluator=pickle.load(fh))
    return functools.partial(timed_call, _WORKER_CACHE["evaluator"])


class EvaluationClock:
    """Where a tuning's evaluation time goes, summed over the calls of :meth:`TuningProblem.evaluate_population`.

    Attributes
    ----------
    calls : int
        Populations evaluated (one per generation, plus the initial one).
    candidates : int
        Rows evaluated.
    wall_s : float
        Seconds inside ``evaluate_population``, as the optimiser waits for them.
    compute_s : float
        Seconds the evaluator itself ran, summed over every chunk wherever it ran (a worker
        process or thread, a Dask worker, this thread). ``compute_s / n_jobs`` is the
        evaluation a perfect split would take; ``wall_s`` minus that is dispatch, gather and
        load imbalance.
    split : int
        Populations evaluated in more than one part (a cheap one is not split: :meth:`TuningProblem.n_chunks`).
    """

    def __init__(self):
        self.calls = 0
        self.candidates = 0
        self.wall_s = 0.0
        self.compute_s = 0.0
        self.split = 0

    def add(self, candidates: int, wall_s: float, compute_s: float, parts: int = 1) -> None:
        self.calls += 1
        self.candidates += int(candidates)
        self.wall_s += wall_s
        self.compute_s += compute_s
        self.split += int(parts > 1)


def worker_pool(n_jobs: int, warm: bool = False):
    """The persistent loky pool that serves an evaluation on ``n_jobs`` processes: n_jobs − 1 workers.

    (The main process is the n_jobs-th: it evaluates a chunk itself.) Started on
    first use. ``warm=True`` also sends every worker a warm-up task (imports,
    loading the compiled kernels from the on-disk cache), without waiting for it,
    so that process start-up overlaps with the caller's own work (simulation).
    """
    n_workers = max(1, n_jobs - 1)
    executor = memmapping_executor(n_workers, timeout=600)  # joblib's flavour: see mosd.optim.workers
    if warm:
        for _ in range(n_workers):
            executor.submit(_warm_up, 0.05)
    return executor


_THREADS: dict = {"pool": None, "size": 0}
#: what one chunk costs beyond its work: a round trip on a worker's socket (pickle, write, wake-up, read;
#: 0.15-0.2 ms on the project's 2-core machine, against 0.5-0.6 ms for a loky task) and a thread hand-over
PROCESS_CHUNK_OVERHEAD_S = 1e-4
THREAD_CHUNK_OVERHEAD_S = 5e-5
#: a chunk carries at least this many times its overhead in work (else the population is split fewer ways)
CHUNK_WORK_FACTOR = 10.0


def _thread_pool(n_threads: int):
    """A process-wide pool of ``n_threads`` threads for the fused evaluation, reused between problems."""
    from concurrent.futures import ThreadPoolExecutor

    if _THREADS["pool"] is None or _THREADS["size"] != n_threads:
        if _THREADS["pool"] is not None:
            _THREADS["pool"].shutdown(wait=True)
        _THREADS.update(pool=ThreadPoolExecutor(n_threads, thread_name_prefix="mosd-evaluate"), size=n_threads)
    return _THREADS["pool"]


def thread_slices(fused, n_rows: int, most: int) -> np.ndarray:
    """Edges of the slices a threaded evaluation cuts ``n_rows`` candidates into: at most ``most``, none shorter
    than the fused kernel's lanes (:attr:`FusedChartEvaluation.lanes`), sized as ``np.array_split`` sizes them."""
    lanes = max(1, int(getattr(fused, "lanes", 1)))
    n_slices = max(1, min(most, n_rows // lanes))
    size, longer = divmod(n_rows, n_slices)  # the first ``longer`` slices one row longer
    return np.cumsum([0] + [size + 1] * longer + [size] * (n_slices - longer))


def dealt(n_rows: int, n_slices: int) -> np.ndarray:
    """The order that deals ``n_rows`` candidates to ``n_slices`` slices like cards: slice j gets rows j, j + n, …

    A candidate's cost depends on its design (on the wavelet path, a larger λ costs up to 1.7× a small one)
    and the optimiser's population is not in random order: cut in consecutive blocks, one thread's slice took
    20 ms where the other's took 14–16 (paper 000's chart, 2 threads), and every generation waited for the
    slow one. Dealt, each slice draws from the whole population. Its slice sizes are
    :func:`thread_slices`' (the first ``n_rows % n_slices`` one row longer), and a candidate's objectives do
    not depend on the others of its slice, so the results are the same bit for bit.
    """
    return np.argsort(np.arange(n_rows) % max(1, n_slices), kind="stable")


def uses_threads(detector, objectives, n_jobs: int, backend: str = "loky") -> bool:
    """Whether a tuning of ``detector`` will evaluate on threads rather than loky processes.

    The loky backend with ``n_jobs > 1`` and the compiled fused evaluation
    applying (:func:`mosd.detectors.fused.applies`, the one decision), known
    before the data exist (the detector and objectives alone), so that a caller
    does not start worker processes it will not use. :attr:`TuningProblem.in_threads`
    is this, and the evaluator's data fitting the kernel.
    """
    if backend != "loky" or n_jobs <= 1:
        return False
    from ..detectors.fused import applies

    return applies(detector, objectives)


class TuningProblem(Problem):
    """Minimise the evaluator's objectives over the detector's tunable parameters (eq. 36).

    Parameters
    ----------
    evaluator : CandidateEvaluator
    bounds : dict name -> (low, high), optional
        Overrides the detector's declared bounds (e.g. K_SD in (0, 5) as in Table 2).
        Open bounds are moved inside by 1e-6.
    n_jobs : int
        Worker processes (1 = in-process with loky; the local cluster's workers with dask).
    backend : {"loky", "dask"}
        Where populations are evaluated: loky processes on this machine, or a Dask
        cluster (:class:`mosd.optim.backends.DaskEvaluation`, started at the first
        generation and shut down by :meth:`close`).
    dask_address : str or None
        ``backend="dask"``: a scheduler address (``tcp://host:8786``); None starts a
        local cluster on 127.0.0.1.
    """

    def __init__(self, evaluator: CandidateEvaluator, bounds: dict | None = None, n_jobs: int = 2,
                 backend: str = "loky", dask_address: str | None = None):
        self.evaluator = evaluator
        self.n_jobs = check_int("optimizer.n_jobs", n_jobs, 1, 64)
        self.backend, self.dask_address = check_backend(backend, dask_address)
        tunable = evaluator.detector.tunable
        self.names = list(tunable)
        xl, xu = [], []
        bounds = dict(bounds or {})
        unknown = set(bounds) - set(self.names)
        if unknown:
            raise ConfigError(f"bounds key {sorted(unknown)[0]!r} is unknown; allowed: {', '.join(self.names)}")
        for name in self.names:
            interval = tunable[name]
            lo, hi = bounds.get(name, (interval.low, interval.high))
            low = lo + (_OPEN_BOUND_MARGIN if interval.open_low and lo == interval.low else 0.0)
            high = hi - (_OPEN_BOUND_MARGIN if interval.open_high and hi == interval.high else 0.0)
            # low == high is a fixed parameter (a 2-tag table leaves n_components only 1, issue 53): both
            # optimisers keep a variable whose bounds coincide at that value
            if not interval.low <= lo <= hi <= interval.high or low > high:
                raise ConfigError(f"bounds.{name}=[{lo}, {hi}] is not allowed; allowed: low <= high within {interval}")
            xl.append(low)
            xu.append(high)
        #: True for the integer parameters (rounded before every evaluation)
        self.is_integer = np.array([tunable[name].integer for name in self.names], bool)
        super().__init__(n_var=len(self.names), n_obj=len(evaluator.objectives), xl=np.array(xl), xu=np.array(xu),
                         exclude_from_serialization=["evaluator", "_payload", "_pipes", "_dask", "in_threads",
                                                     "clock"])
        self._payload: str | None = None
        self._pipes = None  # the WorkerPipes of the process path, opened at the first split population
        self._dask = None  # the DaskEvaluation of backend="dask", started on first use
        #: where the evaluation time went (:class:`EvaluationClock`), summed over this problem's populations
        self.clock = EvaluationClock()
        # measured seconds per candidate (the last population's): sizes the process chunks
        self._per_candidate_s: float | None = None

    @property
    def objectives(self) -> tuple[str, ...]:
        return self.evaluator.objectives

    @functools.cached_property
    def in_threads(self) -> bool:
        """True when the loky backend's extra workers are threads of this process (see the module docstring).

        The compiled fused evaluation releases the GIL for all its work, so
        threads run it in parallel without starting processes or copying the
        cached features to them.
        """
        fused = getattr(self.evaluator, "fused", None)
        return (fused is not None and uses_threads(self.evaluator.detector, self.objectives, self.n_jobs, self.backend)
                and fused() is not None)

    def round(self, X: np.ndarray) -> np.ndarray:
        """X with its integer columns rounded (and kept inside the box)."""
        X = np.array(X, float, copy=True)
        if self.is_integer.any():
            cols = self.is_integer
            X[..., cols] = Interval(self.xl[cols], self.xu[cols], integer=True).round(X[..., cols], clip=True)
        return X

    def _evaluate(self, X, out, *args, **kwargs):
        out["F"] = self.evaluate_population(self.round(X))

    def evaluate_population(self, X: np.ndarray) -> np.ndarray:
        """Objectives for every row of X; with ``n_jobs > 1`` split into chunks sized to the work.

        The main process evaluates the first chunk itself while ``n_jobs − 1``
        pool workers evaluate the others (it would otherwise sit idle waiting),
        so n_jobs processes compute and only the other chunks cross a pipe.
        A population whose measured cost (the previous population's seconds per
        candidate) is too small to pay for a pipe round trip per chunk is split
        into fewer chunks, down to none (:meth:`n_chunks`). Each candidate's
        objectives do not depend on the chunk it lands in, so the result is
        bit-identical for every n_jobs and every split. Every call adds its
        times to :attr:`clock`.
        """
        X = np.atleast_2d(X)
        t0 = time.perf_counter()
        if self.backend == "dask":
            if self._dask is None:
                from .backends import DaskEvaluation

                self._dask = DaskEvaluation(self.evaluator, self.n_jobs, self.dask_address)
            (F, compute), parts = self._dask.evaluate_timed(X), self.n_jobs
        elif self.n_jobs == 1 or X.shape[0] < 2:
            (F, compute), parts = timed_call(self.evaluator, X), 1
        elif self.in_threads:
            F, compute, parts = self._evaluate_in_threads(X)
        else:
            F, compute, parts = self._evaluate_in_processes(X)
        self.clock.add(X.shape[0], time.perf_counter() - t0, compute, parts)
        if X.shape[0]:
            self._per_candidate_s = compute / X.shape[0]
        return F

    def n_chunks(self, n_candidates: int, per_chunk_overhead_s: float, most: int) -> int:
        """Chunks for ``n_candidates``: at most ``most``, each worth at least ``CHUNK_WORK_FACTOR`` overheads.

        The cost per candidate is the previous population's (measured: candidates of
        one problem cost about the same from one generation to the next); the first
        population, with nothing measured, is split ``most`` ways.
        """
        most = max(1, min(most, n_candidates))
        if self._per_candidate_s is None:
            return most
        worth = n_candidates * self._per_candidate_s / (CHUNK_WORK_FACTOR * per_chunk_overhead_s)
        return int(max(1, min(most, worth)))

    def _evaluate_in_processes(self, X: np.ndarray) -> tuple[np.ndarray, float, int]:
        """The first chunk in this process, the others on the pool's workers (their evaluator resident);
        the objectives, the compute seconds and the number of chunks.

        Each worker is reached by a pipe of its own (:class:`~mosd.optim.pipes.WorkerPipes`), written and
        read from this thread: a generation costs no pool task and no thread hand-over.
        """
        chunks = np.array_split(X, self.n_chunks(X.shape[0], PROCESS_CHUNK_OVERHEAD_S, self.n_jobs))
        if len(chunks) == 1:
            return (*timed_call(self.evaluator, X), 1)
        pipes = self._worker_pipes()
        others = range(len(chunks) - 1)
        for index in others:
            pipes.send(index, chunks[index + 1])
        try:
            first, compute = timed_call(self.evaluator, chunks[0])
        finally:  # the answers are read whatever happened here, so that the pipes stay in step
            answers = pipes.receive(others)
        parts = [first]
        for index in others:
            F, seconds = answers[index]
            parts.append(F)
            compute += seconds
        return np.concatenate(parts, axis=0), compute, len(chunks)

    def _worker_pipes(self):
        """The pipes to the pool's ``n_jobs − 1`` workers, each holding this problem's evaluator (opened once)."""
        if self._pipes is None or self._pipes.closed:
            from .pipes import WorkerPipes

            if self._payload is None:
                fd, self._payload = tempfile.mkstemp(prefix="mosd-evaluator-", suffix=".pkl")
                with os.fdopen(fd, "wb") as fh:
                    pickle.dump(self.evaluator, fh, protocol=pickle.HIGHEST_PROTOCOL)
            self._pipes = WorkerPipes(worker_pool(self.n_jobs), max(1, self.n_jobs - 1), _resident_evaluation,
                                      self._payload)
        return self._pipes

    def _evaluate_in_threads(self, X: np.ndarray) -> tuple[np.ndarray, float, int]:
        """The compiled kernel on one slice of the population per thread (this one and ``n_jobs − 1`` pool
        threads); the rest of the evaluation once, here.

        One slice per thread, as long as it can be: the kernel computes a slice's candidates
        side by side in vector lanes (:attr:`FusedChartEvaluation.lanes
        <mosd.detectors.fused.FusedChartEvaluation.lanes>`), so per candidate a short slice
        costs more than a long one (6 candidates 1.5–2× what 16 cost), and no slice is cut
        shorter than the lanes. Only the kernel, which releases the GIL, runs in the
        slices: the designs' validation and coefficients (:meth:`FusedChartEvaluation.plan
        <mosd.detectors.fused.FusedChartEvaluation.plan>`) and the objectives from the
        counts are computed once per population, not once per slice, since every thread
        waits for the GIL they hold (on 16 cores that Python part, once per slice, took
        as long as the kernel's work).
        """
        fused = self.evaluator.fused()
        edges = thread_slices(fused, X.shape[0], self.n_chunks(X.shape[0], THREAD_CHUNK_OVERHEAD_S, self.n_jobs))
        if len(edges) == 2:
            return (*timed_call(self.evaluator, X), 1)
        t0 = time.perf_counter()
        order = dealt(X.shape[0], len(edges) - 1)
        plan = fused.plan(X[order])
        planned = time.perf_counter() - t0

        def slice_counts(index: int):
            started = time.perf_counter()
            counts = fused.counts_of(plan, int(edges[index]), int(edges[index + 1]))
            return counts, time.perf_counter() - started

        futures = [_thread_pool(self.n_jobs - 1).submit(slice_counts, index) for index in range(1, len(edges) - 1)]
        done = [slice_counts(0)] + [future.result() for future in futures]
        t1 = time.perf_counter()
        dealt_F = fused.objectives(np.concatenate([alarms for (alarms, _), _ in done], axis=0),
                                   np.concatenate([misses for (_, misses), _ in done], axis=0))
        F = np.empty_like(dealt_F)
        F[order] = dealt_F
        return F, planned + sum(seconds for _, seconds in done) + (time.perf_counter() - t1), len(edges) - 1

    def worker_pids(self) -> list[int]:
        """The process ids of the pool workers this problem's evaluations are sent to (empty before the first
        split population, on threads or Dask, and where the platform does not tell a socket's peer)."""
        pipes = self._pipes
        if pipes is None or pipes.closed:
            return []
        return [pid for pid in pipes.pids if pid is not None]

    def close(self) -> None:
        """Delete the evaluator file the workers load and shut down the Dask client/cluster this problem started.

        The loky pool itself stays up for reuse.
        """
        dask, self._dask = self._dask, None
        if dask is not None:
            dask.close()
        pipes, self._pipes = self._pipes, None
        if pipes is not None:
            pipes.close()  # the workers' tasks end: the pool is free for its next user
        if self._payload is not None:
            try:
                os.remove(self._payload)
            except OSError:
                pass
            self._payload = None

