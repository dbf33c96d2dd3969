"""Issue 53 item 9: a full disk mid-run is one line on stderr (what happened, what is kept, what to do), never
SQLAlchemy's raw statement (``[SQL: INSERT INTO runs ...] [parameters: ...]``).

Measured on a 12 MB tmpfs filled once the run's first line was out: before, two lines, the first
``mosd: could not mark the MLflow run FAILED: MlflowException: (raised as a result of Query-invoked autoflush;
...) (sqlite3.OperationalError) database or disk is full [SQL: INSERT INTO runs (...) VALUES (...)]
[parameters: (...)] (Background on this error at: ...)``. The end-to-end test below makes the same two failures
without a mount: the run directory's writes raise ENOSPC and the store's answer is that error's text.
"""
from __future__ import annotations

import os
import subprocess
import sys

from mosd.app.store import short_error

from test_app import PACKAGE_PARENT

FULL_STORE = ("MlflowException: (raised as a result of Query-invoked autoflush; consider using a "
              "session.no_autoflush block if this flush is occurring prematurely) (sqlite3.OperationalError) "
              "database or disk is full [SQL: INSERT INTO runs (run_uuid, name, source_type, status, start_time) "
              "VALUES (?, ?, ?, ?, ?)] [parameters: ('7c531e2cfbaa487996ec9909a3f367aa', 'offset_var-ss_dewma-mopso', "
              "'UNKNOWN', 'RUNNING', 1795948372156)] (Background on this error at: https://sqlalche.me/e/21/e3q8)")


def test_short_error_keeps_the_message_and_drops_the_statement():
    assert short_error(FULL_STORE) == "MlflowException: (sqlite3.OperationalError) database or disk is full"
    assert short_error("MlflowException: (sqlite3.OperationalError) disk I/O error (Background on this error at: "
                       "https://sqlalche.me/e/21/e3q8)") == "MlflowException: (sqlite3.OperationalError) disk I/O error"
    for plain in ("OSError: [Errno 28] No space left on device", "TrackingError: the server said [no]"):
        assert short_error(plain) == plain  # a message without SQLAlchemy's parts is left as it is


SCRIPT = """
import errno, os, sys
import mosd.app.run as run
import mosd.app.tracker as tracker

def full_disk(*args, **kwargs):
    raise OSError(errno.ENOSPC, "No space left on device")

def full_store(self, *args, **kwargs):
    raise RuntimeError(os.environ["FULL_STORE"])

run.write_run_files = full_disk
tracker.RunTracker.abort = full_store
from mosd.app import main
sys.exit(main())
"""


def test_a_full_disk_mid_run_is_one_line_without_sql(tmp_path):
    env = {k: v for k, v in os.environ.items() if not k.startswith("MOSD_") and k != "HYDRA_FULL_ERROR"}
    env.update(PYTHONPATH=PACKAGE_PARENT, MOSD_OUTPUTS=str(tmp_path / "outputs"), FULL_STORE=FULL_STORE)
    small = ["optimizer.pop_size=6", "optimizer.n_gen=2", "budget.n_test=2", "budget.n_train=2",
             "budget.n_calibration=2", "optimizer.n_jobs=1", "progress=false", "scenario.duration=3"]
    done = subprocess.run([sys.executable, "-c", SCRIPT, "+fault=offset_var", *small], cwd=tmp_path,
                          env=env, capture_output=True, text=True, timeout=600)
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 1 and len(lines) == 1, done.stderr[-3000:]
    line = lines[0]
    assert "[SQL:" not in line and "INSERT" not in line and "parameters" not in line and "Traceback" not in line
    assert line.startswith("mosd: error: the run directory could not be written: OSError: [Errno 28] No space")
    assert "the MLflow run could not be marked FAILED (MlflowException: (sqlite3.OperationalError) " \
           "database or disk is full)" in line
    assert "summary.json says status 'failed'" in line and line.endswith("free space on that disk (or raise its "
                                                                        "quota) and run again")
