"""MLflow tracking of runs and sweeps (app layer: the science core never imports this).

Design, from measurements on this machine (docs/DECISIONS.md, "Facts"):

* ``import mlflow`` costs 1.5–3.5 s of pure-Python work. A background *thread*
  does not hide it (it competes for the GIL with the simulation), so a run talks
  to MLflow through a small side process (:class:`RunTracker`): the process is
  started when the run starts, imports MLflow and creates the run on the second
  core while the first one simulates, and at the end receives everything in a few
  batched calls. When MLflow is already imported (a sweep under the basic
  launcher, whose callback imported it) the same requests run in-process.
* Every logging call commits (~20 ms), so per-generation metrics go in one
  ``log_batch`` (MLflow splits it into its own 1000-entry chunks).
* The tracking URI is always explicit; the default is a sqlite file under the
  outputs root (an absolute path), artifacts next to it.
* Two processes creating a fresh sqlite DB at once crash in alembic, so a sweep
  creates the DB and the parent run in the launching process
  (:class:`SweepCallback`) before any job starts; jobs find the parent run id in a
  file in the sweep directory (or an environment variable) and attach as children.
"""
from __future__ import annotations

import atexit
import json
import logging
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Iterable, Mapping
from urllib.parse import urlparse

from hydra.experimental.callback import Callback

from ..validation import ConfigError

#: Store schemes accepted for ``tracking.uri`` (MLflow 3.17 refuses the plain file store).
STORE_SCHEMES = ("sqlite", "postgresql", "mysql", "mssql", "http", "https", "databricks")
#: File in a sweep directory that carries the parent run id to the jobs.
PARENT_RUN_FILE = "mlflow_parent_run_id.txt"
#: Environment variable that carries the parent run id to jobs (same process tree).
PARENT_RUN_ENV = "MOSD_MLFLOW_PARENT_RUN_ID"
#: Environment variable that overrides the default outputs root.
OUTPUTS_ENV = "MOSD_OUTPUTS"
TRACKING_KEYS = ("enabled", "uri", "artifact_root", "experiment")
# MLflow limits: param values 6000 characters, tag values 8000.
_MAX_PARAM_LENGTH = 6000
_MAX_TAG_LENGTH = 8000


class TrackingError(RuntimeError):
    """MLflow refused a request (the message is MLflow's, on one line)."""


def default_outputs_root() -> Path:
    """The outputs root: ``$MOSD_OUTPUTS`` or ``./outputs``, made absolute."""
    return Path(os.environ.get(OUTPUTS_ENV) or "outputs").expanduser().resolve()


def default_tracking_uri(outputs_root: str | os.PathLike | None = None) -> str:
    """``sqlite:///<abs outputs root>/mlflow.db`` (the store ``mosd`` and ``mosd report`` use)."""
    root = default_outputs_root() if outputs_root is None else Path(outputs_root).expanduser().resolve()
    return f"sqlite:///{root / 'mlflow.db'}"


@dataclass(frozen=True)
class TrackingSettings:
    """Where runs go: tracking URI, artifact root URI and experiment name."""

    uri: str
    artifact_root: str
    experiment: str

    @classmethod
    def from_config(cls, tracking: Mapping[str, Any], outputs_root: str) -> "TrackingSettings | None":
        """Validate the ``tracking`` config section; None when tracking is disabled."""
        unknown = sorted(set(tracking) - set(TRACKING_KEYS))
        if unknown:
            raise ConfigError(f"tracking.{unknown[0]} is not a tracking key; allowed: {', '.join(TRACKING_KEYS)}")
        enabled = tracking.get("enabled", True)
        if not isinstance(enabled, bool):
            raise ConfigError(f"tracking.enabled={enabled!r} is not allowed; allowed: true, false")
        if not enabled:
            return None
        root = Path(str(outputs_root)).expanduser().resolve()
        uri = tracking.get("uri") or default_tracking_uri(root)
        scheme = urlparse(str(uri)).scheme.split("+")[0]
        if scheme not in STORE_SCHEMES:
            raise ConfigError(f"tracking.uri={uri!r} has no supported scheme; allowed: {', '.join(STORE_SCHEMES)} URIs")
        artifact_root = tracking.get("artifact_root") or str(root / "mlartifacts")
        if not urlparse(str(artifact_root)).scheme:
            artifact_root = Path(str(artifact_root)).expanduser().resolve().as_uri()
        experiment = tracking.get("experiment")
        if not isinstance(experiment, str) or not experiment.strip():
            raise ConfigError(f"tracking.experiment={experiment!r} is not allowed; allowed: a non-empty name")
        return cls(uri=str(uri), artifact_root=str(artifact_root), experiment=experiment)


def git_commit(path: str | os.PathLike | None = None) -> str | None:
    """The commit of the git checkout containing ``path`` (default: this package), if any."""
    where = Path(path) if path is not None else Path(__file__).resolve().parent.parent
    if not (where / ".git").exists():
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
            flat[name] = str(value)[:_MAX_PARAM_LENGTH]
    return flat


