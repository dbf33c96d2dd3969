"""Issue 53 (nothing lost, fourth pass): a stop in a run's last second, labels and gaps that changed numbers
silently, a locked store called damaged, families that could not be re-scored.

Each test reproduces its item as the issue measured it and failed before the fix.
"""
from __future__ import annotations

import json
import os
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import pytest

from test_reliability import _env, _runs

# ---------------------------------------------------------------------------------------
# item 1: a stop signal once the results are printed keeps them
# ---------------------------------------------------------------------------------------
TINY_RUN = ["+fault=offset_var", "optimizer.pop_size=10", "optimizer.n_gen=3", "budget.n_test=3",
            "budget.n_train=3", "budget.n_calibration=3", "progress=false"]


@pytest.mark.serial  # signals and seconds: run after the parallel phase, one at a time (README)
@pytest.mark.slow
@pytest.mark.parametrize("sig, after_s", [(signal.SIGINT, 0.0), (signal.SIGTERM, 0.0), (signal.SIGINT, 0.7)],
                         ids=["ctrl_c-at-once", "sigterm-at-once", "ctrl_c-later"])
def test_a_stop_after_the_results_are_printed_keeps_them_finished(tmp_path, sig, after_s):
    """Before: rc 130, "… is incomplete", summary.json a stub without params or test, MLflow KILLED."""
    proc = subprocess.Popen([sys.executable, "-m", "mosd", *TINY_RUN], cwd=tmp_path, env=_env(), text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True)
    try:
        for line in proc.stdout:
            if line.strip().startswith("MDR"):  # FAR and MDR are on the user's screen
                time.sleep(after_s)
                os.killpg(proc.pid, sig)  # Ctrl-C in a terminal reaches the whole group
                break
        else:
            pytest.fail(f"the run printed no results: {proc.communicate()[1][-3000:]}")
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 128 + sig, err[-3000:]
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err[-3000:]
    assert f"stopped by {signal.Signals(sig).name}" in lines[0] and "incomplete" not in lines[0], lines[0]
    run_dir = next((tmp_path / "outputs" / "runs").iterdir())
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["status"] == "finished", summary
    assert summary["params"] and {"far", "mdr"} <= set(summary["test"]), summary
    assert not [name for name in summary.get("missing", []) if not (run_dir / name).suffix == ".png"], summary
    # MLflow agrees with the run directory: a FINISHED run whose summary.json artifact says 'finished'
    deadline = time.monotonic() + 30  # a tracking process left to end the run alone finishes it shortly
    while True:
        client, runs = _runs(f"sqlite:///{tmp_path / 'outputs' / 'mlflow.db'}")
        if [r.info.status for r in runs] == ["FINISHED"] or time.monotonic() > deadline:
            break
        time.sleep(0.5)
    assert [r.info.status for r in runs] == ["FINISHED"]
    artifact = Path(client.download_artifacts(runs[0].info.run_id, "summary.json", str(tmp_path)))
    logged = json.loads(artifact.read_text())
    assert logged["status"] == "finished" and logged["test"] == summary["test"]
    assert runs[0].data.metrics["far"] == pytest.approx(summary["test"]["far"]["mean"])
