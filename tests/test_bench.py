"""python -m mosd.bench --json: one JSON object with the headline numbers, the table beside it."""
import json

import numpy as np
import pytest

from mosd import bench


#: the candidates section's JSON keys and the table row each repeats (measure name, as printed)
CANDIDATE_KEYS = {
    "candidates_per_s": "candidate evaluations/s, compiled (1 candidate x 1 training sequence, Phase-I limit included)",
    "candidates_numpy_per_s": "candidate evaluations/s, NumPy vectorised population (the reference path)",
    "candidates_speedup_vs_numpy": "speed-up compiled / NumPy",
    "candidates_speedup_vs_naive": "speed-up compiled / naive",
    "candidates_identical": "compiled objectives identical to NumPy's",
    "candidates_plain_per_s": "candidate evaluations/s, compiled, no denoiser (the app's default)",
    "candidates_plain_speedup_vs_numpy": "speed-up compiled / NumPy, no denoiser",
}


def _table(err: str) -> dict[str, float]:
    """``measure -> value`` of the markdown table ``mosd.bench`` printed (values as formatted there)."""
    rows = {}
    for line in err.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) == 4 and cells[0] == "candidates":
            rows[cells[1]] = float(cells[2].replace(",", ""))
    return rows


def test_json_object_carries_the_candidate_keys(capsys):
    assert bench.main(["--json", "--quick", "--only", "candidates"]) == 0
    out, err = capsys.readouterr()
    result = json.loads(out)
    assert set(CANDIDATE_KEYS) <= set(result), sorted(set(CANDIDATE_KEYS) - set(result))
    assert result["candidates_identical"] == 1  # compiled objectives equal the NumPy path's, bit for bit
    assert result["cpus"] >= 1 and result["quick"] == 1
    # each key carries the number of its own row (a throughput where the table has the throughput, a ratio
    # where it has the ratio), to the 4 significant digits the table prints
    table = _table(err)
    for key, measure in CANDIDATE_KEYS.items():
        assert result[key] == pytest.approx(table[measure], rel=1e-3), (key, result[key], table.get(measure))
    assert result["candidates_per_s"] == pytest.approx(result["candidates_numpy_per_s"]
                                                       * result["candidates_speedup_vs_numpy"], rel=1e-4)


def test_unknown_section_is_refused(capsys):
    assert bench.main(["--only", "candidates,bogus"]) == 2
    assert "'bogus' is unknown; allowed:" in capsys.readouterr().err


def test_skipped_sections_are_left_out_and_an_unknown_one_is_refused(capsys, monkeypatch):
    ran = []
    monkeypatch.setattr(bench, "bench_tep", lambda quick: ran.append("tep") or ([], {}))
    monkeypatch.setattr(bench, "bench_serve", lambda quick: ran.append("serve") or ([], {}))
    assert bench.main(["--only", "tep,serve", "--skip", "serve"]) == 0
    assert ran == ["tep"]
    assert bench.main(["--skip", "servr"]) == 2
    assert "--skip 'servr' is unknown; allowed:" in capsys.readouterr().err


def test_parallel_section_reports_identical_archives(monkeypatch):
    """Identical archives for n_jobs 1 and 2 are reported as such, and a difference would be reported too."""
    rows, metrics = bench.bench_parallel(quick=True)
    reported = {name: value for name, value, _ in rows}
    assert metrics["parallel_identical"] == 1 == reported["identical archives for n_jobs 1 and 2"]
    assert metrics["parallel_speedup_2v1"] == reported["speed-up n_jobs=2 vs 1"] == pytest.approx(
        reported["wall time n_jobs=1 (s)"] / reported["wall time n_jobs=2 (s)"])
    # the comparison can fail: the n_jobs=2 problem shifted by one ulp-sized step is reported as different
    real = bench._tuning_setup

    def shifted_when_parallel(n_jobs, **kwargs):
        problem = real(n_jobs, **kwargs)
        if n_jobs == 2:
            evaluate = problem._evaluate

            def shifted(X, out, *args, **kw):
                evaluate(X, out, *args, **kw)
                out["F"] = out["F"] + 1e-12

            problem._evaluate = shifted
        return problem

    monkeypatch.setattr(bench, "_tuning_setup", shifted_when_parallel)
    assert bench.bench_parallel(quick=True)[1]["parallel_identical"] == 0


def test_json_line_leaves_out_what_is_not_a_finite_number(capsys, monkeypatch):
    # a section whose figure the machine could not give (NaN), an infinite ratio, NumPy scalars
    monkeypatch.setattr(bench, "bench_tep", lambda quick: ([], {"tep_a": float("nan"), "tep_b": np.float64(np.inf),
                                                                "tep_c": np.float64(1.23456789), "tep_d": np.int64(3)}))
    monkeypatch.setattr(bench.os, "getloadavg", lambda: (float("nan"),) * 3)
    assert bench.main(["--json", "--only", "tep"]) == 0
    result = json.loads(capsys.readouterr().out, parse_constant=lambda name: pytest.fail(f"bare {name} in the JSON"))
    assert result["tep_c"] == 1.234568 and result["tep_d"] == 3
    assert not {"tep_a", "tep_b", "load_average_1min"} & set(result)


def test_the_skab_section_says_it_skipped_without_the_data_and_times_dpca_with_it(monkeypatch, capsys):
    """``--only skab``: one row naming MOSD_SKAB when the folder is not given; with SKAB's files (as CI sets
    MOSD_SKAB), ``--quick`` times DPCA's whole cross-validated study and writes ``skab_dpca_s``."""
    import json
    import os

    from mosd import bench

    real = os.environ.get("MOSD_SKAB", "")
    monkeypatch.delenv("MOSD_SKAB", raising=False)
    rows, figures = bench.bench_skab(quick=True)
    assert figures == {} and "MOSD_SKAB" in rows[0][0]
    if not real:
        return
    monkeypatch.setenv("MOSD_SKAB", real)
    assert bench.main(["--json", "--only", "skab", "--quick"]) == 0
    out = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert 0 < out["skab_dpca_s"] < 600 and "skab_families_s" not in out
