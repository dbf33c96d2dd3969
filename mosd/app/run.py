"""One run (the Hydra task): build, run the experiment, write the run directory, log to MLflow.

What a run leaves when it does not end normally:

* a signal (SIGINT, SIGTERM, SIGHUP): :func:`install_signal_handlers` turns it into
  :class:`Interrupted` at once, after killing the evaluation workers; the MLflow run
  is marked KILLED, ``summary.json`` says ``"status": "killed"``, one line is
  printed and the process exits with 128 + the signal number;
* an error: the run is marked FAILED and ``summary.json`` says ``"status": "failed"``;
* MLflow fails after the work: the summary is printed, the run directory is
  complete, ``mlflow_pending.json`` holds what was to be logged, one line says how
  to log it later (``python -m mosd log RUN_DIR``) and the exit code is
  :data:`EXIT_NOT_LOGGED`.
"""
from __future__ import annotations

import json
import logging
import os
import signal
import sys
import threading
import time
import traceback
from pathlib import Path
from typing import Any, Callable, Mapping

import numpy as np

from .build import Setup, build
from .config import COMPONENTS, one_line

log = logging.getLogger("mosd.app")

#: Exit code of a run whose work finished but whose MLflow logging failed.
EXIT_NOT_LOGGED = 3
#: File in a run directory with the MLflow requests of a run that was not logged.
PENDING_FILE = "mlflow_pending.json"
#: Signals that stop a run (each gives exit code 128 + its number).
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
#: Seconds a stopped run waits for MLflow to mark it KILLED before leaving that to the tracking process.
ABORT_WAIT_S = 3.0
#: Run directories of this process whose MLflow logging failed (:func:`mosd.app.main` exits non-zero).
NOT_LOGGED: list[Path] = []


class Interrupted(KeyboardInterrupt):
    """A stop signal, raised in the main thread by the handler of :func:`install_signal_handlers`."""

    def __init__(self, signum: int):
        super().__init__(signal.Signals(signum).name)
        self.signum = int(signum)
        #: set once a one-line message has been printed for it
        self.reported = False


def kill_workers() -> int:
    """SIGTERM the process pool's workers (loky), without taking any lock.

    Called from a signal handler: the executor's own ``shutdown`` takes locks the
    interrupted main thread may hold. The workers' pids are read from the pool.
    An evaluation worker dies at once (default action); a job of the joblib
    launcher runs :func:`run`, whose handler marks its own run KILLED first.
    :func:`shutdown_workers` SIGKILLs whatever is left; loky's resource tracker
    exits by itself once its clients are gone.
    """
    module = sys.modules.get("joblib.externals.loky.reusable_executor")
    executor = getattr(module, "_executor", None) if module is not None else None
    killed = 0
    for pid in list(getattr(executor, "_processes", {}) or {}):
        try:
            os.kill(pid, signal.SIGTERM)
            killed += 1
        except (ProcessLookupError, PermissionError):
            pass
    return killed


def shutdown_workers() -> None:
    """Shut the evaluation pool down and reap its workers (after :func:`kill_workers`)."""
    module = sys.modules.get("joblib.externals.loky.reusable_executor")
    executor = getattr(module, "_executor", None) if module is not None else None
    if executor is not None:
        try:
            executor.shutdown(wait=True, kill_workers=True)
        except Exception:  # a broken pool is what we expect here
            pass


#: The stop signal this process received, if any (the sweep's parent run is then ended KILLED).
RECEIVED: list[int] = []


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


