"""The evaluation workers: their process pool and their thread pinning.

Public interfaces only (issue 50 item 4); ``tests/test_compat.py`` checks each against the installed versions:

* :func:`memmapping_executor` — ``joblib.executor.get_memmapping_executor``: joblib's memmapping flavour of
  loky's reusable executor, the one ``joblib.Parallel``'s loky backend itself asks for. A public module of
  joblib (no private name), though not on its documentation's pages; kept because the reusable executor is one
  slot per process that ``joblib.Parallel`` (the optimiser benchmarks, Hydra's joblib launcher) reuses or
  replaces: a plain loky executor (``joblib.externals.loky.get_reusable_executor``) there makes a later
  ``Parallel`` fail (it lacks joblib's temporary-folder manager), and a pool of our own
  (``concurrent.futures.ProcessPoolExecutor``) would be a second set of workers beside joblib's.
* :func:`pool_pids`, :func:`pool_alive` — the loky workers of this process, found among its child processes
  (``psutil``: read from ``/proc``, no lock shared with the main thread, so callable from a signal handler,
  where the executor's own ``shutdown`` would take locks the interrupted main thread may hold; no joblib
  import). A loky worker is a child process started as ``python -m joblib.externals.loky...`` (its command
  line; loky's resource tracker is started with ``-c`` and is not one). Before: loky's module global
  ``_executor`` and its ``_processes``.
* :func:`shutdown_pool` — the executor's public ``shutdown(wait=True, kill_workers=True)`` for the pool this
  module handed out, then SIGKILL for any loky worker left (a pool ``joblib.Parallel`` started).
* :func:`start_resource_trackers` — loky's ``backend.resource_tracker.ensure_running``
  and the standard library's ``multiprocessing.resource_tracker.ensure_running``.
"""
from __future__ import annotations

import os
import sys

#: The package whose workers are the pool's: a child process runs one of its modules (``-m``).
_LOKY_PACKAGE = "joblib.externals.loky"
_PINNED: dict = {}
#: the executor :func:`memmapping_executor` last handed out (joblib's reusable one: the same object when reused)
_POOL: dict = {}


#: the environment variables that size BLAS/OpenMP/numba pools in processes started from here
THREAD_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "BLIS_NUM_THREADS",
                    "NUMBA_NUM_THREADS", "MOSD_KERNEL_THREADS")


def pin_threads(n_threads: int = 1, numba_pool: bool = False) -> None:
    """Limit this process's thread pools to ``n_threads``: BLAS/OpenMP, numba and mosd's own kernels.

    An evaluation worker takes the default, one: n_jobs workers on n_jobs cores must not each start
    a core's worth of threads. A job of a parallel sweep takes its share of the cores
    (:func:`pin_sweep_job`). Pools already loaded are limited now (``threadpoolctl``,
    ``numba.set_num_threads``, :func:`mosd.kernels.set_threads`); the environment variables are set
    too, for the processes this one starts. Results do not depend on the thread count.

    ``numba_pool=True`` also sizes numba's own pool now, which starts its threading layer (an
    OpenMP runtime: 0.1-0.2 s): a sweep job takes that once, an evaluation worker does not
    (mosd's kernels do not use numba's parallel loops; a numba imported later reads
    ``NUMBA_NUM_THREADS``).
    """
    n_threads = max(1, int(n_threads))
    if _PINNED.get("threads") == n_threads:
        return
    for name in THREAD_VARIABLES:
        os.environ[name] = str(n_threads)
    numba = sys.modules.get("numba")
    if numba is not None and numba_pool:  # not imported yet: NUMBA_NUM_THREADS above sizes its pool when it is
        try:
            numba.set_num_threads(min(n_threads, numba.config.NUMBA_NUM_THREADS))
        except (ValueError, RuntimeError):  # a threading layer that cannot start: nothing runs in parallel anyway
            pass
    # after numba: its threading layer (an OpenMP runtime) loads when its threads are first set
    try:
        from threadpoolctl import threadpool_limits

        threadpool_limits(limits=n_threads)
    except ImportError:  # pragma: no cover - threadpoolctl comes with joblib's dependencies (scikit-learn) or not
        pass
    from .. import kernels

    kernels.set_threads(n_threads)
    _PINNED["threads"] = n_threads


def pinned_threads() -> int | None:
    """The thread count :func:`pin_threads` set in this process, or None if it was not called."""
    return _PINNED.get("threads")


