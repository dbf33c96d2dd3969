"""Issue 53 item 9: a joblib sweep whose worker process is SIGKILLed (the out-of-memory killer, ``kill -9``).

Before: Hydra printed joblib's ``TerminatedWorkerError`` in 37 lines, rc 1, and the jobs that were running were
left with a ``mosd.log`` and no ``summary.json``. Now: one line naming the jobs that lost their work and those
that did not start, rc 1, and every job that started has a ``summary.json`` (``failed`` with the reason for
the lost ones; the finished ones keep their results).
"""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from mosd.app import sweep

from test_app import PACKAGE_PARENT


def test_the_line_names_the_lost_and_the_unstarted_jobs(tmp_path, capsys, monkeypatch):
    from concurrent.futures.process import BrokenProcessPool

    from mosd.app import files

    monkeypatch.setattr(files, "NOT_WRITTEN", [])
    monkeypatch.setattr(sweep, "LOST_JOBS", [])
    batch = [["+fault=offset", "seed=1"], ["+fault=variance", "seed=1"], ["+fault=ramp", "seed=1"]]
    for num, overrides in ((0, batch[0]), (1, batch[1])):
        (tmp_path / str(num) / ".hydra").mkdir(parents=True)
        (tmp_path / str(num) / ".hydra" / "overrides.yaml").write_text("".join(f"- {o}\n" for o in overrides))
    (tmp_path / "0" / "summary.json").write_text(json.dumps({"status": "finished", "test": {"far": 0.0}}))
    returns = sweep.lost_worker(tmp_path, batch, 0, BrokenProcessPool(
        "A worker process managed by the executor was unexpectedly terminated.\n\nThe exit codes of the workers "
        "are {SIGKILL(-9)}\n"))
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("mosd: error: a worker process of the joblib launcher ended "
                                               "(SIGKILL(-9)")
    assert "job #1 (+fault=variance) lost its work" in err[0] and "job #2 (+fault=ramp) did not start" in err[0]
    assert "1 finished job(s) keep their results" in err[0]
    assert json.loads((tmp_path / "0" / "summary.json").read_text())["status"] == "finished"  # kept as it was
    lost = json.loads((tmp_path / "1" / "summary.json").read_text())
    assert lost["status"] == "failed" and "SIGKILL(-9)" in lost["error"] and lost["overrides"] == batch[1]
    assert [r.return_value for r in returns] == [None, None, None]  # Hydra ends the sweep without a traceback
    assert files.NOT_WRITTEN == [(tmp_path / "1").resolve()] == sweep.LOST_JOBS  # exit code 1


@pytest.mark.slow
def test_a_sigkilled_job_worker_is_one_line_and_every_started_job_has_a_summary(tmp_path):
    import psutil

    env = {k: v for k, v in os.environ.items() if not k.startswith("MOSD_") and k != "HYDRA_FULL_ERROR"}
    env.update(PYTHONPATH=PACKAGE_PARENT, MOSD_OUTPUTS=str(tmp_path / "out"))
    proc = subprocess.Popen([sys.executable, "-m", "mosd", "-m", "+fault=offset,variance", "optimizer=mopso,nsga2",
                             "hydra/launcher=joblib", "hydra.launcher.n_jobs=2", "optimizer.pop_size=20",
                             "optimizer.n_gen=40", "budget.n_test=2", "budget.n_train=4", "budget.n_calibration=2",
                             "optimizer.n_jobs=1", "progress=false", "tracking=none"], cwd=tmp_path, env=env,
                            text=True, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        deadline = time.monotonic() + 600
        while not list((tmp_path / "out").glob("multirun/*/*/.hydra")):  # a job has started
            assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()[1][-3000:]
            time.sleep(0.1)
        workers = [p for p in psutil.Process(proc.pid).children()
                   if "popen_loky" in " ".join(p.cmdline())]
        assert workers, "no joblib worker found"
        os.kill(workers[0].pid, signal.SIGKILL)
        out, err = proc.communicate(timeout=600)
    finally:
        if proc.poll() is None:
            proc.kill()
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert proc.returncode == 1 and len(lines) == 1, err[-3000:]
    assert lines[0].startswith("mosd: error: a worker process of the joblib launcher ended (SIGKILL(-9)")
    assert "lost" in lines[0] and "Traceback" not in err
    started = [d for d in (tmp_path / "out").glob("multirun/*/*") if (d / ".hydra").is_dir()]
    assert started and all((d / "summary.json").is_file() for d in started)
    statuses = {json.loads((d / "summary.json").read_text())["status"] for d in started}
    assert "failed" in statuses and statuses <= {"failed", "finished"}
