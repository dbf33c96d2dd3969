"""The presets' studies (mosd.systems.paper00N.Study): metric names, figures, report commands, one property each.

Each study runs on a tiny scale here; the properties are things the
reconstruction could get wrong (fusion beating every sensor, the two code paths
of paper 002's separation agreeing, paper 003's replayed faults equalling the
plant's own). The full-scale numbers are in docs/RESULTS.md.
"""
from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from mosd.systems import paper001, paper002, paper003
from mosd.validation import ConfigError

P001_NAMES = {f"rmse_{q}_{f}" for q in ("state", "amplitude") for f in ("fused", "sensor1", "sensor2", "sensor3")} | {
    "isolation_rate", "false_isolation_rate", "far", "mdr", "delay_s", "detected_rate", "no_fault_declared_rate"}
P002_NAMES = {f"{p}{k}_r{r}" for p in ("", "baseline_") for r in (0, 10)
              for k in ("delay_target_s", "detection_rate_target", "false_alarm_nuisance")}
P003_NAMES = {"detection_step_n1", "detection_step_best", "best_window", "detection_rate_n1", "detection_rate_best",
              "far"}


def _result(detector):
    """What a study reads of an ExperimentResult: the tuned detector and its parameters."""
    return SimpleNamespace(detector=detector, params={k: getattr(detector, k) for k in detector.tunable})


def _finite(metrics, names):
    missing = names - set(metrics)
    assert not missing, f"missing metrics {sorted(missing)}"
    bad = {k: metrics[k] for k in names if not math.isfinite(metrics[k])}
    assert not bad, f"non-finite metrics {bad}"


# -- paper 001 ------------------------------------------------------------------------------
def test_paper001_study_names_and_figures(tmp_path):
    experiment = paper001.preset_experiment(seed=3, n_test=20)
    metrics, files = paper001.Study(n_reps=20).run(experiment, _result(experiment.detector.with_params(mu_T=0.8)),
                                                     tmp_path)
    _finite(metrics, P001_NAMES | {"paper_" + k for k in ("isolation_rate", "no_fault_declared_rate")})
    assert len(files) == 4 and all(f.exists() and f.stat().st_size > 10_000 for f in files)
    for key in ("isolation_rate", "false_isolation_rate", "far", "mdr", "detected_rate", "no_fault_declared_rate"):
        assert 0.0 <= metrics[key] <= 1.0
    # the paper's lower threshold can only add declarations on the same fault-free runs
    assert metrics["paper_no_fault_declared_rate"] <= metrics["no_fault_declared_rate"]


def test_paper001_fusion_beats_every_single_sensor_on_100_runs():
    experiment = paper001.preset_experiment(seed=11, n_test=100)
    study = paper001.Study(n_reps=100, figures=False)
    metrics = study.metrics(study.compute(experiment, {"tuned": experiment.detector}))
    for quantity in ("state", "amplitude"):
        fused = metrics[f"rmse_{quantity}_fused"]
        singles = [metrics[f"rmse_{quantity}_sensor{i}"] for i in (1, 2, 3)]
        assert fused < min(singles), (quantity, fused, singles)
    # the slowest sensor (lowest rate, same loss as sensor 2) is the worst by a wide margin
    assert metrics["rmse_state_sensor3"] > 1.1 * max(metrics["rmse_state_sensor1"], metrics["rmse_state_sensor2"])


