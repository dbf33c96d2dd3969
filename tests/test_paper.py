"""Paper 000's comparison: grid tuning (mosd.optim.grid) and the Table 3/4, Fig. 1 commands (mosd.paper)."""
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from mosd import paper
from mosd.detectors import EWMA, MSOEWMA, SSDEWMA
from mosd.denoisers import NoDenoiser
from mosd.experiment import Experiment
from mosd.metrics import DetectionReport, false_alarm_rate, missed_detection_rate
from mosd.optim.grid import constrained_grid_search, grid_objectives
from mosd.optim.problem import CandidateEvaluator
from mosd.optim.selection import SelectionWarning
from mosd.validation import ConfigError

REPO = Path(__file__).resolve().parents[1]


# ------------------------------------------------------------------------------------
# grid search on synthetic subgroups
# ------------------------------------------------------------------------------------
def _synthetic(seed=0, shift=0.6, scale=1.5):
    rng = np.random.default_rng(seed)
    phase1 = rng.standard_normal((4, 240, 5))
    train = rng.standard_normal((3, 240, 5))
    train[:, 120:] = scale * train[:, 120:] + shift
    mask = np.zeros((3, 240), bool)
    mask[:, 120:] = True
    return phase1, train, mask


def _evaluator(chart, data):
    phase1, train, mask = data
    return CandidateEvaluator(chart, chart.features(phase1), chart.features(train), mask)


def _fit_and_score(chart, data):
    """(FAR, MDR) by the plain fit → alarms route, independent of CandidateEvaluator."""
    phase1, train, mask = data
    alarms = chart.fit(phase1).alarms(train)
    return false_alarm_rate(alarms, mask).mean(), missed_detection_rate(alarms, mask).mean()


@pytest.fixture(scope="module")
def synthetic():
    return _synthetic()


def test_grid_objectives_match_fitting_each_point(synthetic):
    chart = SSDEWMA(limit="phase1")
    lam, K = np.array([0.1, 0.35, 0.8]), np.array([0.5, 2.0, 4.0, 7.5])
    far, mdr = grid_objectives(_evaluator(chart, synthetic), lam, K, chunk=5)  # chunks cut across rows
    assert far.shape == mdr.shape == (3, 4)
    for i, l in enumerate(lam):
        for j, k in enumerate(K):
            expected = _fit_and_score(SSDEWMA(lam=l, K=k), synthetic)
            assert (far[i, j], mdr[i, j]) == pytest.approx(expected, abs=1e-15)


def test_grid_rates_are_monotone_in_the_width(synthetic):
    # a wider limit can only remove alarms: FAR never rises, MDR never falls
    far, mdr = grid_objectives(_evaluator(EWMA(limit="phase1"), synthetic), [0.1, 0.5, 1.0],
                               np.linspace(0.2, 6.0, 30))
    assert np.all(np.diff(far, axis=1) <= 1e-15) and np.all(np.diff(mdr, axis=1) >= -1e-15)
    assert far[:, 0].max() > far[:, -1].max() and mdr[:, -1].min() > mdr[:, 0].min()


def test_constrained_grid_search_is_the_brute_force_choice(synthetic):
    lam_grid, width_grid = np.linspace(0.05, 1.0, 20), np.linspace(0.1, 6.0, 60)
    alpha = 0.02
    chart = EWMA(limit="phase1")
    params, (far, mdr) = constrained_grid_search(_evaluator(chart, synthetic), lam_grid, width_grid, alpha)
    # brute force with independent scoring: per λ the smallest feasible L, then the lowest MDR
    candidates = []
    for lam in lam_grid:
        for L in width_grid:
            f, m = _fit_and_score(EWMA(lam=lam, L=L, limit="phase1"), synthetic)
            if f <= alpha:
                candidates.append((m, f, lam, L))
                break
    best = min(candidates)
    assert far <= alpha
    assert (params["lam"], params["L"]) == pytest.approx(best[2:])
    assert (far, mdr) == pytest.approx((best[1], best[0]), abs=1e-15)
    # the constraint binds: without it the optimiser would pick a smaller width somewhere
    loose, _ = constrained_grid_search(_evaluator(chart, synthetic), lam_grid, width_grid, 1.0)
    assert loose["L"] == width_grid[0]


