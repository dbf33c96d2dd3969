"""Preflight checks of the places a run writes to: the outputs directory and the tracking store.

Run before any work (:func:`mosd.app.preflight.check_job`), a few seconds at
most: an unreachable server or a corrupt DB is one line and exit 2, not a
failure after the optimisation. No MLflow import.
"""
from __future__ import annotations

import math
import os
import socket
import tempfile
from pathlib import Path
from urllib.parse import urlparse

from ..validation import ConfigError
from .config import described
from .settings import TrackingSettings, redacted
from .store import StoreState, refusal, sqlite_path, sqlite_store_state, store_lock

#: Seconds preflight waits for a database port or a store lock.
CHECK_TIMEOUT_S = 3.0
#: Seconds preflight waits for a tracking server's answer: the patience a run's own MLflow client
#: has (``MLFLOW_HTTP_REQUEST_TIMEOUT``, 30 s in :mod:`mosd.app.mlflow_client`). The server reads the
#: store, which concurrent runs keep busy: 3 s, then 10 s, refused a healthy one-worker server on
#: PostgreSQL under 7 concurrent runs on 2 loaded cores (CI).
def server_timeout_s() -> float:
    try:
        value = float(os.environ.get("MLFLOW_HTTP_REQUEST_TIMEOUT", "30"))
    except ValueError:
        value = 30.0
    return value if value > 0 else 30.0
#: Default ports of the database back ends (checked with a TCP connection in preflight).
DB_PORTS = {"postgresql": 5432, "mysql": 3306, "mssql": 1433}
#: The REST call preflight makes to a tracking server: MLflow's client makes it first for every run.
MLFLOW_PROBE = "/api/2.0/mlflow/experiments/get-by-name"
#: Bytes of the server's answer preflight reads (MLflow's is a few hundred; a stray server may stream).
MAX_ANSWER_BYTES = 1 << 20


#: Free space below which preflight refuses a directory a run writes to: a run directory takes about
#: 0.3 MB (four PNGs of 40-90 kB and the text files), its MLflow artifacts as much again, and a new
#: sqlite store (MLflow 3.17's tables) about 1 MB; twice that, for the next run to fit too.
MIN_FREE_BYTES = 4 << 20


def write_problem(directory: Path) -> str | None:
    """Why a file cannot be written in the existing ``directory``, or None; leaves nothing behind.

    A real write of real bytes: ``os.access`` says yes to root on a read-only mount's mode bits, ``/proc``
    takes no new file, and an empty file is created even on a full disk (or beyond a quota or a file-size limit).
    """
    try:
        fd, name = tempfile.mkstemp(prefix=".mosd-write-check-", dir=directory)
        try:
            os.write(fd, b"mosd")
        finally:
            os.close(fd)
            os.unlink(name)
    except OSError as exc:
        return f"{directory} is not writable ({exc.strerror or exc})"
    return None


def writable_dir_problem(path: Path) -> str | None:
    """Why ``path`` cannot be (created as) a writable directory with room for a run, or None; leaves nothing behind."""
    path = path.expanduser().resolve()
    probe = path
    while not probe.exists():
        probe = probe.parent
    if not probe.is_dir():
        return f"{probe} is not a directory"
    problem = write_problem(probe)
    if problem is not None:
        return problem
    stats = os.statvfs(probe)
    free = stats.f_bavail * stats.f_frsize
    if free < MIN_FREE_BYTES:
        return (f"{probe} has {free / 1024:.0f} kB free; a run needs about {MIN_FREE_BYTES >> 20} MB "
                f"(disk full?)")
    return None


def check_outputs(outputs_root: str | os.PathLike, *dirs: str | os.PathLike) -> None:
    """Raise ConfigError unless the outputs root (and the run/sweep directories) can be written."""
    for key, where in (("outputs_root", outputs_root), *(("hydra run directory", d) for d in dirs)):
        problem = writable_dir_problem(Path(str(where)))
        if problem:
            raise ConfigError(f"{key}={where} cannot be written: {problem}; allowed: a writable directory")


def _mlflow_request(uri: str, path: str) -> "urllib.request.Request":
    """GET ``uri`` + ``path`` with the credentials MLflow's client would send.

    Those of the URI (``http://user:password@host``, which MLflow's HTTP library
    takes as basic authentication and urllib cannot), else its environment variables.
    """
    import base64
    import urllib.parse
    import urllib.request

    parts = urllib.parse.urlsplit(uri)
    user, password = os.environ.get("MLFLOW_TRACKING_USERNAME"), os.environ.get("MLFLOW_TRACKING_PASSWORD")
    if parts.username is not None:
        user, password = urllib.parse.unquote(parts.username), urllib.parse.unquote(parts.password or "")
        parts = parts._replace(netloc=parts.netloc.rpartition("@")[2])
    request = urllib.request.Request(f"{urllib.parse.urlunsplit(parts).rstrip('/')}{path}",
                                     headers={"Accept": "application/json"})
    token = os.environ.get("MLFLOW_TRACKING_TOKEN")
    if user and password:
        request.add_header("Authorization", "Basic " + base64.b64encode(f"{user}:{password}".encode()).decode())
    elif token:
        request.add_header("Authorization", f"Bearer {token}")
    return request


