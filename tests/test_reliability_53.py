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
    store = tmp_path / "outputs" / "mlflow.db"
    while not store.exists() and time.monotonic() < deadline:  # this test's client must not make the store itself
        time.sleep(0.5)
    while True:
        client, runs = _runs(f"sqlite:///{store}")
        if [r.info.status for r in runs] == ["FINISHED"] or time.monotonic() > deadline:
            break
        time.sleep(0.5)
    assert [r.info.status for r in runs] == ["FINISHED"]
    artifact = Path(client.download_artifacts(runs[0].info.run_id, "summary.json", str(tmp_path)))
    logged = json.loads(artifact.read_text())
    assert logged["status"] == "finished" and logged["test"] == summary["test"]
    assert runs[0].data.metrics["far"] == pytest.approx(summary["test"]["far"]["mean"])


# ---------------------------------------------------------------------------------------
# items 2 and 3: labels and gaps of a table (mosd.data.table)
# ---------------------------------------------------------------------------------------
TAB = ["+experiment=table", "data.time_column=time", "data.label_column=fault", "debug=tiny", "tracking=none"]


def _labelled_csv(path: Path, change=None, **csv) -> Path:
    from test_table_data import labelled_frame

    frame = labelled_frame()
    if change is not None:
        change(frame)
    frame.to_csv(path, index=False, **csv)
    return path


def _mosd(cwd: Path, *args: str, limit_bytes: int | None = None) -> subprocess.CompletedProcess:
    def limited():
        import resource

        resource.setrlimit(resource.RLIMIT_AS, (limit_bytes, limit_bytes))

    return subprocess.run([sys.executable, "-m", "mosd", *args], cwd=cwd, env=_env(), capture_output=True, text=True,
                          timeout=300, preexec_fn=limited if limit_bytes else None)


def _set_label(row: int, value):
    def change(frame):
        frame["fault"] = frame["fault"].astype(object)
        frame.loc[row, "fault"] = value
    return change


@pytest.mark.parametrize("value, shown", [(1e30, "1e+30"), (-1, "-1"), (2.5, "2.5"), (float("inf"), "inf"),
                                          (32768, "32768")])
def test_a_label_that_is_no_fault_id_is_one_line_naming_the_key_row_and_range(tmp_path, value, shown):
    """Before: 1e30 was cast to int64's minimum and counted as faulty (rc 0, the FAR moved)."""
    from mosd.data.table import MAX_LABEL, Table
    from mosd.validation import ConfigError

    path = _labelled_csv(tmp_path / "plant.csv", _set_label(1000, value))
    with pytest.raises(ConfigError) as caught:
        Table(str(path), time_column="time", label_column="fault")
    message = str(caught.value)
    assert "\n" not in message and message.startswith("data.label_column='fault'"), message
    assert f"row 1000 holds '{shown}'" in message and f"0..{MAX_LABEL}" in message, message


def test_the_largest_label_is_a_fault_id(tmp_path):
    from mosd.data.table import MAX_LABEL, Table

    table = Table(str(_labelled_csv(tmp_path / "plant.csv", _set_label(1000, MAX_LABEL))), time_column="time",
                  label_column="fault")
    assert int(table.trace("test").fault_label.max()) == MAX_LABEL  # the id itself, not a wrapped one


def test_a_huge_integer_label_is_refused_without_allocating_for_it(tmp_path):
    """Before: a label of 1,000,000,000 exhausted memory (MemoryError at 4.4 GB naming no column)."""
    _labelled_csv(tmp_path / "plant.csv", _set_label(1000, 1_000_000_000))
    result = _mosd(tmp_path, *TAB, "data.path=plant.csv", limit_bytes=3 << 30)
    assert result.returncode == 2, result.stderr[-3000:]
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in result.stderr, result.stderr[-3000:]
    assert "data.label_column" in lines[0] and "row 1000 holds '1000000000'" in lines[0], lines[0]
    assert not (tmp_path / "outputs" / "runs").exists() or not any((tmp_path / "outputs" / "runs").iterdir())


