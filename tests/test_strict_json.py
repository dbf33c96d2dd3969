"""Every JSON file mosd writes is strict JSON: an undefined number is null, never a bare NaN (issue 30).

Python's json module writes NaN and Infinity by default; JavaScript, PostgreSQL's json type and
``json.loads(..., parse_constant=...)`` reject them. The run directory's files go through
:func:`mosd.app.atomic.write_json`, the report commands' through :func:`mosd.systems.cli.write_json`,
both through :func:`mosd.metrics.json_ready`. ``tests/test_tep_run.py`` parses every JSON file of a
whole run directory this way.
"""
import json
import math

import numpy as np
import pytest

from mosd.app.atomic import write_json
from mosd.metrics import Estimate, json_ready
from mosd.systems import cli


def _refuse(constant):
    raise ValueError(f"non-standard JSON constant {constant}")


PAYLOAD = {"far": {"mean": 0.01, "ci95_half_width": Estimate.of([0.01]).half_width, "n": 1},
           "delays": [1.0, math.nan, math.inf, -math.inf], "array": np.array([0.5, np.nan]),
           "scalar": np.float64("nan"), "count": np.int64(3), "nested": ({"x": np.float32(2.5)},), "text": "NaN"}


def test_json_ready_turns_every_non_finite_number_into_none():
    ready = json_ready(PAYLOAD)
    assert ready["far"]["ci95_half_width"] is None  # one run: no confidence interval
    assert ready["delays"] == [1.0, None, None, None]
    assert ready["array"] == [0.5, None] and ready["scalar"] is None
    assert ready["count"] == 3 and type(ready["count"]) is int
    assert ready["nested"] == [{"x": 2.5}] and ready["text"] == "NaN"


@pytest.mark.parametrize("write", [write_json, cli.write_json])
def test_the_writers_write_strict_json(tmp_path, write):
    path = write(tmp_path / "summary.json", PAYLOAD)
    text = path.read_text()
    assert "NaN" not in text.replace('"NaN"', "") and "Infinity" not in text
    data = json.loads(text, parse_constant=_refuse)
    assert data["delays"] == [1.0, None, None, None] and data["far"]["mean"] == 0.01


def test_python_json_alone_is_not_strict(tmp_path):
    """What the writers guard against: the standard library's default output fails the strict parse."""
    with pytest.raises(ValueError, match="non-standard JSON constant NaN"):
        json.loads(json.dumps({"x": math.nan}), parse_constant=_refuse)


def test_a_paper002_run_directory_is_strict_and_carries_the_per_run_pair(tmp_path):
    """The preset's study lands in summary.json with the per-run pair at every missing rate (issue 30)."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    out = subprocess.run([sys.executable, "-m", "mosd", "+experiment=paper002", "optimizer.pop_size=6",
                          "optimizer.n_gen=2", "optimizer.n_jobs=1", "budget.n_train=20", "budget.n_test=10",
                          "budget.n_calibration=4", "study.n_runs=6", "study.figures=false", "tracking=none",
                          "progress=false"], capture_output=True, text=True, timeout=900,
                         env={**os.environ, "PYTHONPATH": str(root), "MOSD_OUTPUTS": str(tmp_path)})
    assert out.returncode == 0, out.stderr[-3000:]
    (run_dir,) = (tmp_path / "runs").iterdir()
    files = sorted(run_dir.rglob("*.json"))
    assert run_dir / "summary.json" in files
    for path in files:
        json.loads(path.read_text(), parse_constant=_refuse)
    summary = json.loads((run_dir / "summary.json").read_text())
    study = summary["study"]
    for r in (0, 5, 10, 20):
        assert 0.0 <= study[f"nuisance_run_false_isolation_r{r}"] <= 1.0
        assert 0.0 <= study[f"target_run_detection_r{r}"] <= 1.0
    assert summary["test"]["delay"]["unit"] == "points"
    assert not any(k.endswith("fill_rmse_r0") for k in study)  # nothing filled on complete data: not reported