def write_run_files(run_dir: Path, cfg, result, setup: Setup, labels: Mapping[str, str],
                    study: Mapping[str, float] | None = None, figures=None,
                    on_text_files: Callable[[list[Path]], None] | None = None) -> list[Path]:
    """Resolved config, Pareto set and history as CSV, summary JSON and the PNG plots.

    ``figures``: a :class:`mosd.app.plots.FigureWriter` (started with the run) that
    draws the PNGs in its side process while this writes the other files; None
    draws them here. ``on_text_files`` is called with the text files once they
    are written, before the figures are waited for (MLflow takes them meanwhile).
    """
    from omegaconf import OmegaConf

    from . import plots

    run_dir.mkdir(parents=True, exist_ok=True)
    F = result.archive_F
    objectives = list(result.objectives)
    # the figures first: they are the slow part, drawn while the text files are written
    jobs = _figure_jobs(run_dir, result, setup, labels)
    if figures is not None:
        figures.submit(jobs)
    written = []
    path = run_dir / "resolved_config.yaml"
    path.write_text(OmegaConf.to_yaml(cfg, resolve=True))
    written.append(path)

    names = list(result.params)
    order = np.argsort(F[:, 0], kind="stable")
    columns = [result.archive_X[order], F[order]]
    header = [*names, *objectives]
    if objectives == ["far", "mdr"]:
        columns.append(1.0 - F[order].sum(axis=1))
        header.append("accuracy")
    table = np.column_stack([*columns, (order == result.chosen_index).astype(float)])
    path = run_dir / "pareto.csv"
    np.savetxt(path, table, delimiter=",", header=",".join([*header, "chosen"]),
               comments="", fmt=["%.10g"] * (table.shape[1] - 1) + ["%d"])
    written.append(path)

    if result.history:
        keys = list(result.history[0])
        path = run_dir / "history.csv"
        np.savetxt(path, np.array([[r[k] for k in keys] for r in result.history], float), delimiter=",",
                   header=",".join(keys), comments="", fmt="%.10g")
        written.append(path)

    summary = result.summary()
    path = run_dir / "summary.json"
    path.write_text(json.dumps({
        "status": "finished",
        "labels": dict(labels),
        "params": result.params,
        "online": bool(setup.experiment.detector.is_causal),
        "on_bound": on_bound(result.params, setup),
        "objectives": list(result.objectives),
        "train": dict(result.train_objectives),
        "test": {k: {"mean": v.mean, "ci95_half_width": v.half_width, "n": v.n} for k, v in summary.items()},
        "sigma": result.sigma,
        # recorded data: which rows of which recording each split used (mosd.data)
        **({"data": setup.experiment.describe()} if hasattr(setup.experiment, "describe") else {}),
        **({"study": dict(study)} if study else {}),
        "timings": result.timings,
    }, indent=2, allow_nan=True))
    written.append(path)
    if on_text_files is not None:
        on_text_files(list(written))
    written += figures.result() if figures is not None else plots.draw(jobs)
    return written


def _figure_jobs(run_dir: Path, result, setup: Setup, labels: Mapping[str, str]) -> list[tuple[str, dict]]:
    """The run's figures as ``(name in mosd.app.plots, keyword arguments)`` (plain arrays: picklable)."""
    F = result.archive_F
    objectives = tuple(result.objectives)
    ex = result.example
    monitor = setup.experiment.monitor
    title = f"{labels.get('detector', '')} on {labels.get('fault', '')} fault: " + ", ".join(
        f"{k} = {v:.4g}" for k, v in result.params.items())
    archive_title = f"Archive of {labels.get('optimizer', '')} (training replications)"
    jobs = [("pareto_front" if F.shape[1] == 2 else "pareto_pairs",
             dict(path=run_dir / "pareto.png", F=F, chosen=result.chosen_index, title=archive_title,
                  labels=objectives))]
    t = ex["t"] if ex.get("t") is not None else np.arange(len(ex["statistic"])) * ex["seconds_per_point"]
    jobs.append(("chart_trace", dict(path=run_dir / "chart.png", t=t, statistic=ex["statistic"], ucl=ex["ucl"],
                                     fault_mask=ex["fault_mask"], title=title)))
    channel = getattr(setup.experiment.fault, "channel", 0)
    if ex.get("residual") is not None:
        channels = getattr(monitor, "channels", ())
        mean = float(monitor.mean_[channels.index(channel)]) if channel in channels and hasattr(monitor, "mean_") \
            else 0.0
        names = tuple(getattr(setup.experiment.plant, "output_names", ()))
        jobs.append(("residual_trace", dict(path=run_dir / "residual.png", residual=ex["residual"],
                                            fault_mask=ex["residual_fault_mask"], dt=ex["dt"], mean=mean,
                                            sigma=result.sigma,
                                            channel_name=names[channel] if channel < len(names) else "")))
    if result.history:
        n_eval = int(result.history[-1].get("n_eval", 0))
        jobs.append(("optimisation_history", dict(
            path=run_dir / "history.png", records=result.history,
            title=f"{labels.get('optimizer', '')} on the {labels.get('fault', '')} fault: {len(result.history)} "
                  f"generations, {n_eval} evaluations (training replications)")))
    return jobs


