"""The only code that talks to MLflow: :class:`MlflowStore` (MLflow imported on construction).

``import mlflow`` costs 1.5–3.5 s of pure-Python work, so a run reaches this
class through the side process of :mod:`mosd.app.tracker`; a sweep's parent run
(:mod:`mosd.app.sweep`) and ``mosd log`` (:mod:`mosd.app.pending`) use it
directly. Every logging call commits (~20 ms), so per-generation metrics go in
one ``log_batch`` (MLflow splits it into its own 1000-entry chunks). A sqlite
store is created or opened under :func:`mosd.app.store.store_lock`.
"""
from __future__ import annotations

import contextlib
import logging
import os
import subprocess
import time
from pathlib import Path
from typing import Any, Iterable, Mapping

from .settings import TrackingSettings, redacted
from .store import (LOCK_TIMEOUT_S, TrackingError, prepare_sqlite_store, sqlite_path, sqlite_store_state,
                    store_lock, template_directory)

#: MLflow's HTTP retries for a run (its defaults, 7 retries with backoff 2, block ~250 s on a dead server).
HTTP_ENV_DEFAULTS = {"MLFLOW_HTTP_REQUEST_MAX_RETRIES": "2", "MLFLOW_HTTP_REQUEST_BACKOFF_FACTOR": "1",
                     "MLFLOW_HTTP_REQUEST_TIMEOUT": "30"}
# MLflow limits: param values 6000 characters, tag values 8000.
MAX_PARAM_LENGTH = 6000
MAX_TAG_LENGTH = 8000
#: MLflow's table of experiments (the template store's Default experiment is removed from it: store_template)
MLFLOW_EXPERIMENTS_TABLE = "experiments"
#: Tag of a run whose params, metrics or artifacts were not all logged (the run is FAILED until
#: ``mosd log RUN_DIR`` completes it: :mod:`mosd.app.pending`).
LOGGING_ERROR_TAG = "mosd.logging_error"


def git_commit(path: str | os.PathLike | None = None) -> str | None:
    """The commit of the git checkout containing ``path`` (default: this package), if any.

    The checkout's ``.git`` (a folder, or a file in a worktree) is looked for in
    ``path`` and every folder above it: the package lies inside the checkout,
    not at its root. An installed copy (site-packages) is in no checkout: None.
    """
    start = Path(path).resolve() if path is not None else Path(__file__).resolve().parent.parent
    if "site-packages" in start.parts:  # a copy made by pip install: its checkout (if any) may hold other code
        return None
    where = next((folder for folder in (start, *start.parents) if (folder / ".git").exists()), None)
    if where is None:
        return None
    try:
        out = subprocess.run(["git", "-C", str(where), "rev-parse", "HEAD"], capture_output=True, text=True, timeout=5)
    except (OSError, subprocess.SubprocessError):
        return None
    return out.stdout.strip() or None if out.returncode == 0 else None


def flatten(tree: Mapping[str, Any], prefix: str = "") -> dict[str, str]:
    """Nested mapping → ``{"a.b.c": "value"}`` with string values (MLflow params)."""
    flat: dict[str, str] = {}
    for key, value in tree.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping):
            flat.update(flatten(value, name + "."))
        else:
            flat[name] = str(value)[:MAX_PARAM_LENGTH]
    return flat


def store_template() -> Path | None:
    """The empty sqlite store that MLflow makes on an empty database, built once per machine and version.

    MLflow makes a new store by running every schema migration since its first release (~4 s of CPU: 135
    migration scripts, 63 table rebuilds), each time. The result depends only on the versions of MLflow,
    SQLAlchemy, alembic and SQLite, which name the file. MLflow's public store class makes it
    (``SqlAlchemyStore`` migrates an empty database when it is constructed, then adds the Default
    experiment); the Default experiment is then removed from the template, because its artifact
    location depends on the working directory: MLflow adds it again when a store copied from the
    template is first opened, as on a store it made.
    None when templates are off (:func:`mosd.app.store.template_directory`).
    """
    directory = template_directory()
    if directory is None:
        return None
    directory.mkdir(parents=True, exist_ok=True)
    import sqlite3

    import alembic
    import mlflow
    import sqlalchemy
    from mlflow.store.tracking.sqlalchemy_store import SqlAlchemyStore

    key = (f"mlflow-{mlflow.__version__}_sqlalchemy-{sqlalchemy.__version__}_alembic-{alembic.__version__}"
           f"_sqlite-{sqlite3.sqlite_version}")
    template = directory.resolve() / f"empty_{key}.db"
    if template.is_file() and sqlite_store_state(template).state == "ok":
        return template
    partial = template.with_name(f"{template.name}.partial-{os.getpid()}")
    partial.unlink(missing_ok=True)
    try:
        made = SqlAlchemyStore(f"sqlite:///{partial}", (directory / "unused-artifacts").resolve().as_uri())
        made.engine.dispose()
        with contextlib.closing(sqlite3.connect(partial)) as con, con:
            # the Default experiment (id 0) and its artifact location, which belongs to whoever opens the copy
            con.execute(f"DELETE FROM {MLFLOW_EXPERIMENTS_TABLE} WHERE experiment_id = 0")
        os.replace(partial, template)  # another process building it too: either whole file wins
    finally:
        partial.unlink(missing_ok=True)
    return template


