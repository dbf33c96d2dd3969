"""Preflight checks of the places a run writes to: the outputs directory and the tracking store.

Run before any work (:func:`mosd.app.preflight.check_job`), a few seconds at
most: an unreachable server or a corrupt DB is one line and exit 2, not a
failure after the optimisation. No MLflow import.
"""
from __future__ import annotations

import os
import socket
import tempfile
from pathlib import Path
from urllib.parse import urlparse

from ..validation import ConfigError
from .config import described
from .settings import TrackingSettings
from .store import StoreState, refusal, sqlite_path, sqlite_store_state, store_lock

#: Seconds preflight waits for a tracking server or database to answer.
CHECK_TIMEOUT_S = 3.0
#: Default ports of the database back ends (checked with a TCP connection in preflight).
DB_PORTS = {"postgresql": 5432, "mysql": 3306, "mssql": 1433}


def writable_dir_problem(path: Path) -> str | None:
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
        problem = writable_dir_problem(Path(str(where)))
        if problem:
            raise ConfigError(f"{key}={where} cannot be written: {problem}; allowed: a writable directory")


def check_tracking(settings: TrackingSettings, timeout: float = CHECK_TIMEOUT_S) -> None:
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
        import urllib.error
        import urllib.request

        try:
            with urllib.request.urlopen(f"{uri.rstrip('/')}/health", timeout=timeout):
                pass
        except urllib.error.HTTPError:
            pass  # it answered: an auth or routing question for MLflow itself, not reachability
        except (OSError, ValueError) as exc:
            reason = getattr(exc, "reason", exc)
            reason = described(reason) if isinstance(reason, BaseException) else str(reason)
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
        problem = writable_dir_problem(Path(artifacts.path))
        if problem:
            raise ConfigError(f"tracking.artifact_root={settings.artifact_root} cannot be written: {problem}; "
                              f"allowed: a writable directory")