def _gaps(frame, seed=1, n=300):
    import numpy as np

    rows = np.random.default_rng(seed).choice(len(frame), n, replace=False)
    frame.loc[rows, "TI-2"] = float("nan")


def test_fill_drop_records_the_files_rows_and_clock(tmp_path):
    """Before: test rows 675-899 for file rows 900-1199, and t from 0 by dt (13,440 s for 71,940 s)."""
    import numpy as np
    import pandas as pd

    from mosd.data.table import Table

    path = _labelled_csv(tmp_path / "gaps.csv", _gaps)
    frame = pd.read_csv(path)
    clock = (pd.to_datetime(frame["time"]) - pd.to_datetime(frame["time"].iloc[0])).dt.total_seconds().to_numpy()
    kept = frame.dropna().index.to_numpy()  # the oracle: pandas' own dropna
    table = Table(str(path), time_column="time", label_column="fault", fill="drop")
    for split in ("calibration", "training", "test"):
        (start, stop), = [(s.start, s.stop) for s in table.segments(split)]
        rows = kept[start:stop]
        described = table.describe()[split][0]
        assert f"gaps.csv rows {rows[0]}-{rows[-1]} (" in described, described
        dropped = rows[-1] - rows[0] + 1 - len(rows)
        assert f"{dropped} rows with a missing tag dropped" in described, described
        np.testing.assert_array_equal(table.trace(split).t, clock[rows])


def test_fill_drop_run_records_the_files_rows_and_its_stream_the_files_clock(tmp_path):
    import pandas as pd

    path = _labelled_csv(tmp_path / "gaps.csv", _gaps)
    result = _mosd(tmp_path, *TAB, "data.path=gaps.csv", "data.fill=drop", "hydra.run.dir=run")
    assert result.returncode == 0, result.stderr[-3000:]
    frame = pd.read_csv(path)
    clock = (pd.to_datetime(frame["time"]) - pd.to_datetime(frame["time"].iloc[0])).dt.total_seconds().to_numpy()
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    test_rows = summary["data"]["test"][0].split(" rows ")[1].split(" ")[0]
    first, last = map(int, test_rows.split("-"))
    assert last == len(frame) - 1  # the last quarter of the rows kept ends at the file's last row
    stream = pd.read_parquet(tmp_path / "run" / "test_stream.parquet")
    assert stream["t"].iloc[0] == clock[first] and stream["t"].iloc[-1] == clock[last]
    assert len(stream) == len(frame.iloc[first:last + 1].dropna())


# ---------------------------------------------------------------------------------------
# item 4: a healthy store another process holds is locked, not damaged
# ---------------------------------------------------------------------------------------
def _hold(db: Path) -> sqlite3.Connection:
    """Another holder of the store: an open exclusive transaction, as a process writing to it for long."""
    con = sqlite3.connect(db, isolation_level=None, check_same_thread=False)
    con.execute("BEGIN EXCLUSIVE")
    return con


def test_a_locked_healthy_store_is_locked_never_damaged(tmp_path):
    """Before: '… is damaged (OperationalError: database is locked); allowed: … move the file aside'."""
    from mosd.app import store
    from test_reliability import make_store

    db = make_store(tmp_path / "mlflow.db", n_runs=3)
    holder = _hold(db)
    try:
        state = store.sqlite_store_state(db, wait=0.2)
        assert state.state == "locked", state
        line = store.refusal(db, state)
        assert "locked by another process" in line and "\n" not in line, line
        assert "damaged" not in line and "aside" not in line, line
    finally:
        holder.close()
    assert store.sqlite_store_state(db).state == "ok"


def test_report_on_a_locked_store_says_locked_in_one_line(tmp_path, capsys):
    """Before: 'the store … is damaged (OperationalError: database is locked …)'."""
    from mosd.app import report
    from test_reliability import make_store

    db = make_store(tmp_path / "mlflow.db", n_runs=2)
    holder = _hold(db)
    try:
        assert report.main(["--tracking-uri", f"sqlite:///{db}"]) == 2
    finally:
        holder.close()
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and "locked by another process" in lines[0] and "damaged" not in lines[0], lines


