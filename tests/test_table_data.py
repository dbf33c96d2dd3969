"""Any labelled table as recorded data (mosd.data.table): bibmon's real plant export, CSV and Parquet files.

Oracles: pandas itself (to_numeric for the first error code, ffill / interpolate / dropna for the
fill policies), and a CSV and a Parquet file of the same numbers that must load identically.
"""
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from mosd.data.table import Table
from mosd.data.tep import bibmon_directory
from mosd.detectors.pca import PCADetector
from mosd.estimators.measured import MeasuredSignals
from mosd.monitors.outputs import OutputMonitor
from mosd.recorded import RecordedExperiment
from mosd.systems.tep import monitor_table
from mosd.validation import ConfigError

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def real_csv():
    folder = bibmon_directory()
    assert folder is not None, 'bibmon is a test dependency (pip install ".[test]")'
    return folder.parent / "real_process_data" / "real_process_data.csv"


def labelled_frame(n=1200, seed=0):
    """Correlated tags, a fault (label 3: a shift in a direction the normal data never take) in two stretches."""
    rng = np.random.default_rng(seed)
    latent = rng.standard_normal((n, 3))
    tags = latent @ rng.standard_normal((3, 8)) + 0.1 * rng.standard_normal((n, 8))
    label = np.zeros(n, int)
    for start in (700, 1000):
        label[start:start + 120] = 3
    tags[label == 3, 0] += 1.5
    tags[label == 3, 5] -= 1.5
    frame = pd.DataFrame(tags, columns=[f"TI-{i}" for i in range(8)])
    frame.insert(0, "time", pd.date_range("2024-01-01", periods=n, freq="1min"))
    frame["fault"] = label
    return frame


def test_real_export_loads_fits_and_names_the_tags_behind_the_alarms(real_csv, caplog):
    raw = pd.read_csv(real_csv, index_col=0)
    with caplog.at_level("WARNING", logger="mosd.data"):
        table = Table(str(real_csv), time_column=0, errors="nan", fill="hold")
    caught = [r.getMessage() for r in caplog.records]
    assert table.dt == 300.0  # 5-minute samples
    assert len(table.output_names) + len(table.dropped) == raw.shape[1] == 108
    assert table.dropped and any("constant" in line and "\n" not in line for line in caught)
    assert "tag2" in table.output_names  # its 'Inp OutRange' cells are held, the column kept
    result = monitor_table(table, PCADetector(n_components=9, alpha=0.01, fit_runs=None))
    assert result["n_rows"] == raw.shape[0] - int(round(0.5 * raw.shape[0]))
    assert 0.0 < result["alarm_rate"] < 1.0
    top = result["top_spe"]
    assert len(top) == 10 and all(name in table.output_names for name, _ in top)
    assert top[0][1] >= top[-1][1] > 0 and sum(s for _, s in result["top_spe"]) <= 1.0 + 1e-9


def test_strict_policy_names_file_column_row_and_text(real_csv):
    raw = pd.read_csv(real_csv, index_col=0)
    numbers = pd.to_numeric(raw["tag2"], errors="coerce")
    first_bad = int(np.flatnonzero(numbers.isna().to_numpy() & raw["tag2"].notna().to_numpy())[0])
    with pytest.raises(ConfigError) as info:
        Table(str(real_csv), time_column=0, errors="strict", tags=["tag2", "tag3"])
    message = str(info.value)
    assert "\n" not in message
    assert f"column 'tag2' row {first_bad} holds 'Inp OutRange'" in message and str(real_csv) in message