def on_bound(params: Mapping[str, float], setup: Setup) -> list[str]:
    """The chosen parameters that sit on the optimiser's search box (1e-6 of its width)."""
    names = []
    for name, value in params.items():
        interval = setup.experiment.detector.tunable[name]
        low, high = setup.bounds.get(name, (interval.low, interval.high))
        tol = 1e-6 * (high - low) + (1e-6 if interval.open_low or interval.open_high else 0.0)
        if value <= low + tol or value >= high - tol:
            names.append(f"{name} = {value:g} in [{low:g}, {high:g}]")
    return names


def final_metrics(result, seconds_per_point: float) -> dict[str, float]:
    """The run's scalar metrics: test means and CI half-widths, chosen parameters, training objectives."""
    metrics: dict[str, float] = {}
    for key, estimate in result.summary().items():
        metrics[key] = estimate.mean
        metrics[f"{key}_ci"] = estimate.half_width
    for key in ("delay", "delay_censored"):
        if key in metrics:
            metrics[f"{key}_s"] = metrics[key] * seconds_per_point
            metrics[f"{key}_s_ci"] = metrics[f"{key}_ci"] * seconds_per_point
    metrics["delay_censored_median_s"] = result.test.median_censored_delay() * seconds_per_point
    metrics["n_test"] = float(result.test.n_runs)
    metrics.update({name: float(value) for name, value in result.params.items()})
    metrics.update({f"train_{name}": float(value) for name, value in result.train_objectives.items()})
    metrics["sigma"] = float(result.sigma)
    return metrics


def header_line(labels: Mapping[str, str], setup: Setup) -> str:
    """``mosd  fault=…  detector=…  optimizer=… (pop × gen)  estimator=…  denoise=…``: the summary's first line."""
    pop = getattr(setup.algorithm, "pop_size", "?")
    preset = f"experiment={labels['experiment']}  " if labels.get("experiment") else ""
    source = f"data={labels['data']}" if labels.get("data") else f"fault={labels.get('fault')}"
    return (f"mosd  {preset}{source}  detector={labels.get('detector')}  "
            f"optimizer={labels.get('optimizer', '')} ({pop} × {setup.n_gen})  estimator={labels.get('estimator')}  "
            f"denoise={labels.get('denoise')}")


def _format_summary(labels, result, setup: Setup, metrics, timings, run_dir, tracking_line, study=None,
                    header: bool = True) -> str:
    """The summary printed at the end of a run; ``header=False`` leaves out the first line (printed at the start)."""
    n_test = int(metrics["n_test"])
    params = "  ".join(f"{k} = {v}" if isinstance(v, int) else f"{k} = {v:.4f}" for k, v in result.params.items())

    def pm(key, digits=4):
        return f"{metrics[key]:.{digits}f} ± {metrics[key + '_ci']:.{digits}f}"

    train = ", ".join(f"{k} {v:.4g}" for k, v in result.train_objectives.items())
    online = "online (causal detector)" if setup.experiment.detector.is_causal else \
        "NOT online: the detector uses future points (non-causal)"
    lines = [
        *([header_line(labels, setup)] if header else []),
        f"chosen    {params}   (training: {train}; archive of {len(result.archive_F)})",
        *([f"          on the search bound: {', '.join(on_bound(result.params, setup))} "
           "(widen detector.bounds: the optimum may lie outside the box)"] if on_bound(result.params, setup) else []),
        f"test      {n_test} fresh replications, mean ± 95 % CI half-width; {online}",
        f"  FAR       {pm('far')}",
        f"  MDR       {pm('mdr')}",
        f"  accuracy  {pm('accuracy')}",
        f"  detected  {pm('detection_rate')} of the runs",
        f"  delay     {pm('delay_s', 4)} s over detected runs; censored median "
        f"{metrics['delay_censored_median_s']:.4g} s (undetected runs beyond the horizon)",
        "wall time " + f"{timings['wall_s']:.1f} s  (" + ", ".join(
            f"{k.removesuffix('_s')} {v:.1f}" for k, v in timings.items() if k != "wall_s") + ")",
        *([f"study     {type(setup.study).__name__}: " + ", ".join(f"{k} {v:.4g}" for k, v in study.items())]
          if study else []),
        f"run dir   {run_dir}",
    ]
    if tracking_line:
        lines.append(tracking_line)
    return "\n".join(lines)


