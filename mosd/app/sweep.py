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
import threading
from pathlib import Path

from hydra.experimental.callback import Callback

from . import signals
from .mlflow_client import MlflowStore, git_commit
from .settings import TrackingSettings, redacted

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


#: Idle CPUs beside the launching process's own from which preflight starts a joblib sweep's workers early
#: (:func:`warm_job_workers`). With one (the project's 2-core machine, 16 jobs on 2 workers, two alternated pairs):
#: the jobs started 0.6-0.9 s after preflight instead of 1.6-1.9 s, but preflight took 5.6-6.0 s instead of 4.4-6.3 s,
#: its dry runs sharing that CPU with the workers' imports: no gain to show.
WARM_FREE_CPUS = 2


class _Warming:
    """The pool :func:`warm_job_workers` started for this command (one per process)."""

    thread = None
    #: the launcher's ``Parallel`` arguments the pool was started with, and whether its workers all started
    arguments: dict | None = None
    started = False


def warm_job_workers(hydra_cfg, n_jobs_in_sweep: int) -> bool:
    """Start the joblib launcher's workers now, while preflight checks the sweep's jobs; True if started.

    A job worker of the joblib launcher starts (a Python process, joblib, then Hydra, mosd, NumPy,
    SciPy, numba and pymoo imported where its first job is unpickled and run) only when Hydra launches
    the jobs, after preflight: 2.5 s before the first job on the project's 2-core machine, while the
    launching process waits (docs/SCALING.md). The same ``Parallel`` the launcher will call
    (:func:`mosd.app.compat.joblib_launcher_arguments`: joblib reuses a worker pool for the same
    arguments) runs one :func:`_warm_worker` per worker on a thread of this process, so the workers
    start and import on the cores preflight leaves idle, and the launcher hands the jobs to them.
    What the launching process sets up for its workers before the first one starts
    (:meth:`SweepCallback.on_multirun_start`: the stop directory, the resource trackers) is set up
    here first. Nothing when the launcher runs its jobs in this process (one worker) or a pool was
    started already; a command that stops before launching ends the pool (:func:`discard_warm_workers`).
    """
    if _Warming.thread is not None or not under_joblib_launcher(hydra_cfg):
        return False
    from joblib import effective_n_jobs

    from ..optim.workers import start_resource_trackers
    from .compat import joblib_launcher_arguments

    arguments = joblib_launcher_arguments(hydra_cfg.launcher)
    n_workers = effective_n_jobs(arguments.get("n_jobs"))
    if n_workers < 2:
        return False
    signals.jobs_run_in_pool()
    with quiet_resource_trackers():
        start_resource_trackers()
    _Warming.arguments = arguments
    _Warming.thread = threading.Thread(target=_start_pool, args=(arguments, min(n_workers, n_jobs_in_sweep)),
                                       name="mosd-warm-job-workers", daemon=True)
    _Warming.thread.start()
    return True


def _start_pool(arguments: dict, n_workers: int) -> None:
    from joblib import Parallel, delayed

    try:
        Parallel(**arguments)(delayed(_warm_worker)() for _ in range(n_workers))
        _Warming.started = True
    except BaseException:  # noqa: BLE001 - the launcher starts its own pool, and its jobs report what fails
        pass


def warm_workers_ready() -> bool:
    """Whether the pool :func:`warm_job_workers` started has all its workers started and imported, now."""
    return _Warming.thread is not None and not _Warming.thread.is_alive() and _Warming.started


def run_on_warm_workers(function, calls: list[tuple]):
    """``function(*call)`` for each call on the pool of :func:`warm_job_workers` (which the launcher's jobs then run
    on: the same ``Parallel`` arguments reuse it): the results in the calls' order, each as soon as it and those
    before it are done. Leaving the loop early cancels the calls not yet started."""
    from joblib import Parallel, delayed

    arguments = {**_Warming.arguments, "return_as": "generator"}
    return Parallel(**arguments)(delayed(function)(*call) for call in calls)


def _warm_worker() -> int:
    """In a job worker before its first job: stop signals handled as between two jobs, then the imports a job makes."""
    from . import signals as worker_signals

    worker_signals.install_signal_handlers(job_worker=True)
    worker_signals.run_ended()
    import hydra.core.utils  # noqa: F401  (the launcher's task runs the job with its run_job)

    # what a job's run imports (NumPy, SciPy, numba, pymoo, the components, the builder), short of the app's run
    # module itself, which imports this one
    from .. import experiment, optim  # noqa: F401
    from . import build  # noqa: F401
    return os.getpid()


def discard_warm_workers() -> None:
    """End the pool :func:`warm_job_workers` started (a command that stops before launching its sweep into it)."""
    if _Warming.thread is None:
        return
    from ..optim.workers import shutdown_pool

    shutdown_pool()


#: Job directories of this process's sweep whose joblib worker ended before the job did (:func:`lost_worker`)
LOST_JOBS: list[Path] = []


