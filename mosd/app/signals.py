"""Stop signals: SIGINT, SIGTERM and SIGHUP end a run as KILLED, with exit code 128 + the signal number.

:func:`install_signal_handlers` turns a stop signal into :class:`Interrupted` in the
main thread at once, after killing the evaluation workers
(:func:`kill_workers`); :func:`mosd.app.run.run` then marks the MLflow run KILLED
and writes ``"status": "killed"`` to ``summary.json``, and a sweep's parent run
(:mod:`mosd.app.sweep`) is ended KILLED from :data:`RECEIVED`.
"""
from __future__ import annotations

import os
import signal
import sys
import threading

#: Signals that stop a run (each gives exit code 128 + its number).
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
#: The stop signals this process received, in order (the sweep's parent run is then ended KILLED).
RECEIVED: list[int] = []
#: The worker-pool adapter, never imported here (it loads the optimisers): read from sys.modules. Any loky
#: pool of this process (the evaluation's, the joblib launcher's) starts after preflight has loaded it.
_WORKERS = "mosd.optim.workers"


class Interrupted(KeyboardInterrupt):
    """A stop signal, raised in the main thread by the handler of :func:`install_signal_handlers`."""

    def __init__(self, signum: int):
        super().__init__(name(signum))
        self.signum = int(signum)
        #: set once a one-line message has been printed for it
        self.reported = False


def name(signum: int) -> str:
    """``SIGTERM`` for 15."""
    return signal.Signals(signum).name


def kill_workers() -> int:
    """SIGTERM the process pool's workers (loky), without taking any lock.

    Called from a signal handler: the executor's own ``shutdown`` takes locks the
    interrupted main thread may hold. An evaluation worker dies at once (default
    action); a job of the joblib launcher runs :func:`mosd.app.run.run`, whose
    handler marks its own run KILLED first. :func:`shutdown_workers` SIGKILLs
    whatever is left; loky's resource tracker exits by itself once its clients are gone.
    """
    workers = sys.modules.get(_WORKERS)
    killed = 0
    for pid in workers.pool_pids() if workers is not None else ():
        try:
            os.kill(pid, signal.SIGTERM)
            killed += 1
        except (ProcessLookupError, PermissionError):
            pass
    return killed


def shutdown_workers() -> None:
    """Shut the evaluation pool down and reap its workers (after :func:`kill_workers`)."""
    workers = sys.modules.get(_WORKERS)
    if workers is not None:
        workers.shutdown_pool()


def _on_signal(signum, frame):
    # cleanup (marking the run KILLED, writing the status) must not be cut short by a second signal
    for sig in STOP_SIGNALS:
        signal.signal(sig, signal.SIG_IGN)
    RECEIVED.append(int(signum))
    kill_workers()
    raise Interrupted(signum)


def install_signal_handlers() -> None:
    """SIGINT/SIGTERM/SIGHUP raise :class:`Interrupted` in the main thread (no-op elsewhere)."""
    if threading.current_thread() is not threading.main_thread():
        return
    for sig in STOP_SIGNALS:
        if signal.getsignal(sig) is not signal.SIG_IGN or sig == signal.SIGINT:
            signal.signal(sig, _on_signal)


def ignore_stop_signals() -> None:
    """Ignore the stop signals from now on (the work is over: a late one must not raise in the teardown)."""
    for sig in STOP_SIGNALS:
        signal.signal(sig, signal.SIG_IGN)
