"""Runs that MLflow did not take at the time, and ``mosd log RUN_DIR``, which logs them later.

When MLflow fails after the work, the run directory is complete and
``mlflow_pending.json`` holds what was to be logged (:func:`mark_not_logged`).
If the MLflow run exists (the store took the run but not all of its params,
metrics or artifacts, e.g. a full artifact directory), it is ended FAILED with
the tag ``mosd.logging_error`` (:class:`mosd.app.channel.Handler`), and
``python -m mosd log RUN_DIR`` completes that same run (:func:`log_pending`):
it logs what the run does not hold yet, uploads the files again, logs the
run's model ``detector`` from the fitted pipeline saved in the run directory if
the run lacks it, and ends it FINISHED. It is idempotent: run twice, it logs once.
A model record whose upload failed (MLflow leaves it FAILED or PENDING: the run's
own attempt, or a ``mosd log`` that failed half-way) is deleted once the model is
logged whole (:func:`drop_unfinished_models`): the run shows one model, the good one.
"""
from __future__ import annotations

import json
import math
import os
import sys
from dataclasses import asdict
from pathlib import Path
from typing import Any, Iterable, Mapping

from ..validation import ConfigError
from .checks import check_tracking
from .config import described
from .atomic import write_atomically, write_json
from .mlflow_client import MlflowStore
from .settings import TrackingSettings, redacted, without_password
from .store import TrackingError, short_error

#: File in a run directory with the MLflow requests of a run that was not logged.
PENDING_FILE = "mlflow_pending.json"
#: What the pending file is renamed to once ``mosd log`` has logged it.
LOGGED_FILE = PENDING_FILE + ".logged"
#: Exit code of a run whose work finished but whose MLflow logging failed.
EXIT_NOT_LOGGED = 3
#: Run directories of this process whose MLflow logging failed (:func:`mosd.app.main` exits non-zero).
NOT_LOGGED: list[Path] = []


def pending_request(tracker, params: Mapping[str, str], metrics: Iterable[tuple[str, float, int]],
                    files: Iterable[str | os.PathLike], model: str | os.PathLike | None = None) -> dict:
    """What :func:`log_pending` needs to log a :class:`~mosd.app.tracker.RunTracker`'s run later.

    ``run_id`` is the MLflow run the tracker created (None if the store did not
    take even that): ``mosd log`` completes it rather than making a second one.
    ``model``: the fitted pipeline saved in the run directory
    (:func:`mosd.app.detector_model.save_for_run`), logged as the run's model
    ``detector`` if the run lacks it.
    """
    # the password of tracking.uri stays out of the file: `mosd log` takes it from the driver's
    # environment (PGPASSWORD, ~/.pgpass, MLFLOW_TRACKING_PASSWORD) or --tracking-uri
    settings = {**asdict(tracker.settings), "uri": redacted(tracker.settings.uri)}
    return {"settings": settings, "run_id": tracker.run_id, "run_name": tracker.run_name,
            "tags": tracker.tags, "parent_run_id": tracker.parent_run_id, "params": dict(params),
            "metrics": [(k, float(v), int(step)) for k, v, step in metrics], "artifacts": [str(f) for f in files],
            "model": None if model is None else str(model)}


def _update_summary(run_dir: Path, tracking: Mapping[str, Any]) -> None:
    summary_path = run_dir / "summary.json"
    try:
        summary = json.loads(summary_path.read_text())
    except (OSError, ValueError):
        summary = {"status": "finished"}
    summary["tracking"] = dict(tracking)
    write_json(summary_path, summary)


def mark_not_logged(run_dir: Path, error: str, pending: Mapping[str, Any], status: str | None = None) -> Path:
    """Keep what was to be logged in ``mlflow_pending.json`` and say so in ``summary.json``.

    ``status``: what the MLflow run ``pending["run_id"]`` was ended with (FAILED
    when it did not get everything), recorded in the summary.
    """
    path = write_json(run_dir / PENDING_FILE, pending)
    _update_summary(run_dir, {"logged": False, "error": error, "pending": PENDING_FILE,
                              **({"run_id": pending["run_id"], "mlflow_status": status} if pending.get("run_id")
                                 else {})})
    return path


