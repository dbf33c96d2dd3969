"""Online detection (issue 15, item 1): what claims to be causal is, and the main command is causal by default.

A detector is causal when its decision at point k uses points 1..k only. Checked directly: change
the data after k0 and every statistic and decision before k0 must stay bit-for-bit the same; a
detector that says it is not causal must actually move (so the flag is not just conservative).
"""
from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest
from hydra import compose, initialize_config_dir

from mosd.app import build as build_module, config as config_module
from mosd.detectors import EWMA, MDEWMA, MSOEWMA, SSDEWMA
from mosd.denoisers import NoDenoiser, WaveletDenoiser

K0 = 300


def _detectors():
    yield "ss_dewma-raw", SSDEWMA(lam=0.3, K=3.0, denoiser=NoDenoiser()), True
    yield "ss_dewma-causal-wavelet", SSDEWMA(lam=0.3, K=3.0, denoiser=WaveletDenoiser(window=128)), True
    yield "ss_dewma-causal-wavelet-48-sln", SSDEWMA(denoiser=WaveletDenoiser(window=48, scaling="sln")), True
    yield "ss_dewma-normalised-causal", SSDEWMA(limit="normalised", denoiser=WaveletDenoiser(window=64)), True
    yield "ss_dewma-theoretical-raw", SSDEWMA(limit="theoretical"), True
    yield "m_dewma-raw", MDEWMA(lam=0.3, K=2.0), True
    yield "ewma-phase1", EWMA(limit="phase1"), True
    yield "ms_oewma-causal-prefilter", MSOEWMA(prefilter=WaveletDenoiser(window=64, scaling="sln")), True
    yield "ss_dewma-whole-series-wavelet", SSDEWMA(denoiser=WaveletDenoiser()), False
    yield "ms_oewma-whole-series-prefilter", MSOEWMA(), False


@pytest.mark.parametrize("name,detector,causal", list(_detectors()), ids=[d[0] for d in _detectors()])
def test_causal_flag_is_true_exactly_when_the_past_ignores_the_future(name, detector, causal):
    rng = np.random.default_rng(31)
    calibration = rng.standard_normal((4, 600, 5))
    z = rng.standard_normal((4, 600, 5))
    changed = z.copy()
    changed[:, K0:] = 3.0 * changed[:, K0:] + 2.0  # a large fault from K0 on
    before, after = detector.decide(calibration, z), detector.decide(calibration, changed)
    assert detector.is_causal is causal
    same = np.array_equal(before.statistic[:, :K0], after.statistic[:, :K0])
    assert same is causal, f"{name}: prefix {'changed' if not same else 'unchanged'} by the future"
    if causal:
        np.testing.assert_array_equal(before.decision[:, :K0], after.decision[:, :K0])


@pytest.fixture(scope="module")
def composer():
    with initialize_config_dir(config_dir=str(config_module.CONFIG_DIR), version_base="1.3", job_name="test"):
        yield lambda *overrides: compose("config", overrides=list(overrides))


@pytest.mark.parametrize("overrides,causal", [
    (("+fault=offset_var",), True),                                     # the main command
    (("+fault=offset",), True),
    (("+fault=offset_var", "denoise=wavelet_causal"), True),
    (("+fault=offset_var", "denoise=wavelet"), False),                 # the old default, labelled NOT online
    (("+experiment=paper000",), False),                                # the literal paper reproduction
])
def test_main_command_is_causal_by_default_and_the_paper_preset_is_not(composer, overrides, causal):
    setup = build_module.build(composer(*overrides))
    assert setup.experiment.detector.is_causal is causal


