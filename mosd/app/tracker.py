"""One MLflow run of one experiment: :class:`RunTracker` (created at the start, closed at the end).

The run is created in the side process of :mod:`mosd.app.channel` as soon as the
job starts; the app queues batches (:meth:`RunTracker.log`), hands the text files
to MLflow while the figures are drawn (:meth:`RunTracker.send`) and ends the run
with its status (:meth:`RunTracker.finish`, :meth:`RunTracker.abort`).
"""
from __future__ import annotations

import os
import sys
from dataclasses import asdict
from pathlib import Path
from typing import Iterable, Mapping

from . import channel
from .channel import InProcess
from .mlflow_client import MAX_TAG_LENGTH
from .settings import TrackingSettings
from .store import TrackingError, short_error


class RunTracker:
    """One MLflow run of one experiment, created at :meth:`start`, closed at :meth:`finish`.

    Parameters
    ----------
    settings : TrackingSettings
    run_name : str
    tags : mapping
        Tags set at creation (e.g. the overrides, the git commit).
    parent_run_id : str, optional
        Makes this a child run (a job of a sweep).
    in_process : bool, optional
        Talk to MLflow in this process. Default: only if MLflow is already imported.
    """

    def __init__(self, settings: TrackingSettings, run_name: str, tags: Mapping[str, str] | None = None,
                 parent_run_id: str | None = None, in_process: bool | None = None):
        self.settings = settings
        self.run_name = run_name
        self.tags = dict(tags or {})
        self.parent_run_id = parent_run_id
        self.in_process = "mlflow" in sys.modules if in_process is None else bool(in_process)
        self.run_id: str | None = None
        #: the run's experiment id (after finish): the UI's runs-table address (mosd.app.ui.runs_address)
        self.experiment_id: str | None = None
        #: MLflow import and run-creation seconds, measured where MLflow ran (after finish)
        self.startup_timings: dict[str, float] = {}
        #: what happened to the store on the way in (an unfinished store moved aside), after finish
        self.note: str | None = None
        self._channel = None
        self._queued: list[dict] = []
        #: the logged model's URI, or why it was not logged (after finish; mosd.app.detector_model)
        self.model_uri: str | None = None
        self.model_error: str | None = None
        #: the status the run was ended with (after finish): FAILED, not FINISHED, when a batch was not logged
        self.status: str | None = None

    def start(self) -> "RunTracker":
        """Create the run (in the side process this returns at once)."""
        self._channel = InProcess() if self.in_process else channel.take()
        self._channel.send({"op": "start", "settings": asdict(self.settings), "run_name": self.run_name,
                            "tags": self.tags, "parent_run_id": self.parent_run_id})
        return self

    def log(self, params: Mapping[str, str] | None = None, metrics: Iterable[tuple[str, float, int]] = (),
            tags: Mapping[str, str] | None = None, artifacts: Iterable[str | os.PathLike] = ()) -> None:
        """Queue one batch of params, metrics ``(key, value, step)``, tags and artifact paths."""
        self._queued.append({"op": "log", "params": dict(params or {}),
                             "metrics": [(k, float(v), int(s)) for k, v, s in metrics],
                             "tags": {k: str(v) for k, v in (tags or {}).items()},
                             "artifacts": [str(Path(a).resolve()) for a in artifacts]})

    def log_model(self, state_file: str | os.PathLike) -> None:
        """Queue the fitted pipeline ``state_file`` as the run's pyfunc model ``detector``."""
        self._queued.append({"op": "model", "state": str(Path(state_file).resolve())})

    def send(self) -> None:
        """Send the queued batches now; their replies are read by :meth:`finish`.

        MLflow then works on them (in the side process) while the app goes on;
        a failure is reported by :meth:`finish`, as for batches sent there.
        """
        if self._channel is None:
            raise TrackingError("RunTracker.send called before start")
        for request in self._queued:
            self._channel.send(request)
        self._queued = []

    def finish(self, status: str = "FINISHED", error: str | None = None, timeout: float | None = None) -> str | None:
        """Send the queued batches, end the run with ``status`` and return its id.

        Raises :class:`TrackingError` with MLflow's message if any request failed
        (the run is still ended when it exists: FAILED, tagged ``mosd.logging_error``,
        when a batch was not logged, see :class:`mosd.app.channel.Handler`). With ``timeout``, a side process
        that has not answered by then (still importing MLflow) is left to carry
        out the requests alone, and None is returned.
        """
        if self._channel is None:
            raise TrackingError("RunTracker.finish called before start")
        for request in self._queued:
            self._channel.send(request)
        self._queued = []
        self._channel.send({"op": "end", "status": status, "error": error})
        detached = False
        try:
            replies = self._channel.replies(timeout)
        except TimeoutError:
            detached = True
            return None
        finally:
            self._channel.close(wait=not detached)
            self._channel = None
        if replies and replies[0].get("ok"):
            self.run_id = replies[0]["run_id"]
            self.startup_timings = replies[0].get("timings", {})
            self.note = replies[0].get("note")
            self.experiment_id = replies[0].get("experiment_id")
        self.status = next((r["status"] for r in replies if r.get("status")), None)
        self.model_uri = next((r["model_uri"] for r in replies if r.get("model_uri")), None)
        self.model_error = next((r["model_error"] for r in replies if r.get("model_error")), None)
        failed = [r["error"] for r in replies if not r.get("ok")]
        if failed:  # the store's message, without the SQL statement a database error carries
            raise TrackingError(short_error(failed[0]))
        return self.run_id


    @property
    def open(self) -> bool:
        """True between :meth:`start` and :meth:`finish`."""
        return self._channel is not None

    def abort(self, status: str, error: str, details: str | None = None, timeout: float | None = None) -> str | None:
        """End the run as FAILED/KILLED with the error text; queued batches are dropped.

        ``timeout``: see :meth:`finish` (None returned: the side process ends the run by itself).
        """
        self._queued = []
        if details:
            self.log(tags={"error.traceback": details[-(MAX_TAG_LENGTH - 100):]})
        return self.finish(status, error=error, timeout=timeout)

