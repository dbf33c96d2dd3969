"""Issue 29: every family declares the search box its calibration data allow (``data_bounds``), and preflight
narrows the optimiser's box to it for every system (mosd.app.preflight.narrow_to_data)."""
from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from mosd.detectors.autoencoder import AutoencoderDetector
from mosd.detectors.cva import CVADetector
from mosd.detectors.dpca import DPCADetector
from mosd.detectors.ica import ICADetector
from mosd.detectors.kpca import KernelPCADetector
from mosd.detectors.latent import lam_floor
from mosd.detectors.pca import PCADetector
from mosd.detectors.sfa import SFADetector
from mosd.detectors.tag_ewma import TagEwmaDetector


def _calibration(runs=3, rows=100, m=4, seed=0):
    rng = np.random.default_rng(seed)
    return rng.standard_normal((runs, rows, m)) @ rng.standard_normal((m, m))


def test_each_family_declares_its_own_rule():
    z = _calibration()                                      # 3 runs of 100 rows, 4 tags; run 0 fits
    floor = lam_floor(100)
    boxes = {type(d).__name__: d.data_bounds(z) for d in (
        PCADetector(fit_runs=1), DPCADetector(fit_runs=1, max_lags=5), CVADetector(fit_runs=1, max_lags=5),
        ICADetector(fit_runs=1), KernelPCADetector(fit_runs=1), SFADetector(fit_runs=1),
        AutoencoderDetector(fit_runs=1), TagEwmaDetector(fit_runs=1))}
    assert all(box["lam"] == (pytest.approx(floor), 1.0) for box in boxes.values())
    assert boxes["PCADetector"]["n_components"] == (1, 3)
    assert boxes["DPCADetector"]["lags"] == (0, 5) and boxes["DPCADetector"]["n_components"] == (1, 23)
    assert boxes["CVADetector"]["past"] == (1, 5) and boxes["CVADetector"]["n_states"] == (1, 19)
    assert boxes["ICADetector"]["n_components"] == (1, 3)
    assert boxes["KernelPCADetector"]["n_components"] == (1, 99)    # N − 1 of the 100 fit rows
    assert boxes["SFADetector"]["n_slow"] == (1, 3) and boxes["AutoencoderDetector"]["n_components"] == (1, 3)
    assert set(boxes["TagEwmaDetector"]) == {"lam"}
    # a short fit run limits the horizons: CVA needs 2 h m complete (past, future) rows, DPCA (l + 1) m + 1
    short = z[:, :20]
    assert CVADetector(fit_runs=1).data_bounds(short)["past"] == (1, 2)       # h = 2: 17 rows >= 16; h = 3: 15 < 24
    assert DPCADetector(fit_runs=1).data_bounds(short)["lags"] == (0, 3)      # l = 3: 17 rows > 16; l = 4: 16 <= 20
    # nothing held back (in-sample limits): λ keeps its declared range
    assert PCADetector().data_bounds(z)["lam"] == (0.0, 1.0)


def _table(path, n_tags=4, n_rows=600, seed=0):
    rng = np.random.default_rng(seed)
    tags = rng.standard_normal((n_rows, 2)) @ rng.standard_normal((2, n_tags)) + 0.3 * rng.standard_normal(
        (n_rows, n_tags))
    fault = np.zeros(n_rows, int)
    for start in (350, 480):
        fault[start:start + 40] = 1
        tags[start:start + 40, 1] += 3.0
    frame = pd.DataFrame(tags, columns=[f"tag{i}" for i in range(n_tags)])
    frame.insert(0, "fault", fault)
    frame.to_csv(path, index=False)
    return path


@pytest.mark.parametrize("family, key, top", [("ica", "n_components", 3), ("cva", "n_states", 19)])
def test_a_few_tags_table_runs_a_family_whose_default_box_exceeds_it(tmp_path, monkeypatch, capsys, family, key,
                                                                       top):
    """Fails before issue 29's data box: ICA's default range (up to 20 components) was refused on 4 tags, and
    CVA's was searched far beyond what the data can take (SFA's likewise: the explicit-bound test below)."""
    from mosd.app import main
    from mosd.app.preflight import preflight

    path = _table(tmp_path / "plant.csv")
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("MOSD_OUTPUTS", str(tmp_path / "outputs"))
    argv = ["+experiment=table", f"data.path={path}", "data.label_column=fault", f"detector={family}",
            "tracking=none", "optimizer.pop_size=4", "optimizer.n_gen=2", "progress=false",
            *(["detector.max_iter=200"] if family == "ica" else [])]
    (setup,) = [s for same in preflight(argv)._setups.values() for s in same]
    assert setup.experiment.detector.tunable[key].high == top
    assert main(argv) == 0, capsys.readouterr().err
    summary = json.loads(next((tmp_path / "outputs" / "runs").glob("*/summary.json")).read_text())
    assert summary["status"] == "finished" and 1 <= summary["params"][key] <= top


def test_an_explicit_bound_the_data_cannot_take_is_one_line(tmp_path, monkeypatch, capsys):
    from mosd.app import main

    path = _table(tmp_path / "plant.csv")
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("MOSD_OUTPUTS", str(tmp_path / "outputs"))
    # SFA lowers too many slow features itself: only the data box can refuse the user's
    code = main(["+experiment=table", f"data.path={path}", "data.label_column=fault", "detector=sfa",
                 "+detector.bounds.n_slow=[1,8]", "tracking=none", "progress=false"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "\n" not in err and "Traceback" not in err, err
    assert "detector.bounds.n_slow=[1, 8] reaches n_slow=8," in err and "allowed: integers in [1, 3]" in err
    assert not (tmp_path / "outputs" / "runs").exists()


def test_an_explicit_lam_below_the_floor_is_one_line_on_te(capsys):
    from mosd.app import main

    code = main(["+experiment=tep", "detector=tag_ewma", "+detector.bounds.lam=[0.05,1]", "tracking=none",
                 "progress=false"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "\n" not in err, err
    assert "detector.bounds.lam=[0.05, 1] reaches lam=0.05," in err and f"[{lam_floor(160):g}, 1]" in err


def test_a_job_built_without_preflight_gets_the_same_box_on_a_simulated_system():
    """A launcher's worker builds its job itself (fit_to_data): the mould oscillator's 3 residual channels take
    at most 2 components, as preflight's dry run finds (before issue 29 the worker kept [1, 1000])."""
    from hydra import compose, initialize_config_dir

    from mosd.app.build import build
    from mosd.app.config import CONFIG_DIR, CONFIG_NAME
    from mosd.app.preflight import fit_to_data

    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3", job_name="mosd"):
        cfg = compose(CONFIG_NAME, overrides=["+fault=offset_var", "detector=pca", "monitor=signals",
                                              "tracking=none"])
    setup = build(cfg)
    assert setup.experiment.detector.tunable["n_components"].high == 1000
    fit_to_data(setup)
    detector = setup.experiment.detector
    assert detector.tunable["n_components"].high == 2 and detector.n_components == 2 and setup.bounds == {}