def start_from_template(db: Path) -> bool:
    """Make the new sqlite store ``db`` a copy of :func:`store_template` (under the store lock).

    False when it could not (templates off, a read-only cache, MLflow's internals moved): MLflow then
    creates the store itself, as it always did.
    """
    try:
        template = store_template()
        if template is None:
            return False
        import shutil

        from .atomic import write_atomically

        with open(template, "rb") as source:  # whole or absent: a full disk leaves no half store
            write_atomically(db, lambda out: shutil.copyfileobj(source, out), binary=True)
        return True
    except Exception as exc:  # only a shortcut: MLflow's own creation follows
        logging.getLogger(__name__).debug("no store template: %s", exc)
        return False


class MlflowStore:
    """The only object that talks to MLflow (imported on construction).

    Parameters
    ----------
    settings : TrackingSettings
    """

    def __init__(self, settings: TrackingSettings):
        for key, value in HTTP_ENV_DEFAULTS.items():
            os.environ.setdefault(key, value)
        if redacted(settings.uri) != settings.uri:  # MLflow prints each run's URL, with the URI's password
            os.environ["MLFLOW_SUPPRESS_PRINTING_URL_TO_STDOUT"] = "true"
        from mlflow.tracking import MlflowClient

        # alembic prints its migration steps at INFO when a fresh sqlite DB is created
        logging.getLogger("alembic").setLevel(logging.WARNING)
        logging.getLogger("mlflow.store.db.utils").setLevel(logging.WARNING)
        self.settings = settings
        #: what happened to the store on the way in (e.g. an unfinished one moved aside), or None
        self.note: str | None = None
        self._experiment_id: str | None = None
        db = sqlite_path(settings.uri)
        if db is None:
            self.client = MlflowClient(tracking_uri=settings.uri)
            return
        # create/migrate exactly once across processes (the client opens the store when it is
        # constructed), and the experiment with it
        with store_lock(settings.uri) as held:
            if not held:
                raise TrackingError(f"the tracking store {db} stayed locked for {LOCK_TIMEOUT_S:g} s "
                                    f"(another process creating it?)")
            self.note = prepare_sqlite_store(db)
            if not db.exists() or db.stat().st_size == 0:
                start_from_template(db)
            self.client = MlflowClient(tracking_uri=settings.uri)
            self._experiment_id = self.experiment_id()

    def experiment_id(self) -> str:
        """Id of the settings' experiment, created (with its artifact location) if new; asked once per store.

        Kept after the first answer: the run's start reply names it after the run is created, and a tracking
        server that dies in between must not make the created run look uncreated (its id would be lost, and
        ``mosd log`` would make a second run: issue 53 item 7).
        """
        if self._experiment_id is None:
            self._experiment_id = self._find_or_create_experiment()
        return self._experiment_id

    def _find_or_create_experiment(self) -> str:
        name = self.settings.experiment
        found = self.client.get_experiment_by_name(name)
        # the kind of a training-runs experiment: MLflow UIs that read it open it on its runs, not the GenAI
        # overview (3.17 follows its Model training switch instead: README, "The MLflow UI")
        kind = {"mlflow.experimentKind": "custom_model_development"}
        if found is not None:
            if "mlflow.experimentKind" not in found.tags:  # made before mosd set the kind
                self.client.set_experiment_tag(found.experiment_id, *next(iter(kind.items())))
            return found.experiment_id
        location = f"{self.settings.artifact_root.rstrip('/')}/{name}"
        try:
            return self.client.create_experiment(name, artifact_location=location, tags=kind)
        except Exception:
            # another process created it in between
            found = self.client.get_experiment_by_name(name)
            if found is None:
                raise
            return found.experiment_id

    def create_run(self, run_name: str, tags: Mapping[str, str], parent_run_id: str | None = None) -> str:
        tags = {k: redacted(str(v))[:MAX_TAG_LENGTH] for k, v in tags.items()}
        if parent_run_id:
            tags["mlflow.parentRunId"] = parent_run_id
        run = self.client.create_run(self.experiment_id(), run_name=run_name, tags=tags)
        return run.info.run_id

    def log(self, run_id: str, params: Mapping[str, str] | None = None,
            metrics: Iterable[tuple[str, float, int]] = (), tags: Mapping[str, str] | None = None,
            artifacts: Iterable[str] = ()) -> None:
        """One batched call for params, metrics and tags (URI passwords masked), then the artifact files."""
        from mlflow.entities import Metric, Param, RunTag

        stamp = int(time.time() * 1000)
        self.client.log_batch(
            run_id,
            metrics=[Metric(key, float(value), stamp, int(step)) for key, value, step in metrics],
            params=[Param(k, redacted(str(v))[:MAX_PARAM_LENGTH]) for k, v in (params or {}).items()],
            tags=[RunTag(k, redacted(str(v))[:MAX_TAG_LENGTH]) for k, v in (tags or {}).items()],
        )
        for path in artifacts:
            p = Path(path)
            if p.is_dir():
                self.client.log_artifacts(run_id, str(p))
            elif p.is_file():
                self.client.log_artifact(run_id, str(p))

    def end(self, run_id: str, status: str = "FINISHED", error: str | None = None) -> None:
        if error:
            self.client.set_tag(run_id, "error", redacted(error)[:MAX_TAG_LENGTH])
        self.client.set_terminated(run_id, status=status)

    def active_run(self, run_id: str | None) -> bool:
        """True if ``run_id`` is a run of this store that is not deleted."""
        from mlflow.exceptions import MlflowException

        if not run_id:
            return False
        try:
            return self.client.get_run(run_id).info.lifecycle_stage == "active"
        except MlflowException as exc:
            if exc.error_code == "RESOURCE_DOES_NOT_EXIST":
                return False
            raise

    def run_of_directory(self, run_dir: str) -> str | None:
        """The id of the one active run of the experiment tagged ``mosd.run_dir=run_dir``, else None."""
        if "'" in run_dir:  # not expressible in a filter string: no guess
            return None
        runs = self.client.search_runs([self.experiment_id()], f"tags.`mosd.run_dir` = '{run_dir}'", max_results=2)
        return runs[0].info.run_id if len(runs) == 1 else None

    def not_yet_logged(self, run_id: str, params: Mapping[str, str], metrics: Iterable[tuple[str, float, int]]
                       ) -> tuple[dict[str, str], list[tuple[str, float, int]]]:
        """The params and metric values ``(key, value, step)`` that run ``run_id`` does not hold yet.

        Logging only these makes logging again idempotent: a param is logged
        once, and a metric value that is already in the key's history (same
        step, same value; NaN equal to NaN) is not added a second time.
        """
        run = self.client.get_run(run_id)
        new_params = {k: v for k, v in params.items() if k not in run.data.params}
        history: dict[str, set[tuple[int, str]]] = {}
        new_metrics = []
        for key, value, step in metrics:
            if key not in run.data.metrics:
                new_metrics.append((key, value, step))
                continue
            if key not in history:
                history[key] = {(m.step, repr(float(m.value))) for m in self.client.get_metric_history(run_id, key)}
            if (int(step), repr(float(value))) not in history[key]:
                new_metrics.append((key, value, step))
        return new_params, new_metrics

    def complete(self, run_id: str, tags: Mapping[str, str] | None = None) -> None:
        """End run ``run_id`` FINISHED with ``tags``, without the error tags of an earlier failure."""
        held = self.client.get_run(run_id).data.tags
        for key in ("error", LOGGING_ERROR_TAG):
            if key in held:
                self.client.delete_tag(run_id, key)
        if tags:
            self.log(run_id, tags=tags)
        self.client.set_terminated(run_id, status="FINISHED")