def _mlflow_tls():
    """The TLS context of MLflow's client settings (insecure, a server CA bundle, a client certificate), or None."""
    import ssl

    if os.environ.get("MLFLOW_TRACKING_INSECURE_TLS", "").strip().lower() in ("true", "1"):
        from .compat import unverified_tls_context

        return unverified_tls_context()
    cafile, client_cert = (os.environ.get("MLFLOW_TRACKING_SERVER_CERT_PATH"),
                           os.environ.get("MLFLOW_TRACKING_CLIENT_CERT_PATH"))
    if not (cafile or client_cert):
        return None
    context = ssl.create_default_context(cafile=cafile or None)
    if client_cert:
        context.load_cert_chain(client_cert)
    return context


def check_mlflow_server(uri: str, experiment: str, timeout: float | None = None) -> None:
    """Raise ConfigError (one line) unless ``uri`` is an MLflow tracking server that can take the experiment's runs.

    Something answering HTTP is not enough (a web server or a proxy answers every
    path): the server must answer MLflow's ``GET experiments/get-by-name`` as
    MLflow does, with the experiment (not deleted) or MLflow's
    ``RESOURCE_DOES_NOT_EXIST`` error (the run creates it). The request carries the
    credentials and TLS settings MLflow's client reads from its environment.
    """
    import json
    import urllib.error
    import urllib.parse
    import urllib.request

    timeout = server_timeout_s() if timeout is None else timeout
    shown = redacted(uri)
    allowed = ("allowed: a running MLflow tracking server (mlflow server --host 127.0.0.1 ...), "
               "another tracking.uri, or tracking=none")
    try:  # a malformed URI (ValueError) or an unreadable certificate (OSError) is answered like no server
        request = _mlflow_request(uri, f"{MLFLOW_PROBE}?{urllib.parse.urlencode({'experiment_name': experiment})}")
        with urllib.request.urlopen(request, timeout=timeout, context=_mlflow_tls()) as response:
            status, kind, body = response.status, response.headers.get_content_type(), response.read(MAX_ANSWER_BYTES)
    except urllib.error.HTTPError as exc:  # an answer all the same: MLflow's errors come with a status
        status, kind = exc.code, exc.headers.get_content_type() if exc.headers else "no content type"
        try:
            body = exc.read(MAX_ANSWER_BYTES)
        except OSError:
            body = b""
    except (OSError, ValueError) as exc:
        reason = getattr(exc, "reason", exc)
        if isinstance(reason, TimeoutError):  # connected (or connecting) but silent: a busy or a stray server
            raise ConfigError(f"tracking.uri={shown} does not answer MLflow's REST API within {timeout:g} s; "
                              f"{allowed}") from None
        reason = described(reason) if isinstance(reason, BaseException) else str(reason)
        raise ConfigError(f"tracking.uri={shown} is not reachable ({reason}, checked for {timeout:g} s); "
                          f"{allowed}") from None
    try:
        answer = json.loads(body)
    except ValueError:
        answer = None
    answer = answer if isinstance(answer, dict) else {}
    found = answer.get("experiment")
    if status == 200 and isinstance(found, dict) and "experiment_id" in found:
        if found.get("lifecycle_stage") == "deleted":
            raise ConfigError(f"tracking.experiment={experiment!r} is deleted in the store at tracking.uri={shown} "
                              f"(runs cannot be created in it); allowed: another tracking.experiment, or restore it "
                              f"(mlflow experiments restore --experiment-id {found['experiment_id']})")
        return
    error_code = answer.get("error_code")
    if status == 404 and error_code == "RESOURCE_DOES_NOT_EXIST":
        return  # an MLflow server without the experiment yet: the first run creates it
    if status in (401, 403):
        raise ConfigError(f"tracking.uri={shown} refuses mosd's request (HTTP {status}"
                          f"{', ' + error_code if isinstance(error_code, str) else ''}); allowed: the server's "
                          f"credentials in MLFLOW_TRACKING_USERNAME and MLFLOW_TRACKING_PASSWORD (or "
                          f"MLFLOW_TRACKING_TOKEN), another tracking.uri, or tracking=none")
    if isinstance(error_code, str) and isinstance(answer.get("message"), str):
        message = " ".join(answer["message"].split())[:300]
        raise ConfigError(f"tracking.uri={shown}: the MLflow server fails (HTTP {status}, {error_code}: {message}); "
                          f"{allowed}")
    raise ConfigError(f"tracking.uri={shown} answers HTTP but not as an MLflow tracking server "
                      f"(GET {MLFLOW_PROBE}: HTTP {status}, {kind}); {allowed}")


