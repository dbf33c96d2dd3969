"""The channel between a run and MLflow: a side process that holds the MLflow client, or the same in-process.

A background *thread* does not hide MLflow's import (it competes for the GIL
with the simulation), so a run talks to MLflow through a small side process
(:class:`SideProcess`, ``python -c '...channel._serve()'``): started when the
run starts (before the command line is checked when the machine has a core to
spare: :func:`start_early`), it imports MLflow and creates the run on the second
core while the first one checks or simulates, and at the end receives everything
in a few batched requests. When MLflow is already imported (a sweep under the basic launcher,
whose callback imported it) the same requests run in this process
(:class:`InProcess`). Requests and replies are JSON lines; :class:`Handler`
executes them with :class:`mosd.app.mlflow_client.MlflowStore`.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from .config import described
from .mlflow_client import HTTP_ENV_DEFAULTS, LOGGING_ERROR_TAG, MlflowStore
from .settings import TrackingSettings
from .store import TrackingError


class Handler:
    """Executes tracking requests (in the side process or in-process).

    A run whose params, metrics or artifacts were not all logged (a ``log``
    request failed: the artifact store full, the server gone) is not ended
    FINISHED whatever the app asks: it is ended FAILED with the tag
    ``mosd.logging_error``, and ``python -m mosd log RUN_DIR`` completes it
    (:mod:`mosd.app.pending`).
    """

    def __init__(self):
        self.store: MlflowStore | None = None
        self.run_id: str | None = None
        self.run_dir: str = "RUN_DIR"
        self.timings: dict[str, float] = {}
        #: the first failed ``log`` request's error
        self.logging_error: str | None = None
        #: seconds MLflow's import took before the first request (the side process imports it at once)
        self.imported_s = 0.0

    def __call__(self, request: dict) -> dict:
        op = request["op"]
        if op == "start":
            t0 = time.perf_counter()
            self.store = MlflowStore(TrackingSettings(**request["settings"]))
            t1 = time.perf_counter()
            self.run_id = self.store.create_run(request["run_name"], request["tags"], request.get("parent_run_id"))
            self.run_dir = request["tags"].get("mosd.run_dir", self.run_dir)
            self.timings = {"mlflow_import_s": self.imported_s + t1 - t0,
                            "mlflow_create_run_s": time.perf_counter() - t1}
            return {"run_id": self.run_id, "timings": self.timings, "note": self.store.note,
                    "experiment_id": self.store.experiment_id()}
        if self.store is None or self.run_id is None:
            raise TrackingError("the MLflow run was not created")
        if op == "log":
            # how long MLflow took to start, measured where it ran (overlapping the experiment)
            metrics = [*request.get("metrics", ()), *((k, v, 0) for k, v in self.timings.items())]
            self.timings = {}
            try:
                self.store.log(self.run_id, request.get("params"), metrics, request.get("tags"),
                               request.get("artifacts", ()))
            except Exception as exc:
                self.logging_error = self.logging_error or described(exc)
                raise
            return {}
        if op == "model":  # the fitted pipeline as the run's pyfunc model (mosd.app.detector_model)
            from .detector_model import log_model

            try:
                return {"model_uri": log_model(request["state"], self.store.settings.uri, self.run_id)}
            except Exception as exc:  # the run itself is complete: reported, not fatal
                return {"model_error": described(exc)}
        if op == "end":
            status, error = request["status"], request.get("error")
            if self.logging_error is not None:
                hint = f"python -m mosd log {self.run_dir} completes this run"
                if status == "FINISHED":
                    status, error = "FAILED", f"not all logged ({self.logging_error}); {hint}"
                try:
                    self.store.log(self.run_id, tags={LOGGING_ERROR_TAG: f"{self.logging_error}; {hint}"})
                except Exception:  # the store is failing: ending the run comes first
                    pass
            self.store.end(self.run_id, status, error)
            self.store = None
            return {"status": status}
        raise TrackingError(f"unknown tracking request {op!r}")


def _warm_model_logging() -> None:
    try:
        from .detector_model import warm_up

        warm_up()
    except Exception:  # only a warm-up: the model request reports its own errors
        pass


def _serve() -> None:
    """Side-process main loop: JSON requests on stdin, one JSON reply per line on stdout."""
    import signal

    # the app decides how the run ends (KILLED on a signal) and closes stdin; a signal
    # meant for the app must not end this process first and leave the run RUNNING
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    signal.signal(signal.SIGHUP, signal.SIG_IGN)  # a stop signal of the app's too (mosd.app.signals.STOP_SIGNALS)
    replies = os.fdopen(os.dup(1), "w", buffering=1)
    os.dup2(2, 1)  # anything MLflow prints must not corrupt the reply channel
    handler = Handler()
    # MLflow now, before the first request: a process started ahead of its run (start_early) imports it
    # on the core that checking the command leaves idle; the import counts in the run's mlflow_import_s
    t0 = time.perf_counter()
    try:
        import mlflow.tracking  # noqa: F401
    except Exception:  # the start request reports it (MlflowStore imports it again), as it always did
        pass
    handler.imported_s = time.perf_counter() - t0
    for line in sys.stdin:
        if not line.strip():
            continue
        request = json.loads(line)
        try:
            reply = {"ok": True, **handler(request)}
        except Exception as exc:  # reported to the app, which decides
            reply = {"ok": False, "error": described(exc)}
        try:
            replies.write(json.dumps(reply) + "\n")
            if request.get("op") == "start":
                # this process idles until the run's end: import what logging a model needs meanwhile
                # (~0.8 s: mlflow.pyfunc, signatures) rather than on the run's critical path
                import threading

                threading.Thread(target=_warm_model_logging, daemon=True).start()
            if request.get("op") == "end":
                replies.flush()
        except OSError:
            pass  # the app stopped waiting (a signal): finish its requests all the same
        if request.get("op") == "end":
            # every call above has committed; skip the interpreter teardown with MLflow
            # loaded (~1 s), which the app would otherwise wait for
            os._exit(0)
    # stdin closed before "end": the app died; do not leave the run RUNNING
    if handler.store is not None and handler.run_id is not None:
        handler.store.end(handler.run_id, "FAILED", "the mosd process ended before the run finished")


class SideProcess:
    """Requests go to ``python -c 'mosd.app.channel._serve()'``; replies are read lazily."""

    def __init__(self):
        package_parent = str(Path(__file__).resolve().parents[2])  # the directory holding mosd/
        self._stderr = tempfile.TemporaryFile(mode="w+")
        self._proc = subprocess.Popen(
            [sys.executable, "-c", "import sys; sys.path.insert(0, sys.argv[1]); "
             "from mosd.app.channel import _serve; _serve()", package_parent],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=self._stderr, text=True, bufsize=1,
            # its own session: Ctrl-C or SIGTERM to the app's process group does not reach it
            start_new_session=True, env={**HTTP_ENV_DEFAULTS, **os.environ},
        )
        self._pending = 0

    def send(self, request: dict) -> None:
        try:
            self._proc.stdin.write(json.dumps(request) + "\n")
            self._proc.stdin.flush()
        except BrokenPipeError:
            raise TrackingError(f"the tracking process ended: {self._stderr_tail()}") from None
        self._pending += 1

    def replies(self, timeout: float | None = None) -> list[dict]:
        """Wait for the replies to every request sent so far (at most ``timeout`` s, else TimeoutError)."""
        import select

        deadline = None if timeout is None else time.monotonic() + timeout
        out = []
        while self._pending:
            if deadline is not None:
                ready, _, _ = select.select([self._proc.stdout], [], [], max(deadline - time.monotonic(), 0.0))
                if not ready:
                    raise TimeoutError(f"no answer from the tracking process within {timeout:g} s")
            line = self._proc.stdout.readline()
            if not line:
                raise TrackingError(f"the tracking process ended: {self._stderr_tail()}")
            out.append(json.loads(line))
            self._pending -= 1
        return out

    def close(self, wait: bool = True) -> None:
        """Close the request channel; ``wait=False`` leaves the process to finish its requests alone."""
        if self._proc.stdin and not self._proc.stdin.closed:
            try:
                self._proc.stdin.close()
            except OSError:
                pass
        if not wait:
            self._proc.returncode = 0  # detached on purpose: no "still running" warning at exit
            return
        try:
            self._proc.wait(timeout=60)
        except subprocess.TimeoutExpired:
            self._proc.kill()
        self._stderr.close()

    def kill(self) -> None:
        """End the process now (one started ahead of a run that does not use it: nothing sent yet)."""
        if self._proc.poll() is None:
            self._proc.kill()
            self._proc.wait()
        self._stderr.close()

    def _stderr_tail(self) -> str:
        self._stderr.seek(0)
        lines = [ln.strip() for ln in self._stderr.read().splitlines() if ln.strip()]
        return lines[-1] if lines else f"exit code {self._proc.poll()}"


class InProcess:
    """Same interface as :class:`SideProcess`, executing at once."""

    def __init__(self):
        self._handler = Handler()
        self._replies: list[dict] = []

    def send(self, request: dict) -> None:
        try:
            self._replies.append({"ok": True, **self._handler(request)})
        except Exception as exc:
            self._replies.append({"ok": False, "error": described(exc)})

    def replies(self, timeout: float | None = None) -> list[dict]:
        out, self._replies = self._replies, []
        return out

    def close(self, wait: bool = True) -> None:
        pass


# ------------------------------------------------------------------------------------
# a single run's tracking process, started before the command line is checked
# ------------------------------------------------------------------------------------
_EARLY: list[SideProcess] = []


def start_early() -> None:
    """Start the tracking side process now, for the run this process is about to check and start.

    MLflow's import (1.5–3.5 s of Python) then runs on the core that checking the
    command line leaves idle, not beside the run's simulation and optimiser threads.
    :class:`mosd.app.tracker.RunTracker` takes it (:func:`take`); :func:`discard`
    ends one no run took (tracking disabled by the configuration, an error, a sweep).
    """
    discard()
    _EARLY.append(SideProcess())


def take() -> SideProcess:
    """The side process :func:`start_early` started (once), else a new one."""
    return _EARLY.pop() if _EARLY else SideProcess()


def early_pids() -> list[int]:
    """The process id of the tracking process :func:`start_early` started, while no run has taken it."""
    return [side._proc.pid for side in _EARLY if getattr(side, "_proc", None) is not None]


def discard() -> None:
    """Kill the side process :func:`start_early` started, if no run took it (it holds no run yet)."""
    while _EARLY:
        _EARLY.pop().kill()
