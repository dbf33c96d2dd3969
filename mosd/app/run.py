"""One run (the Hydra task): build, run the experiment, write the run directory, log to MLflow.

What a run leaves when it does not end normally:

* a signal (SIGINT, SIGTERM, SIGHUP): :func:`mosd.app.signals.install_signal_handlers` turns it into
  :class:`~mosd.app.signals.Interrupted` at once, after killing the evaluation workers; the MLflow run
  is marked KILLED, ``summary.json`` says ``"status": "killed"``, one line is
  printed and the process exits with 128 + the signal number (a job in a joblib-launcher worker
  reports to its launcher instead, :func:`mosd.app.signals.end_job_worker`). Once the results are
  printed, a signal waits until ``summary.json`` holds them and then cuts only what follows (figures,
  model): the run ends FINISHED, ``summary.json`` keeps its results and lists what it lacks, one line
  says so (:func:`_keep_results`). Once the run is complete (ended FINISHED, or kept for ``mosd log``)
  a signal no longer changes it;
* an error: the run is marked FAILED and ``summary.json`` says ``"status": "failed"``;
* MLflow fails after the work: the summary is printed, the run directory is
  complete, ``mlflow_pending.json`` holds what was to be logged (:mod:`mosd.app.pending`),
  the MLflow run, if the store took it, is marked FAILED with the tag ``mosd.logging_error``,
  one line says how to log it later (``python -m mosd log RUN_DIR``, which completes that run)
  and the exit code is :data:`mosd.app.pending.EXIT_NOT_LOGGED`;
* the run directory cannot be written (disk full, quota): the MLflow run is marked FAILED,
  ``summary.json`` (if it can be written) says ``"status": "failed"`` and lists the files the
  directory lacks (``missing``), no file is left cut short, one line is printed and the exit
  code is 1 (:data:`mosd.app.files.NOT_WRITTEN`).
"""
from __future__ import annotations

import json
import logging
import signal
import sys
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from .build import build
from .config import COMPONENTS, one_line
from .deploy import STREAM_FILE, deployable, record_model, save_for_run
from .files import NOT_WRITTEN, expected_files, lacking, write_run_files, write_status
from .pending import NOT_LOGGED, mark_not_logged, pending_request
from . import signals
from .report import logged_study_name, study_metric_tags
from .settings import redacted
from .signals import RECEIVED, Interrupted, name
from .store import short_error
from .sweep import under_joblib_launcher
from .summary import (UndefinedResult, closing_lines, final_metrics, format_summary, header_line, result_lines,
                      undefined_metrics)

log = logging.getLogger("mosd.app")

#: Seconds a stopped run waits for MLflow to mark it KILLED before leaving that to the tracking process.
ABORT_WAIT_S = 3.0

def _start_tracking(cfg, hc, labels: Mapping[str, str], n_jobs: int, run_dir: Path, params=()):
    """Create the job's MLflow run (a child of the sweep's parent in a multirun); None if disabled."""
    from hydra.types import RunMode

    from .mlflow_client import git_commit
    from .settings import TrackingSettings
    from .sweep import parent_run_id
    from .tracker import RunTracker

    settings = TrackingSettings.from_config(dict(cfg.tracking), str(cfg.outputs_root))
    if settings is None:
        return None
    multirun = hc.mode == RunMode.MULTIRUN
    tags = {"mosd.role": "job", "mosd.mode": "multirun" if multirun else "run",
            "mosd.overrides": redacted(" ".join(hc.overrides.task)), "mosd.run_dir": str(run_dir.resolve()),
            "mosd.n_jobs": str(n_jobs), "mosd.backend": str(cfg.optimizer.get("backend", "loky")),
            **{f"mosd.{k}": v for k, v in labels.items()}}
    if params:
        tags["mosd.params"] = ",".join(params)
    commit = git_commit()
    if commit:
        tags["mlflow.source.git.commit"] = commit
    name = run_name(cfg, labels) + (f"-{hc.job.num}" if multirun else "")
    return RunTracker(settings, name, tags, parent_run_id(hc.sweep.dir if multirun else None)).start()