def _saved_model(run_dir: Path) -> Path | None:
    """The fitted pipeline a run saved under ``model/``, for a pending file written before it named it."""
    from .detector_model import LEGACY_FILES, STATE_FILE

    return next((run_dir / "model" / name for name in (STATE_FILE, *LEGACY_FILES)
                 if (run_dir / "model" / name).is_file()), None)


def log_pending(run_dir: str | os.PathLike, uri: str | None = None) -> tuple[str, bool, list[str], str | None]:
    """Log a run directory's ``mlflow_pending.json`` (a run whose logging failed).

    Returns ``(run id, logged now, files that were to be logged and are gone,
    the model's models:/ URI or None)``.

    The MLflow run the pending file names is completed when it is in the store
    (``uri``, default the run's own): only the params and metric values it
    does not hold yet are logged, the files are uploaded again (a copy cut short
    by a full disk is replaced) and it is ended FINISHED, without its error
    tags (a pending file written before mosd recorded the run id: the one run
    tagged with the same ``mosd.run_dir``). Otherwise a new run is made, and
    its id written to the pending file first, so that a ``mosd log`` that fails
    half-way is resumed, not repeated. A file gone from the run directory since
    is named in the result, not silently skipped. The fitted pipeline the run
    saved under ``model/`` is logged as the run's pyfunc model ``detector``
    unless the run holds it complete already (the store took it at the time);
    a pending file written before it named the model: the one file under
    ``model/`` there is (``chart_detector.npz`` or ``pca_detector.npz``).
    The pending file is then renamed ``*.logged`` and ``summary.json`` records
    the id; a second ``mosd log`` finds it logged and logs nothing (``logged
    now`` False).
    """
    run_dir = Path(run_dir)
    path = run_dir / PENDING_FILE
    if not path.is_file():
        done = run_dir / LOGGED_FILE
        if done.is_file():
            logged = json.loads(done.read_text())
            return logged.get("run_id") or "", False, [], logged.get("model_uri")
        raise ConfigError(f"{run_dir} has no {PENDING_FILE}; allowed: a run directory whose run was not logged")
    pending = json.loads(path.read_text())
    stored = {**pending["settings"], "uri": without_password(pending["settings"]["uri"])}
    settings = TrackingSettings(**{**stored, **({"uri": uri} if uri else {})})
    check_tracking(settings)
    store = MlflowStore(settings)
    run_id = None
    if without_password(redacted(settings.uri)) == stored["uri"]:
        # no run id (a pending file written before mosd recorded it, or a store that created the run and died
        # before it answered): the one run made for the same directory
        run_id = pending.get("run_id") or store.run_of_directory(pending["tags"].get("mosd.run_dir", ""))
    if not store.active_run(run_id):
        parent = pending.get("parent_run_id")
        if parent and not store.active_run(parent):  # the sweep's parent is in another store, or gone
            parent = None
        run_id = store.create_run(pending["run_name"], pending["tags"], parent)
        pending = {**pending, "run_id": run_id, "settings": {**asdict(settings), "uri": redacted(settings.uri)}}
        write_json(path, pending)
    # strict JSON wrote an undefined value (NaN) as null: MLflow takes it back as NaN
    logged = [(name, math.nan if value is None else value, step) for name, value, step in pending["metrics"]]
    params, metrics = store.not_yet_logged(run_id, pending["params"], logged)
    # the files where the run directory is now (it may have been moved since)
    recorded = Path(pending["tags"].get("mosd.run_dir") or run_dir)

    def here(file: str) -> Path:
        return run_dir / Path(file).relative_to(recorded) if Path(file).is_relative_to(recorded) else Path(file)

    files = [here(a) for a in pending["artifacts"]]
    model = _saved_model(run_dir) if "model" not in pending else (
        None if pending["model"] is None else here(pending["model"]))
    # summary.json says where the run is logged before it is sent: the store's copy is the final one
    summary_path = run_dir / "summary.json"
    before = summary_path.read_bytes() if summary_path.is_file() else None
    if before is not None:
        _update_summary(run_dir, {"logged": True, "run_id": run_id, "uri": redacted(settings.uri)})
    try:
        store.log(run_id, params, metrics, artifacts=[str(f) for f in files if f.exists()])
        gone = [str(f) for f in files if not f.exists()]
        model_uri = None
        if model is not None and model.exists():
            from .detector_model import log_model, logged_model_uri

            model_uri = logged_model_uri(settings.uri, run_id) or log_model(str(model), settings.uri, run_id)
            drop_unfinished_models(settings.uri, run_id)  # the record a failed upload left beside the good one
        elif model is not None:
            gone.append(str(model))
    except BaseException:
        if before is not None:
            write_atomically(summary_path, lambda out: out.write(before), binary=True)
        store.end(run_id, "FAILED", f"mosd log: logging the run directory failed; python -m mosd log {run_dir} "
                                    f"completes this run")
        raise
    store.complete(run_id, {"mosd.logged_later": "true"})
    if model_uri is not None:  # a second `mosd log` prints it too
        write_json(path, {**pending, "model_uri": model_uri})
    path.rename(run_dir / LOGGED_FILE)
    return run_id, True, gone, model_uri