def write_status(run_dir: Path, status: str, labels: Mapping[str, str], error: str | None = None,
                 **extra: Any) -> Path:
    """``summary.json`` of a run that did not finish (``killed``, ``failed``): never a silent stub."""
    run_dir.mkdir(parents=True, exist_ok=True)
    path = run_dir / "summary.json"
    path.write_text(json.dumps({"status": status, "labels": dict(labels), **({"error": error} if error else {}),
                                **extra}, indent=2, allow_nan=True))
    return path


def mark_not_logged(run_dir: Path, error: str, pending: Mapping[str, Any]) -> Path:
    """Keep what was to be logged in ``mlflow_pending.json`` and say so in ``summary.json``."""
    path = run_dir / PENDING_FILE
    path.write_text(json.dumps(pending, indent=1, allow_nan=True))
    summary_path = run_dir / "summary.json"
    try:
        summary = json.loads(summary_path.read_text())
    except (OSError, ValueError):
        summary = {"status": "finished"}
    summary["tracking"] = {"logged": False, "error": error, "pending": PENDING_FILE}
    summary_path.write_text(json.dumps(summary, indent=2, allow_nan=True))
    return path


def _under_joblib_launcher(hydra_cfg) -> bool:
    target = str(hydra_cfg.launcher.get("_target_", ""))
    return "joblib" in target.lower()


def _start_tracking(cfg, hc, labels: Mapping[str, str], n_jobs: int, run_dir: Path, params=()):
    """Create the job's MLflow run (a child of the sweep's parent in a multirun); None if disabled."""
    from hydra.types import RunMode

    from .tracking import RunTracker, TrackingSettings, git_commit, parent_run_id

    settings = TrackingSettings.from_config(dict(cfg.tracking), str(cfg.outputs_root))
    if settings is None:
        return None
    multirun = hc.mode == RunMode.MULTIRUN
    tags = {"mosd.role": "job", "mosd.mode": "multirun" if multirun else "run",
            "mosd.overrides": " ".join(hc.overrides.task), "mosd.run_dir": str(run_dir.resolve()),
            "mosd.n_jobs": str(n_jobs), "mosd.backend": str(cfg.optimizer.get("backend", "loky")),
            **{f"mosd.{k}": v for k, v in labels.items()}}
    if params:
        tags["mosd.params"] = ",".join(params)
    commit = git_commit()
    if commit:
        tags["mlflow.source.git.commit"] = commit
    name = f"{labels['fault']}-{labels['detector']}-{labels['optimizer']}" + (f"-{hc.job.num}" if multirun else "")
    return RunTracker(settings, name, tags, parent_run_id(hc.sweep.dir if multirun else None)).start()


def _pending(tracker, params, metrics, files) -> dict:
    """What :func:`mosd.app.tracking.log_pending` needs to log this run later."""
    from dataclasses import asdict

    return {"settings": asdict(tracker.settings), "run_name": tracker.run_name, "tags": tracker.tags,
            "parent_run_id": tracker.parent_run_id, "params": params,
            "metrics": [(k, float(v), int(step)) for k, v, step in metrics], "artifacts": [str(f) for f in files]}


