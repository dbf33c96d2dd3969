"""python -m mosd +experiment=tep end to end (small budget) and the report python -m mosd.systems.tep."""
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from mosd.systems.tep import YIN2012_FDR_COMBINED

ROOT = Path(__file__).resolve().parents[1]


def _env(tmp_path):
    return {**os.environ, "PYTHONPATH": str(ROOT), "MOSD_OUTPUTS": str(tmp_path / "out")}


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    tmp_path = tmp_path_factory.mktemp("tep")
    out = subprocess.run([sys.executable, "-m", "mosd", "+experiment=tep", "optimizer.pop_size=8",
                          "optimizer.n_gen=2", "optimizer.n_jobs=1", "tracking=none", "progress=false"],
                         capture_output=True, text=True, env=_env(tmp_path), timeout=900)
    assert out.returncode == 0, out.stderr
    run_dir = next((tmp_path / "out" / "runs").iterdir())
    return out, run_dir, json.loads((run_dir / "summary.json").read_text())


def test_summary_has_the_study_keys_and_the_splits(run):
    out, run_dir, summary = run
    assert out.stdout.splitlines()[0].startswith("mosd  experiment=tep  data=tep  detector=pca")
    study = summary["study"]
    for n in range(1, 22):
        for stat in ("t2", "spe", "combined"):
            assert 0.0 <= study[f"lit_fdr_{stat}_idv{n}"] <= 1.0
        assert 0.0 <= study[f"tuned_fdr_combined_idv{n}"] <= 1.0
    assert 0.0 <= study["tuned_far_combined"] <= 1.0
    # the literature design's numbers are the published ones (tests/test_tep_pca.py explains the tolerance)
    for n, published in YIN2012_FDR_COMBINED.items():
        assert abs(100 * study[f"lit_fdr_combined_idv{n}"] - published) <= 0.13
    assert abs(100 * study["lit_far_combined"] - 6.13) <= 0.13
    splits = summary["data"]
    assert splits["calibration"][0] == "d00.dat rows 0-499 (fault-free)"
    assert splits["test"][0] == "d01_te.dat rows 160-959 (fault 1 from row 160)"
    assert len(splits["training"]) == 3 * 18 + 11
    # the pipeline's own test metrics are on the same test split: the FAR is the d00_te run's
    assert summary["test"]["far"]["n"] == 1
    for name in ("tep_detection_rates.png", "tep_statistics.png", "tep_contributions.png", "tep_table.csv"):
        assert (run_dir / name).stat().st_size > 0
    # the study's figures went to the figure process as jobs of their own (Study.figure_jobs), not drawn here
    assert "figures drawn in-process" not in (run_dir / "mosd.log").read_text()


def test_report_command_prints_the_classic_table(tmp_path):
    out = subprocess.run([sys.executable, "-m", "mosd.systems.tep", "--out", str(tmp_path)], capture_output=True,
                         text=True, env=_env(tmp_path), timeout=600)
    assert out.returncode == 0, out.stderr
    line = next(row for row in out.stdout.splitlines() if row.startswith("| IDV(1) |"))
    assert "| 99.25 | 99.88 | 99.88 |" in line and line.endswith("| 99.88 |")  # lit T², SPE, combined; Yin 2012
    assert "| FAR d00_te |" in out.stdout
    study = json.loads((tmp_path / "tep_study.json").read_text())
    assert set(study["designs"]) == {"tuned", "lit"}


def test_report_command_bad_input_exits_2(tmp_path):
    out = subprocess.run([sys.executable, "-m", "mosd.systems.tep", "--directory", str(tmp_path / "none"),
                          "--out", str(tmp_path)], capture_output=True, text=True, env=_env(tmp_path), timeout=600)
    assert out.returncode == 2
    assert len(out.stderr.strip().splitlines()) == 1 and "is not a directory" in out.stderr


def _refuse(constant):
    raise ValueError(f"non-standard JSON constant {constant}")


def test_every_json_file_of_the_run_directory_is_strict(run):
    """NaN by construction (a one-run FAR CI, recorded data's accuracy) is null or left out, never a bare NaN."""
    _, run_dir, summary = run
    files = sorted(run_dir.rglob("*.json"))
    assert run_dir / "summary.json" in files
    for path in files:
        json.loads(path.read_text(), parse_constant=_refuse)
    test = summary["test"]
    assert test["far"]["ci95_half_width"] is None and test["far"]["n"] == 1  # one fault-free test run: no CI
    # no run is both fault-free and faulty: the accuracy of the mean rates, as the console prints it
    assert test["accuracy"]["mean"] == pytest.approx(1 - test["far"]["mean"] - test["mdr"]["mean"], abs=1e-12)
    assert test["delay"]["unit"] == "points" and test["delay_censored"]["unit"] == "points"


def test_study_credits_the_gain_to_its_causes_and_reports_per_fault_delays(run):
    """Issue 30: the ablation, the equal-FAR row with the tuned design's information, delays per fault."""
    study = run[2]["study"]
    from mosd.systems.tep import ABLATION
    for row in ABLATION:
        for key in ("far", "mdr", "equal_far_far", "equal_far_mdr"):
            assert 0.0 <= study[f"ablation_{row}_{key}"] <= 1.0
    # the ablation's end points are the study's two designs
    assert study["ablation_lit_far"] == study["lit_far_combined"]
    assert study["ablation_tuned_far"] == study["tuned_far_combined"]
    assert study["ablation_lit_mdr"] == pytest.approx(study["lit_mdr_combined_mean"], abs=1e-12)
    # the equal-FAR baseline gets the held-back rows the tuned design's limits come from
    assert study["lit_equal_far_mdr_combined_mean"] == pytest.approx(study["ablation_lit_heldback_limits_equal_far_mdr"],
                                                                     abs=1e-12)
    # (an empirical limit is at most the held-back maximum: below some FAR no α gets there)
    assert (study["lit_equal_far_far_combined"] <= study["tuned_far_combined"]
            or study["lit_equal_far_alpha"] == pytest.approx(1e-12))
    assert "lit_d00_equal_far_mdr_combined_mean" in study
    # per fault: a run of 3 alarms cannot end before the first alarm; an undetected fault has no delay
    for design in ("lit", "tuned", "lit_equal_far"):
        for n in range(1, 22):
            first, run3 = (study.get(f"{design}_delay_{k}_min_idv{n}") for k in ("first_alarm", "run3"))
            if run3 is not None:
                assert first is not None and 0 <= first <= run3 - 6  # 3 rows of 3 minutes: 6 minutes at least