def run_name(cfg, labels: Mapping[str, str]) -> str:
    """What the run is, as its MLflow name: ``SYSTEM-DETECTOR-OPTIMIZER``.

    The system is the preset (``paper002-threshold-mopso``), else the data source
    (``tep-pca-mopso``; a table by its file: ``table:plant-pca-mopso``), else the
    fault of the main command (``offset_var-ss_dewma-mopso``).
    """
    from omegaconf import OmegaConf

    system = labels.get("experiment") or labels.get("data") or labels.get("fault") or "run"
    if system == "table":
        path = OmegaConf.select(cfg, "data.path", default=None)
        system = f"table:{Path(str(path)).stem}" if path else system
    return f"{system}-{labels.get('detector', '')}-{labels.get('optimizer', '')}"


def ui_line(uri: str, experiment_id: str) -> str:
    """Where the run is seen in the MLflow UI: the runs table, with FAR, MDR and the tuned design as columns."""
    from .ui import runs_address

    if uri.startswith(("http://", "https://")):  # a tracking server: its UI (never its password)
        return f"ui        {runs_address(redacted(uri), experiment_id)}"
    from .settings import default_tracking_uri

    store = "" if uri == default_tracking_uri() else f" --tracking-uri {redacted(uri)}"
    return (f"ui        python -m mosd ui{store}, then "
            f"{runs_address('http://127.0.0.1:5000', experiment_id)}")


def rescoring_command(model_uri: str, run_dir: Path, tracking_uri: str) -> str:
    """The command that re-scores a run's own test stream, as typed from where the user stands (issue 51: the bare
    file name failed there with 'no such file'); the store is named when it is not the one ``mosd monitor`` reads
    by default."""
    import os
    import shlex

    from .settings import default_tracking_uri

    stream = Path(run_dir) / STREAM_FILE
    try:
        shown = os.path.relpath(stream)
    except ValueError:  # another drive (Windows)
        shown = str(stream)
    command = f"python -m mosd monitor --model {model_uri} {shlex.quote(shown)}"
    # the store mosd monitor reads without --tracking-uri: $MLFLOW_TRACKING_URI, else the default one
    if tracking_uri != (os.environ.get("MLFLOW_TRACKING_URI") or default_tracking_uri()):
        command += f" --tracking-uri {shlex.quote(redacted(tracking_uri))}"
    return command


def recorded_labels(labels: dict[str, str]) -> dict[str, str]:
    """A recorded-data run's labels without plant, noise and fault: the data took their place."""
    if not labels.get("data"):
        return labels
    return {k: v for k, v in labels.items() if k not in ("plant", "noise", "fault")}


@dataclass
class _Job:
    """What one run's steps share (:func:`run`): the job, its components, its results and how far it got."""

    cfg: Any
    hc: Any
    multirun: bool
    job_worker: bool
    started: float
    task_start: float
    run_dir: Path
    labels: dict
    setup: Any = None
    tracker: Any = None
    progress: Any = None
    figures: Any = None
    result: Any = None
    n_jobs: int = 1
    share: int | None = None  # a job worker's share of the cores
    timings: dict = field(default_factory=dict)
    metrics: dict = field(default_factory=dict)
    study_metrics: dict = field(default_factory=dict)
    study_figures: list = field(default_factory=list)
    params: dict = field(default_factory=dict)
    logged: list = field(default_factory=list)  # metrics (key, value, step) handed to MLflow
    sent: list = field(default_factory=list)  # artifacts already handed to MLflow
    files: list = field(default_factory=list)  # the run directory's files, once written
    writing: bool = False  # an OSError while True: the run directory cannot be written (disk full, quota)
    done: bool = False  # the run is complete (FINISHED, or its files kept for `mosd log`): a signal changes nothing
    holding: bool = False  # the results are printed, not yet in summary.json: a signal waits (signals.hold)
    results_kept: bool = False  # summary.json holds the results and MLflow has them: a signal ends the run FINISHED
    printed: bool = False  # the results are on stdout (a single run prints them as soon as they exist)