def test_a_run_never_moves_a_locked_store_aside(tmp_path, monkeypatch):
    from mosd.app import store
    from test_reliability import make_store

    db = make_store(tmp_path / "mlflow.db", n_runs=3)
    monkeypatch.setattr(store, "LOCKED_WAIT_S", 0.2)
    holder = _hold(db)
    try:
        with pytest.raises(store.TrackingError, match="locked by another process"):
            store.prepare_sqlite_store(db)
    finally:
        holder.close()
    assert [p.name for p in tmp_path.iterdir()] == ["mlflow.db"]  # nothing moved aside, nothing created
    assert store.sqlite_store_state(db).n_runs == 3


def test_a_lock_released_within_the_wait_is_a_healthy_store(tmp_path):
    import threading

    from mosd.app import store
    from test_reliability import make_store

    db = make_store(tmp_path / "mlflow.db", n_runs=1)
    holder = _hold(db)
    threading.Timer(0.5, holder.close).start()  # another run's write transaction, ending shortly
    assert store.sqlite_store_state(db, wait=10).state == "ok"


def test_monitor_on_a_locked_store_is_one_line_saying_so(tmp_path):
    from test_reliability import make_store

    db = make_store(tmp_path / "mlflow.db", n_runs=1)
    (tmp_path / "stream.csv").write_text("a\n1\n")
    holder = _hold(db)
    try:
        result = _mosd(tmp_path, "monitor", "--model", "models:/m-0", "--tracking-uri", f"sqlite:///{db}",
                       "stream.csv")
    finally:
        holder.close()
    assert result.returncode == 2, result.stderr[-3000:]
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "locked by another process" in lines[0] and "damaged" not in lines[0], lines


# ---------------------------------------------------------------------------------------
# item 5: `mosd monitor` on every family's model
# ---------------------------------------------------------------------------------------
def _families() -> list[str]:
    """Every conf/detector option whose class is a recorded-data monitor family (a LatentDetector): found, not listed."""
    import importlib

    import yaml

    from mosd.detectors.latent import LatentDetector

    names = []
    for path in sorted((Path(__file__).resolve().parents[1] / "conf" / "detector").glob("*.yaml")):
        module, _, name = yaml.safe_load(path.read_text())["_target_"].rpartition(".")
        if issubclass(getattr(importlib.import_module(module), name), LatentDetector):
            names.append(path.stem)
    return names


FAMILIES = _families()


def build_family_run(family: str):
    """``build(folder)`` for ``shared_build``: a table run of ``family`` with MLflow on in ``folder`` (plant.csv,
    run/, outputs/mlflow.db, the run's stdout in stdout.txt); the run tests/test_served_families.py serves too."""
    def build(folder: Path) -> None:
        _labelled_csv(folder / "plant.csv")
        run = _mosd(folder, *[a for a in TAB if a != "tracking=none"], "data.path=plant.csv", f"detector={family}",
                    "hydra.run.dir=run", "progress=false")
        assert run.returncode == 0, run.stderr[-3000:]
        (folder / "stdout.txt").write_text(run.stdout)
    return build


def _monitor_a_runs_own_stream(tmp_path: Path, folder: Path) -> None:
    """Re-score the test_stream.parquet of the run in ``folder`` (MLflow on: run/, outputs/mlflow.db, stdout.txt)
    with its logged model, as the README does; what monitor writes goes to ``tmp_path``."""
    import re

    import pandas as pd

    model = re.search(r"model (models:/\S+)", (folder / "stdout.txt").read_text())
    assert model, (folder / "stdout.txt").read_text()[-3000:]
    stream_path = folder / "run" / "test_stream.parquet"
    scored = _mosd(tmp_path, "monitor", "--model", model.group(1), "--tracking-uri",
                   f"sqlite:///{folder / 'outputs' / 'mlflow.db'}", "--out", "scored.csv", str(stream_path))
    assert scored.returncode == 0 and "Traceback" not in scored.stderr, scored.stderr[-3000:]
    stream = pd.read_parquet(stream_path)
    out = pd.read_csv(tmp_path / "scored.csv")
    assert len(out) == len(stream) and f"{len(stream)} of {len(stream)} rows agree" in scored.stdout, scored.stdout
    # the run's own alarms, row by row, and the first one named with its statistics beside their limits
    assert out["alarm"].to_numpy(bool).tolist() == stream["alarm"].to_numpy(bool).tolist()
    if stream["alarm"].any():
        first = int(stream["alarm"].to_numpy(bool).argmax())
        line = re.search(rf"first alarm at row {first}: (.+)", scored.stdout)
        assert line and "(limit " in line.group(1), scored.stdout