def drop_unfinished_models(uri: str, run_id: str) -> int:
    """Delete the run's ``detector`` model records whose upload did not finish (FAILED, PENDING); returns how many."""
    from mlflow import MlflowClient
    from mlflow.entities import LoggedModelStatus

    from .detector_model import MODEL_NAME

    client = MlflowClient(uri)
    models = client.search_logged_models([client.get_run(run_id).info.experiment_id],
                                         filter_string=f"source_run_id = '{run_id}' AND name = '{MODEL_NAME}'")
    unfinished = [m for m in models if m.status != LoggedModelStatus.READY]
    for model in unfinished:
        client.delete_logged_model(model.model_id)
    return len(unfinished)


def log_main(argv) -> int:
    """``mosd log RUN_DIR [--tracking-uri URI]``: log runs that MLflow did not take at the time."""
    import argparse

    parser = argparse.ArgumentParser(prog="mosd log", description="Log run directories whose MLflow logging failed.")
    parser.add_argument("run_dirs", nargs="+", metavar="RUN_DIR")
    parser.add_argument("--tracking-uri", default=None, help="another store than the one the run was meant for")

    def error(message: str):
        raise ConfigError(message)

    parser.error = error
    try:
        args = parser.parse_args(list(argv))
        for run_dir in args.run_dirs:
            run_id, now, gone, model_uri = log_pending(run_dir, args.tracking_uri)
            print(f"mosd log: {run_dir} -> MLflow run {run_id}" if now else
                  f"mosd log: {run_dir} was logged already (MLflow run {run_id}); nothing logged")
            if model_uri:  # as the run's own summary gives it
                print(f"          model {model_uri} (runs:/{run_id}/detector): "
                      f"python -m mosd monitor --model {model_uri} DATA.csv")
            if gone:  # removed from the run directory since: said, not silently skipped
                print(f"mosd log: not logged, no longer in {run_dir}: {', '.join(gone)}", file=sys.stderr)
    except (ConfigError, TrackingError) as exc:
        print(f"mosd log: error: {short_error(described(exc)) if isinstance(exc, TrackingError) else exc}",
              file=sys.stderr)
        return 2
    except Exception as exc:  # MLflow's own errors: one line (no SQL statement), the pending file is kept
        print(f"mosd log: error: {short_error(described(exc))}; the pending file is kept: run it again once the "
              f"store can take it", file=sys.stderr)
        return 1
    return 0

