"""Issue 53 item 6: a search box the data collapse to one value is a fixed parameter, not an error.

Before: a 2-tag table passed preflight and then stopped in the tuning (``ConfigError: bounds.n_components=[1, 1]
is not allowed``, a failed run left behind); a 1-tag table was refused with "only in [1, 0] … more (or longer)
calibration runs", advice that cannot help (a PCA of one tag has no residual space).
"""
from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
from pymoo.optimize import minimize

from mosd.detectors.pca import PCADetector
from mosd.optim.mopso import MOPSO
from mosd.optim.problem import CandidateEvaluator, TuningProblem
from mosd.validation import ConfigError


def _table(path, n_tags, n_rows=900, seed=0):
    rng = np.random.default_rng(seed)
    tags = rng.standard_normal((n_rows, n_tags))
    fault = np.zeros(n_rows, int)
    for start in (560, 760):
        fault[start:start + 60] = 1
        tags[start:start + 60] += 2.5
    frame = pd.DataFrame(tags, columns=[f"tag{i}" for i in range(n_tags)])
    frame.insert(0, "fault", fault)
    frame.to_csv(path, index=False)
    return path


def _main(tmp_path, monkeypatch, *argv):
    from mosd.app import main

    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("MOSD_OUTPUTS", str(tmp_path / "outputs"))
    return main(["+experiment=table", "data.label_column=fault", "tracking=none", "progress=false",
                 "optimizer.pop_size=6", "optimizer.n_gen=3", *argv])


@pytest.mark.parametrize("family, key", [("pca", "n_components"), ("sfa", "n_slow")])
def test_a_two_tag_table_tunes_with_the_collapsed_parameter_fixed(tmp_path, monkeypatch, capsys, family, key):
    path = _table(tmp_path / "two.csv", n_tags=2)
    code = _main(tmp_path, monkeypatch, f"data.path={path}", f"detector={family}")
    assert code == 0, capsys.readouterr().err
    summary = json.loads(next((tmp_path / "outputs" / "runs").glob("*/summary.json")).read_text())
    assert summary["status"] == "finished" and summary["params"][key] == 1
    assert "test" in summary


def test_a_one_tag_table_is_one_line_that_names_the_parameter_and_what_helps(tmp_path, monkeypatch, capsys):
    path = _table(tmp_path / "one.csv", n_tags=1)
    code = _main(tmp_path, monkeypatch, f"data.path={path}", "detector=pca")
    err = capsys.readouterr().err.strip()
    assert code == 2 and "\n" not in err and "Traceback" not in err, err
    assert "detector.n_components at most 0" in err and "detector=tag_ewma" in err and "more tags" in err
    assert not (tmp_path / "outputs" / "runs").exists()
    # and what it suggests works on the same table
    assert _main(tmp_path, monkeypatch, f"data.path={path}", "detector=tag_ewma") == 0, capsys.readouterr().err


def test_the_tuning_keeps_a_fixed_parameter_at_its_value_and_refuses_a_reversed_box(small_chart_data):
    phase1, train, mask = small_chart_data
    z1, z2 = phase1.reshape(-1, 5)[None], train
    detector = PCADetector(n_components=2)
    evaluator = CandidateEvaluator(detector, detector.features(z1), detector.features(z2), mask)
    problem = TuningProblem(evaluator, bounds={"n_components": (2, 2)}, n_jobs=1)
    column = list(detector.tunable).index("n_components")
    result = minimize(problem, MOPSO(pop_size=8), ("n_gen", 3), seed=0)
    assert np.all(np.atleast_2d(result.X)[:, column] == 2)
    with pytest.raises(ConfigError, match=r"bounds.n_components=\[3, 2\] is not allowed; allowed: low <= high"):
        TuningProblem(evaluator, bounds={"n_components": (3, 2)}, n_jobs=1)


def test_tep_table_report_on_one_tag_is_one_line(tmp_path, capsys):
    """Before: 'detector.n_components=0 is out of range' from ``python -m mosd.systems.tep --table``."""
    from mosd.systems import tep

    path = _table(tmp_path / "one.csv", n_tags=1)
    assert tep.main(["--table", str(path), "--label-column", "fault", "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "1 tag(s)" in err and "detector=tag_ewma" in err and "n_components=0" not in err, err


def test_report_commands_check_their_output_folders_before_the_work(tmp_path, capsys):
    """Before: ``tep --export /proc/te_csv`` and ``tep --families --out /proc/fam`` ended in a FileNotFoundError
    traceback, the second after its tuning had run."""
    import time

    from mosd.systems import tep

    for argv in (["--export", "/proc/te_csv"], ["--families", "--family", "pca", "--out", "/proc/fam"]):
        t0 = time.perf_counter()
        assert tep.main(argv) == 2
        err = capsys.readouterr().err.strip()
        assert "\n" not in err and "cannot be written" in err and argv[-1] in err, err
        assert time.perf_counter() - t0 < 5.0  # refused before any tuning (the tuning takes minutes)
