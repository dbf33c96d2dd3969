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
* Two processes creating a fresh sqlite DB at once crash in alembic (duplicate
  columns, ``_alembic_tmp_*`` tables) and leave it broken, so every process
  creates or opens a sqlite store under an exclusive lock on ``<db>.lock``
  (:func:`store_lock`): the first creates and migrates it, the others find it
  at the head revision. A store that a killed migration left half-built and
  that holds no run is moved aside and recreated; one that holds runs is
  refused with one line naming the file (:func:`sqlite_store_state`).
* Preflight checks the store and the outputs directory before any work
  (:func:`check_tracking`, a few seconds at most): an unreachable server or a
  corrupt DB is one line and exit 2, not a failure after the optimisation.
* A sweep creates the parent run in the launching process
  (:class:`SweepCallback`) before any job starts; jobs find the parent run id in
  a file in the sweep directory (or an environment variable) and attach as children.
"""
from __future__ import annotations

import atexit
import contextlib
import fcntl
import json
import logging
import os
import socket
import sqlite3
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


#: Seconds preflight waits for a tracking server or database to answer.
CHECK_TIMEOUT_S = 3.0
#: MLflow's HTTP retries for a run (its defaults, 7 retries with backoff 2, block ~250 s on a dead server).
HTTP_ENV_DEFAULTS = {"MLFLOW_HTTP_REQUEST_MAX_RETRIES": "2", "MLFLOW_HTTP_REQUEST_BACKOFF_FACTOR": "1",
                     "MLFLOW_HTTP_REQUEST_TIMEOUT": "30"}
#: Default ports of the database back ends (checked with a TCP connection in preflight).
DB_PORTS = {"postgresql": 5432, "mysql": 3306, "mssql": 1433}
#: Seconds a process waits for another one creating or migrating the sqlite store.
LOCK_TIMEOUT_S = 300.0
#: Tables every MLflow tracking store has (MLflow creates them first, then migrates).
_CORE_TABLES = ("experiments", "runs", "alembic_version")


class TrackingError(RuntimeError):
    """MLflow refused a request (the message is MLflow's, on one line)."""


# ------------------------------------------------------------------------------------
# the store: lock, health, preflight checks (no MLflow import)
# ------------------------------------------------------------------------------------
def sqlite_path(uri: str) -> Path | None:
    """The DB file of a ``sqlite:///`` URI (None for other schemes and in-memory DBs)."""
    parsed = urlparse(uri)
    if parsed.scheme != "sqlite" or parsed.path in ("", "/", "/:memory:"):
        return None
    # SQLAlchemy: sqlite:///rel/path is relative to the working directory, sqlite:////abs/path absolute
    return Path(parsed.path[1:])


@contextlib.contextmanager
def store_lock(uri: str, shared: bool = False, timeout: float = LOCK_TIMEOUT_S):
    """Inter-process lock on ``<db>.lock`` for a sqlite store (a no-op for other stores).

    ``flock`` locks die with their process, so a killed holder never leaves the
    store locked. Yields True when the lock is held, False when ``timeout`` ran
    out (the caller decides whether that matters).
    """
    path = sqlite_path(uri)
    if path is None or (shared and not Path(f"{path}.lock").exists()):
        # a reader writes nothing: without a lock file nobody has been creating the store
        yield True
        return
    path.parent.mkdir(parents=True, exist_ok=True)
    fd = os.open(f"{path}.lock", os.O_RDWR | os.O_CREAT, 0o666)
    try:
        deadline = time.monotonic() + timeout
        held = False
        while True:
            try:
                fcntl.flock(fd, (fcntl.LOCK_SH if shared else fcntl.LOCK_EX) | fcntl.LOCK_NB)
                held = True
                break
            except BlockingIOError:
                if time.monotonic() >= deadline:
                    break
                time.sleep(0.05)
        yield held
    finally:
        os.close(fd)  # releases the lock


@dataclass(frozen=True)
class StoreState:
    """What :func:`sqlite_store_state` found: ``missing``, ``empty``, ``ok``, ``incomplete`` or ``corrupt``."""

    state: str
    detail: str = ""
    n_runs: int = 0


def sqlite_store_state(path: str | os.PathLike) -> StoreState:
    """Health of a sqlite MLflow store, read with the standard library only (fast, read-only).

    ``incomplete``: some MLflow tables exist but the creation or a migration did
    not finish (a killed process; ``_alembic_tmp_*`` tables, no version row).
    """
    path = Path(path)
    if not path.exists():
        return StoreState("missing")
    if not path.is_file():
        return StoreState("corrupt", "it is not a file")
    if path.stat().st_size == 0:
        return StoreState("empty")
    try:
        con = sqlite3.connect(f"{path.resolve().as_uri()}?mode=ro", uri=True, timeout=CHECK_TIMEOUT_S)
    except sqlite3.Error as exc:
        return StoreState("corrupt", _one_line(exc))
    try:
        check = con.execute("PRAGMA quick_check").fetchone()
        if not check or check[0] != "ok":
            return StoreState("corrupt", f"sqlite integrity check: {check[0] if check else 'no answer'}")
        tables = {row[0] for row in con.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
        if not tables:
            return StoreState("empty")
        n_runs = con.execute("SELECT count(*) FROM runs").fetchone()[0] if "runs" in tables else 0
        leftovers = sorted(t for t in tables if t.startswith("_alembic_tmp_"))
        missing = [t for t in _CORE_TABLES if t not in tables]
        if leftovers or missing:
            what = f"left-over {leftovers[0]}" if leftovers else f"no table {missing[0]}"
            return StoreState("incomplete", f"an interrupted creation or migration ({what})", n_runs)
        if con.execute("SELECT count(*) FROM alembic_version").fetchone()[0] != 1:
            return StoreState("incomplete", "an interrupted creation or migration (no schema version)", n_runs)
        return StoreState("ok", n_runs=n_runs)
    except sqlite3.Error as exc:
        return StoreState("corrupt", _one_line(exc))
    finally:
        con.close()


def _refusal(path: Path, state: StoreState) -> str:
    return (f"tracking store {path} is damaged ({state.detail}); allowed: a healthy MLflow store: move the file "
            f"aside (mosd then creates a new one), point tracking.uri elsewhere, or tracking=none")


def _writable_dir_problem(path: Path) -> str | None:
    """Why ``path`` cannot be (created as) a writable directory, or None; leaves nothing behind."""
    path = path.expanduser().resolve()
    probe = path
    while not probe.exists():
        probe = probe.parent
    if not probe.is_dir():
        return f"{probe} is not a directory"
    try:  # a real write: os.access says yes to root on a read-only mount's mode bits
        fd, name = tempfile.mkstemp(prefix=".mosd-write-check-", dir=probe)
        os.close(fd)
        os.unlink(name)
    except OSError as exc:
        return f"{probe} is not writable ({exc.strerror or exc})"
    return None


def check_outputs(outputs_root: str | os.PathLike, *dirs: str | os.PathLike) -> None:
    """Raise ConfigError unless the outputs root (and the run/sweep directories) can be written."""
    for key, where in (("outputs_root", outputs_root), *(("hydra run directory", d) for d in dirs)):
        problem = _writable_dir_problem(Path(str(where)))
        if problem:
            raise ConfigError(f"{key}={where} cannot be written: {problem}; allowed: a writable directory")


def check_tracking(settings: "TrackingSettings", timeout: float = CHECK_TIMEOUT_S) -> None:
    """Raise ConfigError (one line) if the store cannot take a run; bounded by ``timeout`` per check.

    sqlite: the DB file is read-only checked (a store a killed migration left
    without runs passes: the run recreates it); its directory must be writable.
    http(s): the server answers ``/health``. Databases: the port accepts a TCP
    connection. A ``file:`` artifact root must be writable.
    """
    uri = settings.uri
    parsed = urlparse(uri)
    scheme = parsed.scheme.split("+")[0]
    db = sqlite_path(uri)
    if db is not None:
        problem = _writable_dir_problem(db.parent)
        if problem:
            raise ConfigError(f"tracking.uri={uri} cannot be written: {problem}; allowed: a writable location")
        if db.exists():
            if db.is_file() and not os.access(db, os.W_OK):
                raise ConfigError(f"tracking store {db} is read-only; allowed: a writable file, or tracking=none")
            with store_lock(uri, shared=True, timeout=timeout) as held:
                # not held: another process is creating the store right now; it will be checked under the lock
                state = sqlite_store_state(db) if held else StoreState("ok")
            if state.state == "corrupt" or (state.state == "incomplete" and state.n_runs):
                raise ConfigError(_refusal(db, state))
    elif scheme in ("http", "https"):
        import urllib.error
        import urllib.request

        try:
            with urllib.request.urlopen(f"{uri.rstrip('/')}/health", timeout=timeout):
                pass
        except urllib.error.HTTPError:
            pass  # it answered: an auth or routing question for MLflow itself, not reachability
        except (OSError, ValueError) as exc:
            reason = getattr(exc, "reason", exc)
            reason = _one_line(reason) if isinstance(reason, BaseException) else str(reason)
            raise ConfigError(f"tracking.uri={uri} is not reachable ({reason}, checked for {timeout:g} s); "
                              f"allowed: a running MLflow server "
                              f"(mlflow server --host 127.0.0.1 ...), another tracking.uri, or tracking=none") from None
    elif scheme in DB_PORTS:
        host, port = parsed.hostname or "localhost", parsed.port or DB_PORTS[scheme]
        try:
            socket.create_connection((host, port), timeout=timeout).close()
        except OSError as exc:
            raise ConfigError(f"tracking.uri: the {scheme} server {host}:{port} is not reachable ({exc.strerror or exc}, "
                              f"checked for {timeout:g} s); allowed: a running database, or tracking=none") from None
    artifacts = urlparse(settings.artifact_root)
    if artifacts.scheme == "file":
        problem = _writable_dir_problem(Path(artifacts.path))
        if problem:
            raise ConfigError(f"tracking.artifact_root={settings.artifact_root} cannot be written: {problem}; "
                              f"allowed: a writable directory")


def _prepare_sqlite_store(path: Path) -> str | None:
    """Under the store lock: move aside a store a killed creation left without runs; refuse a damaged one.

    Returns a note for the user when a store was moved aside.
    """
    state = sqlite_store_state(path)
    if state.state in ("missing", "empty", "ok"):
        return None
    if state.state == "incomplete" and not state.n_runs:
        aside = path.with_name(f"{path.name}.incomplete-{time.strftime('%Y%m%d-%H%M%S')}-{os.getpid()}")
        path.rename(aside)
        return f"moved an unfinished store aside ({state.detail}) to {aside} and created a new one"
    raise TrackingError(_refusal(path, state))


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
        for key, value in HTTP_ENV_DEFAULTS.items():
            os.environ.setdefault(key, value)
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
            self.note = _prepare_sqlite_store(db)
            self.client = MlflowClient(tracking_uri=settings.uri)
            self._experiment_id = self.experiment_id()

    def experiment_id(self) -> str:
        """Id of the settings' experiment, created (with its artifact location) if new."""
        if self._experiment_id is not None:
            return self._experiment_id
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
            return {"run_id": self.run_id, "timings": self.timings, "note": self.store.note}
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

    # the app decides how the run ends (KILLED on a signal) and closes stdin; a signal
    # meant for the app must not end this process first and leave the run RUNNING
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
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
        try:
            replies.write(json.dumps(reply) + "\n")
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


class _SideProcess:
    """Requests go to ``python -c 'mosd.app.tracking._serve()'``; replies are read lazily."""

    def __init__(self):
        package_parent = str(Path(__file__).resolve().parents[2])  # the directory holding mosd/
        self._stderr = tempfile.TemporaryFile(mode="w+")
        self._proc = subprocess.Popen(
            [sys.executable, "-c", "import sys; sys.path.insert(0, sys.argv[1]); "
             "from mosd.app.tracking import _serve; _serve()", package_parent],
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

    def replies(self, timeout: float | None = None) -> list[dict]:
        out, self._replies = self._replies, []
        return out

    def close(self, wait: bool = True) -> None:
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
        #: what happened to the store on the way in (an unfinished store moved aside), after finish
        self.note: str | None = None
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
        (the run is still ended when it exists). With ``timeout``, a side process
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
        failed = [r["error"] for r in replies if not r.get("ok")]
        if failed:
            raise TrackingError(failed[0])
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
            self.log(tags={"error.traceback": details[-(_MAX_TAG_LENGTH - 100):]})
        return self.finish(status, error=error, timeout=timeout)


def log_pending(run_dir: str | os.PathLike, uri: str | None = None) -> str:
    """Log a run directory's ``mlflow_pending.json`` (a run whose logging failed) as a new run.

    Returns the new run id; the pending file is renamed ``*.logged`` and
    ``summary.json`` records the id.
    """
    from .run import PENDING_FILE

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
        print(f"mosd log: error: {_one_line(exc) if isinstance(exc, TrackingError) else exc}", file=sys.stderr)
        return 2
    except Exception as exc:  # MLflow's own errors: one line, the pending file is kept
        print(f"mosd log: error: {_one_line(exc)}", file=sys.stderr)
        return 1
    return 0


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
        received = getattr(sys.modules.get("mosd.app.run"), "RECEIVED", None)
        if status != "FINISHED" and received:
            import signal

            status, error = "KILLED", f"the sweep was stopped by {signal.Signals(received[0]).name}"
        run_id, self._run_id = self._run_id, None
        os.environ.pop(PARENT_RUN_ENV, None)
        self._store.end(run_id, status, error)