def run(cfg, started: float | None = None, checked=None):
    """The Hydra task: one experiment, its files and its MLflow run.

    Parameters
    ----------
    cfg : DictConfig
        The job's composed config (validated by :func:`preflight` beforehand).
    started : float, optional
        ``time.perf_counter()`` at process start (single runs), for the wall time.
    checked : mosd.app.preflight.Checked, optional
        The components preflight built for the command's jobs: this job takes its
        own instead of building them again (a job in another process builds them).

    Notes
    -----
    The steps: :func:`_setup_job` (components, cores), :func:`_start_job` (MLflow run, progress, header),
    :func:`_optimise` (the tuning, the test, the study), :func:`_write_files` (the run directory, MLflow's
    early batches), :func:`_finish_tracking` (the MLflow run ended), :func:`_print_summary`; on an
    exception, :func:`_on_failure`.
    """
    job = _new_job(cfg, started)
    try:
        _setup_job(job, checked)
        _start_job(job)
        _optimise(job)
        model_file, deployment = _write_files(job)
        tracking_line, not_logged = _finish_tracking(job, model_file, deployment)
        _print_summary(job, tracking_line, not_logged)
        return job.result
    except BaseException as exc:
        return _on_failure(job, exc)
    finally:
        signals.run_ended()


def _new_job(cfg, started: float | None) -> _Job:
    """The job's Hydra context and labels, its stop signals handled (a job worker's stop ends it here)."""
    from hydra.core.hydra_config import HydraConfig
    from hydra.types import RunMode

    import multiprocessing

    from .settings import install_warning_display

    install_warning_display()  # a job in a launcher's worker shows warnings as the launching process does
    hc = HydraConfig.get()
    multirun = hc.mode == RunMode.MULTIRUN
    # a job in a joblib-launcher worker: its launcher waits for it to mark its run on a signal
    job_worker = multirun and under_joblib_launcher(hc) and multiprocessing.parent_process() is not None
    signals.install_signal_handlers(job_worker=job_worker)
    stopped = signals.sweep_stopped() if job_worker else None
    if stopped is not None:  # the sweep was stopped while this job was on its way: no run to start
        signals.end_job_worker(stopped)
    task_start = time.perf_counter()
    started = task_start if (started is None or multirun) else started
    choices = {k: v for k, v in hc.runtime.choices.items() if not k.startswith("hydra/") and v is not None}
    labels = recorded_labels({group: str(choices.get(group, "")) for group in (*COMPONENTS, "tracking", "experiment")})
    return _Job(cfg, hc, multirun, job_worker, started, task_start, Path(hc.runtime.output_dir), labels)


def _setup_job(job: _Job, checked) -> None:
    """The job's components (preflight's, or built here) and the cores its evaluation may use."""
    setup = checked.take(job.cfg) if checked is not None else None
    if setup is None:  # a job in another process: built here, its component count bounded as preflight does
        from .preflight import fit_to_data

        setup = build(job.cfg)
        fit_to_data(setup)
    job.setup = setup
    job.labels["online"] = "true" if setup.experiment.detector.is_causal else "false"
    job.n_jobs = setup.n_jobs
    if job.n_jobs > 1 and under_joblib_launcher(job.hc):
        # nested joblib under the joblib launcher silently becomes threads: evaluate in-process
        log.info("joblib launcher: fitness evaluation runs in-process (optimizer.n_jobs=%d -> 1)", job.n_jobs)
        job.n_jobs = 1
    if job.job_worker:
        from ..optim.workers import pin_sweep_job

        # jobs side by side: each keeps BLAS/OpenMP/numba to its share of the cores (docs/SCALING.md)
        job.share = pin_sweep_job(job.hc.launcher.get("n_jobs"))
        log.info("joblib launcher: this job's thread pools pinned to %d thread(s)", job.share)


def _start_job(job: _Job) -> None:
    """The MLflow run, the progress bar, the summary's first line and the figure process."""
    from . import plots
    from .progress import Progress

    setup, hc = job.setup, job.hc
    with signals.deferred():  # a run that exists in MLflow is one this process can mark KILLED
        job.tracker = _start_tracking(job.cfg, hc, job.labels, job.n_jobs, job.run_dir,
                                      tuple(setup.experiment.detector.tunable))
    if job.tracker is None or job.tracker.in_process:
        from . import channel

        channel.discard()  # a tracking process started ahead of this run, which does not use it
    position = int(hc.job.num) if job.multirun and under_joblib_launcher(hc) else 0
    job.progress = Progress(setup.n_gen, enabled=job.cfg.progress, position=position,
                            description=f"job {hc.job.num}" if job.multirun else "",
                            objectives=setup.experiment.objectives)
    job.timings = {"startup_s": job.task_start - job.started}
    if not job.multirun:
        # the summary's first line now, so that a user (or a log file) sees the run start; the
        # results come when the test is scored (a sweep prints each job's summary whole: jobs may run at once)
        print(header_line(job.labels, setup), flush=True)
    # started before preflight for a single run (plots.start_early), else now: matplotlib loads on the
    # other core while this process checks the command or simulates; a sweep's job draws on its share
    job.figures = plots.take(drawers=job.share)


