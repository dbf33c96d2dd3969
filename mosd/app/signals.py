"""Stop signals: SIGINT, SIGTERM and SIGHUP end a run as KILLED, with exit code 128 + the signal number.

:func:`install_signal_handlers` turns the first stop signal into :class:`Interrupted`, raised in
the main thread; :func:`mosd.app.run.run` then marks the MLflow run KILLED and writes
``"status": "killed"`` to ``summary.json``, and a sweep's parent run (:mod:`mosd.app.sweep`) is
ended KILLED from :data:`RECEIVED`. Later signals change nothing (the cleanup runs to its end).

Where the signal may not raise at once:

* the evaluation workers of a run (loky) are SIGTERMed first (:func:`kill_workers`);
* a process that launches a sweep's jobs into a worker pool (the joblib launcher,
  :func:`jobs_run_in_pool`) passes the signal on to the workers and waits, up to
  :data:`JOB_STOP_WAIT_S`, until each has reported that its run is marked
  (:func:`stop_job_workers`), before it raises. Its teardown then SIGKILLs the workers (joblib's
  abort), as loky does to all of them as soon as one ends: a worker therefore does not end after
  marking its run KILLED, it reports and waits (:func:`end_job_worker`);
* in a job worker between two runs there is nothing to mark: it reports at once; a job that
  starts after the sweep was stopped does not start its run (:func:`sweep_stopped`);
* inside :func:`deferred` (creating the MLflow run) or between :func:`hold` and :func:`release` (a run's
  results, printed but not yet in ``summary.json``) it is raised when the section ends;
* inside numba's unpickling hook, which compiled code calls to box its results and which does
  not expect an exception (one raised there crashes the process with a segmentation fault), it
  is raised again a few milliseconds later, once control is back in ordinary Python code.

The handler takes no lock (a byte on a pipe wakes the retry thread, :func:`_wake_retry`): a second
signal runs it again inside itself, and a lock it held there would never be released.
"""
from __future__ import annotations

import os
import signal
import sys
import threading
import time
from contextlib import contextmanager

#: Signals that stop a run (each gives exit code 128 + its number).
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
#: The stop signals this process received, in order (the first one decides the exit code).
RECEIVED: list[int] = []
#: The worker-pool adapter, never imported here (it loads the optimisers): read from sys.modules. Any loky
#: pool of this process (the evaluation's, the joblib launcher's) starts after preflight has loaded it.
_WORKERS = "mosd.optim.workers"
#: Seconds a sweep's launching process waits for its job workers to mark their runs KILLED.
JOB_STOP_WAIT_S = 30.0
#: Environment variable naming the directory through which a joblib sweep's launching process and its
#: job workers agree on a stop: ``stop`` (written by the launcher: the signal number), ``<pid>`` (a worker done).
STOP_DIR_ENV = "MOSD_SWEEP_STOP_DIR"
#: Seconds before a signal that landed in numba's unpickling hook is raised again.
RETRY_S = 0.005


class Interrupted(KeyboardInterrupt):
    """A stop signal, raised in the main thread by the handler of :func:`install_signal_handlers`."""

    def __init__(self, signum: int):
        super().__init__(name(signum))
        self.signum = int(signum)
        #: set once a one-line message has been printed for it
        self.reported = False


class _State:
    raised = False        # Interrupted has been raised: later signals change nothing
    busy = False          # the first signal's handler is stopping the workers
    deferring = 0         # depth of deferred() sections
    job_pool = False      # this process launches a sweep's jobs into the loky pool
    job_worker = False    # this process is a joblib-launcher worker running mosd jobs
    in_run = False        # ... and one of them is running (it has an MLflow run to mark)
    retry_fd = -1         # write end of the pipe that wakes this process's retry thread (-1: none)
    retry_pid = 0         # the process that owns that thread and pipe (a forked child has neither)


def name(signum: int) -> str:
    """``SIGTERM`` for 15."""
    return signal.Signals(signum).name


def _signal_pool(pids, signum: int) -> None:
    for pid in pids:
        try:
            os.kill(pid, signum)
        except (ProcessLookupError, PermissionError):
            pass


def kill_workers() -> int:
    """SIGTERM the evaluation pool's workers (loky), without taking any lock; the number signalled.

    Called from a signal handler: the executor's own ``shutdown`` takes locks the
    interrupted main thread may hold. An evaluation worker dies at once (default
    action); :func:`shutdown_workers` SIGKILLs whatever is left; loky's resource
    tracker exits by itself once its clients are gone.
    """
    workers = sys.modules.get(_WORKERS)
    pids = workers.pool_pids() if workers is not None else []
    _signal_pool(pids, signal.SIGTERM)
    return len(pids)