def test_monitor_rescores_a_cva_runs_own_stream(tmp_path, shared_build):
    """Before: rc 1, KeyError: 't2_smoothed' after scoring, --out never written."""
    _monitor_a_runs_own_stream(tmp_path, shared_build("table-run-cva", build_family_run("cva")))


def test_the_first_alarm_line_reads_each_familys_own_columns():
    import pandas as pd

    from mosd.app.monitor import first_alarm

    cva = pd.DataFrame({"t2s": [1.0, 50.0], "t2s_smoothed": [1.0, 45.0], "t2s_limit": [43.6, 43.6],
                        "q": [2.0, 30.0], "q_smoothed": [2.0, 20.0], "q_limit": [23.7, 23.7], "alarm": [False, True]})
    assert first_alarm(cva, 1) == "first alarm at row 1: T2S 45 (limit 43.6), Q 20 (limit 23.7)"
    pca = pd.DataFrame({"t2": [9.0], "t2_smoothed": [8.0], "t2_limit": [7.0], "spe": [1.0], "spe_smoothed": [0.5],
                        "spe_limit": [2.0], "top_t2": ["TI-1"], "top_spe": ["TI-2"], "alarm": [True]})
    assert first_alarm(pca, 0) == ("first alarm at row 0: T² 8 (limit 7), SPE 0.5 (limit 2); top T² TI-1, "
                                   "top SPE TI-2")


@pytest.mark.slow
@pytest.mark.parametrize("family", FAMILIES)
def test_monitor_rescores_every_familys_run_on_a_table(tmp_path, family, shared_build):
    # the run is shared (trained once) with test_monitor_rescores_a_cva_runs_own_stream and test_served_families
    _monitor_a_runs_own_stream(tmp_path, shared_build(f"table-run-{family}", build_family_run(family)))


@pytest.mark.slow
@pytest.mark.parametrize("family", ["cva", "tag_ewma"])
def test_monitor_rescores_a_te_run(tmp_path, family):
    run = _mosd(tmp_path, "+experiment=tep", "debug=tiny", f"detector={family}", "hydra.run.dir=run", "progress=false")
    assert run.returncode == 0, run.stderr[-3000:]
    (tmp_path / "stdout.txt").write_text(run.stdout)
    _monitor_a_runs_own_stream(tmp_path, tmp_path)


@pytest.mark.slow
def test_a_run_on_a_locked_store_keeps_its_results_and_mosd_log_completes_it(tmp_path):
    """Before: rc 2 '… is damaged (OperationalError: database is locked); allowed: … move the file aside'."""
    _labelled_csv(tmp_path / "plant.csv")
    tab = [a for a in TAB if a != "tracking=none"]
    assert _mosd(tmp_path, *tab, "data.path=plant.csv").returncode == 0  # a healthy store with one run
    db = tmp_path / "outputs" / "mlflow.db"
    holder = _hold(db)
    try:
        result = _mosd(tmp_path, *tab, "data.path=plant.csv", "hydra.run.dir=locked")
    finally:
        holder.close()
    assert result.returncode == 3, result.stderr[-3000:]
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "locked by another process" in lines[0], result.stderr[-3000:]
    assert "damaged" not in result.stderr + result.stdout and "aside" not in result.stderr + result.stdout
    summary = json.loads((tmp_path / "locked" / "summary.json").read_text())
    assert summary["status"] == "finished" and summary["test"] and summary["tracking"]["logged"] is False
    logged = _mosd(tmp_path, "log", "locked")
    assert logged.returncode == 0, logged.stderr[-3000:]
    _, runs = _runs(f"sqlite:///{db}")
    assert sorted(r.info.status for r in runs) == ["FINISHED", "FINISHED"]