def _optimise(job: _Job) -> None:
    """The tuning and the test (and a system's study); the results printed once they exist."""
    setup = job.setup
    result = job.result = setup.experiment.run(
        setup.algorithm, setup.termination, n_jobs=job.n_jobs, bounds=setup.bounds, choose=setup.choose,
        callback=job.progress, backend=setup.backend, dask_address=setup.dask_address)
    job.progress.close()
    job.timings.update(result.timings)
    job.writing = True
    if setup.study is not None:
        t0 = time.perf_counter()
        job.run_dir.mkdir(parents=True, exist_ok=True)
        job.study_metrics, study_data = setup.study.measure(setup.experiment, result)
        if setup.study.figures:
            # drawn by the figure process with the run's own figures, while this process writes the files
            job.study_figures = [("study_figures", {"study": setup.study, "method": method, "kwargs": kwargs})
                                 for method, kwargs in setup.study.figure_jobs(study_data, job.run_dir)]
        result.timings["study_s"] = job.timings["study_s"] = time.perf_counter() - t0
    test_metrics = final_metrics(result, result.example["seconds_per_point"])
    # a study metric named like a test metric (paper 003's far, scored its own way; paper 000's with
    # study.n_runs != budget.n_test) must not replace the test metric: MLflow gets it as study_<name>
    job.metrics = {**test_metrics, **{logged_study_name(k, test_metrics): float(v)
                                      for k, v in job.study_metrics.items()}}
    # the studies' own metrics may be NaN by definition (e.g. paper 003's step of a window that never detects)
    undefined = undefined_metrics(test_metrics)
    if undefined:  # the last guard behind preflight: a NaN rate is no result, whatever the exit code said
        raise UndefinedResult(f"the run's metrics {', '.join(undefined)} are NaN (no points to score them on); "
                              f"the run is not finished")
    # from here the results exist: a stop signal waits until summary.json holds them (a few file writes)
    signals.hold()
    job.holding = True
    if not job.multirun:
        # the results as soon as they exist; where the files and the MLflow run are, once they are
        # (a sweep prints each job's summary whole: jobs may run at once)
        print(result_lines(result, setup, job.metrics), flush=True)
        job.printed = True


def _log_early(job: _Job, text_files: list[Path]) -> None:
    """MLflow gets the config, the history, the results and the text files while the figures are drawn; only the
    timings and the PNGs are left for the end."""
    from omegaconf import OmegaConf

    from .mlflow_client import flatten

    if job.tracker is None:
        return
    result = job.result
    job.params = {k: redacted(v) for k, v in flatten(OmegaConf.to_container(job.cfg, resolve=True)).items()}
    job.logged.extend((key, record[key], record["generation"]) for record in result.history
                      for key in ("hypervolume", "archive_size", "best_accuracy", "n_eval",
                                  *(f"best_{name}" for name in result.objectives))
                      if np.isfinite(record[key]))
    job.logged.extend((k, v, 0) for k, v in job.metrics.items())
    job.sent.extend(text_files)
    job.tracker.log(params=job.params, metrics=job.logged, tags=study_metric_tags(job.study_metrics),
                    artifacts=job.sent)
    job.tracker.send()


def _write_files(job: _Job):
    """The run directory (MLflow's early batches sent meanwhile), then the deployable pipeline; returns
    ``(model file, deployment)``."""
    from . import plots

    found = []

    def while_figures_are_drawn(text_files: list[Path]) -> None:
        _log_early(job, text_files)
        # summary.json holds the results and MLflow has them: a stop from now on cuts the extras only
        job.results_kept, job.holding = True, False
        signals.release()
        # the deployable pipeline and its test stream are built (and pyarrow imported to write it) while
        # the figure process draws; they are written after the figures (below)
        found.append(deployable(job.setup, job.result))

    t0 = time.perf_counter()
    files = write_run_files(job.run_dir, job.cfg, job.result, job.setup, job.labels, job.study_metrics, job.figures,
                            on_text_files=while_figures_are_drawn, extra_figures=job.study_figures)
    # the deployable pipeline and the first test replication's stream, after the run's own files (a disk
    # that fills up takes the extras, not the results); logged with the last artifacts
    model_file, deployment = save_for_run(job.setup, job.result, job.run_dir, found[0] if found else None)
    files += [job.run_dir / STREAM_FILE] if deployment.stream is not None else []
    record_model(job.run_dir, deployment, model_file)
    job.files = files
    fallback = job.figures.fallback
    # a sweep's next job in this process draws with this figure process, matplotlib loaded and warm
    if not (job.multirun and plots.keep(job.figures)):
        job.figures.close()
    job.figures = None
    job.timings["files_s"] = time.perf_counter() - t0
    if fallback:
        log.warning("figures drawn in-process: %s", fallback)
    return model_file, deployment