def sweep_share(launcher_n_jobs: int | None, cpus: int | None = None) -> int:
    """The cores of one job of a sweep whose launcher runs ``launcher_n_jobs`` jobs at once (joblib's convention).

    ``None`` or 0 means one job at a time; negative counts are joblib's ``cpus + 1 + n_jobs``
    (-1: one job per CPU).
    """
    cpus = cpus or available_cpus()
    parallel = int(launcher_n_jobs or 1)
    if parallel < 0:
        parallel = max(1, cpus + 1 + parallel)
    return max(1, cpus // parallel)


def available_cpus() -> int:
    """The CPUs this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not on Linux
        return os.cpu_count() or 1


def pin_sweep_job(launcher_n_jobs: int | None) -> int:
    """Pin this sweep job's thread pools to its share of the cores (:func:`sweep_share`); return the share.

    Without it, each of k jobs running at once starts a core's worth of BLAS, OpenMP and numba
    threads: k × cores threads on the cores, and each job runs several times slower beside the
    others than alone (issue 32's measurement: 2.8×).
    """
    share = sweep_share(launcher_n_jobs)
    pin_threads(share, numba_pool=True)
    return share


def ignore_interrupt() -> None:
    """A worker's initializer: SIGINT is ignored (a Ctrl-C reaches the whole process group).

    The run's own handler stops the workers with SIGTERM (:func:`mosd.app.signals.kill_workers`); a
    KeyboardInterrupt in each worker would print a traceback that the SIGTERM cuts off half-way.
    """
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)


def memmapping_executor(n_workers: int, timeout: float):
    """joblib's reusable memmapping executor with ``n_workers`` processes (started or resized on first use);
    its workers ignore SIGINT (:func:`ignore_interrupt`)."""
    from joblib.executor import get_memmapping_executor

    start_resource_trackers()
    executor = get_memmapping_executor(n_workers, timeout=timeout, initializer=ignore_interrupt)
    _POOL["executor"] = executor
    return executor


def start_resource_trackers() -> None:
    """Start loky's and multiprocessing's resource trackers (if not running) with SIGHUP blocked in them.

    They ignore SIGINT and SIGTERM by themselves, but SIGHUP to the process group
    (a closed terminal, ``kill -HUP -PGID``) killed them: loky then relaunched one,
    which printed a KeyError traceback for each pool resource it had never seen.
    A blocked signal mask is inherited through fork and exec; this process's own
    mask is restored at once (a SIGHUP meanwhile is delivered then).
    """
    import signal
    from multiprocessing import resource_tracker as stdlib_tracker

    from joblib.externals.loky.backend import resource_tracker as loky_tracker

    blocked = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGHUP})
    try:
        loky_tracker.ensure_running()
        stdlib_tracker.ensure_running()
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, blocked)


def _is_loky_worker(cmdline: list[str]) -> bool:
    """Whether a process's command line is a loky worker's (``python -m joblib.externals.loky.…``)."""
    return any(flag == "-m" and module.startswith(_LOKY_PACKAGE + ".")
               for flag, module in zip(cmdline, cmdline[1:]))


def pool_pids() -> list[int]:
    """The process ids of this process's loky workers (empty when joblib was never loaded). Lock-free."""
    if _LOKY_PACKAGE not in sys.modules:
        return []
    import psutil

    found = []
    try:
        children = psutil.Process().children()
    except psutil.Error:  # pragma: no cover - this process can always read its own children
        return []
    for child in children:
        try:
            if _is_loky_worker(child.cmdline()) and child.status() != psutil.STATUS_ZOMBIE:
                found.append(child.pid)
        except psutil.Error:  # it ended meanwhile
            pass
    return sorted(found)


def pool_alive(pids) -> list[int]:
    """Those of ``pids`` still running (not ended, not a zombie waiting to be reaped). Lock-free."""
    import psutil

    alive = []
    for pid in pids:
        try:
            if psutil.Process(pid).status() != psutil.STATUS_ZOMBIE:
                alive.append(pid)
        except psutil.Error:
            pass
    return alive


def shutdown_pool() -> None:
    """Shut the worker pool down and end its workers, if there is one (a broken pool is expected)."""
    executor = _POOL.pop("executor", None)
    if executor is not None:
        try:
            executor.shutdown(wait=True, kill_workers=True)
        except Exception:  # a broken pool is what a signal leaves behind
            pass
    import psutil

    killed = []
    for pid in pool_pids():  # a pool joblib.Parallel started (Hydra's joblib launcher): idle workers, killed
        try:
            worker = psutil.Process(pid)
            worker.kill()
            killed.append(worker)
        except psutil.Error:  # it ended meanwhile
            pass
    # a SIGKILL is delivered asynchronously: wait until they are gone (a loaded machine took longer than the
    # caller's next look at its children), a few seconds at most
    psutil.wait_procs(killed, timeout=5)
