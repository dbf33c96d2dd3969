"""Where a tuning problem's fitness evaluations run: this machine (loky) or a Dask cluster.

``loky`` (the default) is this machine: threads of the run's own process when
the compiled chart evaluation applies, else :class:`~mosd.optim.problem.TuningProblem`'s
persistent loky process pool. ``dask`` sends every generation to a
`Dask distributed <https://distributed.dask.org>`_ cluster: a ``LocalCluster``
of ``n_jobs`` single-threaded worker processes on 127.0.0.1 started for the
problem, or the running scheduler at ``dask_address``. The evaluator (the cached
features of the training runs) is scattered to every worker once per problem and
kept there by a Dask actor per worker; a generation then ships only candidate
vectors, one call per worker straight from the client (no task, no scheduler in
the way), as with loky.

Results do not depend on the backend: each candidate's objectives are computed
by the same code on the same arrays whatever process or chunk it lands in, so
``dask`` gives bit-for-bit the archive of ``loky`` and of ``n_jobs=1`` for the
same seed (``tests/test_scaleout.py``), provided the workers run the same mosd,
NumPy and ``MOSD_KERNELS`` setting as the main process.

``distributed`` is imported only when a Dask evaluation starts, so the core's
import time does not change; without it, ``backend=dask`` fails with one line
naming the install command.
"""
from __future__ import annotations

import importlib.util
import logging
import socket
import threading
import time
from urllib.parse import urlsplit

import numpy as np

from ..timing import timed_call
from ..validation import ConfigError

#: The evaluation backends (``optimizer.backend``).
BACKENDS = ("loky", "dask")
#: What to install for ``backend=dask`` (and for the submitit launcher of sweeps).
CLUSTER_INSTALL = 'pip install "mosd[cluster]"'
#: Seconds to wait for a scheduler at ``dask_address`` before giving up.
CONNECT_TIMEOUT_S = 30.0
#: A worker computes a chunk expected to take at most this many seconds on its event loop (no thread hand-over);
#: a longer one in a thread, so that its heartbeats to the scheduler keep going (:class:`_ResidentEvaluator`).
INLINE_S = 0.25


def _missing_distributed() -> ConfigError:
    return ConfigError(f"optimizer.backend=dask needs the 'distributed' package, which is not installed; "
                       f"install it with: {CLUSTER_INSTALL}")


def check_backend(backend: str = "loky", dask_address: str | None = None) -> tuple[str, str | None]:
    """Validate ``optimizer.backend`` and ``optimizer.dask_address``; return them.

    Parameters
    ----------
    backend : {"loky", "dask"}
        Where fitness evaluations run.
    dask_address : str or None
        ``backend=dask`` only: a scheduler address (``tcp://host:8786``), or None to
        start a local cluster for the problem.

    Raises
    ------
    ConfigError
        An unknown backend, an address without ``backend=dask`` (it would be silently
        ignored), an empty address, or ``backend=dask`` without ``distributed`` installed
        (checked without importing it).
    """
    if backend not in BACKENDS:
        raise ConfigError(f"optimizer.backend={backend!r} is not allowed; allowed: {', '.join(BACKENDS)}")
    if dask_address is not None:
        if not isinstance(dask_address, str) or not dask_address.strip():
            raise ConfigError(f"optimizer.dask_address={dask_address!r} is not an address; allowed: null "
                              "(a local cluster) or a scheduler address such as tcp://host:8786")
        if backend != "dask":
            raise ConfigError(f"optimizer.dask_address={dask_address!r} is set but optimizer.backend={backend}; "
                              "allowed: optimizer.backend=dask with an address, or dask_address=null")
        dask_address = dask_address.strip()
    if backend == "dask" and importlib.util.find_spec("distributed") is None:
        raise _missing_distributed()
    return backend, dask_address