def test_constrained_grid_search_warns_and_falls_back_when_infeasible(synthetic):
    chart = SSDEWMA(limit="phase1")
    lam, K = [0.2, 0.6], [0.1, 0.2]  # far too narrow: every point raises false alarms
    far_grid, _ = grid_objectives(_evaluator(chart, synthetic), lam, K)
    assert far_grid.min() > 0
    with pytest.warns(SelectionWarning, match="no grid point"):
        params, (far, _) = constrained_grid_search(_evaluator(chart, synthetic), lam, K, alpha=0.0)
    assert far == far_grid.min()
    assert params["K"] == 0.2  # the wider limit has the lower FAR


def test_grid_validation(synthetic):
    ev = _evaluator(SSDEWMA(limit="phase1"), synthetic)
    with pytest.raises(ConfigError, match="chart.lam"):
        grid_objectives(ev, [0.5, 1.0], [1.0])  # SS-DEWMA's λ is in the open (0, 1)
    with pytest.raises(ConfigError, match="strictly increasing"):
        grid_objectives(ev, [0.5, 0.2], [1.0])
    with pytest.raises(ConfigError, match="empty"):
        constrained_grid_search(ev, [], [1.0])
    with pytest.raises(ConfigError, match="alpha"):
        constrained_grid_search(ev, [0.5], [1.0], alpha=1.5)


def test_ms_oewma_grid_tuning_detects_a_mean_shift_better_than_a_blind_choice():
    # MS-OEWMA tuned on training data, then scored on fresh data from the same model
    data = _synthetic(seed=1, shift=0.5, scale=1.0)
    chart = MSOEWMA(prefilter=NoDenoiser())
    params, (far, mdr) = constrained_grid_search(_evaluator(chart, data), np.linspace(0.05, 1.0, 20),
                                                 np.linspace(0.1, 8.0, 80), alpha=0.01)
    fresh = _synthetic(seed=2, shift=0.5, scale=1.0)
    tuned = _fit_and_score(chart.with_params(**params), fresh)
    shewhart = _fit_and_score(chart.with_params(lam=1.0, L=params["L"]), fresh)
    assert far <= 0.01
    assert tuned[1] < shewhart[1]  # memory helps against a small sustained shift


# ------------------------------------------------------------------------------------
# the paper module
# ------------------------------------------------------------------------------------
def test_presets_and_faults_follow_table3():
    base = SSDEWMA(limit="phase1", denoiser=NoDenoiser())

    assert paper.make_chart("M-DEWMA", paper.PAPER_PRESETS["M-DEWMA"]["variance"], base).tunable_params() == {
        "lam": 0.3, "K": 0.2}
    assert paper.make_chart("MS-OEWMA", paper.PAPER_PRESETS["MS-OEWMA"]["offset"], base).tunable_params() == {
        "lam": 0.3388, "L": 4.8621}
    # the recorded designs (mosd/systems/designs/paper000.json) are the paper's Table 3 columns
    for method, by_fault in paper.PAPER_PRESETS.items():
        for fault, params in by_fault.items():
            lam, width = paper.PAPER_TABLE3[method][fault][2:]
            assert list(params.values()) == [lam, width]
    assert list(paper.PAPER_TABLE4_PARAMS.values()) == list(paper.PAPER_TABLE3["MO-SS-DEWMA"]["offset_var"][2:])
    # §3.3's faults are conf/fault's, from the onset asked for
    offset, variance, both = (paper.make_fault(f, onset=0.7) for f in ("offset", "variance", "offset_var"))
    assert (offset.kind, offset.a, offset.b, offset.onset) == ("offset", 2.0, 1.0, 0.7)
    assert (variance.kind, variance.b) == ("variance", 2.0)
    assert (both.kind, both.a, both.b) == ("offset_var", 2.0, 2.0)
    assert [paper.paper_error_bound(f) for f in paper.FAULTS] == pytest.approx([0.002, 0.136, 0.14])
    with pytest.raises(ConfigError, match="method"):
        paper.make_chart("CUSUM", {}, base)
    with pytest.raises(ConfigError, match="budget"):
        paper.PaperSettings(budget="huge")