# ------------------------------------------------------------------------------------
# the MLflow side
# ------------------------------------------------------------------------------------
class MlflowStore:
    """The only object that talks to MLflow (imported on construction).

    Parameters
    ----------
    settings : TrackingSettings
    """

    def __init__(self, settings: TrackingSettings):
        from mlflow.tracking import MlflowClient

        # alembic prints its migration steps at INFO when a fresh sqlite DB is created
        logging.getLogger("alembic").setLevel(logging.WARNING)
        self.settings = settings
        parsed = urlparse(settings.uri)
        if parsed.scheme == "sqlite" and parsed.path not in ("", "/", "/:memory:"):
            Path(parsed.path).parent.mkdir(parents=True, exist_ok=True)
        self.client = MlflowClient(tracking_uri=settings.uri)

    def experiment_id(self) -> str:
        """Id of the settings' experiment, created (with its artifact location) if new."""
        name = self.settings.experiment
        found = self.client.get_experiment_by_name(name)
        if found is not None:
            return found.experiment_id
        location = f"{self.settings.artifact_root.rstrip('/')}/{name}"
        try:
            return self.client.create_experiment(name, artifact_location=location)
        except Exception:
            # another process created it in between
            found = self.client.get_experiment_by_name(name)
            if found is None:
                raise
            return found.experiment_id

    def create_run(self, run_name: str, tags: Mapping[str, str], parent_run_id: str | None = None) -> str:
        tags = {k: str(v)[:_MAX_TAG_LENGTH] for k, v in tags.items()}
        if parent_run_id:
            tags["mlflow.parentRunId"] = parent_run_id
        run = self.client.create_run(self.experiment_id(), run_name=run_name, tags=tags)
        return run.info.run_id

    def log(self, run_id: str, params: Mapping[str, str] | None = None,
            metrics: Iterable[tuple[str, float, int]] = (), tags: Mapping[str, str] | None = None,
            artifacts: Iterable[str] = ()) -> None:
        """One batched call for params, metrics and tags, then the artifact files."""
        from mlflow.entities import Metric, Param, RunTag

        stamp = int(time.time() * 1000)
        self.client.log_batch(
            run_id,
            metrics=[Metric(key, float(value), stamp, int(step)) for key, value, step in metrics],
            params=[Param(k, str(v)[:_MAX_PARAM_LENGTH]) for k, v in (params or {}).items()],
            tags=[RunTag(k, str(v)[:_MAX_TAG_LENGTH]) for k, v in (tags or {}).items()],
        )
        for path in artifacts:
            p = Path(path)
            if p.is_dir():
                self.client.log_artifacts(run_id, str(p))
            elif p.is_file():
                self.client.log_artifact(run_id, str(p))

    def end(self, run_id: str, status: str = "FINISHED", error: str | None = None) -> None:
        if error:
            self.client.set_tag(run_id, "error", error[:_MAX_TAG_LENGTH])
        self.client.set_terminated(run_id, status=status)


class _Handler:
    """Executes tracking requests (in the side process or in-process)."""

    def __init__(self):
        self.store: MlflowStore | None = None
        self.run_id: str | None = None
        self.timings: dict[str, float] = {}

    def __call__(self, request: dict) -> dict:
        op = request["op"]
        if op == "start":
            t0 = time.perf_counter()
            self.store = MlflowStore(TrackingSettings(**request["settings"]))
            t1 = time.perf_counter()
            self.run_id = self.store.create_run(request["run_name"], request["tags"], request.get("parent_run_id"))
            self.timings = {"mlflow_import_s": t1 - t0, "mlflow_create_run_s": time.perf_counter() - t1}
            return {"run_id": self.run_id, "timings": self.timings}
        if self.store is None or self.run_id is None:
            raise TrackingError("the MLflow run was not created")
        if op == "log":
            # how long MLflow took to start, measured where it ran (overlapping the experiment)
            metrics = [*request.get("metrics", ()), *((k, v, 0) for k, v in self.timings.items())]
            self.timings = {}
            self.store.log(self.run_id, request.get("params"), metrics, request.get("tags"),
                           request.get("artifacts", ()))
            return {}
        if op == "end":
            self.store.end(self.run_id, request["status"], request.get("error"))
            self.store = None
            return {}
        raise TrackingError(f"unknown tracking request {op!r}")


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def _serve() -> None:
    """Side-process main loop: JSON requests on stdin, one JSON reply per line on stdout."""
    import signal

    # Ctrl-C reaches the whole process group; the app decides how the run ends
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    replies = os.fdopen(os.dup(1), "w", buffering=1)
    os.dup2(2, 1)  # anything MLflow prints must not corrupt the reply channel
    handler = _Handler()
    for line in sys.stdin:
        if not line.strip():
            continue
        request = json.loads(line)
        try:
            reply = {"ok": True, **handler(request)}
        except Exception as exc:  # reported to the app, which decides
            reply = {"ok": False, "error": _one_line(exc)}
        replies.write(json.dumps(reply) + "\n")
        if request.get("op") == "end":
            replies.flush()
            # every call above has committed; skip the interpreter teardown with MLflow
            # loaded (~1 s), which the app would otherwise wait for
            os._exit(0)
    # stdin closed before "end": the app died; do not leave the run RUNNING
    if handler.store is not None and handler.run_id is not None:
        handler.store.end(handler.run_id, "FAILED", "the mosd process ended before the run finished")


