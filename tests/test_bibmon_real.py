"""bibmon's real process data as a labelled table (mosd.systems.bibmon_real) and the missing-value line of
data=table (mosd.data.table): docs/systems/table.md, "A real plant export: bibmon's Petrobras data".

Oracles: pandas (the source file's cells, its timestamps, to_numeric for what is not a number), bibmon's
public ``train_val_test_split`` for the tutorial's windows, and the documented numbers for the run.
"""
import json
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

from mosd.data.table import Table
from mosd.systems import bibmon_real

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "systems" / "table.md"


@pytest.fixture(scope="module")
def source():
    return bibmon_real.source_file()


@pytest.fixture(scope="module")
def exported(tmp_path_factory, source):
    folder = tmp_path_factory.mktemp("bibmon_real")
    path, facts = bibmon_real.export(folder)
    return path, facts


def _texts(frame):
    """(tag, text) -> count of the cells pandas cannot read as numbers."""
    stacked = frame.stack()
    bad = stacked[pd.to_numeric(stacked, errors="coerce").isna()]
    return {(tag, text): int(n) for (tag, text), n in bad.groupby([bad.index.get_level_values(1), bad]).size().items()}


def test_export_labels_the_tutorials_fault_window_and_keeps_every_cell(source, exported):
    path, facts = exported
    raw = pd.read_csv(source, index_col=0, dtype=str, keep_default_na=False)
    out = pd.read_csv(path, dtype=str, keep_default_na=False)
    assert list(out.columns) == ["time", "fault", *raw.columns]
    assert out["time"].tolist() == raw.index.tolist()
    stamps = pd.to_datetime(out["time"])
    expected = (stamps >= "2018-01-02 06:00") & (stamps < "2018-01-02 09:00")
    assert (out["fault"].astype(int) == expected.astype(int)).all()
    assert expected.sum() == 36 and facts["faulty"] == (2664, 2699, 36)
    assert (out.drop(columns=["time", "fault"]).to_numpy() == raw.to_numpy()).all()  # untouched, text and all
    texts = _texts(out.drop(columns=["time", "fault"]))
    assert texts == {("tag70", "Bad"): 326, ("tag2", "Inp OutRange"): 156, ("tag34", "Bad"): 14,
                     ("tag36", "Scan Timeout"): 1, ("tag72", "Scan Timeout"): 1}


def test_tutorial_rows_match_bibmons_own_split(source, exported):
    bibmon = pytest.importorskip("bibmon")
    data = pd.read_csv(source, index_col=0, parse_dates=True)  # what bibmon.load_real_data reads
    t = bibmon_real.TUTORIAL
    train, validation, test = bibmon.train_val_test_split(data, t["start"], t["training"], t["validation"],
                                                          t["test"], tags_Y=data.columns[0])[:3]
    index = list(data.index)
    rows = exported[1]["tutorial"]
    for name, window in (("training", train), ("validation", validation), ("test", test)):
        a, b = rows[name]
        assert (index.index(window.index[0]), index.index(window.index[-1]) + 1) == (a, b), name
    splits = exported[1]["splits"]
    assert splits == {"calibration": (144, 2305), "training": (2305, 2682), "test": (2682, 3169)}
    assert splits["training"][0] == rows["validation"][0] and splits["test"][1] == rows["test"][1]


def _line(out: str) -> list[str]:
    return [line for line in out.splitlines() if "were not numbers" in line]


def test_not_numbers_line_counts_a_small_table(tmp_path, capsys):
    n = 40
    frame = pd.DataFrame({"time": range(n), "fault": [0] * n,
                          **{f"t{i}": [float(r % 7 + i + (r * r) % 5) for r in range(n)] for i in range(8)}})
    frame = frame.astype(object)
    frame.loc[[3, 4, 5], "t0"] = "Bad"
    frame.loc[7, "t0"] = "Scan Timeout"
    frame.loc[[1, 2], "t1"] = " Inp OutRange "
    frame.loc[9, "t1"] = "1e308"  # an error code that is a number: beyond ±MAX_ABS
    for i, tag in enumerate(["t2", "t3", "t4", "t5", "t6"]):
        frame.loc[10 + i, tag] = "Bad"
    frame.loc[20, "t6"] = "Comm Fail"
    frame.loc[21, "t6"] = "I/O Timeout"
    path = tmp_path / "plant.csv"
    frame.to_csv(path, index=False)
    Table(str(path), time_column="time", label_column="fault")
    lines = _line(capsys.readouterr().out)
    assert lines == [f'data: 14 cells of {path} were not numbers (read as missing; data.fill=hold): '
                     't0 4 ("Bad" 3, "Scan Timeout" 1), t1 3 ("Inp OutRange" 2, "1e308" 1), '
                     't6 3 ("Bad" 1, "Comm Fail" 1, ...), t2 1 "Bad", t3 1 "Bad", 2 more tags 2']
    Table(str(path), time_column="time", label_column="fault", fill="drop")
    assert "data.fill=drop" in _line(capsys.readouterr().out)[0]
    frame.drop(columns=["t0", "t1", "t2", "t3", "t4", "t5", "t6"]).assign(
        t8=lambda f: f["time"] * 0.5).to_csv(path, index=False)
    Table(str(path), time_column="time", label_column="fault")
    assert _line(capsys.readouterr().out) == []  # every cell a number: no line


