"""python -m mosd.bench --json: one JSON object with the headline numbers, the table beside it."""
import json

import numpy as np

from mosd import bench


def test_json_object_carries_the_candidate_keys(capsys):
    assert bench.main(["--json", "--quick", "--only", "candidates"]) == 0
    out, err = capsys.readouterr()
    result = json.loads(out)
    assert result["candidates_identical"] == 1  # compiled objectives equal the NumPy path's, bit for bit
    assert result["candidates_per_s"] > result["candidates_speedup_vs_naive"] > 1.0
    assert result["candidates_speedup_vs_numpy"] > 1.0
    assert result["cpus"] >= 1 and result["quick"] == 1
    assert "| candidates | speed-up compiled / NumPy |" in err


def test_unknown_section_is_refused(capsys):
    assert bench.main(["--only", "candidates,bogus"]) == 2
    assert "'bogus' is unknown; allowed:" in capsys.readouterr().err


def test_parallel_section_reports_identical_archives():
    rows, metrics = bench.bench_parallel(quick=True)
    assert metrics["parallel_identical"] == 1
    assert metrics["parallel_speedup_2v1"] > 0
    assert np.isfinite([value for _, value, _ in rows]).all()