def check_scheduler(address: str, timeout: float = 5.0) -> None:
    """Raise ConfigError unless a Dask scheduler answers at a ``tcp://`` or ``tls://host:port`` address within ``timeout``.

    Something accepting TCP connections is not enough (an HTTP server, a proxy, a
    Dask worker): Dask's own comm handshake, then the scheduler's ``identity``
    call, must answer with ``type == "Scheduler"`` before the deadline. The probe
    runs in a daemon thread with its own event loop, so that a service that sends
    nothing, garbage (Dask then reads a frame length of exabytes) or an endless
    stream costs ``timeout`` seconds at most and never the run. A ``tls://`` address is
    checked the same way, the handshake made with the TLS settings of the Dask config
    (``distributed.comm.tls``: what the run's client connects with); without them, one line
    says so. Addresses of other schemes (``ucx://``, ``inproc://``) are left to Dask.
    """
    parts = urlsplit(address if "://" in address else f"tcp://{address}")
    if parts.scheme not in ("tcp", "tls"):
        return
    try:
        host, port = parts.hostname, parts.port
    except ValueError:
        host, port = None, None
    if not host or port is None:
        raise ConfigError(f"optimizer.dask_address={address!r} has no host and port; "
                          f"allowed: a scheduler address such as {parts.scheme}://host:8786")
    allowed = "allowed: the address a running `dask scheduler` prints, or null for a local cluster"
    try:  # a refused or unroutable address says so plainly, without Dask's import
        with socket.create_connection((host, port), timeout=timeout):
            pass
    except OSError as exc:
        raise ConfigError(f"optimizer.dask_address={address!r}: no Dask scheduler answers there "
                          f"({type(exc).__name__}: {exc}); {allowed}") from None
    try:
        import distributed  # noqa: F401 - the probe's comm layer
    except ImportError:
        raise _missing_distributed() from None
    connection_args: dict = {}
    if parts.scheme == "tls":
        from distributed.security import Security

        # the Dask config's TLS settings: what distributed.Client(address) itself connects with
        connection_args = Security().get_connection_args("client")
        if connection_args.get("ssl_context") is None:
            raise ConfigError(f"optimizer.dask_address={address!r} is a TLS address but the Dask config has no TLS "
                              "settings (distributed.comm.tls.ca-file, .client.cert and .client.key, or "
                              "DASK_DISTRIBUTED__COMM__TLS__* variables); allowed: those settings, or a tcp:// address")
    answer: dict = {}
    probe = threading.Thread(target=_identify, args=(f"{parts.scheme}://{host}:{port}", timeout, answer,
                                                     connection_args), daemon=True)
    probe.start()
    probe.join(timeout + 1.0)  # the probe's own deadline is timeout; this bounds a probe stuck outside its loop
    identity, error = answer.get("identity"), answer.get("error")
    if identity is None:
        import asyncio

        if error is None or isinstance(error, (TimeoutError, asyncio.TimeoutError)):
            what = f"no Dask handshake within {timeout:g} s"
        else:
            detail = " ".join(str(error).split())[:200]
            what = f"its answer is not Dask's protocol: {type(error).__name__}: {detail}"
        raise ConfigError(f"optimizer.dask_address={address!r} accepts connections but is not a Dask scheduler "
                          f"({what}); {allowed}")
    kind = identity.get("type") if isinstance(identity, dict) else None
    if kind != "Scheduler":
        scheduler = identity.get("scheduler") if isinstance(identity, dict) else None
        raise ConfigError(f"optimizer.dask_address={address!r} is a Dask {kind or 'service'}, not a scheduler"
                          + (f" (its scheduler: {scheduler})" if scheduler else "") + f"; {allowed}")


def _identify(address: str, timeout: float, answer: dict, connection_args: dict | None = None) -> None:
    """Dask's handshake and the ``identity`` call at ``address`` within ``timeout`` s; the reply or error into ``answer``."""
    import asyncio  # here, not at the top: a run that names no Dask scheduler never loads it

    from distributed.comm import connect

    async def identify():
        comm = await connect(address, timeout=timeout, **(connection_args or {}))
        try:
            await comm.write({"op": "identity", "reply": True})
            return await comm.read()
        finally:
            comm.abort()

    try:
        answer["identity"] = asyncio.run(asyncio.wait_for(identify(), timeout))
    except BaseException as exc:  # noqa: BLE001 - whatever a stray service provokes is the answer "not Dask"
        answer["error"] = exc


