"""Paper 002 (reconstruction), issue 20: the objectives measure isolation, the tuned design isolates,
each filter is scored at its own threshold, and the study reports every mechanism × fill."""
import math

import numpy as np
import pytest

from mosd.app.presets import compose_preset
from mosd.metrics import detection, objective_values
from mosd.metrics.registry import METRICS
from mosd.optim.selection import choose
from mosd.systems import base, cli, paper002
from mosd.types import Subgroups
from mosd.validation import ConfigError


def test_nuisance_alarm_rate_counts_alarms_while_only_the_nuisance_acts():
    # run 0: target from point 2; run 1: nuisance from point 2; run 2: fault-free
    label = np.array([[0, 0, 1, 1], [0, 0, 2, 2], [0, 0, 0, 0]])
    alarms = np.array([[1, 0, 1, 0], [1, 1, 0, 1], [1, 1, 1, 1]], bool)
    truth = Subgroups(z=np.empty((0,)), fault_mask=label == 1, fault_label=label, fault_roles=("target", "nuisance"))
    per_run = detection.role_alarm_rate(alarms, label, truth.fault_roles)
    np.testing.assert_array_equal(per_run, [np.nan, 0.5, np.nan])
    assert METRICS["nuisance_alarm_rate"].minimise
    assert objective_values(["nuisance_alarm_rate", "mdr"], alarms, truth).tolist() == [0.5, 0.5]


def test_the_preset_trades_false_isolation_against_missed_target_points():
    cfg = compose_preset("paper002")
    assert list(cfg.optimizer.objectives) == ["nuisance_alarm_rate", "mdr"]
    assert (cfg.selection.rule, cfg.selection.alpha) == ("min_mdr_far_le", 0.02)
    # the constrained rule reads nuisance_alarm_rate as its false-alarm column
    F = np.array([[0.10, 0.05], [0.015, 0.20], [0.03, 0.12], [0.0, 0.5]])
    assert choose(np.zeros((4, 2)), F, rule="min_mdr_far_le", alpha=0.02,
                  objectives=("nuisance_alarm_rate", "mdr")) == 1
    with pytest.raises(ConfigError, match="selection.rule=max_accuracy needs far and mdr"):
        choose(np.zeros((1, 2)), F[:1], rule="max_accuracy", objectives=("nuisance_alarm_rate", "delay"))


@pytest.fixture(scope="module")
def experiment():
    experiment = cli.preset("paper002").experiment
    experiment.fit_estimator()
    return experiment


def test_the_recorded_tuned_design_isolates_per_point_but_not_per_run(experiment):
    """Issue 30: the tuned design meets its per-point objective, yet about 30 % of nuisance runs alarm.

    The claim is per run (a run is declared the target fault or not): with the target counted per run
    and the nuisance per point the verdict read "reproduced"; in the same units it is not.
    """
    study = paper002.Study(n_runs=200, missing_rates=[0.0, 0.05, 0.1], mechanisms=["mcar"], fills=["em"],
                           figures=False, amplitude_laws=[])
    tuned = experiment.detector.with_params(**base.recorded_designs("paper002")["tuned"])
    metrics = study.metrics(study.compute(experiment, {"tuned": tuned}))
    for tag in ("r0", "r5", "r10"):
        assert metrics[f"target_run_detection_{tag}"] >= 0.95
        assert metrics[f"nuisance_point_false_isolation_{tag}"] <= 0.05
        assert metrics[f"nuisance_run_false_isolation_{tag}"] > 0.2


def test_each_filter_is_scored_at_its_own_threshold(experiment):
    study = paper002.Study(n_runs=60, missing_rates=[0.0], mechanisms=["mcar"], fills=["em"], figures=False)
    baseline = study.baseline(experiment.estimator)
    own = {name: paper002.midway_threshold(experiment, 60, est)
           for name, est in (("entropy", experiment.estimator), ("baseline", baseline))}
    assert own["baseline"] > own["entropy"] + 0.1      # the fixed gain's errors sit higher
    midway = {name: experiment.detector.with_params(threshold=t, persistence=3) for name, t in own.items()}
    tuned = experiment.detector.with_params(threshold=0.63, persistence=4)
    data = study.compute(experiment, {"tuned": tuned, "midway": midway})
    assert data["baseline_params"]["midway"]["threshold"] == pytest.approx(own["baseline"])
    assert data["params"]["midway"]["threshold"] == pytest.approx(own["entropy"])
    metrics = study.metrics(data)
    # the tuned baseline: the lowest threshold of the sweep whose false isolation on the calibration
    # runs does not exceed the entropy design's; far from the entropy filter's own threshold
    assert metrics["baseline_threshold"] > 0.63 + 0.1
    assert metrics["midway_baseline_threshold"] == pytest.approx(own["baseline"])
    for prefix in ("", "midway_"):
        assert metrics[f"{prefix}baseline_nuisance_point_false_isolation_r0"] < 0.05
    table = paper002.format_report({name: {"entropy": data["params"][name], "baseline": data["baseline_params"][name]}
                                    for name in data["designs"]}, metrics, ["mcar"], ["em"])
    assert f"threshold {own['baseline']:.3g}, L 3) | baseline" in table