def _finish_tracking(job: _Job, model_file, deployment) -> tuple[str, str | None]:
    """End the MLflow run FINISHED (or keep what it lacks for ``mosd log``); returns ``(tracking line, the logging
    error or None)``."""
    from .mlflow_client import LOGGING_ERROR_TAG
    from .store import TrackingError

    tracker = job.tracker
    if tracker is None:
        return (f"model     none: {deployment.reason}" if deployment.reason else ""), None
    t0 = time.perf_counter()
    finals = [(k, v, 0) for k, v in {**job.timings, "wall_time_s": time.perf_counter() - job.started}.items()]
    job.logged.extend(finals)
    tracker.log(metrics=finals, artifacts=[f for f in job.files if f not in job.sent])
    if model_file is not None:
        tracker.log_model(model_file)
    try:
        # a signal now is raised once the run is ended FINISHED: never a FINISHED run with a 'killed' summary
        with signals.deferred():
            try:
                run_id = tracker.finish("FINISHED")
            finally:
                job.done = True
    except TrackingError as exc:
        # the work is done and on disk: keep it, say how to log it later
        not_logged = redacted(one_line(exc))
        mark_not_logged(job.run_dir, not_logged,
                        pending_request(tracker, job.params, job.logged, job.files, model_file), tracker.status)
        line = f"mlflow    NOT LOGGED ({redacted(tracker.settings.uri)}): {not_logged}"
        if tracker.run_id:
            ended = (f"marked {tracker.status} (tag {LOGGING_ERROR_TAG})" if tracker.status
                     else "left RUNNING (the store failed)")
            line += f"\n          run {tracker.run_id} {ended}: mosd log completes it"
        signals.raise_pending()  # one that arrived while MLflow failed: the pending file is written
        return line, not_logged
    # what MLflow still took after the figures (the rest overlapped them)
    job.timings["mlflow_s"] = time.perf_counter() - t0
    where = "in-process" if tracker.in_process else "side process, overlapping the run"
    startup = ", ".join(f"{k.removeprefix('mlflow_').removesuffix('_s')} {v:.1f} s"
                        for k, v in tracker.startup_timings.items())
    line = (f"mlflow    run {run_id}  experiment {tracker.settings.experiment!r}"
            f"  store {redacted(tracker.settings.uri)}\n          ({where}: {startup})")
    if tracker.model_uri:
        record_model(job.run_dir, deployment, model_file, uri=tracker.model_uri)
        line += (f"\n          model {tracker.model_uri} (runs:/{run_id}/detector): "
                 f"{rescoring_command(tracker.model_uri, job.run_dir, tracker.settings.uri)}")
    elif tracker.model_error:
        line += f"\n          model NOT LOGGED: {tracker.model_error}"
    elif deployment.reason:
        line += f"\n          no model: {deployment.reason}"
    if tracker.note:
        line += f"\n          store: {tracker.note}"
    if tracker.experiment_id:
        line += "\n" + ui_line(tracker.settings.uri, tracker.experiment_id)
    signals.raise_pending()
    return line, None


def _print_summary(job: _Job, tracking_line: str, not_logged: str | None) -> None:
    """The summary's closing lines (a sweep's job: the whole summary), the log file's copy, a logging error's line."""
    job.writing = False
    job.done = True
    timings, run_dir, setup = job.timings, job.run_dir, job.setup
    timings["wall_s"] = time.perf_counter() - job.started
    summary_text = format_summary(job.labels, job.result, setup, job.metrics, timings, run_dir, tracking_line,
                                  job.study_metrics, header=job.multirun)
    print(summary_text if job.multirun else closing_lines(setup, timings, run_dir, tracking_line, job.study_metrics),
          flush=True)
    to_log_file(summary_text if job.multirun else header_line(job.labels, setup) + "\n" + summary_text)
    if not_logged is not None:
        NOT_LOGGED.append(run_dir)
        print(f"mosd: error: the run was not logged to MLflow ({not_logged}); its files are complete in "
              f"{run_dir}; log it later with: python -m mosd log {run_dir}", file=sys.stderr, flush=True)