def stop_job_workers(signum: int, wait_s: float = JOB_STOP_WAIT_S) -> list[int]:
    """Pass ``signum`` on to the job workers and wait until each has marked its run; the pids not done.

    Writes ``stop`` (the signal number) to the stop directory first, so that a
    job starting meanwhile does not start its run. The signal is passed on as
    received (a Ctrl-C stays SIGINT in the jobs' summaries). A worker is done
    when it has written ``<pid>`` there (:func:`end_job_worker`) or has ended.
    Lock-free, like :func:`kill_workers`: it polls the workers' state in ``/proc``
    (:func:`mosd.optim.workers.pool_alive`) and the stop directory only.
    """
    stop_dir = os.environ.get(STOP_DIR_ENV)
    if stop_dir:
        try:
            with open(os.path.join(stop_dir, "stop"), "w") as out:
                out.write(str(int(signum)))
        except OSError:
            stop_dir = None
    workers = sys.modules.get(_WORKERS)
    alive = workers.pool_pids() if workers is not None else []
    _signal_pool(alive, signum)
    deadline = time.monotonic() + wait_s
    while alive and time.monotonic() < deadline:
        time.sleep(0.05)
        alive = [pid for pid in workers.pool_alive(alive)
                 if not (stop_dir and os.path.exists(os.path.join(stop_dir, str(pid))))]
    return sorted(alive)


def shutdown_workers() -> None:
    """Shut the process pool down and reap its workers (after :func:`kill_workers`)."""
    workers = sys.modules.get(_WORKERS)
    if workers is not None:
        workers.shutdown_pool()


def _in_compiled_callback(frame) -> bool:
    """True inside numba's unpickling hook, which compiled code calls and which must not raise.

    Compiled code that returns an array calls back into numba's ``numba.core.serialize`` module to box it; an
    exception raised there crashes the process (issue 22). Any frame of that module's file counts (found by the
    module's public ``__file__`` and each frame's public ``f_code.co_filename``, not by the hook's private name):
    a signal that lands in the module's other code, pickling a kernel for the cache, waits a few milliseconds too.
    """
    serialize = sys.modules.get("numba.core.serialize")
    where = getattr(serialize, "__file__", None)
    while where is not None and frame is not None:
        if frame.f_code.co_filename == where:
            return True
        frame = frame.f_back
    return False


def _retry_loop(wake_fd: int) -> None:
    import _thread

    while True:
        try:
            if not os.read(wake_fd, 512):  # every wake-up written so far
                return
        except OSError:
            return
        time.sleep(RETRY_S)
        if RECEIVED and not _State.raised:
            _thread.interrupt_main(RECEIVED[0])  # runs the handler again, in the main thread


def _wake_retry() -> None:
    """Wake the retry thread with a byte on its pipe: a system call, no lock.

    The handler may run again inside itself (a second stop signal: a process group's Ctrl-C and the
    launcher passing it on arrive together), and a lock such as ``threading.Event``'s is not reentrant:
    the handler that woke the thread through ``Event.set`` and ran again inside ``Event.set`` waited for
    the lock it held, for ever (the joblib sweep's job worker that never marked its run).
    """
    if _State.retry_pid != os.getpid():
        return
    try:
        os.write(_State.retry_fd, b"\0")
    except OSError:  # a full pipe (wake-ups pending already) or a closed one
        pass


def _on_signal(signum, frame):
    if _State.busy or _State.raised:
        return  # the stop is on its way: the cleanup must not be cut short
    if not RECEIVED:
        RECEIVED.append(int(signum))
        _State.busy = True
        try:
            if _State.job_pool:
                stop_job_workers(signum)
            else:
                kill_workers()
        finally:
            _State.busy = False
    first = RECEIVED[0]
    if _State.job_worker and not _State.in_run:
        end_job_worker(first)  # between two jobs: no run of this worker to mark
    if _State.deferring:
        return  # raised when the section ends
    if _in_compiled_callback(frame):
        _wake_retry()
        return
    _State.raised = True
    raise Interrupted(first)