class _ResidentEvaluator:
    """A Dask actor: one per worker, holding the evaluator for the problem's life; a generation calls it once.

    Its calls go from the client straight to the worker (Dask's ``actor_execute``), not through
    the scheduler as tasks do. A chunk expected to finish within :data:`INLINE_S` (the previous
    call's seconds per candidate) runs on the worker's event loop itself, saving the hand-over to
    a thread; a longer one runs in the actor's own thread, so the worker keeps answering the
    scheduler's heartbeats while it computes.
    """

    def __init__(self, evaluator):
        from .workers import pin_threads

        # the LocalCluster's nanny already sets OMP/MKL/OpenBLAS to one thread; a worker of a
        # remote cluster may not, and n workers each starting a core's worth of BLAS threads thrash
        pin_threads()
        self.evaluator = evaluator
        self.per_candidate_s = float("inf")  # unknown until the first chunk: that one runs in the thread
        self._thread = None

    def _timed(self, X: np.ndarray) -> tuple[np.ndarray, float]:
        F, seconds = timed_call(self.evaluator, X)
        self.per_candidate_s = seconds / max(1, X.shape[0])
        return F, seconds

    async def evaluate(self, X: np.ndarray) -> tuple[np.ndarray, float]:
        """Objectives of the chunk X and the seconds they took on this worker."""
        if self.per_candidate_s * X.shape[0] <= INLINE_S:
            return self._timed(X)
        import asyncio
        from concurrent.futures import ThreadPoolExecutor

        if self._thread is None:
            self._thread = ThreadPoolExecutor(1, thread_name_prefix="mosd-evaluator")
        return await asyncio.get_running_loop().run_in_executor(self._thread, self._timed, X)


def _quiet_dask_logs() -> None:
    # distributed configures its loggers at INFO: every worker start and stop would reach the
    # run's stderr (the scheduler and nannies of a local cluster live in this process)
    dask_logger = logging.getLogger("distributed")
    if dask_logger.getEffectiveLevel() < logging.WARNING:
        dask_logger.setLevel(logging.WARNING)


def _local_cluster(n_jobs: int):
    """A ``LocalCluster`` of ``n_jobs`` single-threaded worker processes on 127.0.0.1, no dashboard."""
    import distributed

    _quiet_dask_logs()
    # no dashboard; the scheduler's remaining HTTP routes (health) on a free local port,
    # not on 8787, which another cluster on the machine may hold
    return distributed.LocalCluster(
        n_workers=n_jobs, threads_per_worker=1, processes=True, host="127.0.0.1",
        scheduler_port=0, dashboard_address=None, scheduler_kwargs={"dashboard_address": "127.0.0.1:0"},
        silence_logs=logging.ERROR)


#: local clusters being started ahead of their problem: n_jobs -> Future of the LocalCluster
_EARLY: dict = {}


def start_local_cluster(n_jobs: int) -> None:
    """Start the local cluster of a coming ``DaskEvaluation(…, n_jobs, address=None)`` now, in a background thread.

    A local cluster takes seconds to start (worker processes, their imports); started before the
    simulation, it is ready when the first generation needs it, as loky's pool is
    (:func:`mosd.optim.problem.worker_pool` with ``warm=True``). The next :class:`DaskEvaluation`
    of the same ``n_jobs`` adopts it (and closes it); :func:`discard_local_clusters` closes one that
    no evaluation took (a run that failed before tuning).
    """
    if int(n_jobs) in _EARLY:
        return
    from concurrent.futures import ThreadPoolExecutor

    starter = ThreadPoolExecutor(1, thread_name_prefix="mosd-dask-start")
    _EARLY[int(n_jobs)] = starter.submit(_local_cluster, int(n_jobs))
    starter.shutdown(wait=False)