def test_the_reproduction_runs_the_preset_with_the_settings_as_overrides(tiny_study):
    from mosd.denoisers import WaveletDenoiser
    from mosd.detectors import MDEWMA

    exp = tiny_study.experiment
    assert (exp.budget.n_calibration, exp.budget.n_train, exp.budget.n_test) == (2, 2, 3)
    # the preset's denoiser is paper 000's literal MATLAB call (conf/denoise/wavelet.yaml)
    assert exp.detector.denoiser.describe() == WaveletDenoiser(scaling="one", scope="global",
                                                               global_source="coarsest").describe()
    m_dewma = tiny_study.chart("M-DEWMA", {"lam": 0.4, "K": 1.5})
    assert isinstance(m_dewma, MDEWMA) and m_dewma.denoiser is exp.detector.denoiser
    assert not tiny_study.chart("MO-SS-DEWMA", {"lam": 0.4, "K": 1.5}).is_causal
    assert tiny_study.chart(paper.CAUSAL_OURS, {"lam": 0.4, "K": 1.5}).is_causal
    channels = paper.PaperSettings(budget="tiny", wavelet="none", subgroups="channels").overrides()
    assert {"denoise=none", "monitor=channels", "scenario.duration=1.2", "fault.onset=0.7"} <= set(channels)


def test_fig1_axes_cut_both_ranges_into_twenty_equal_parts():
    lam, K = paper.fig1_axes()
    assert lam.size == K.size == 20
    assert np.allclose(np.diff(lam), 0.05) and np.allclose(np.diff(K), 0.5)
    assert 0 < lam[0] and lam[-1] < 1 and 0 < K[0] and K[-1] < 10


def _row(method, far, mdr):
    far, mdr = np.asarray(far, float), np.asarray(mdr, float)
    report = DetectionReport({"far": far, "mdr": mdr, "accuracy": 1.0 - far - mdr, "delay": np.zeros(len(far))})
    return paper.Row(method, "offset", {}, report)


def test_bars_are_paired_and_ci_aware():
    rng = np.random.default_rng(3)
    base_far = rng.uniform(0.0, 0.02, 40)
    ours = _row("MO-SS-DEWMA", base_far, np.zeros(40))
    worse = _row("SS-DEWMA", base_far + 0.01, np.zeros(40))
    same = _row("M-DEWMA", base_far, np.zeros(40))
    assert paper.compare_accuracy(ours, worse).verdict.startswith("better")
    tie = paper.compare_accuracy(ours, same)
    assert tie.met and tie.verdict.startswith("tie")
    loses = paper.compare_accuracy(worse, ours)
    assert not loses.met and loses.verdict.startswith("worse")
    # FAR + MDR against the paper's 0.2 % for the offset fault
    assert paper.compare_with_paper(_row("MO-SS-DEWMA", np.full(5, 0.001), np.zeros(5))).met
    high = paper.compare_with_paper(_row("MO-SS-DEWMA", np.full(5, 0.003), np.zeros(5)))
    assert not high.met and high.verdict == "not met"


@pytest.fixture(scope="module")
def tiny_study():
    return paper.build_study(paper.PaperSettings(budget="tiny", n_jobs=1))