@pytest.mark.parametrize("fill", ["hold", "interpolate", "drop", "none"])
def test_fill_policies_against_pandas(tmp_path, fill):
    # 12 rows, 9 complete: every split keeps 2 rows or more and the calibration more rows than tags (issue 34)
    frame = pd.DataFrame({"a": [1.0, None, 3.0, "Bad", 5.0, 6.0, 7.0, 8.0, 9.5, 10.0, 11.0, 12.5],
                          "b": [2.0, 2.5, "Scan Timeout", 4.0, 4.5, 7.0, 6.0, 5.0, 3.0, 2.0, 1.0, 0.5]})
    path = tmp_path / "gaps.csv"
    frame.to_csv(path, index=False)
    table = Table(str(path), fill=fill, splits={"calibration": [0, 6], "training": [6, 9], "test": [9, 12]}
                  if fill != "drop" else {"calibration": [0, 3], "training": [3, 6], "test": [6, 9]})
    numeric = frame.apply(pd.to_numeric, errors="coerce")
    expected = {"hold": numeric.ffill().bfill(), "interpolate": numeric.interpolate(limit_direction="both"),
                "drop": numeric.dropna(), "none": numeric}[fill].to_numpy()
    np.testing.assert_array_equal(table.values(str(path)), expected)


def test_csv_and_parquet_of_the_same_numbers_load_the_same(tmp_path):
    frame = labelled_frame()
    frame.to_csv(tmp_path / "plant.csv", index=False)
    frame.to_parquet(tmp_path / "plant.parquet")
    tables = [Table(str(tmp_path / name), time_column="time", label_column="fault") for name in
              ("plant.csv", "plant.parquet")]
    for split in ("calibration", "training", "test"):
        a, b = (t.trace(split) for t in tables)
        np.testing.assert_allclose(a.y, b.y, rtol=1e-15)
        np.testing.assert_array_equal(a.fault_label, b.fault_label)
    assert tables[0].dt == 60.0 and tables[0].output_names == tuple(f"TI-{i}" for i in range(8))
    assert tables[0].trace("test").fault_label.max() == 3


def test_pipeline_tunes_on_a_written_table(tmp_path):
    frame = labelled_frame()
    frame.to_parquet(tmp_path / "plant.parquet")
    table = Table(str(tmp_path / "plant.parquet"), time_column="time", label_column="fault",
                  splits={"calibration": [0, 0.5], "training": [0.5, 0.75], "test": [0.75, 1.0]})
    experiment = RecordedExperiment(table, MeasuredSignals(), OutputMonitor(), PCADetector(n_components=3,
                                                                                             max_components=6))
    data = experiment.prepare()
    F = experiment.evaluator(data)(np.array([[3, 0.01, 1.0, 1], [2, 0.05, 0.3, 2]]))
    assert F.shape == (2, 2) and F[0, 1] < 0.5  # the fault is seen
    report, _ = experiment.evaluate(experiment.detector, data)
    assert report.n_runs == 1


@pytest.mark.parametrize("suffix", ["csv", "parquet"])
def test_app_runs_on_a_written_file(tmp_path, suffix):
    frame = labelled_frame()
    path = tmp_path / f"plant.{suffix}"
    frame.to_csv(path, index=False) if suffix == "csv" else frame.to_parquet(path)
    env = {**os.environ, "PYTHONPATH": str(ROOT), "MOSD_OUTPUTS": str(tmp_path / "out")}
    out = subprocess.run([sys.executable, "-m", "mosd", "data=table", f"data.path={path}",
                          "data.time_column=time", "data.label_column=fault", "estimator=measured",
                          "monitor=signals", "detector=pca", "detector.n_components=3", "detector.max_components=6",
                          "optimizer.pop_size=6", "optimizer.n_gen=2", "optimizer.n_jobs=1", "tracking=none",
                          "progress=false"], capture_output=True, text=True, env=env, timeout=600)
    assert out.returncode == 0, out.stderr
    summary = json.loads(next((tmp_path / "out" / "runs").glob("*/summary.json")).read_text())
    assert summary["status"] == "finished"
    assert summary["data"]["calibration"] == [f"{path} rows 0-599 (0 labelled faulty)"]
    assert summary["test"]["mdr"]["mean"] < 0.5