def _on_failure(job: _Job, exc: BaseException):
    """A run that did not end normally: a stop signal, a full disk, an error (module docstring).

    Returns None for a run directory that could not be written (the job ends, a sweep goes on); otherwise
    raises (the signal's :class:`~mosd.app.signals.Interrupted`, or the error itself).
    """
    if job.holding:  # a failure while the results were being written: a stop signal is handled below
        signals.release(raise_now=False)
    if job.progress is not None:
        job.progress.close()
    if job.figures is not None:
        job.figures.close(wait=False)
    # a signal raised inside compiled code (numba) comes out as a SystemError with the
    # Interrupted as its context: what counts is that a stop signal arrived
    killed = isinstance(exc, KeyboardInterrupt) or bool(RECEIVED)
    signum = None
    if killed:
        signals.shutdown_workers()
        signum = exc.signum if isinstance(exc, Interrupted) else (RECEIVED[0] if RECEIVED else int(signal.SIGINT))
        if job.done:  # the run is complete, its summary.json and MLflow run say so: leave them
            print(f"mosd: stopped by {name(signum)} after the run was complete ({job.run_dir})",
                  file=sys.stderr, flush=True)
            _stopped(exc, signum, job.job_worker)
        if job.results_kept:  # the results are in summary.json and MLflow: the stop cut only the extras
            _keep_results(exc, signum, job.job_worker, job.started, job.run_dir, (job.result, job.setup, job.labels),
                          job.tracker, (job.params, job.logged, job.sent))
    status = "KILLED" if killed else "FAILED"
    error = f"stopped by {name(signum)}" if killed else f"{type(exc).__name__}: {redacted(one_line(exc))}"
    not_written = job.writing and not killed and isinstance(exc, OSError)
    kept, missing = {}, []
    if not_written:
        error = f"the run directory could not be written: {error}"
        kept, missing = _what_is_kept(job)
    marked = _mark_tracker(job, status, error, killed)
    try:
        write_status(job.run_dir, status.lower(), job.labels, error, mlflow_run_id=marked[0],
                     elapsed_s=time.perf_counter() - job.started, **kept)
        said = ("summary.json says status 'failed', keeps the results and lists what it lacks"
                if "params" in kept else "summary.json says status 'failed' and lists what it lacks")
    except OSError:
        said = "it has no summary.json (that could not be written either)" + (
            ": the results are those printed above" if job.printed else "")
    if not_written:
        # one line: what happened, what is kept, what to do; the job ends here, a sweep goes on with its other
        # jobs, and the exit code is 1
        print(f"mosd: error: {error}; {job.run_dir} lacks {', '.join(missing) or 'no result file'}; {said}; "
              f"{marked[1]}free space on that disk (or raise its quota) and run again",
              file=sys.stderr, flush=True)
        NOT_WRITTEN.append(job.run_dir)
        return None
    if killed:
        print(f"mosd: stopped by {name(signum)} after {time.perf_counter() - job.started:.1f} s: "
              f"{marked[1]}{job.run_dir} is incomplete (summary.json status 'killed')", file=sys.stderr, flush=True)
        _stopped(exc, signum, job.job_worker)
    if marked[2]:  # the error's traceback follows (Hydra's): the store's failure is said before it
        print(f"mosd: {marked[2]}", file=sys.stderr, flush=True)
    raise exc


def _what_is_kept(job: _Job) -> tuple[dict, list[str]]:
    """A run directory the disk did not take whole: ``(summary.json's results to keep, the files it lacks)``.

    Each file is complete or absent (atomic writes) and the figure process is stopped: what is absent now stays
    absent; summary.json is rewritten, keeping the results it holds.
    """
    missing = [n for n in lacking(job.run_dir, expected_files(job.run_dir, job.result, job.setup, job.labels))
               if n != "summary.json"]
    try:
        kept = {k: v for k, v in json.loads((job.run_dir / "summary.json").read_text()).items()
                if k not in ("status", "labels", "error")}
    except (OSError, ValueError):
        kept = {}
    kept["missing"] = missing
    return kept, missing


