"""The sqlite tracking store: its file, an inter-process lock, its health (no MLflow import).

Two processes creating a fresh sqlite DB at once crash in alembic (duplicate
columns, ``_alembic_tmp_*`` tables) and leave it broken, so every process
creates or opens a sqlite store under an exclusive lock on ``<db>.lock``
(:func:`store_lock`): the first creates and migrates it, the others find it at
the head revision. A store that a killed migration left half-built and that
holds no run is moved aside and recreated (:func:`prepare_sqlite_store`); one that
holds runs is refused with one line naming the file (:func:`sqlite_store_state`). A healthy store that
another process holds locked (an open write transaction, ``BEGIN EXCLUSIVE``) is waited for a few seconds,
then reported as locked, never as damaged: moving it aside would orphan every run it holds.
What this module knows of MLflow's schema (table names) comes from
:mod:`mosd.app.compat`.
"""
from __future__ import annotations

import contextlib
import fcntl
import os
import re
import sqlite3
import time
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import urlparse

from .compat import MLFLOW_CORE_TABLES, MLFLOW_MIGRATION_LEFTOVER, MLFLOW_RUNS_TABLE, MLFLOW_VERSION_TABLE
from .config import described

#: Seconds a process waits for another one creating or migrating the sqlite store.
LOCK_TIMEOUT_S = 300.0
#: Seconds a read of the store waits for a writer (preflight: a few seconds at most).
READ_TIMEOUT_S = 3.0
#: Seconds the tracking process waits for another process's lock on the store before it gives up (it runs
#: beside the run, so it may wait longer than preflight; the run keeps its results for ``mosd log`` then).
LOCKED_WAIT_S = 20.0


class TrackingError(RuntimeError):
    """MLflow (or the store) refused a request (the message is one line)."""


#: What SQLAlchemy appends to a database error after its message: the statement, its parameters, a web link
_SQL_DETAIL = re.compile(r"\s*(\[SQL: .*|\(Background on this error at: [^)]*\))$", re.DOTALL)
#: SQLAlchemy's note on where a failed flush came from, before the message
_AUTOFLUSH_NOTE = re.compile(r"\(raised as a result of Query-invoked autoflush;[^)]*\)\s*")


def short_error(text: str) -> str:
    """A store's error without SQLAlchemy's statement, parameters and link (``[SQL: INSERT INTO runs ...]``).

    A full disk fails MLflow's sqlite store with ``(sqlite3.OperationalError) database or disk is full`` and then
    the raw INSERT with its values and a link; only the first part tells the user anything (issue 53 item 9).
    """
    return _SQL_DETAIL.sub("", _AUTOFLUSH_NOTE.sub("", str(text))).strip()


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
    """What :func:`sqlite_store_state` found: ``missing``, ``empty``, ``ok``, ``incomplete``, ``corrupt`` or
    ``locked`` (healthy as far as anyone can tell, but another process holds it)."""

    state: str
    detail: str = ""
    n_runs: int = 0