def test_bad_tables_are_one_line(tmp_path):
    frame = labelled_frame(200)
    path = tmp_path / "plant.csv"
    frame.to_csv(path, index=False)
    cases = [
        (dict(path=str(tmp_path / "missing.csv")), "no such file"),
        (dict(path=str(path), label_column="label"), "column 'label' is not in"),
        (dict(path=str(path), tags=["TI-0", "TI-9"]), "column 'TI-9' is not in"),
        (dict(path=str(path), label_column="fault", splits={"calibration": [0, 0.5], "training": [0.5, 0.75],
                                                            "test": [0.75, 1.0]}), None),
    ]
    for kwargs, match in cases:
        if match is None:
            Table(**kwargs)
            continue
        with pytest.raises(ConfigError, match=match):
            Table(**kwargs)
    all_faulty = frame.assign(fault=3)
    all_faulty.loc[:50, "fault"] = 0
    all_faulty.to_csv(path, index=False)
    with pytest.raises(ConfigError, match=r"data.splits.training: rows 100-149 of .* have no fault-free row"):
        Table(str(path), label_column="fault", splits={"calibration": [0, 0.5], "training": [0.5, 0.75],
                                                      "test": [0.75, 1.0]})
    frame.assign(fault=["x"] + [0] * 199).to_csv(path, index=False)
    with pytest.raises(ConfigError, match="column 'fault' row 0 holds 'x', not a fault id"):
        Table(str(path), label_column="fault")
    # no more calibration rows than tags (4 for 8; so also no more than the components): refused by the
    # table, before any fit, naming the file and the counts (issue 34)
    frame.to_csv(path, index=False)
    with pytest.raises(ConfigError, match=r"data.splits.calibration: 4 fault-free complete rows of .*plant.csv for 8 "
                                          r"tags: the covariance is singular"):
        Table(str(path), time_column="time", label_column="fault",
              splits={"calibration": [0, 4], "training": [4, 100], "test": [100, 200]})


def _stamped(tmp_path, **extra) -> Path:
    """labelled_frame's tags and labels with its time as text in a column 'stamp' (every 2 s)."""
    frame = labelled_frame().drop(columns="time")
    frame.insert(0, "stamp", pd.date_range("2024-01-01", periods=len(frame), freq="2s").strftime("%Y-%m-%d %H:%M:%S"))
    for name, column in extra.items():
        frame[name] = column(frame)
    path = tmp_path / "stamped.csv"
    frame.to_csv(path, index=False)
    return path


def test_the_one_column_of_timestamps_is_the_time_column_when_none_is_named(tmp_path, capsys):
    """issue 51: without data.time_column the timestamp was a tag of 400 'not numbers', dropped as constant."""
    table = Table(str(_stamped(tmp_path)), label_column="fault")
    said = capsys.readouterr().out
    assert "column 'stamp' holds a timestamp on every row" in said and said.count("\n") == 1
    assert table.time_column == "stamp" and "stamp" not in table.output_names
    assert table.dt == pytest.approx(2.0)


def test_no_detection_with_time_column_false_or_two_timestamp_columns(tmp_path, capsys):
    tags = [f"TI-{i}" for i in range(8)]
    table = Table(str(_stamped(tmp_path)), label_column="fault", time_column=False, tags=tags)
    assert table.time_column is False and table.dt == 1.0
    two = _stamped(tmp_path, again=lambda f: f["stamp"])
    table = Table(str(two), label_column="fault", tags=tags)
    assert table.time_column is None and table.dt == 1.0
    # timestamps out of order are not the table's clock unless data.sort=true (a named column would be refused)
    shuffled = _stamped(tmp_path, stamp=lambda f: f["stamp"].iloc[::-1].to_numpy())
    table = Table(str(shuffled), label_column="fault", tags=tags)
    assert table.time_column is None and table.dt == 1.0
    assert "holds a timestamp" not in capsys.readouterr().out
    assert Table(str(shuffled), label_column="fault", tags=tags, sort=True).time_column == "stamp"