def test_not_numbers_line_on_a_float_column_with_an_error_code(tmp_path, capsys):
    frame = pd.DataFrame({"a": [float(i % 5) for i in range(20)], "b": [float(i % 3) for i in range(20)],
                          "c": [float(i % 4) for i in range(20)]})
    frame.loc[6, "a"] = -1.7e308
    path = tmp_path / "codes.parquet"
    pytest.importorskip("pyarrow")
    frame.to_parquet(path)
    Table(str(path))
    assert _line(capsys.readouterr().out) == [f'data: 1 cells of {path} were not numbers (read as missing; '
                                              'data.fill=hold): a 1 "-1.7e+308"']


def test_not_numbers_line_on_bibmons_file(source, capsys):
    Table(str(source), time_column=0)
    raw = pd.read_csv(source, index_col=0)
    texts = _texts(raw)
    # most first; a tie in the file's column order
    tags = [tag for tag in raw.columns if any(t == tag for t, _ in texts)]
    per_tag = sorted(((sum(n for (t, _), n in texts.items() if t == tag), tag) for tag in tags), key=lambda x: -x[0])
    said = ", ".join(f'{tag} {n} "{next(x for t, x in texts if t == tag)}"' for n, tag in per_tag)
    assert sum(texts.values()) == 498
    assert _line(capsys.readouterr().out) == [f"data: 498 cells of {source} were not numbers (read as missing; "
                                              f"data.fill=hold): {said}"]


def test_export_without_bibmon_is_one_line_naming_the_extra(tmp_path, monkeypatch, capsys):
    real = bibmon_real.importlib.util.find_spec
    monkeypatch.setattr(bibmon_real.importlib.util, "find_spec",
                        lambda name, *a: None if name == "bibmon" else real(name, *a))
    assert bibmon_real.main(["--export", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and '.[te]' in err and not (tmp_path / "x").exists()
    with pytest.raises(SystemExit) as stop:
        bibmon_real.main([])
    assert stop.value.code == 2 and "--export" in capsys.readouterr().err


def _run(command: str, tmp_path: Path) -> subprocess.CompletedProcess:
    argv = shlex.split(command)
    assert argv[:3] == ["python", "-m", "mosd"]
    env = {**os.environ, "PYTHONPATH": str(ROOT), "MOSD_OUTPUTS": str(tmp_path / "out")}
    return subprocess.run([sys.executable, *argv[1:], "tracking=none", "progress=false"], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=600)


def test_documented_command_runs_end_to_end(tmp_path, capsys):
    folder = tmp_path / "export"
    assert bibmon_real.main(["--export", str(folder)]) == 0
    printed = capsys.readouterr().out.splitlines()
    command = printed[printed.index("run next:") + 1]
    # the page's command is this one, for the folder it names
    documented = [line for line in DOC.read_text().splitlines() if line.startswith("python -m mosd +experiment")]
    assert documented == [command.replace(str(folder), "outputs/bibmon_real")]
    out = _run(command, tmp_path)
    assert out.returncode == 0, out.stderr[-2000:]
    assert len(_line(out.stdout)) == 1 and " 498 cells " in _line(out.stdout)[0]
    summary = json.loads(next((tmp_path / "out" / "runs").glob("*/summary.json")).read_text())
    assert summary["data"]["training"][0].endswith("rows 2305-2681 (18 labelled faulty)")
    assert summary["data"]["test"][0].endswith("rows 2682-3168 (18 labelled faulty)")
    far, mdr = summary["test"]["far"]["mean"], summary["test"]["mdr"]["mean"]
    page = DOC.read_text()
    assert f"FAR {far:.4f}" in page and f"MDR {mdr:.4f}" in page, (far, mdr)  # the page's numbers are the run's


def test_tutorials_own_windows_are_refused_in_one_line(exported, tmp_path):
    path, facts = exported
    tutorial = facts["tutorial"]
    splits = {"calibration": tutorial["training"], "training": tutorial["validation"], "test": tutorial["test"]}
    out = _run(bibmon_real.run_command(path, splits), tmp_path)
    assert out.returncode == 2
    error = [line for line in out.stderr.splitlines() if line.strip()][-1]
    assert re.fullmatch(r"mosd: error: data split training has no faulty row .*", error)
    assert "Traceback" not in out.stderr
    assert error in DOC.read_text()