def sqlite_store_state(path: str | os.PathLike, wait: float = READ_TIMEOUT_S) -> StoreState:
    """Health of a sqlite MLflow store, read with the standard library only (fast, read-only).

    ``incomplete``: some MLflow tables exist but the creation or a migration did
    not finish (a killed process; ``_alembic_tmp_*`` tables, no version row).
    ``locked``: another process held the store for ``wait`` seconds (sqlite's busy timeout).
    """
    path = Path(path)
    if not path.exists():
        return StoreState("missing")
    if not path.is_file():
        return StoreState("corrupt", "it is not a file")
    if path.stat().st_size == 0:
        return StoreState("empty")
    try:
        con = sqlite3.connect(f"{path.resolve().as_uri()}?mode=ro", uri=True, timeout=wait)
    except sqlite3.Error as exc:
        return _failed(exc, wait)
    try:
        check = con.execute("PRAGMA quick_check").fetchone()
        if not check or check[0] != "ok":
            return StoreState("corrupt", f"sqlite integrity check: {check[0] if check else 'no answer'}")
        tables = {row[0] for row in con.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
        if not tables:
            return StoreState("empty")
        n_runs = con.execute(f"SELECT count(*) FROM {MLFLOW_RUNS_TABLE}").fetchone()[0] \
            if MLFLOW_RUNS_TABLE in tables else 0
        leftovers = sorted(t for t in tables if t.startswith(MLFLOW_MIGRATION_LEFTOVER))
        missing = [t for t in MLFLOW_CORE_TABLES if t not in tables]
        if leftovers or missing:
            what = f"left-over {leftovers[0]}" if leftovers else f"no table {missing[0]}"
            return StoreState("incomplete", f"an interrupted creation or migration ({what})", n_runs)
        if con.execute(f"SELECT count(*) FROM {MLFLOW_VERSION_TABLE}").fetchone()[0] != 1:
            return StoreState("incomplete", "an interrupted creation or migration (no schema version)", n_runs)
        return StoreState("ok", n_runs=n_runs)
    except sqlite3.Error as exc:
        return _failed(exc, wait)
    finally:
        con.close()


def _failed(exc: sqlite3.Error, wait: float) -> StoreState:
    """What a failed read says of the store: locked by another process (busy), else damaged."""
    busy = (getattr(exc, "sqlite_errorcode", None) in (sqlite3.SQLITE_BUSY, sqlite3.SQLITE_LOCKED)
            or "locked" in str(exc).lower())  # Python < 3.11 has no error code on the exception
    if busy:
        return StoreState("locked", f"{described(exc)}, for {wait:g} s")
    return StoreState("corrupt", described(exc))


def template_directory() -> Path | None:
    """Where empty stores made by MLflow are kept for new stores to start from (None: not kept).

    ``MOSD_STORE_TEMPLATES`` names the folder (``off``: none); default ``$XDG_CACHE_HOME/mosd/mlflow-stores``
    (``~/.cache/mosd/mlflow-stores``).
    """
    chosen = os.environ.get("MOSD_STORE_TEMPLATES", "").strip()
    if chosen.lower() in ("off", "0", "false", "none"):
        return None
    if chosen:
        return Path(chosen).expanduser()
    cache = os.environ.get("XDG_CACHE_HOME", "").strip() or os.path.join("~", ".cache")
    return Path(cache).expanduser() / "mosd" / "mlflow-stores"


def refusal(path: Path, state: StoreState) -> str:
    """The one line that refuses a damaged (or locked) store, with what to do about it."""
    if state.state == "locked":  # a healthy store: nothing to repair, and moving it aside orphans its runs
        return (f"tracking store {path} is locked by another process ({state.detail}); allowed: wait until that "
                f"process has released it (fuser {path} names it), point tracking.uri elsewhere, or tracking=none")
    return (f"tracking store {path} is damaged ({state.detail}); allowed: a healthy MLflow store: move the file "
            f"aside (mosd then creates a new one), point tracking.uri elsewhere, or tracking=none")


def prepare_sqlite_store(path: Path) -> str | None:
    """Under the store lock: move aside a store a killed creation left without runs; refuse a damaged one.

    Returns a note for the user when a store was moved aside. A store another process holds is waited for
    (:data:`LOCKED_WAIT_S`), then refused as locked.
    """
    state = sqlite_store_state(path, wait=LOCKED_WAIT_S)
    if state.state in ("missing", "empty", "ok"):
        return None
    if state.state == "incomplete" and not state.n_runs:
        aside = path.with_name(f"{path.name}.incomplete-{time.strftime('%Y%m%d-%H%M%S')}-{os.getpid()}")
        path.rename(aside)
        return f"moved an unfinished store aside ({state.detail}) to {aside} and created a new one"
    raise TrackingError(refusal(path, state))
