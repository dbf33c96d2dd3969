"""Issue 29: the λ floor of the family base (smoothing needs held-back runs as long as its memory) and the
ablation of ``python -m mosd.systems.tep --ablation`` (docs/systems/tep.md)."""
from __future__ import annotations

import json

import numpy as np
import pytest

from mosd.data.tep import DEFAULT_FAULTS
from mosd.detectors import latent
from mosd.detectors.pca import PCADetector
from mosd.systems import cli, tep
from mosd.validation import ConfigError


def test_lam_floor_fits_ten_memories_in_a_run():
    for run in (50, 160, 1000):
        floor = latent.lam_floor(run)
        assert (2 - floor) / floor == pytest.approx(run / latent.MEMORIES_PER_RUN)
    assert latent.lam_floor(160) == pytest.approx(2 / 17)


def _runs(rng, runs, rows, m=4):
    return rng.standard_normal((runs, rows, m)) @ rng.standard_normal((m, m))


def test_base_refuses_a_smoothing_its_held_back_runs_cannot_judge():
    rng = np.random.default_rng(0)
    calibration, z = _runs(rng, 3, 100), _runs(rng, 2, 50)   # run 0 fits, two 100-row runs are held back
    floor = 2 / 11
    detector = PCADetector(n_components=2, fit_runs=1, alpha=0.01, lam=0.1)
    assert detector.lam_bounds(calibration) == (pytest.approx(floor), 1.0)
    with pytest.raises(ConfigError, match=r"detector\.lam=0\.1\b.*allowed: lam >= 0\.1818"):
        detector.decide(calibration, z)
    with pytest.raises(ConfigError, match=r"detector\.lam"):   # the optimiser's path refuses it too
        detector.population(calibration, z, np.array([[2, 0.01, 0.1, 1]]))
    detector.with_params(lam=0.19).decide(calibration, z)
    # NaN-padded held-back runs count their own rows: 40 rows give a floor of 2 / 5
    padded = calibration.copy()
    padded[1:, 40:] = np.nan
    assert detector.lam_bounds(padded)[0] == pytest.approx(0.4)
    # nothing held back (in-sample limits): λ's declared range
    assert PCADetector(n_components=2, lam=0.1).lam_bounds(calibration) == (0.0, 1.0)


def test_every_family_is_tuned_within_the_floor_on_te():
    floor = latent.lam_floor(160)
    calibration = None
    for name in tep.FAMILIES:
        setup = cli.preset("tep", [f"detector={name}"])
        # no literal box in the preset: the detector's own range starts at the floor (its data_bounds)
        assert "lam" not in setup.bounds, name
        lam = setup.experiment.detector.tunable["lam"]
        assert lam.low == pytest.approx(floor) and lam.open_low and lam.high == 1.0, name
        if calibration is None:
            calibration = tep._z(setup.experiment, setup.experiment.data.trace("calibration"))
        assert setup.experiment.detector.lam_bounds(calibration) == (pytest.approx(floor), 1.0), name


@pytest.mark.slow
def test_ablation_command_credits_each_decision(tmp_path, capsys):
    assert tep.main(["--ablation", "--out", str(tmp_path)]) == 0
    assert "| + tuned components |" in capsys.readouterr().out
    results = json.loads((tmp_path / "tep_ablation.json").read_text())["results"]
    assert set(results) == set(tep.FAMILY_ABLATION)

    def mdr(row):
        return 1 - np.mean([results[row][f"fdr_idv{f}"] for f in DEFAULT_FAULTS])

    for row, result in results.items():
        assert {"far", "far_episodes", "far_ci_low", "far_ci_high", "fdr_idv21"} <= set(result)
        if row != "tuned, limits from d00.dat in-sample":
            assert result["train"]["far"] <= tep.PROTOCOL_FAR + 1e-12, row   # every row at the operating point
    # the smoothed design's limits need the held-back rows: in-sample on d00.dat no α reaches the operating point
    assert results["tuned, limits from d00.dat in-sample"]["train"]["far"] > tep.PROTOCOL_FAR
    assert results["literature"]["calibration"] == "d00.dat"
    assert results["tuned PCA"]["calibration"] == "d00.dat + held-back lead-ins"
    # the component count is the largest single gain over the literature's design
    gains = {row: mdr("literature") - mdr(row) for row in results if row.startswith("+")}
    assert max(gains, key=gains.get) == "+ tuned components"