def test_paper001_report_command_rejects_bad_input_in_one_line(tmp_path, capsys):
    out = tmp_path / "out"
    assert paper001.main(["--n-reps", "1", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "study.n_reps" in err and "allowed" in err
    assert not out.exists()
    assert paper001.main(["--mu-T", "1.5", "--out", str(out)]) == 2
    assert "detector.mu_T" in capsys.readouterr().err and not out.exists()


# -- paper 002 ------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def paper002_setup():
    from mosd.estimators.entropy_filter import EntropyIsolationFilter

    experiment = paper002.preset_experiment(seed=5)
    experiment.estimator = EntropyIsolationFilter(n_particles=100)  # a coarser gain design: seconds, not tens
    experiment.fit_estimator()
    return experiment


def test_paper002_study_names_and_figures(paper002_setup, tmp_path):
    detector = paper002_setup.detector.with_params(threshold=0.67, L=1)
    study = paper002.Study(n_runs=10, missing_rates=[0.0, 0.1])
    metrics, files = study.run(paper002_setup, _result(detector), tmp_path)
    _finite(metrics, P002_NAMES | {"roc_auc", "baseline_roc_auc", "equal_fa_target_detection"})
    assert not any(k.endswith("_r5") for k in metrics)
    assert len(files) == 3 and all(f.exists() and f.stat().st_size > 10_000 for f in files)


def test_paper002_separation_paths_agree_and_target_error_dominates(paper002_setup):
    detector = paper002_setup.detector.with_params(threshold=0.67, L=2)
    study = paper002.Study(n_runs=40, missing_rates=[0.0, 0.2], figures=False)
    data = study.compute(paper002_setup, detector)
    metrics = study.metrics(data)
    # the ROC sweep and the study's own scoring count nuisance false alarms the same way at the same design
    for name, prefix in paper002.FILTER_PREFIXES.items():
        roc = data["roc"][name]
        k = int(np.flatnonzero(np.isclose(roc["threshold"], 0.67))[0])
        assert roc["false_alarm"][k] == pytest.approx(metrics[f"{prefix}false_alarm_nuisance_r0"], abs=1e-12)
    # a ROC curve: fewer alarms of both kinds as the threshold rises
    for roc in data["roc"].values():
        assert np.all(np.diff(roc["false_alarm"]) <= 1e-12) and np.all(np.diff(roc["detection"]) <= 1e-12)
    # isolation needs the target's steady error well above the nuisance's at every missing rate
    for tag in ("r0", "r20"):
        assert metrics[f"error_level_target_{tag}"] > 1.5 * metrics[f"error_level_nuisance_{tag}"]


def test_paper002_study_validates_its_parameters():
    with pytest.raises(ConfigError, match="study.missing_rates"):
        paper002.Study(missing_rates=[0.0, 0.95])
    with pytest.raises(ConfigError, match="study.missing_rates"):
        paper002.Study(missing_rates=[0.1, 0.1])
    with pytest.raises(ConfigError, match="study.n_runs"):
        paper002.Study(n_runs=1)


# -- paper 003 ------------------------------------------------------------------------------
def test_paper003_replayed_ramp_equals_the_plant_simulating_it():
    from mosd.faults.ramp import RampFault
    from mosd.scenario import replication_rngs

    plant, noise = paper003.FlappingWingMAV(), paper003.default_noise()
    fault = RampFault(rate=0.7, onset=40.0)
    clean = plant.simulate(300, noise, None, replication_rngs(2, "test", 2))
    direct = plant.simulate(300, noise, fault, replication_rngs(2, "test", 2))
    replayed = paper003.with_fault(clean, fault)
    np.testing.assert_array_equal(replayed.y, direct.y)
    np.testing.assert_array_equal(replayed.fault_mask, direct.fault_mask)


def _tiny_paper003(tmp_path, epochs=3):
    pytest.importorskip("torch")
    from mosd.estimators.neural_observer import MultiStepNeuralObserver
    from mosd.experiment import Budget, Experiment
    from mosd.monitors.outputs import OutputMonitor

    return Experiment(paper003.FlappingWingMAV(), paper003.default_noise(), paper003.RampFault(onset=30.0),
                      MultiStepNeuralObserver(window=3, epochs=epochs, cache_dir=str(tmp_path / "cache"),
                                              progress=False),
                      OutputMonitor(outputs=["observer_chi2", "observer_residual"], burn_in=15),
                      paper003.AdaptiveChi2Detector(), duration=50.0,
                      budget=Budget(n_calibration=2, n_train=2, n_test=2, n_estimator=2), seed=4)


def test_paper003_study_names_and_figures(tmp_path):
    experiment = _tiny_paper003(tmp_path)
    experiment.fit_estimator()
    study = paper003.Study(windows=[1, 3], rates=[0.5, 1.0], n_runs=2, trace_rate=1.0)
    metrics, files = study.run(experiment, _result(experiment.detector), tmp_path / "out")
    _finite(metrics, P003_NAMES | {"paper_far", "innovation_far"})
    assert metrics["best_window"] in (1.0, 3.0)
    assert len(files) == 4 and all(f.exists() and f.stat().st_size > 10_000 for f in files)
    # the experiment's own window reuses its trained observer; the other was trained and cached
    assert len(list((tmp_path / "cache").glob("*.npz"))) == 2


def test_paper003_study_validates_its_parameters():
    with pytest.raises(ConfigError, match="study.windows"):
        paper003.Study(windows=[2, 4])
    with pytest.raises(ConfigError, match="study.trace_rate"):
        paper003.Study(rates=[0.5], trace_rate=0.1)
    with pytest.raises(ConfigError, match="study.rates"):
        paper003.Study(rates=[0.0, 0.5], trace_rate=0.5)


def test_paper003_with_window_keeps_every_other_setting():
    from mosd.estimators.neural_observer import MultiStepNeuralObserver

    base = MultiStepNeuralObserver(window=12, hidden=7, epochs=11, weighting="uniform", cache_dir=None)
    other = paper003.with_window(base, 4)
    assert other.window == 4 and {**base.config(), "window": 4} == other.config()
    assert other.ekf is base.ekf and other.cache_dir is None


# -- the report commands run the presets' experiments -----------------------------------------
def _same(a, b, path=""):
    """Recursive comparison of two components' parameters (arrays exactly, nested components by their vars)."""
    if hasattr(a, "__dict__") and not isinstance(a, type):
        assert type(a) is type(b), path
        keys = {k for k in vars(a) if not k.endswith("_")}
        assert keys == {k for k in vars(b) if not k.endswith("_")}, path
        for k in keys:
            _same(vars(a)[k], vars(b)[k], f"{path}.{k}")
    elif isinstance(a, (list, tuple)) and a and hasattr(a[0], "__dict__"):
        assert len(a) == len(b), path
        for i, (x, y) in enumerate(zip(a, b)):
            _same(x, y, f"{path}[{i}]")
    else:
        np.testing.assert_array_equal(np.asarray(a, dtype=object), np.asarray(b, dtype=object), err_msg=path)


@pytest.mark.parametrize("module", [paper001, paper002, paper003])
def test_report_command_experiment_is_the_preset(module):
    from pathlib import Path

    from hydra import compose, initialize_config_dir

    from mosd.app.build import build

    name = module.__name__.rsplit(".", 1)[-1]
    conf = Path(__file__).resolve().parents[1] / "conf"
    with initialize_config_dir(config_dir=str(conf), version_base="1.3", job_name="test"):
        setup = build(compose("config", overrides=[f"+experiment={name}"]))
    preset, ours = setup.experiment, module.preset_experiment()
    for part in ("plant", "noise", "fault", "estimator", "monitor", "detector"):
        _same(getattr(preset, part), getattr(ours, part), part)
    assert (preset.duration, preset.budget, preset.seed) == (ours.duration, ours.budget, ours.seed)
    assert type(setup.study) is module.Study


# -- the documented bars (slow: full Monte Carlo scale) --------------------------------------
@pytest.mark.slow
def test_paper001_bars_at_500_runs():
    experiment = paper001.preset_experiment(seed=0, n_test=500)
    study = paper001.Study(n_reps=500, figures=False)
    tuned = experiment.detector.with_params(**paper001.TUNED_DESIGN)
    metrics = study.metrics(study.compute(experiment, {"tuned": tuned}))
    verdicts = {name: met for name, met, _ in paper001.bars(metrics)}
    assert all(verdicts.values()), verdicts


@pytest.mark.slow
def test_paper003_multi_step_window_detects_sooner_only_on_the_observer_residual(tmp_path):
    """Reading 2 shows the paper's window effect, reading 1 does not; FAR stays within 2α (about 1 min)."""
    pytest.importorskip("torch")
    experiment = paper003.preset_experiment(seed=0, cache_dir=str(tmp_path))
    study = paper003.Study(windows=[1, 8], rates=[0.2, 0.5], n_runs=10, trace_rate=0.2, figures=False)
    data = study.compute(experiment, {"paper": experiment.detector.with_params(**paper003.PAPER_DESIGN)})
    observer = study.summary(data, "paper", "observer_chi2")
    innovation = study.summary(data, "paper", "chi2")
    assert observer["best_window"] == 8
    assert observer["detection_step_n1"] >= 3 * observer["detection_step_best"]
    assert observer["detection_rate_best"] > observer["detection_rate_n1"] + 0.3
    assert observer["far"] <= 2 * paper003.PAPER_DESIGN["alpha"]
    # the filter's innovation does not gain from the observer's window: it only raises the threshold
    i1, i8 = data["windows"].index(1), data["windows"].index(8)
    rate = data["table"]["paper"]["chi2"]["detection_rate"].mean(axis=1)
    assert rate[i8] <= rate[i1] + 0.02 and innovation["far"] <= 2 * paper003.PAPER_DESIGN["alpha"]