def install_signal_handlers(job_worker: bool = False) -> None:
    """SIGINT/SIGTERM/SIGHUP raise :class:`Interrupted` in the main thread (no-op elsewhere).

    ``job_worker``: this process is a joblib-launcher worker and a job's run starts
    now (:func:`run_ended` when it is complete); a stopped run ends the worker.
    """
    if threading.current_thread() is not threading.main_thread():
        return
    if _State.retry_pid != os.getpid():  # once per process (a forked child has no such thread)
        wake_fd, _State.retry_fd = os.pipe()
        os.set_blocking(_State.retry_fd, False)
        _State.retry_pid = os.getpid()
        threading.Thread(target=_retry_loop, args=(wake_fd,), name="mosd-signal-retry", daemon=True).start()
    if job_worker:
        _State.job_worker = _State.in_run = True
    for sig in STOP_SIGNALS:
        current = signal.getsignal(sig)
        if current is _on_signal:
            continue
        if current is not signal.SIG_IGN or sig == signal.SIGINT:
            signal.signal(sig, _on_signal)


def run_ended() -> None:
    """The job's run is complete: a stop signal now ends a job worker without touching it."""
    _State.in_run = False


def jobs_run_in_pool() -> None:
    """This process launches a sweep's jobs into the loky pool (the joblib launcher): see :func:`stop_job_workers`.

    Creates the stop directory (removed at exit) and names it in the environment the workers inherit.
    """
    import atexit
    import shutil
    import tempfile

    if _State.job_pool:
        return
    _State.job_pool = True
    stop_dir = tempfile.mkdtemp(prefix="mosd-sweep-stop-")
    os.environ[STOP_DIR_ENV] = stop_dir
    atexit.register(shutil.rmtree, stop_dir, True)


def sweep_stopped() -> int | None:
    """In a joblib sweep's job worker: the signal number that stopped the sweep, else None."""
    stop_dir = os.environ.get(STOP_DIR_ENV)
    try:
        with open(os.path.join(stop_dir, "stop")) as stop:
            return int(stop.read().strip() or signal.SIGTERM)
    except (TypeError, OSError, ValueError):
        return None


def end_job_worker(signum: int) -> None:
    """Report to the launching process that this worker's run is marked, wait to be ended, exit 128 + ``signum``.

    Ending at once would make loky kill the other workers, which may still be
    marking their runs. The launcher's teardown ends this process; should the
    launcher die first, the worker ends by itself when it sees it gone.
    """
    import logging

    logging.shutdown()  # the job's log file
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError, RuntimeError):  # RuntimeError: the signal interrupted a write to that stream
            pass
    stop_dir = os.environ.get(STOP_DIR_ENV)
    if stop_dir:
        launcher = os.getppid()
        try:
            open(os.path.join(stop_dir, str(os.getpid())), "w").close()
        except OSError:
            pass
        else:
            deadline = time.monotonic() + JOB_STOP_WAIT_S + 10
            while os.getppid() == launcher and time.monotonic() < deadline:
                time.sleep(0.1)
    os._exit(128 + int(signum))


@contextmanager
def deferred():
    """A section a stop signal must not cut (creating the MLflow run): it is raised when the section ends."""
    hold()
    try:
        yield
    finally:
        release(raise_now=False)
    raise_pending()


def hold() -> None:
    """Begin a section a stop signal must not cut that ends elsewhere than it begins (:func:`release`).

    For a section that ends inside a callback: a run's results, from the moment they are
    printed until ``summary.json`` holds them (:func:`mosd.app.run.run`).
    """
    _State.deferring += 1


def release(raise_now: bool = True) -> None:
    """End a :func:`hold` section; ``raise_now``: raise a stop signal that arrived meanwhile."""
    _State.deferring = max(_State.deferring - 1, 0)
    if raise_now:
        raise_pending()


def raise_pending() -> None:
    """Raise a stop signal that arrived in a :func:`deferred` section which then ended with an exception."""
    if RECEIVED and not _State.raised and not _State.deferring:
        _State.raised = True
        raise Interrupted(RECEIVED[0])


def _ignore(signum, frame):
    pass


def ignore_stop_signals() -> None:
    """Ignore the stop signals from now on (the work is over: a late one must not raise in the teardown).

    A Python handler that does nothing rather than ``SIG_IGN``: a signal already
    received but not yet handled would otherwise raise ``OSError: Signal N ignored
    due to race condition`` wherever the main thread is.
    """
    for sig in STOP_SIGNALS:
        if signal.getsignal(sig) is not signal.SIG_IGN:
            signal.signal(sig, _ignore)