def test_a_small_main_command_run_records_online(tmp_path):
    env = {**os.environ, "MOSD_OUTPUTS": str(tmp_path)}
    done = subprocess.run(
        [sys.executable, "-m", "mosd", "+fault=offset_var", "optimizer.pop_size=4", "optimizer.n_gen=1",
         "optimizer.n_jobs=1", "budget.n_calibration=2", "budget.n_train=2", "budget.n_test=2", "tracking=none",
         "progress=false"], capture_output=True, text=True, env=env, timeout=300)
    assert done.returncode == 0, done.stderr
    assert "NOT online" not in done.stdout
    summaries = list((tmp_path / "runs").glob("*/summary.json"))
    assert len(summaries) == 1
    assert json.loads(summaries[0].read_text())["online"] is True


# ------------------------------------------------------------------------------------------
# paper 000's tables: the literal (non-causal) design labelled, its causal counterpart beside it,
# and delays that count missed runs
# ------------------------------------------------------------------------------------------
def _paper_row(method, fault, causal, detected, delay):
    from mosd import paper
    from mosd.metrics import DetectionReport

    detected = np.asarray(detected, float)
    delay = np.asarray(delay, float)
    values = {"far": np.zeros(detected.size), "mdr": 1.0 - detected, "accuracy": detected,
              "delay": np.where(detected == 1.0, delay, np.nan), "detection_rate": detected,
              "delay_censored": np.where(detected == 1.0, delay, 500.0)}
    return paper.Row(method, fault, {"lam": 0.3, "K": 3.0}, DetectionReport(values), causal=causal)


def test_paper_tables_label_online_and_count_missed_runs():
    from mosd import paper

    literal = _paper_row("MO-SS-DEWMA", "offset", False, [1, 1, 1, 1], [0, 1, 1, 2])
    # the causal design misses 3 runs of 4: its mean delay over detected runs (0) looks better, the
    # detection rate and the censored median say otherwise
    online = _paper_row(paper.CAUSAL_OURS, "offset", True, [1, 0, 0, 0], [0, 0, 0, 0])
    table = paper.Table3({}, [literal], [], {}, {}, causal=[online],
                         causal_bars=[paper.compare_accuracy(online, literal)])
    main = paper.format_table3(table).splitlines()
    assert "| online |" in main[0] and "detected %" in main[0] and "missed = ∞" in main[0]
    assert "| MO-SS-DEWMA | **no** |" in main[2] and main[2].rstrip().endswith("| 100 | 1.00 ± 1.30 | 1 |")
    causal = paper.format_causal(table).splitlines()
    assert causal[2].startswith("| offset | MO-SS-DEWMA | **no** |")
    assert causal[3].startswith(f"| offset | {paper.CAUSAL_OURS} | yes |")
    assert "| 25 | 0.00 | beyond horizon |" in causal[3]
    from mosd.denoisers import WaveletDenoiser
    from mosd.detectors import SSDEWMA

    literal = SSDEWMA(denoiser=WaveletDenoiser(scaling="one", scope="global", global_source="coarsest"))
    assert paper.make_chart(paper.CAUSAL_OURS, {"lam": 0.3, "K": 3.0}, literal).is_causal
    assert not paper.make_chart("MO-SS-DEWMA", {"lam": 0.3, "K": 3.0}, literal).is_causal  # the literal wavelet


@pytest.mark.slow
def test_paper_table3_command_writes_the_causal_result_beside_the_literal(tmp_path):
    done = subprocess.run([sys.executable, "-m", "mosd.paper", "table3", "--budget", "tiny", "--n-jobs", "1",
                           "--out", str(tmp_path)], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    result = json.loads((tmp_path / "table3.json").read_text())
    assert all(r["online"] is False for r in result["rows"] if r["method"] == "MO-SS-DEWMA")
    assert [r["fault"] for r in result["causal"]] == ["offset", "variance", "offset_var"]
    for r in result["causal"]:
        assert r["online"] is True and 0.0 <= r["detection_rate"]["mean"] <= 1.0
        assert 0.0 < r["params"]["lam"] < 1.0 and 0.0 <= r["params"]["K"] <= 5.0
    assert (tmp_path / "table3_causal.md").read_text().count("| yes |") == 3