def run(cfg, started: float | None = None):
    """The Hydra task: one experiment, its files and its MLflow run.

    Parameters
    ----------
    cfg : DictConfig
        The job's composed config (validated by :func:`preflight` beforehand).
    started : float, optional
        ``time.perf_counter()`` at process start (single runs), for the wall time.
    """
    from hydra.core.hydra_config import HydraConfig
    from hydra.types import RunMode
    from omegaconf import OmegaConf

    from .plots import FigureWriter
    from .progress import Progress
    from .tracking import TrackingError, flatten

    install_signal_handlers()
    task_start = time.perf_counter()
    hc = HydraConfig.get()
    multirun = hc.mode == RunMode.MULTIRUN
    started = task_start if (started is None or multirun) else started
    run_dir = Path(hc.runtime.output_dir)
    choices = {k: v for k, v in hc.runtime.choices.items() if not k.startswith("hydra/") and v is not None}
    labels = {group: str(choices.get(group, "")) for group in (*COMPONENTS, "tracking", "experiment")}
    setup = build(cfg)
    labels["online"] = "true" if setup.experiment.detector.is_causal else "false"
    n_jobs = setup.n_jobs
    if n_jobs > 1 and _under_joblib_launcher(hc):
        # nested joblib under the joblib launcher silently becomes threads: evaluate in-process
        log.info("joblib launcher: fitness evaluation runs in-process (optimizer.n_jobs=%d -> 1)", n_jobs)
        n_jobs = 1

    tracker = _start_tracking(cfg, hc, labels, n_jobs, run_dir, tuple(setup.experiment.detector.tunable))
    position = int(hc.job.num) if multirun and _under_joblib_launcher(hc) else 0
    progress = Progress(setup.n_gen, enabled=cfg.progress, position=position,
                        description=f"job {hc.job.num}" if multirun else "")
    timings = {"startup_s": task_start - started}
    figures = None
    try:
        if not multirun:
            # the summary's first line now, so that a user (or a log file) sees the run start; the
            # rest comes at the end (a sweep prints each job's summary whole: jobs may run at once)
            print(header_line(labels, setup), flush=True)
        # started now: matplotlib loads on the other core while this process simulates
        figures = FigureWriter()
        result = setup.experiment.run(setup.algorithm, setup.termination, n_jobs=n_jobs, bounds=setup.bounds,
                                      choose=setup.choose, callback=progress, backend=setup.backend,
                                      dask_address=setup.dask_address)
        progress.close()
        timings.update(result.timings)
        study_metrics, study_files = {}, []
        if setup.study is not None:
            t0 = time.perf_counter()
            run_dir.mkdir(parents=True, exist_ok=True)
            study_metrics, study_files = setup.study.run(setup.experiment, result, run_dir)
            result.timings["study_s"] = timings["study_s"] = time.perf_counter() - t0
        metrics = {**final_metrics(result, result.example["seconds_per_point"]),
                   **{k: float(v) for k, v in study_metrics.items()}}
        logged: list[tuple[str, float, int]] = []
        params: dict[str, str] = {}
        sent: list[Path] = []  # artifacts already handed to MLflow

        def log_early(text_files: list[Path]) -> None:
            # MLflow logs the config, the history, the results and the text files while the
            # figures are drawn; only the timings and the PNGs are left for the end
            nonlocal params
            if tracker is None:
                return
            params = flatten(OmegaConf.to_container(cfg, resolve=True))
            logged.extend((key, record[key], record["generation"]) for record in result.history
                          for key in ("hypervolume", "archive_size", "best_accuracy", "n_eval")
                          if np.isfinite(record[key]))
            logged.extend((k, v, 0) for k, v in metrics.items())
            sent.extend([*text_files, *study_files])
            tracker.log(params=params, metrics=logged, artifacts=sent)
            tracker.send()

        t0 = time.perf_counter()
        files = write_run_files(run_dir, cfg, result, setup, labels, study_metrics, figures,
                                on_text_files=log_early) + list(study_files)
        figures.close()
        timings["files_s"] = time.perf_counter() - t0
        if figures.fallback:
            log.warning("figures drawn in-process: %s", figures.fallback)
        tracking_line, not_logged = "", None
        if tracker is not None:
            t0 = time.perf_counter()
            finals = [(k, v, 0) for k, v in {**timings, "wall_time_s": time.perf_counter() - started}.items()]
            logged.extend(finals)
            tracker.log(metrics=finals, artifacts=[f for f in files if f not in sent])
            try:
                run_id = tracker.finish("FINISHED")
            except TrackingError as exc:
                # the work is done and on disk: keep it, say how to log it later
                not_logged = one_line(exc)
                mark_not_logged(run_dir, not_logged, _pending(tracker, params, logged, files))
                tracking_line = f"mlflow    NOT LOGGED ({tracker.settings.uri}): {not_logged}"
            else:
                # what MLflow still took after the figures (the rest overlapped them)
                timings["mlflow_s"] = time.perf_counter() - t0
                where = "in-process" if tracker.in_process else "side process, overlapping the run"
                startup = ", ".join(f"{k.removeprefix('mlflow_').removesuffix('_s')} {v:.1f} s"
                                    for k, v in tracker.startup_timings.items())
                tracking_line = (f"mlflow    run {run_id}  experiment {tracker.settings.experiment!r}"
                                 f"  store {tracker.settings.uri}\n          ({where}: {startup})")
                if tracker.note:
                    tracking_line += f"\n          store: {tracker.note}"
        timings["wall_s"] = time.perf_counter() - started
        print(_format_summary(labels, result, setup, metrics, timings, run_dir, tracking_line, study_metrics,
                              header=multirun), flush=True)
        if not_logged is not None:
            NOT_LOGGED.append(run_dir)
            print(f"mosd: error: the run was not logged to MLflow ({not_logged}); its files are complete in "
                  f"{run_dir}; log it later with: python -m mosd log {run_dir}", file=sys.stderr, flush=True)
        return result
    except BaseException as exc:
        progress.close()
        if figures is not None:
            figures.close(wait=False)
        # a signal raised inside compiled code (numba) comes out as a SystemError with the
        # Interrupted as its context: what counts is that a stop signal arrived
        killed = isinstance(exc, KeyboardInterrupt) or bool(RECEIVED)
        if killed:
            shutdown_workers()
            signum = exc.signum if isinstance(exc, Interrupted) else (RECEIVED[-1] if RECEIVED else signal.SIGINT)
        status = "KILLED" if killed else "FAILED"
        error = f"stopped by {signal.Signals(signum).name}" if killed else f"{type(exc).__name__}: {one_line(exc)}"
        run_id, marked = None, ""
        if tracker is not None and tracker.open:
            try:
                # on a signal, do not wait for a side process still importing MLflow: it ends the run alone
                run_id = tracker.abort(status, error, traceback.format_exc(), timeout=ABORT_WAIT_S if killed else None)
                marked = f"MLflow run {run_id} marked {status}; " if run_id else \
                    f"the MLflow run will be marked {status} by the tracking process; "
            except Exception as tracking_exc:
                print(f"mosd: could not mark the MLflow run {status}: {one_line(tracking_exc)}", file=sys.stderr)
        try:
            write_status(run_dir, status.lower(), labels, error, mlflow_run_id=run_id,
                         elapsed_s=time.perf_counter() - started)
        except OSError:
            pass
        if killed:
            print(f"mosd: stopped by {signal.Signals(signum).name} after {time.perf_counter() - started:.1f} s: "
                  f"{marked}{run_dir} is incomplete (summary.json status 'killed')", file=sys.stderr, flush=True)
            interrupted = exc if isinstance(exc, Interrupted) else Interrupted(signum)
            interrupted.reported = True
            if interrupted is not exc:
                raise interrupted from None
        raise


