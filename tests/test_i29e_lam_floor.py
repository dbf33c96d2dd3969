"""Issue 29 (i29e): ``lam_min`` is listed where it is declared, and a simulated system's dry run knows λ's floor.

Before: no detector YAML listed ``lam_min``, and a simulated dry run calibrated on one replication, so nothing
was held back and λ kept its declared range (0, 1]; the run, with ``budget.n_calibration`` > ``fit_runs``, then
refused a λ below the floor midway, after its outputs directory existed.
"""
from __future__ import annotations

import importlib
from pathlib import Path

import pytest
import yaml

from mosd.app.config import CONFIG_DIR, CONFIG_NAME
from mosd.detectors.latent import lam_floor

#: the mould oscillator at 3 s: 3000 residual rows per replication (onset 2.7 s), a few seconds per dry run
SIMULATED = ["+fault=offset_var", "detector=pca", "monitor=signals", "tracking=none", "progress=false",
             "scenario.duration=3.0", "detector.fit_runs=1", "budget.n_calibration=3", "budget.n_train=2",
             "budget.n_test=2", "optimizer.pop_size=4", "optimizer.n_gen=1"]


def _declared(path: Path) -> bool:
    target = yaml.safe_load(path.read_text())["_target_"]
    module, name = target.rsplit(".", 1)
    return "lam_min" in getattr(importlib.import_module(module), name).params


def test_every_detector_yaml_that_declares_lam_min_lists_it_with_its_meaning():
    declaring = [p for p in sorted((Path(CONFIG_DIR) / "detector").glob("*.yaml")) if _declared(p)]
    assert len(declaring) >= 9          # the nine families of issue 29
    for path in declaring:
        line = next((ln for ln in path.read_text().splitlines() if ln.startswith("lam_min:")), None)
        assert line is not None, f"{path.name} does not list lam_min"
        value, _, comment = line.partition("#")
        assert float(value.split(":", 1)[1]) == 0.0 and "lam" in comment and "held-back" in comment, line
        # the base's other common option (detector.flatline) is listed beside it, off by default
        flat = next((ln for ln in path.read_text().splitlines() if ln.startswith("flatline:")), "")
        assert yaml.safe_load(flat) == {"flatline": None} and "#" in flat, f"{path.name}: {flat!r}"


def _setup(overrides):
    from hydra import compose, initialize_config_dir

    from mosd.app.build import build

    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3", job_name="mosd"):
        return build(compose(CONFIG_NAME, overrides=overrides))


def test_the_simulated_dry_run_applies_the_floor_of_the_held_back_runs():
    from mosd.app.preflight import dry_run, fit_to_data

    floor = lam_floor(3000)
    setup = _setup(SIMULATED)
    box = dry_run(setup)
    assert box["lam"] == (pytest.approx(floor), 1.0)
    assert setup.experiment.detector.lam_min == pytest.approx(floor)
    assert setup.experiment.detector.tunable["lam"].low == pytest.approx(floor)
    # a launcher's worker (built without preflight) gets the same floor
    worker = _setup(SIMULATED)
    fit_to_data(worker)
    assert worker.experiment.detector.lam_min == pytest.approx(floor)
    # nothing held back (one calibration replication per fit run): the limits are in-sample, no floor
    assert dry_run(_setup([*SIMULATED, "budget.n_calibration=1"]))["lam"] == (0.0, 1.0)


@pytest.mark.parametrize("override, expected", [
    ("detector.lam=0.003", "detector.lam=0.003 is outside what the calibration data allow; allowed: (0.00664"),
    ("+detector.bounds.lam=[0.001,1]", "detector.bounds.lam=[0.001, 1] reaches lam=0.001,"),
])
def test_a_lam_below_the_floor_is_one_line_before_any_output(tmp_path, monkeypatch, capsys, override, expected):
    from mosd.app import main

    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("MOSD_OUTPUTS", str(tmp_path / "outputs"))
    code = main([*SIMULATED, override])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "\n" not in err and "Traceback" not in err, err
    assert expected in err, err
    assert not (tmp_path / "outputs").exists()