def _mark_tracker(job: _Job, status: str, error: str, killed: bool) -> tuple[str | None, str, str]:
    """End the job's MLflow run ``status``; returns ``(run id or None, the clause that says so, the store's failure
    as a sentence or "")``, the store's error without SQLAlchemy's statement (:func:`mosd.app.store.short_error`)."""
    tracker = job.tracker
    if tracker is None or not tracker.open:
        return None, "", ""
    try:
        # on a signal, do not wait for a side process still importing MLflow: it ends the run alone
        run_id = tracker.abort(status, error, traceback.format_exc(), timeout=ABORT_WAIT_S if killed else None)
    except Exception as tracking_exc:  # noqa: BLE001 - the store failed too (a full disk): said, not raised
        failure = f"the MLflow run could not be marked {status} ({short_error(redacted(one_line(tracking_exc)))})"
        return None, failure + "; ", failure
    if run_id:
        return run_id, f"MLflow run {run_id} marked {status}; ", ""
    return None, f"the MLflow run will be marked {status} by the tracking process; ", ""


def to_log_file(text: str) -> None:
    """Write ``text`` to the run's log file (Hydra's ``mosd.log``) only: the console already showed it.

    The run's messages go to the console and ``mosd.log`` through logging, but
    its result is printed; without this the log file of a run held at most a
    warning, usually nothing.
    """
    for handler in logging.getLogger().handlers:
        if isinstance(handler, logging.FileHandler):
            record = logging.LogRecord("mosd.app", logging.INFO, __file__, 0, "%s", (text,), None)
            handler.handle(record)


def _keep_results(exc: BaseException, signum: int, job_worker: bool, started: float, run_dir: Path, run, tracker,
                  logging_state) -> None:
    """A stop after ``summary.json`` holds the results: they stay, the run ends FINISHED, one line says so.

    What the stop cuts short is only what follows the results (the figures, the deployable model):
    ``summary.json`` keeps its results and gains ``stopped`` (the signal) and ``missing`` (the files the
    directory lacks); MLflow gets that summary and whatever files exist, and the run is ended FINISHED,
    as its ``summary.json`` artifact says, so that its results count wherever finished runs are read.
    ``run``: ``(result, setup, labels)``; ``logging_state``: ``(params, metrics logged, artifacts sent)``.
    """
    from .atomic import write_json
    from .store import TrackingError

    result, setup, labels = run
    params, logged, sent = logging_state
    expected = expected_files(run_dir, result, setup, labels)
    missing = lacking(run_dir, expected)
    summary_file = run_dir / "summary.json"
    try:
        summary = json.loads(summary_file.read_text())
        summary.update(stopped=name(signum), missing=missing)
        write_json(summary_file, summary)
    except (OSError, ValueError):
        pass  # the summary as written with the results: whole, without the note
    ended = ""
    if tracker is not None and tracker.open:
        present = [p for p in expected if p.exists() and (p not in sent or p == summary_file)]
        tracker.log(tags={"mosd.stopped": name(signum)}, artifacts=present)
        try:
            run_id = tracker.finish("FINISHED", timeout=ABORT_WAIT_S)
            ended = (f"; MLflow run {run_id} ended FINISHED" if run_id
                     else "; the tracking process ends the MLflow run FINISHED")
        except TrackingError as tracking_exc:
            error = redacted(one_line(tracking_exc))
            mark_not_logged(run_dir, error, pending_request(tracker, params, logged, present), tracker.status)
            ended = f"; the MLflow run was not logged ({error}): python -m mosd log {run_dir} completes it"
    lacks = f", lacking {', '.join(missing)}" if missing else ""
    print(f"mosd: stopped by {name(signum)} after {time.perf_counter() - started:.1f} s, once the results were "
          f"complete: {summary_file} keeps them (status 'finished'{lacks}){ended}", file=sys.stderr, flush=True)
    _stopped(exc, signum, job_worker)


def _stopped(exc: BaseException, signum: int, job_worker: bool):
    """After a stopped run's one line: end a job worker (its launcher waits for it), else raise Interrupted."""
    if job_worker:
        signals.end_job_worker(signum)
    interrupted = exc if isinstance(exc, Interrupted) else Interrupted(signum)
    interrupted.reported = True
    if interrupted is exc:
        raise
    raise interrupted from None


