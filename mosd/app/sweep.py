"""A sweep in MLflow: one parent run per multirun, the jobs attach as children.

:class:`SweepCallback` (a Hydra callback, named in ``conf/config.yaml``) creates
the parent run in the launching process before any job starts; jobs find the
parent run id in a file in the sweep directory (or an environment variable,
:func:`parent_run_id`) and attach as children.
"""
from __future__ import annotations

import atexit
import contextlib
import json
import os
from pathlib import Path

from hydra.experimental.callback import Callback

from . import signals
from .mlflow_client import MlflowStore, git_commit
from .settings import TrackingSettings

#: File in a sweep directory that carries the parent run id to the jobs.
PARENT_RUN_FILE = "mlflow_parent_run_id.txt"
#: Environment variable that carries the parent run id to jobs (same process tree).
PARENT_RUN_ENV = "MOSD_MLFLOW_PARENT_RUN_ID"


def parent_run_id(sweep_dir: str | os.PathLike | None) -> str | None:
    """The sweep's parent run id for a job: from the sweep directory, else the environment."""
    if sweep_dir is not None:
        path = Path(sweep_dir) / PARENT_RUN_FILE
        if path.is_file():
            return path.read_text().strip() or None
    return os.environ.get(PARENT_RUN_ENV) or None


def record_job_outcomes(sweep_dir: str | os.PathLike) -> bool:
    """Note the sweep's jobs that could not write their run directory, or whose run MLflow did not take.

    They join :data:`mosd.app.files.NOT_WRITTEN` and :data:`mosd.app.pending.NOT_LOGGED`,
    which give the command's exit code: a job of the joblib launcher runs in
    another process, and its ``summary.json`` is what this process learns of
    it. Returns True if a job could not write its run directory.
    """
    from .files import NOT_WRITTEN
    from .pending import NOT_LOGGED

    not_written = False
    for path in sorted(Path(sweep_dir).resolve().glob("*/summary.json")):
        try:
            summary = json.loads(path.read_text())
        except (OSError, ValueError):
            continue
        job = path.parent
        if summary.get("status") == "failed" and "missing" in summary:
            not_written = True
            if job not in {d.resolve() for d in NOT_WRITTEN}:
                NOT_WRITTEN.append(job)
        if (summary.get("tracking") or {}).get("logged") is False and job not in {d.resolve() for d in NOT_LOGGED}:
            NOT_LOGGED.append(job)
    return not_written


#: the warnings filter the resource trackers start with: their "leaked semaphore/folder objects" warnings
TRACKER_WARNINGS = "ignore:resource_tracker:UserWarning"


@contextlib.contextmanager
def quiet_resource_trackers():
    """Resource trackers started in this section do not warn about the objects they clean up.

    A stopped joblib sweep ends its job workers with SIGKILL (joblib's abort), so the semaphores they
    registered are left to the trackers, which unlink them at exit and say so on stderr ("There appear
    to be 1 leaked semaphore objects to clean up at shutdown"): nothing a user can act on, the cleanup
    is done. The trackers are separate interpreters started with this process's environment, so the
    filter goes in through ``PYTHONWARNINGS`` while they start, and this process's value is restored.
    """
    before = os.environ.get("PYTHONWARNINGS")
    os.environ["PYTHONWARNINGS"] = ",".join(w for w in (before, TRACKER_WARNINGS) if w)
    try:
        yield
    finally:
        if before is None:
            os.environ.pop("PYTHONWARNINGS", None)
        else:
            os.environ["PYTHONWARNINGS"] = before


def under_joblib_launcher(hydra_cfg) -> bool:
    """True when ``hydra_cfg`` (the ``hydra`` section) names the joblib launcher: its jobs run in loky workers."""
    return "joblib" in str(hydra_cfg.launcher.get("_target_", "")).lower()


class SweepCallback(Callback):
    """Hydra callback: one MLflow parent run per multirun, the jobs attach as children.

    ``on_multirun_start`` runs in the launching process before any job: it creates
    the store (a fresh sqlite DB is created here, once), the experiment and the
    parent run, and writes the parent id to ``<sweep dir>/mlflow_parent_run_id.txt``
    and ``$MOSD_MLFLOW_PARENT_RUN_ID``. ``on_multirun_end`` ends the parent run.
    Hydra skips ``on_multirun_end`` when a job raised, so the parent is also ended
    (FAILED) at interpreter exit if it is still open.
    """

    def __init__(self):
        self._store: MlflowStore | None = None
        self._run_id: str | None = None

    def on_multirun_start(self, config, **kwargs) -> None:
        if under_joblib_launcher(config.hydra):
            from ..optim.workers import start_resource_trackers

            # a stop signal must reach the jobs in the launcher's workers before the launcher kills them
            signals.jobs_run_in_pool()
            with quiet_resource_trackers():
                start_resource_trackers()
        settings = TrackingSettings.from_config(dict(config.tracking), config.outputs_root)
        if settings is None:
            return
        sweep_dir = Path(str(config.hydra.sweep.dir))
        sweep_dir.mkdir(parents=True, exist_ok=True)
        tags = {"mosd.role": "sweep", "mosd.overrides": " ".join(config.hydra.overrides.task),
                "mosd.sweep_dir": str(sweep_dir.resolve())}
        commit = git_commit()
        if commit:
            tags["mlflow.source.git.commit"] = commit
        self._store = MlflowStore(settings)
        self._run_id = self._store.create_run(f"sweep {sweep_dir.name}", tags)
        (sweep_dir / PARENT_RUN_FILE).write_text(self._run_id)
        os.environ[PARENT_RUN_ENV] = self._run_id
        atexit.register(self._close, "FAILED", "a job of the sweep failed (see its child run)")

    def on_multirun_end(self, config, **kwargs) -> None:
        if record_job_outcomes(str(config.hydra.sweep.dir)):
            self._close("FAILED", "a job of the sweep could not write its run directory (see its summary.json)")
        else:
            self._close("FINISHED")

    def _close(self, status: str, error: str | None = None) -> None:
        if self._store is None or self._run_id is None:
            return
        if status != "FINISHED" and signals.RECEIVED:
            status, error = "KILLED", f"the sweep was stopped by {signals.name(signals.RECEIVED[0])}"
        run_id, self._run_id = self._run_id, None
        os.environ.pop(PARENT_RUN_ENV, None)
        self._store.end(run_id, status, error)