def report_lost_workers() -> None:
    """A joblib sweep whose worker process dies (SIGKILL, the out-of-memory killer) ends in one line, not a traceback.

    joblib raises ``TerminatedWorkerError`` (a ``BrokenProcessPool``) out of the launcher's ``Parallel``, and
    loky ends every worker with it: Hydra printed 36 lines of traceback, the exit code was 1 and the jobs that
    were running were left without ``summary.json`` (issue 53 item 9). The joblib launcher's public ``launch``
    is wrapped, in this process, so that the failure is reported by :func:`lost_worker` and the sweep ends as
    one whose jobs could not write their run directory (exit code 1, the parent MLflow run FAILED).
    """
    from hydra_plugins.hydra_joblib_launcher.joblib_launcher import JoblibLauncher

    launch = JoblibLauncher.launch
    if getattr(launch, "reports_lost_workers", False):
        return

    def reporting(self, job_overrides, initial_job_idx):
        from concurrent.futures.process import BrokenProcessPool

        try:
            return launch(self, job_overrides, initial_job_idx)
        except BrokenProcessPool as exc:
            if signals.RECEIVED:  # a stop signal ended the workers: the sweep's stop is reported as such
                raise
            return lost_worker(Path(str(self.config.hydra.sweep.dir)), job_overrides, initial_job_idx, exc)

    reporting.reports_lost_workers = True
    JoblibLauncher.launch = reporting


def _job_dirs(sweep_dir: Path) -> dict[tuple[str, ...], Path]:
    """The sweep's started jobs by their overrides (Hydra writes ``.hydra/overrides.yaml`` as a job starts)."""
    from omegaconf import OmegaConf

    found = {}
    for path in sweep_dir.glob("*/.hydra/overrides.yaml"):
        try:
            # (as saved: a password in tracking.uri masked, mosd.app.files.RedactConfigFiles)
            found[tuple(redacted(str(o)) for o in OmegaConf.load(path))] = path.parent.parent.resolve()
        except Exception:  # noqa: BLE001 - a file cut short by the dying worker: that job is not found, said so
            continue
    return found


def _varying(job_overrides) -> list[str]:
    """Each job's overrides that differ from another job's (the sweep's own choices), as one string per job."""
    lists = [list(o) for o in job_overrides]
    common = set.intersection(*(set(o) for o in lists)) if lists else set()
    return [" ".join(o for o in job if o not in common) for job in lists]


def lost_worker(sweep_dir: Path, job_overrides, initial_job_idx: int, exc: BaseException) -> list:
    """The jobs of a batch whose joblib worker pool broke: marked, named in one line on stderr.

    A job that started and has no ``summary.json`` lost its work with its worker: it gets a ``summary.json`` with
    status ``failed``, the error and the jobs' overrides (its MLflow run is ended FAILED by its tracking process,
    which sees the job's process end); finished jobs keep theirs; the jobs that had not started are named. The
    launcher's return values say the batch completed, so that Hydra ends the sweep normally (its callback then
    ends the parent MLflow run FAILED) instead of printing a traceback.
    """
    import re
    import sys

    from hydra.core.utils import JobReturn, JobStatus

    from .files import NOT_WRITTEN, write_status

    codes = re.search(r"exit codes of the workers are \{([^}]*)\}", str(exc))
    how = codes.group(1) if codes else type(exc).__name__
    error = f"the joblib worker process running this job ended ({how}) before the job did"
    started = _job_dirs(sweep_dir)
    shown = _varying(job_overrides)
    lost, unstarted, returns = [], [], []
    for index, overrides in enumerate(job_overrides):
        name = f"#{initial_job_idx + index}" + (f" ({shown[index]})" if shown[index] else "")
        job_dir = started.get(tuple(redacted(str(o)) for o in overrides))
        if job_dir is None and (sweep_dir / str(initial_job_idx + index)).is_dir():
            # killed before Hydra saved its overrides: the directory named by the job's number (hydra.sweep.subdir)
            job_dir = (sweep_dir / str(initial_job_idx + index)).resolve()
        if job_dir is None:
            unstarted.append(name)
        elif not (job_dir / "summary.json").is_file():
            lost.append(name)
            try:
                write_status(job_dir, "failed", {}, error, overrides=list(overrides), missing=["the job's results"])
            except OSError:
                pass  # the line below still names the job
            NOT_WRITTEN.append(job_dir)
            LOST_JOBS.append(job_dir)
        returns.append(JobReturn(overrides=list(overrides), working_dir=str(job_dir or ""),
                                 status=JobStatus.COMPLETED))
    done = len(job_overrides) - len(lost) - len(unstarted)

    def jobs(names: list[str], verb: str, plural: str) -> str:
        return f"job {names[0]} {verb}" if len(names) == 1 else f"jobs {', '.join(names)} {plural}"

    print(f"mosd: error: a worker process of the joblib launcher ended ({how}, e.g. the out-of-memory killer): "
          + (jobs(lost, "lost its work (its summary.json", "lost their work (their summary.json")
             + " says status 'failed')" if lost else "no running job lost its work")
          + (f"; {jobs(unstarted, 'did not start', 'did not start')}" if unstarted else "")
          + f"; {done} finished job(s) keep their results in {sweep_dir}; run the others again (fewer "
          f"hydra.launcher.n_jobs if memory ran out)", file=sys.stderr, flush=True)
    return returns


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

            report_lost_workers()  # a worker that dies: one line, the jobs marked (not Hydra's traceback)

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
        not_written = record_job_outcomes(str(config.hydra.sweep.dir))
        if LOST_JOBS:
            self._close("FAILED", f"the worker process of {len(LOST_JOBS)} job(s) ended before the job did "
                                  f"(see their summary.json)")
        elif not_written:
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
