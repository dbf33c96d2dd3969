"""Issue 29 (i29f): the stuck-valve statistic's smoothing λ_f (``detector.flatline``) is part of the tuned box.

Before, λ_f was a fixed option read off the TE test split; now a design with the statistic on has λ_f as one more
column of the optimiser's box (above the same floor as λ), chosen on the training split by the selection rule like
every other parameter. ``flatline: null`` is off and outside the box, as before.
"""
from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from mosd.detectors.cva import CVADetector
from mosd.detectors.latent import lam_floor
from mosd.detectors.sfa import SFADetector
from tests.test_families import plant_rows


def test_flatline_is_a_column_of_the_box_only_when_switched_on():
    off, on = SFADetector(n_slow=2, fit_runs=1), SFADetector(n_slow=2, fit_runs=1, flatline=0.5)
    assert list(off.tunable) == ["n_slow", "alpha", "lam", "persistence"] == list(SFADetector.tunable)
    assert list(on.tunable) == ["n_slow", "alpha", "lam", "persistence", "flatline"]
    assert on.design().tolist() == [[2.0, 0.01, 1.0, 1.0, 0.5]]
    # the box the data allow: λ_f above λ's floor (a 200-row held-back run: 2/21), and not at all when off
    X = plant_rows()
    calibration = np.stack([X[:200], X[200:400]])
    assert on.data_bounds(calibration)["flatline"] == (pytest.approx(lam_floor(200)), 1.0)
    assert "flatline" not in off.data_bounds(calibration)
    # its range ends at lam_min, as λ's does (narrow_to_data raises that one parameter to the floor)
    assert on.with_params(lam_min=0.2).tunable["flatline"].low == 0.2


def test_the_population_reads_lambda_f_from_its_column():
    """A valve stuck from row 600: two designs that differ only in their λ_f column decide differently, each as the
    design with that λ_f does on its own (the optimiser's and the design's scores are one computation)."""
    X = plant_rows(shift_at=10_000)
    X[:, 3] = 0.3 * np.random.default_rng(7).standard_normal(len(X))
    X[600:, 3] = 0.0
    calibration, z = np.stack([X[:200], X[200:400]]), X[None, 400:]
    detector = CVADetector(past=2, future=2, n_states=3, alpha=0.02, lam=0.6, persistence=1, fit_runs=1,
                           flatline=0.3)
    rows = np.vstack([detector.design(), detector.design()])
    rows[1, -1] = 0.95
    population = detector.population(calibration, z, rows).decision
    assert np.array_equal(population[0], detector.decide(calibration, z).decision)
    assert np.array_equal(population[1], detector.with_params(flatline=0.95).decide(calibration, z).decision)
    assert not np.array_equal(population[0], population[1])


def _stuck_valve_table(path, n_rows=900, seed=3):
    """4 correlated tags; tag 3 a valve's noise that sticks at its set point in the faulty stretches."""
    rng = np.random.default_rng(seed)
    tags = rng.standard_normal((n_rows, 2)) @ rng.standard_normal((2, 4)) + 0.3 * rng.standard_normal((n_rows, 4))
    tags[:, 3] = 0.5 * rng.standard_normal(n_rows)
    fault = np.zeros(n_rows, int)
    for start in (500, 620, 760):
        fault[start:start + 60] = 1
        tags[start:start + 60, 3] = 0.0
    frame = pd.DataFrame(tags, columns=[f"tag{i}" for i in range(4)])
    frame.insert(0, "fault", fault)
    frame.to_csv(path, index=False)
    return path


def test_a_tuned_run_chooses_lambda_f_in_the_box(tmp_path, monkeypatch, capsys):
    """Fails on the old code: there ``flatline`` was not tunable, so a run kept the given 0.5 and its summary had
    no ``flatline`` among the chosen parameters."""
    from mosd.app import main

    path = _stuck_valve_table(tmp_path / "valve.csv")
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("MOSD_OUTPUTS", str(tmp_path / "outputs"))
    code = main(["+experiment=table", f"data.path={path}", "data.label_column=fault", "detector=sfa",
                 "detector.flatline=0.5", "detector.fit_runs=1", "tracking=none", "optimizer.pop_size=6",
                 "optimizer.n_gen=2", "progress=false", "seed=1"])
    assert code == 0, capsys.readouterr().err
    summary = json.loads(next((tmp_path / "outputs" / "runs").glob("*/summary.json")).read_text())
    chosen = summary["params"]["flatline"]
    assert 0.0 < chosen <= 1.0 and chosen != 0.5