def discard_local_clusters() -> None:
    """Close the local clusters started ahead (:func:`start_local_cluster`) that no evaluation adopted."""
    while _EARLY:
        _, future = _EARLY.popitem()
        try:
            future.result().close()
        except Exception:  # it failed to start: nothing to close; the evaluation would have said why
            pass


class WorkerLost(RuntimeError):
    """A Dask worker holding the evaluator went away during a run (its process died, the cluster closed)."""


class DaskEvaluation:
    """Evaluate populations of one problem on a Dask cluster; owns the client (and cluster) it starts.

    Parameters
    ----------
    evaluator : callable
        X (P, d) -> F (P, n_obj), picklable (:class:`~mosd.optim.problem.CandidateEvaluator`);
        scattered to every worker once, where an actor keeps it.
    n_jobs : int
        Workers of the local cluster (one thread each); ignored with an address, where
        the cluster's own workers count.
    address : str or None
        A scheduler address to connect to; None starts a ``LocalCluster`` on 127.0.0.1
        (processes, one thread per worker, no dashboard).
    timeout : float
        Seconds to wait for the scheduler at ``address``.

    Notes
    -----
    At the start, the evaluator is scattered to every worker of the cluster and a
    :class:`_ResidentEvaluator` actor is placed on each, holding it. A generation then
    splits the population into one chunk per worker (at most one candidate per
    chunk) and calls every actor once, straight from this client to the worker: one
    round trip per worker per generation, with no task and no scheduler in it (a
    task goes client → scheduler → worker → scheduler → client, with the scheduler's
    bookkeeping at every step). Workers that join the cluster later are not used;
    each worker evaluates one chunk at a time, so a cluster's workers are best
    started with one thread each (``dask worker --nworkers N --nthreads 1``).
    Each candidate's objectives are independent of its chunk, so the split never
    changes the result. A worker that is lost during a generation raises
    :class:`WorkerLost` (it never hangs); an error of the evaluation itself reaches
    the caller as itself. :meth:`close` (called by :meth:`TuningProblem.close`) shuts
    down what this object started: the actors, the client, and the local cluster
    if it started one.
    """

    def __init__(self, evaluator, n_jobs: int, address: str | None = None,
                 timeout: float = CONNECT_TIMEOUT_S):
        try:
            import distributed
        except ImportError:
            raise _missing_distributed() from None
        _quiet_dask_logs()
        self.n_jobs = int(n_jobs)
        self.address = address
        self.cluster = None
        self.client = None
        self._actors: list = []  # (worker address, actor key), one per worker
        self._actor_futures: list = []  # held: releasing them would delete the actors
        # straight to the workers; through the scheduler where this machine reaches only the scheduler
        self.direct = True
        self._answered = False  # whether a generation has been answered yet
        try:
            if address is None:
                # started early (start_local_cluster, while the run simulated), or now
                early = _EARLY.pop(self.n_jobs, None)
                self.cluster = early.result() if early is not None else _local_cluster(self.n_jobs)
                # direct_to_workers: the actors' calls and their answers skip the scheduler
                self.client = distributed.Client(self.cluster, set_as_default=False, direct_to_workers=True)
            else:
                try:
                    self.client = distributed.Client(address, timeout=timeout, set_as_default=False,
                                                     direct_to_workers=True)
                except OSError as exc:
                    raise ConfigError(f"optimizer.dask_address={address!r}: could not connect within "
                                      f"{timeout:g} s ({' '.join(str(exc).split())}); allowed: the address of "
                                      "a running Dask scheduler, or null for a local cluster") from None
            self._place_actors(evaluator)
        except BaseException:
            self.close()
            raise

    def _place_actors(self, evaluator) -> None:
        """Scatter the evaluator to every worker once and start one :class:`_ResidentEvaluator` on each."""
        workers = sorted(self.client.nthreads())
        if not workers:
            raise WorkerLost(f"the Dask cluster at {self.client.scheduler.address} has no workers")
        scattered = self.client.scatter(evaluator, broadcast=True, hash=False)
        self._actor_futures = [
            self.client.submit(_ResidentEvaluator, scattered, actor=True, workers=[worker],
                               allow_other_workers=False, pure=False)
            for worker in workers]
        deadline = time.monotonic() + CONNECT_TIMEOUT_S
        for worker, future in zip(workers, self._actor_futures):
            try:
                # an actor is bound to its worker: one that left meanwhile would leave it waiting for ever
                actor = future.result(timeout=max(0.1, deadline - time.monotonic()))
            except TimeoutError:
                raise WorkerLost(f"the evaluator's actor did not start on Dask worker {worker} within "
                                 f"{CONNECT_TIMEOUT_S:g} s (did the worker leave the cluster?)") from None
            self._actors.append((worker, actor.key))
        # the actors hold the evaluator now; the scattered copy is not needed any more
        del scattered

    def n_chunks(self) -> int:
        """The workers holding an actor: one chunk each (fixed at the start, no scheduler round trip)."""
        return max(1, len(self._actors))

    def evaluate(self, X: np.ndarray) -> np.ndarray:
        """Objectives of every row of X, computed on the cluster's workers, in the order of X."""
        return self.evaluate_timed(X)[0]

    def evaluate_timed(self, X: np.ndarray) -> tuple[np.ndarray, float]:
        """:meth:`evaluate`, and the seconds the workers computed (summed over the chunks)."""
        if self.client is None:
            raise WorkerLost("this Dask evaluation is closed")
        X = np.atleast_2d(X)
        chunks = np.array_split(X, max(1, min(self.n_chunks(), X.shape[0])))
        answers = self.client.sync(self._call_actors, chunks)
        if (self.direct and not self._answered and self.cluster is None
                and all(isinstance(answer, OSError) for answer in answers)):
            # no worker of the cluster at the address answers from here (a private network behind its
            # scheduler): the scheduler relays the calls instead, slower but the same answers
            self.direct = False
            answers = self.client.sync(self._call_actors, chunks)
        parts = []
        for (worker, _), answer in zip(self._actors, answers):
            if isinstance(answer, OSError):  # the connection to the worker broke or was refused
                raise WorkerLost(f"Dask worker {worker} holding the evaluator was lost "
                                 f"({type(answer).__name__}: {' '.join(str(answer).split())[:200]})") from answer
            if isinstance(answer, BaseException):
                raise answer
            if answer.get("status") != "OK":
                raise answer["exception"]
            parts.append(answer["result"])
        self._answered = True
        return np.concatenate([F for F, _ in parts], axis=0), float(sum(seconds for _, seconds in parts))

    async def _call_actors(self, chunks: list) -> list:
        """Every chunk to its worker's actor at once; the answers (or the exceptions raised) in order."""
        import asyncio

        from distributed.protocol import to_serialize

        def call(worker: str, key: str, chunk: np.ndarray):
            # the worker's handler of an actor's method call (what distributed.Actor sends), for every
            # chunk at once on the client's loop, without an ActorFuture and a thread hand-over each
            message = dict(function="evaluate", actor=key, args=[to_serialize(chunk)], kwargs={})
            if self.direct:
                return self.client.rpc(worker).actor_execute(**message)
            return self.client.scheduler.proxy(worker=worker, msg={"op": "actor_execute", **message})

        calls = [call(worker, key, chunk) for (worker, key), chunk in zip(self._actors, chunks)]
        # every call answered before any error is raised: none is left running behind the caller
        return await asyncio.gather(*calls, return_exceptions=True)

    def close(self) -> None:
        """Release the actors, close the client, then the local cluster if this object started it (idempotent)."""
        client, cluster = self.client, self.cluster
        self.client = self.cluster = None
        self._actors, self._actor_futures = [], []
        for owned in (client, cluster):
            if owned is not None:
                try:
                    owned.close()
                except Exception:  # closing after a failure: what matters is that nothing stays up
                    pass