def test_fault_data_is_cached_and_laid_out_as_the_paper(tiny_study):
    data = paper.fault_data(tiny_study, "offset")
    assert paper.fault_data(tiny_study, "offset") is data  # simulated once
    # one calibration for every fault: the calibration stream is fault-free
    other = paper.fault_data(tiny_study, "variance")
    np.testing.assert_array_equal(data.prepared.phase1.z, other.prepared.phase1.z)
    assert not np.array_equal(data.prepared.train.z, other.prepared.train.z)
    # 1,000 subgroups of 5 per run, the fault on the second half (subgroups 501–1000)
    test = data.test_subgroups
    assert test.z.shape[1:] == (1000, 5)
    assert np.array_equal(np.flatnonzero(test.fault_mask[0]), np.arange(500, 1000))


def test_fig1_scan_and_table4_on_a_tiny_budget(tiny_study, tmp_path):
    scan = paper.run_fig1(tiny_study, "offset", n=4)
    assert scan.far.shape == (4, 4)
    # a wider K never raises the FAR at fixed λ
    assert np.all(np.diff(scan.far, axis=1) <= 1e-15)
    paths = paper.write_fig1(scan, tmp_path)
    assert all(p.stat().st_size > 0 for p in paths)
    assert len(paths[0].read_text().splitlines()) == 1 + 16
    table = paper.run_table4(tiny_study)
    assert [r.fault for r in table.rows] == list(paper.FAULTS)
    assert all(r.params == table.params for r in table.rows)
    assert 0.0 < table.params["lam"] < 1.0 and 0.0 <= table.params["K"] <= 5.0
    assert "| offset a = 2 |" in paper.format_table4(table)


def test_table3_command_on_a_tiny_budget(tmp_path):
    done = subprocess.run([sys.executable, "-m", "mosd.paper", "table3", "--budget", "tiny", "--n-jobs", "1",
                           "--out", str(tmp_path)], cwd=REPO, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert "## Table 3" in done.stdout and "MO-SS-DEWMA" in done.stdout
    def refuse(constant):  # strict JSON: NaN/Infinity are not JSON
        raise AssertionError(f"table3.json holds {constant}")

    result = json.loads((tmp_path / "table3.json").read_text(), parse_constant=refuse)
    rows = result["rows"]
    methods = {r["method"] for r in rows}
    assert methods == set(paper.METHODS) | {paper.TUNED_MS_OEWMA}
    assert len(rows) == 5 * 3 and result["settings"]["n_test"] == paper.BUDGETS["tiny"].replications.n_test
    for r in rows:
        for key in ("mdr", "far", "accuracy"):
            assert 0.0 <= r[key]["mean"] <= 1.0
        assert r["accuracy"]["mean"] == pytest.approx(1.0 - r["mdr"]["mean"] - r["far"]["mean"])
        if r["method"] in paper.BASELINES:
            assert r["params"] == paper.PAPER_PRESETS[r["method"]][r["fault"]]
        if r["method"] == "MO-SS-DEWMA":
            assert 0.0 < r["params"]["lam"] < 1.0 and 0.0 <= r["params"]["K"] <= 5.0  # Table 2's box
    # the error anatomy accounts for every error of the optimised design (500 subgroups per half)
    for r in rows:
        if r["method"] == "MO-SS-DEWMA":
            a = result["anatomy"][r["fault"]]
            assert a["missed_onset"] + a["missed_later"] == pytest.approx(500 * r["mdr"]["mean"])
            assert a["false_near_onset"] + a["false_elsewhere"] == pytest.approx(500 * r["far"]["mean"])
            assert 0.0 <= a["missed_onset"] <= 1.0
    # one bar per baseline (+ the tuned MS-OEWMA) and the paper's bound, for every fault
    assert len(result["bars"]) == 3 * (len(paper.BASELINES) + 2)
    # per fault: 5 table rows, 5 bars, 3 self-referenced rows, 1 error-anatomy row
    assert (tmp_path / "table3.md").read_text().count("| offset a = 2 |") == 5 + 5 + 3 + 1


def test_command_line_rejects_a_bad_option():
    with pytest.raises(SystemExit):
        paper.main(["table3", "--budget", "huge"])
    assert paper.main(["table3", "--n-jobs", "0"]) == 2
