"""The redesign changed no number: paper 000's chosen designs and metrics, pinned from the code before it.

The values were produced by the pre-redesign pipeline (commit 64b9c36) with the same seeds and
settings: the main command at a small budget and ``python -m mosd.paper table3 --budget tiny``.
Both paths now run through :class:`mosd.experiment.Experiment`'s verbs.
"""
import numpy as np
import pytest
from hydra import compose, initialize_config_dir

from mosd import paper
from mosd.app.build import build
from mosd.app.config import CONFIG_DIR
from mosd.optim.mopso import MOPSO


def test_main_command_setup_gives_the_pinned_design_and_metrics():
    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3"):
        cfg = compose("config", overrides=["+fault=offset_var", "denoise=wavelet", "budget.n_test=10",
                                              "detector.bounds.K=[0.0,5.0]", "tracking=none"])
    setup = build(cfg)
    algorithm = MOPSO.paper(pop_size=20)  # the pre-redesign default was the paper's Table 2
    result = setup.experiment.run(algorithm, ("n_gen", 10), n_jobs=1, bounds=setup.bounds, choose=setup.choose)
    assert result.params["lam"] == pytest.approx(0.5145937447268027, abs=1e-12)
    assert result.params["K"] == pytest.approx(5.0, abs=1e-12)
    assert result.train_objectives["far"] == pytest.approx(0.0022, abs=1e-12)
    assert result.train_objectives["mdr"] == pytest.approx(0.0006, abs=1e-12)
    summary = result.summary()
    assert summary["far"].mean == pytest.approx(0.001, abs=1e-12)
    assert summary["far"].half_width == pytest.approx(0.001815998628528468, rel=1e-9)
    assert summary["mdr"].mean == pytest.approx(0.0014, abs=1e-12)
    assert summary["mdr"].half_width == pytest.approx(0.0009656582238663674, rel=1e-9)


def test_paper_table3_tiny_gives_the_pinned_mo_ss_dewma_design():
    study = paper.build_study(paper.PaperSettings(budget="tiny", n_jobs=1))
    table = paper.run_table3(study, faults=("offset",), include_tuned=False)
    ours = table.row("MO-SS-DEWMA", "offset")
    assert ours.params["lam"] == pytest.approx(0.20072117954380408, abs=1e-12)
    assert ours.params["K"] == pytest.approx(4.675362118938841, abs=1e-12)
    assert ours.train_objectives == pytest.approx((0.0, 0.003), abs=1e-12)
    summary = ours.summary()
    assert summary["mdr"].mean == pytest.approx(0.0033333333333333335, abs=1e-12)
    assert summary["far"].mean == 0.0
    assert summary["delay"].mean == pytest.approx(1.6666666666666667, abs=1e-12)
    # the paper-parameter baselines, scored on the same test runs
    ss = table.row("SS-DEWMA", "offset").summary()
    assert ss["far"].mean == pytest.approx(0.0167, abs=5e-5) and ss["mdr"].mean == 0.0
    assert np.isfinite(table.row("M-DEWMA", "offset").summary()["far"].mean)