def test_the_study_reports_every_mechanism_and_fill(experiment):
    study = paper002.Study(n_runs=20, missing_rates=[0.0, 0.2], figures=False, amplitude_laws=[])
    tuned = experiment.detector.with_params(threshold=0.63, persistence=4)
    metrics = study.metrics(study.compute(experiment, {"tuned": tuned}))
    for mechanism in ("mcar", "burst", "gap"):
        for fill in ("em", "hold", "skip"):
            for key in paper002.GRID_KEYS:
                # nothing is filled by skip: its fill error is not reported (never a NaN)
                assert (f"{mechanism}_{fill}_{key}_r20" in metrics) == (key != "fill_rmse" or fill != "skip")
            assert f"{mechanism}_{fill}_fill_rmse_r0" not in metrics    # nothing missing
    assert all(math.isfinite(v) for v in metrics.values())
    # the EM fill is the former default: its MCAR numbers are the study's main rows
    for key in ("nuisance_run_false_isolation", "nuisance_point_false_isolation", "target_run_detection"):
        assert metrics[f"mcar_em_{key}_r20"] == metrics[f"{key}_r20"]
    # long gaps without a neighbour are where a fill matters: skipping lets the error fluctuate most
    assert metrics["gap_skip_error_fluct_target_r20"] > metrics["mcar_em_error_fluct_target_r20"]


def _same(a, b, where="data") -> None:
    """``a`` and ``b`` hold the same numbers, bit for bit, under the same keys in the same order."""
    assert type(a) is type(b), where
    if isinstance(a, dict):
        assert list(a) == list(b), where
        for key in a:
            _same(a[key], b[key], f"{where}[{key!r}]")
    elif isinstance(a, (list, tuple)):
        assert len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b)):
            _same(x, y, f"{where}[{i}]")
    elif isinstance(a, np.ndarray):
        np.testing.assert_array_equal(a, b, err_msg=where)
    else:
        assert a == b or (a != a and b != b), where


def test_the_study_is_the_same_on_one_thread_and_on_several(experiment, monkeypatch):
    """The rates and the grid's mechanism x rate cells run on threads (issue 32): the same numbers, in the same
    order, as on one."""
    from mosd import kernels

    study = paper002.Study(n_runs=10, missing_rates=[0.0, 0.2], figures=False, amplitude_laws=[])
    tuned = experiment.detector.with_params(threshold=0.63, persistence=4)
    found = []
    for threads in (1, 3):
        monkeypatch.setattr(kernels, "threads", lambda threads=threads: threads)
        found.append(study.compute(experiment, {"tuned": tuned}))
    assert list(found[0]["grid"]) == [(m, f, r) for m in study.mechanisms for r in (0.0, 0.2) for f in study.fills]
    _same(found[0], found[1])


def test_the_study_validates_mechanisms_fills_and_burst_length():
    with pytest.raises(ConfigError, match=r"study.mechanisms='mcar' is not allowed; allowed: a list"):
        paper002.Study(mechanisms="mcar")
    with pytest.raises(ConfigError, match=r"study.mechanisms='bursts' is not allowed; allowed: mcar, burst, gap"):
        paper002.Study(mechanisms=["bursts"])
    with pytest.raises(ConfigError, match=r"study.fills=\['em', 'em'\] is not allowed"):
        paper002.Study(fills=["em", "em"])
    with pytest.raises(ConfigError, match="study.fills='ffill' is not allowed; allowed: em, hold, skip"):
        paper002.Study(fills=["ffill"])
    with pytest.raises(ConfigError, match="study.burst_length"):
        paper002.Study(missing_rates=[0.0, 0.6], burst_length=1.0)
