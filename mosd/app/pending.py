"""Runs that MLflow did not take at the time, and ``mosd log RUN_DIR``, which logs them later.

When MLflow fails after the work, the run directory is complete and
``mlflow_pending.json`` holds what was to be logged (:func:`mark_not_logged`);
``python -m mosd log RUN_DIR`` sends it as a new run (:func:`log_pending`).
"""
from __future__ import annotations

import json
import os
import sys
from dataclasses import asdict
from pathlib import Path
from typing import Any, Iterable, Mapping

from ..validation import ConfigError
from .checks import check_tracking
from .config import described
from .mlflow_client import MlflowStore
from .settings import TrackingSettings
from .store import TrackingError

#: File in a run directory with the MLflow requests of a run that was not logged.
PENDING_FILE = "mlflow_pending.json"
#: Exit code of a run whose work finished but whose MLflow logging failed.
EXIT_NOT_LOGGED = 3
#: Run directories of this process whose MLflow logging failed (:func:`mosd.app.main` exits non-zero).
NOT_LOGGED: list[Path] = []


def pending_request(tracker, params: Mapping[str, str], metrics: Iterable[tuple[str, float, int]],
                    files: Iterable[str | os.PathLike]) -> dict:
    """What :func:`log_pending` needs to log a :class:`~mosd.app.tracker.RunTracker`'s run later."""
    return {"settings": asdict(tracker.settings), "run_name": tracker.run_name, "tags": tracker.tags,
            "parent_run_id": tracker.parent_run_id, "params": dict(params),
            "metrics": [(k, float(v), int(step)) for k, v, step in metrics], "artifacts": [str(f) for f in files]}


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


def log_pending(run_dir: str | os.PathLike, uri: str | None = None) -> str:
    """Log a run directory's ``mlflow_pending.json`` (a run whose logging failed) as a new run.

    Returns the new run id; the pending file is renamed ``*.logged`` and
    ``summary.json`` records the id.
    """
    run_dir = Path(run_dir)
    path = run_dir / PENDING_FILE
    if not path.is_file():
        raise ConfigError(f"{run_dir} has no {PENDING_FILE}; allowed: a run directory whose run was not logged")
    pending = json.loads(path.read_text())
    settings = TrackingSettings(**{**pending["settings"], **({"uri": uri} if uri else {})})
    check_tracking(settings)
    store = MlflowStore(settings)
    parent = pending.get("parent_run_id")
    try:
        if parent:
            store.client.get_run(parent)
    except Exception:  # the sweep's parent is in another store, or gone
        parent = None
    run_id = store.create_run(pending["run_name"], {**pending["tags"], "mosd.logged_later": "true"}, parent)
    try:
        store.log(run_id, pending["params"], [tuple(m) for m in pending["metrics"]],
                  artifacts=[a for a in pending["artifacts"] if Path(a).exists()])
    except BaseException:
        store.end(run_id, "FAILED", "mosd log: logging the run directory failed")
        raise
    store.end(run_id, "FINISHED")
    path.rename(path.with_name(path.name + ".logged"))
    summary_path = run_dir / "summary.json"
    try:
        summary = json.loads(summary_path.read_text())
        summary["tracking"] = {"logged": True, "run_id": run_id, "uri": settings.uri}
        summary_path.write_text(json.dumps(summary, indent=2, allow_nan=True))
    except (OSError, ValueError):
        pass
    return run_id


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
            run_id = log_pending(run_dir, args.tracking_uri)
            print(f"mosd log: {run_dir} -> MLflow run {run_id}")
    except (ConfigError, TrackingError) as exc:
        print(f"mosd log: error: {described(exc) if isinstance(exc, TrackingError) else exc}", file=sys.stderr)
        return 2
    except Exception as exc:  # MLflow's own errors: one line, the pending file is kept
        print(f"mosd log: error: {described(exc)}", file=sys.stderr)
        return 1
    return 0