@pytest.mark.slow
def test_te_families_tune_lambda_f_and_keep_the_fixed_value_as_a_labelled_ablation(tmp_path, capsys):
    """``--families`` tunes λ_f in (λ's floor, 1] on the training split in the labelled row ``sfa_flatline`` (issue 49:
    the headline ``sfa`` never has the statistic); ``--flatline`` only adds ablation rows of the labelled row."""
    from mosd.systems import tep

    code = tep.main(["--families", "--family", "sfa", "--pop-size", "6", "--n-gen", "1", "--flatline", "off",
                     "--out", str(tmp_path)])
    assert code == 0, capsys.readouterr().err
    written = json.loads((tmp_path / "tep_families.json").read_text())
    results = written["results"]
    chosen = results["sfa_flatline"]["params"]["flatline"]
    assert lam_floor(160) <= chosen <= 1.0 and chosen != tep.FLATLINE_START
    assert "flatline" not in results["sfa"]["params"] and results["sfa_flatline"]["label"] == tep.FLATLINE_WHY
    assert written["headline_flatline"] == "off" and written["flatline_rows"] == ["sfa_flatline"]
    assert written["flatline_ablation"] == [None]
    off = results["sfa_flatline_off"]
    assert "ablation" in off and "flatline" not in off["params"] and "ablation" not in results["sfa_flatline"]
    # IDV(21), the stuck valve: seen on most rows within 90 minutes with the statistic, on fewer than three rows in
    # four without it, by the headline design and by the literature designs (none of them flat)
    assert results["sfa_flatline"]["fdr_idv21"] > 0.9 and results["sfa_flatline"]["delay_run_idv21"] < 90
    assert max(off["fdr_idv21"], results["sfa"]["fdr_idv21"], results["sfa_lit"]["fdr_idv21"],
               results["pca_lit"]["fdr_idv21"]) < 0.75
    code = tep.main(["--families", "--family", "sfa", "--flatline", "0", "--out", str(tmp_path)])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "\n" not in err and "--flatline='0'" in err and "off or a number in (0, 1]" in err


def test_a_te_run_s_study_names_its_protocol_keys_by_family():
    """A sweep over ``detector=`` compares the families side by side: each run's study carries its design's
    protocol keys also as ``family_fdr_<family>_idvN`` and ``family_far_<family>`` (fails on the old code)."""
    from mosd.data.tep import ALL_FAULTS
    from mosd.systems import tep

    rng = np.random.default_rng(0)
    labels = np.array([*ALL_FAULTS, 0])
    decision = rng.random((len(labels), 800)) < np.where(labels > 0, 0.9, 0.01)[:, None]
    protocol = tep.protocol(decision, labels)
    data = {"fdr": {}, "far": {}, "faults": list(ALL_FAULTS), "train_faults": [], "protocol": {"tuned": protocol},
            "family": "sfa"}
    metrics = tep.Study(figures=False).metrics(data)
    assert metrics["family_far_sfa"] == metrics["far"] == protocol["far"]
    assert metrics["family_far_episodes_sfa"] == protocol["far_episodes"]
    assert all(metrics[f"family_fdr_sfa_idv{n}"] == protocol[f"fdr_idv{n}"] for n in ALL_FAULTS)


def test_sfa_drops_the_features_slower_than_the_held_back_runs_can_judge(tmp_path):
    """``drop_unjudged``: features with ω/2 below λ's floor of the held-back runs leave every statistic; the rest are
    scored as before, the theoretical limits count only what is kept, and the stream scores the population's bits."""
    from tests.test_families import stream_equals_population

    X = plant_rows(shift_at=10_000)
    X[:, 0] += 3 * np.sin(2 * np.pi * np.arange(len(X)) / 300)      # a slow wave on tag a: its feature has ω ≈ 0.08
    calibration = np.stack([X[:200], X[200:400]])
    keep = SFADetector(n_slow=3, fit_runs=1, limits="empirical")
    drop = keep.with_params(drop_unjudged=True)
    fitted = drop.fitted(calibration)
    omega = np.asarray(fitted["omega"])
    d = int(np.count_nonzero(omega / 2 < lam_floor(200)))
    assert fitted["dropped"] == d >= 1 and "dropped" not in keep.fitted(calibration)
    s2, _, _ = drop._features(fitted, X[None, 400:], None)
    kept, _ = drop.score(fitted, X[None, 400:], drop.design_values())
    assert np.allclose(kept["t2"], s2[..., d:3].sum(-1)) and np.allclose(kept["t2e"], s2[..., 3:].sum(-1))
    # χ² with M − d degrees of freedom instead of M
    assert drop.limit(fitted, "t2", 0.01, drop.design_values()) == pytest.approx(stats.chi2.ppf(0.99, 3 - d))
    assert keep.limit(keep.fitted(calibration), "t2", 0.01, keep.design_values()) == pytest.approx(
        stats.chi2.ppf(0.99, 3))
    stream_equals_population(drop.with_params(alpha=0.02, persistence=2), X, tmp_path)
    # nothing held back: nothing dropped (no runs to judge by)
    assert SFADetector(n_slow=3).with_params(drop_unjudged=True).fitted(calibration).get("dropped", 0) == 0