class _SideProcess:
    """Requests go to ``python -c 'mosd.app.tracking._serve()'``; replies are read lazily."""

    def __init__(self):
        package_parent = str(Path(__file__).resolve().parents[2])  # the directory holding mosd/
        self._stderr = tempfile.TemporaryFile(mode="w+")
        self._proc = subprocess.Popen(
            [sys.executable, "-c", "import sys; sys.path.insert(0, sys.argv[1]); "
             "from mosd.app.tracking import _serve; _serve()", package_parent],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=self._stderr, text=True, bufsize=1,
        )
        self._pending = 0

    def send(self, request: dict) -> None:
        try:
            self._proc.stdin.write(json.dumps(request) + "\n")
            self._proc.stdin.flush()
        except BrokenPipeError:
            raise TrackingError(f"the tracking process ended: {self._stderr_tail()}") from None
        self._pending += 1

    def replies(self) -> list[dict]:
        """Wait for the replies to every request sent so far."""
        out = []
        while self._pending:
            line = self._proc.stdout.readline()
            if not line:
                raise TrackingError(f"the tracking process ended: {self._stderr_tail()}")
            out.append(json.loads(line))
            self._pending -= 1
        return out

    def close(self) -> None:
        if self._proc.stdin and not self._proc.stdin.closed:
            self._proc.stdin.close()
        try:
            self._proc.wait(timeout=60)
        except subprocess.TimeoutExpired:
            self._proc.kill()
        self._stderr.close()

    def _stderr_tail(self) -> str:
        self._stderr.seek(0)
        lines = [ln.strip() for ln in self._stderr.read().splitlines() if ln.strip()]
        return lines[-1] if lines else f"exit code {self._proc.poll()}"


class _InProcess:
    """Same interface as :class:`_SideProcess`, executing at once."""

    def __init__(self):
        self._handler = _Handler()
        self._replies: list[dict] = []

    def send(self, request: dict) -> None:
        try:
            self._replies.append({"ok": True, **self._handler(request)})
        except Exception as exc:
            self._replies.append({"ok": False, "error": _one_line(exc)})

    def replies(self) -> list[dict]:
        out, self._replies = self._replies, []
        return out

    def close(self) -> None:
        pass


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
        #: MLflow import and run-creation seconds, measured where MLflow ran (after finish)
        self.startup_timings: dict[str, float] = {}
        self._channel = None
        self._queued: list[dict] = []

    def start(self) -> "RunTracker":
        """Create the run (in the side process this returns at once)."""
        self._channel = _InProcess() if self.in_process else _SideProcess()
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

    def finish(self, status: str = "FINISHED", error: str | None = None) -> str:
        """Send the queued batches, end the run with ``status`` and return its id.

        Raises :class:`TrackingError` with MLflow's message if any request failed
        (the run is still ended when it exists).
        """
        if self._channel is None:
            raise TrackingError("RunTracker.finish called before start")
        for request in self._queued:
            self._channel.send(request)
        self._queued = []
        self._channel.send({"op": "end", "status": status, "error": error})
        try:
            replies = self._channel.replies()
        finally:
            self._channel.close()
            self._channel = None
        if replies and replies[0].get("ok"):
            self.run_id = replies[0]["run_id"]
            self.startup_timings = replies[0].get("timings", {})
        failed = [r["error"] for r in replies if not r.get("ok")]
        if failed:
            raise TrackingError(failed[0])
        return self.run_id


    @property
    def open(self) -> bool:
        """True between :meth:`start` and :meth:`finish`."""
        return self._channel is not None

    def abort(self, status: str, error: str, details: str | None = None) -> str:
        """End the run as FAILED/KILLED with the error text; queued batches are dropped."""
        self._queued = []
        if details:
            self.log(tags={"error.traceback": details[-(_MAX_TAG_LENGTH - 100):]})
        return self.finish(status, error=error)


def parent_run_id(sweep_dir: str | os.PathLike | None) -> str | None:
    """The sweep's parent run id for a job: from the sweep directory, else the environment."""
    if sweep_dir is not None:
        path = Path(sweep_dir) / PARENT_RUN_FILE
        if path.is_file():
            return path.read_text().strip() or None
    return os.environ.get(PARENT_RUN_ENV) or None


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
        self._close("FINISHED")

    def _close(self, status: str, error: str | None = None) -> None:
        if self._store is None or self._run_id is None:
            return
        run_id, self._run_id = self._run_id, None
        os.environ.pop(PARENT_RUN_ENV, None)
        self._store.end(run_id, status, error)