#: What each database driver calls its connection deadline (SQLAlchemy passes ``connect_args`` through).
_CONNECT_TIMEOUT_ARG = {"postgresql": "connect_timeout", "mysql": "connect_timeout"}


def check_database(uri: str, scheme: str, timeout: float = CHECK_TIMEOUT_S) -> None:
    """Raise ConfigError (one line) unless the database at ``uri`` takes a login, through MLflow's own driver.

    An open port is not a database that takes the run: a wrong password, a missing
    database or a service that is not one would fail only after the work (MLflow
    retries a failing engine for about 100 s), so preflight logs in with SQLAlchemy,
    as MLflow does, and runs ``SELECT 1``.
    """
    shown = redacted(uri)
    try:
        from sqlalchemy import create_engine, text
        from sqlalchemy.pool import NullPool

        arg = _CONNECT_TIMEOUT_ARG.get(scheme)
        engine = create_engine(uri, poolclass=NullPool,
                               connect_args={arg: max(2, int(math.ceil(timeout)))} if arg else {})
        try:
            with engine.connect() as connection:
                connection.execute(text("SELECT 1"))
        finally:
            engine.dispose()
    except ImportError as exc:
        raise ConfigError(f"tracking.uri={shown}: the {scheme} driver is not installed ({exc}); allowed: "
                          f'pip install "mosd[team]" (PostgreSQL), another tracking.uri, or tracking=none') from None
    except Exception as exc:  # noqa: BLE001 - SQLAlchemy's and the driver's errors: the reason, on one line
        text = str(getattr(exc, "orig", None) or exc)  # a stray service's bytes may be quoted: printable only
        reason = " ".join("".join(c if c.isprintable() else " " for c in text).split())
        raise ConfigError(f"tracking.uri={shown}: the {scheme} database does not take a login "
                          f"({type(getattr(exc, 'orig', None) or exc).__name__}: {redacted(reason)[:300]}); allowed: "
                          f"its user, password (in the URI, or the driver's own: PGPASSWORD, ~/.pgpass) and "
                          f"database, another tracking.uri, or tracking=none") from None


def check_tracking(settings: TrackingSettings, timeout: float = CHECK_TIMEOUT_S,
                   server_timeout: float | None = None) -> None:
    """Raise ConfigError (one line) if the store cannot take a run; bounded by ``timeout`` per check.

    sqlite: the DB file is read-only checked (a store a killed migration left
    without runs passes: the run recreates it); its directory must be writable.
    http(s): the server answers MLflow's REST API as MLflow does within ``server_timeout``
    (:func:`check_mlflow_server`).
    Databases: the port accepts a TCP connection, then the database a login (:func:`check_database`).
    A ``file:`` artifact root must be writable.
    """
    uri = settings.uri
    parsed = urlparse(uri)
    scheme = parsed.scheme.split("+")[0]
    db = sqlite_path(uri)
    if db is not None:
        problem = writable_dir_problem(db.parent)
        if problem:
            raise ConfigError(f"tracking.uri={uri} cannot be written: {problem}; allowed: a writable location")
        if db.exists():
            if db.is_file() and not os.access(db, os.W_OK):
                raise ConfigError(f"tracking store {db} is read-only; allowed: a writable file, or tracking=none")
            with store_lock(uri, shared=True, timeout=timeout) as held:
                # not held: another process is creating the store right now; it will be checked under the lock
                state = sqlite_store_state(db) if held else StoreState("ok")
            if state.state == "corrupt" or (state.state == "incomplete" and state.n_runs):
                raise ConfigError(refusal(db, state))
    elif scheme in ("http", "https"):
        check_mlflow_server(uri, settings.experiment, server_timeout)
    elif scheme in DB_PORTS:
        host, port = parsed.hostname or "localhost", parsed.port or DB_PORTS[scheme]
        try:
            socket.create_connection((host, port), timeout=timeout).close()
        except OSError as exc:
            raise ConfigError(f"tracking.uri: the {scheme} server {host}:{port} is not reachable ({exc.strerror or exc}, "
                              f"checked for {timeout:g} s); allowed: a running database, or tracking=none") from None
        check_database(uri, scheme, timeout)
    artifacts = urlparse(settings.artifact_root)
    if artifacts.scheme == "file":
        problem = writable_dir_problem(Path(artifacts.path))
        if problem:
            raise ConfigError(f"tracking.artifact_root={settings.artifact_root} cannot be written: {problem}; "
                              f"allowed: a writable directory")
