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

from mosd.systems import base, cli, paper000, paper001, paper002, paper003
from mosd.validation import ConfigError

P001_NAMES = {f"rmse_{q}_{f}" for q in ("state", "amplitude") for f in ("fused", "sensor1", "sensor2", "sensor3")} | {
    "isolation_rate", "false_isolation_rate", "far", "mdr", "delay_s", "detection_rate", "no_fault_declared_rate",
    "paper_no_fault_declared_rate", "mode_calibration_ece"} | {
    f"mse_{q}_{a}_minus_{b}{ci}" for q in ("state", "amplitude") for a, b in paper001.RMSE_PAIRS for ci in ("", "_ci95")}
P002_NAMES = {f"{p}{k}_r{r}" for p in ("", "baseline_") for r in (0, 10)
              for k in ("delay_target_s", "target_run_detection", "nuisance_run_false_isolation",
                        "target_point_detection", "nuisance_point_false_isolation")}
P003_NAMES = {"censored_step_n1", "censored_step_best", "best_window", "detection_rate_n1", "detection_rate_best",
              "far", "threshold_relative_range", "base_threshold", "paper_base_threshold"}


def _preset(name, *overrides):
    """The experiment of ``+experiment=NAME`` with Hydra overrides: what the report commands run."""
    return cli.preset(name, list(overrides)).experiment


def _result(detector):
    """What a study reads of an ExperimentResult: the tuned detector and its parameters."""
    return SimpleNamespace(detector=detector, params={k: getattr(detector, k) for k in detector.tunable})


def _finite(metrics, names):
    missing = names - set(metrics)
    assert not missing, f"missing metrics {sorted(missing)}"
    bad = {k: metrics[k] for k in names if not math.isfinite(metrics[k])}
    assert not bad, f"non-finite metrics {bad}"


# -- paper 000 ------------------------------------------------------------------------------
def test_paper000_study_scores_the_tuned_design_like_the_experiment_and_pairs_the_runs(tmp_path):
    experiment = _preset("paper000", "seed=2", "budget.n_calibration=2", "budget.n_train=2", "budget.n_test=4")
    # the tuned design here is Table 3's own SS-DEWMA for the fault: the paired difference must be exactly 0
    tuned = experiment.detector.with_params(**paper000.PAPER_PRESETS["SS-DEWMA"]["offset_var"])
    metrics, files = paper000.Study(n_runs=4).run(experiment, _result(tuned), tmp_path)
    names = {"far", "mdr", "accuracy", "detection_rate"}
    _finite(metrics, names | {f"{d}_{k}" for d in ("m_dewma", "ms_oewma", "ss_dewma") for k in names})
    assert metrics["accuracy_vs_ss_dewma"] == 0.0 and metrics["accuracy_vs_ss_dewma_ci95"] == 0.0
    assert metrics["ss_dewma_far"] == metrics["far"]
    assert len(files) == 1 and files[0].stat().st_size > 10_000
    # with n_runs = budget.n_test the study's runs are the experiment's own test runs
    report, _ = experiment.evaluate(tuned, experiment.prepare())
    assert metrics["far"] == pytest.approx(report.summary()["far"].mean, abs=1e-15)
    assert metrics["mdr"] == pytest.approx(report.summary()["mdr"].mean, abs=1e-15)


# -- paper 001 ------------------------------------------------------------------------------
def test_paper001_study_names_and_figures(tmp_path):
    experiment = _preset("paper001", "seed=3", "budget.n_test=20")
    study = paper001.Study(n_runs=20, prior_intervals=[20, 16.5])
    metrics, files = study.run(experiment, _result(experiment.detector.with_params(mu_T=0.8)), tmp_path)
    priors = {f"prior_{tag}_{k}" for tag in ("20", "16p5") for k in (
        "isolation_rate", "far", "no_fault_declared_rate", "paper_no_fault_declared_rate", "rmse_state_fused",
        "rmse_amplitude_fused", "mode_calibration_ece")}
    _finite(metrics, P001_NAMES | priors | {"paper_" + k for k in ("isolation_rate", "no_fault_declared_rate")})
    assert all(math.isfinite(v) for v in metrics.values())  # an undefined number is left out, never NaN
    # a hazard of 1/20 expects faults sooner than 1/40: the filter's μ₂ rises sooner on fault-free runs too
    assert metrics["prior_20_no_fault_declared_rate"] <= metrics["no_fault_declared_rate"]
    assert len(files) == 5 and all(f.exists() and f.stat().st_size > 10_000 for f in files)
    for key in ("isolation_rate", "false_isolation_rate", "far", "mdr", "detection_rate", "no_fault_declared_rate"):
        assert 0.0 <= metrics[key] <= 1.0
    # the paper's lower threshold can only add declarations on the same fault-free runs
    assert metrics["paper_no_fault_declared_rate"] <= metrics["no_fault_declared_rate"]


def test_paper001_fusion_beats_every_single_sensor_on_100_runs():
    experiment = _preset("paper001", "seed=11", "budget.n_test=100")
    study = paper001.Study(n_runs=100, figures=False)
    metrics = study.metrics(study.compute(experiment, {"tuned": experiment.detector}))
    for quantity in ("state", "amplitude"):
        fused = metrics[f"rmse_{quantity}_fused"]
        singles = [metrics[f"rmse_{quantity}_sensor{i}"] for i in (1, 2, 3)]
        assert fused < min(singles), (quantity, fused, singles)
    # the slowest sensor (lowest rate, same loss as sensor 2) is the worst by a wide margin
    assert metrics["rmse_state_sensor3"] > 1.1 * max(metrics["rmse_state_sensor1"], metrics["rmse_state_sensor2"])


def test_paper001_report_command_rejects_bad_input_in_one_line(tmp_path, capsys):
    out = tmp_path / "out"
    assert paper001.main(["--n-runs", "1", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "study.n_runs" in err and "allowed" in err
    assert not out.exists()
    assert paper001.main(["--mu-T", "1.5", "--out", str(out)]) == 2
    assert "detector.mu_T" in capsys.readouterr().err and not out.exists()


# -- paper 002 ------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def paper002_setup():
    from mosd.estimators.entropy_filter import EntropyIsolationFilter

    experiment = _preset("paper002", "seed=5")
    experiment.estimator = EntropyIsolationFilter(n_particles=100)  # a coarser gain design: seconds, not tens
    experiment.fit_estimator()
    return experiment


def test_paper002_study_names_and_figures(paper002_setup, tmp_path):
    detector = paper002_setup.detector.with_params(threshold=0.67, persistence=1)
    study = paper002.Study(n_runs=10, missing_rates=[0.0, 0.1])
    metrics, files = study.run(paper002_setup, _result(detector), tmp_path)
    assert not any(k.startswith("paper_") for k in metrics)  # the paper's threshold is lost: no reference design
    _finite(metrics, P002_NAMES | {"roc_auc", "baseline_roc_auc", "equal_fa_target_detection"})
    assert not any(k.endswith("_r5") for k in metrics)
    assert all(math.isfinite(v) for v in metrics.values())  # an undefined number is left out, never NaN
    # nothing is filled on complete data or by skip: no fill error is reported for them
    assert "mcar_em_fill_rmse_r10" in metrics and "mcar_em_fill_rmse_r0" not in metrics
    assert not any(k.startswith("mcar_skip_fill_rmse") for k in metrics)
    # a run with any alarm counts once per run: per run at least the per-point share
    for tag in ("r0", "r10"):
        assert metrics[f"nuisance_run_false_isolation_{tag}"] >= metrics[f"nuisance_point_false_isolation_{tag}"]
        assert metrics[f"target_run_detection_{tag}"] >= metrics[f"target_point_detection_{tag}"]
    assert len(files) == 3 and all(f.exists() and f.stat().st_size > 10_000 for f in files)


def test_paper002_per_run_false_isolation_counts_nuisance_runs_and_follows_the_nuisance_law(paper002_setup):
    detector = paper002_setup.detector.with_params(threshold=0.67, persistence=2)
    laws = [[[0.5, 1.5], [0.0, 0.6]], [[0.5, 1.5], [0.0, 1.0]]]
    study = paper002.Study(n_runs=30, missing_rates=[0.0], figures=False, amplitude_laws=laws,
                           mechanisms=["mcar"], fills=["em"])
    data = study.compute(paper002_setup, {"tuned": detector})
    metrics = study.metrics(data)
    # the share of nuisance runs with an alarm after the onset, counted from the decisions directly
    trace = study._simulate(paper002_setup, 0.0)
    outputs = paper002_setup.estimator.estimate(trace, paper002_setup.model)
    points = paper002_setup.monitor.transform(outputs)
    d = detector.decide(points.z[:1], points.z).decision != 0
    nuisance = ~paper002.Study._roles(points.fault_label, points.fault_roles)
    direct = np.mean((d[nuisance] & (points.fault_label[nuisance] > 0)).any(axis=-1))
    assert metrics["nuisance_run_false_isolation_r0"] == pytest.approx(direct, abs=1e-12)
    # the reconstruction's laws on the same seeds give the same runs as the study's own
    assert metrics["laws_t50_150_n0_60_nuisance_run_false_isolation"] == metrics["nuisance_run_false_isolation_r0"]
    # the same uniform draws scaled to a wider nuisance support: every nuisance amplitude grows, so do its alarms
    assert (metrics["laws_t50_150_n0_100_nuisance_run_false_isolation"]
            > metrics["laws_t50_150_n0_60_nuisance_run_false_isolation"])


def test_paper002_separation_paths_agree_and_target_error_dominates(paper002_setup):
    detector = paper002_setup.detector.with_params(threshold=0.67, persistence=2)
    study = paper002.Study(n_runs=40, missing_rates=[0.0, 0.2], figures=False)
    data = study.compute(paper002_setup, {"tuned": detector})
    metrics = study.metrics(data)
    # the ROC sweep and the study's own scoring count nuisance false alarms the same way at the same design
    # (each filter at its own threshold)
    for name, prefix in paper002.FILTER_PREFIXES.items():
        roc = data["designs"]["tuned"]["roc"][name]
        own = data["params" if name == "entropy" else "baseline_params"]["tuned"]["threshold"]
        k = int(np.flatnonzero(np.isclose(roc["threshold"], own))[0])
        assert roc["false_alarm"][k] == pytest.approx(metrics[f"{prefix}nuisance_point_false_isolation_r0"],
                                                     abs=1e-12)
    # a ROC curve: fewer alarms of both kinds as the threshold rises
    for roc in data["designs"]["tuned"]["roc"].values():
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
    with pytest.raises(ConfigError, match="study.amplitude_laws"):
        paper002.Study(amplitude_laws=[[[0.5, 1.5], [0.6, 0.0]]])


# -- paper 003 ------------------------------------------------------------------------------
def test_paper003_replayed_ramp_equals_the_plant_simulating_it():
    from mosd.faults.ramp import RampFault
    from mosd.scenario import replication_rngs

    preset = _preset("paper003")
    plant, noise = preset.plant, preset.noise
    fault = RampFault(rate=0.7, onset=40.0)
    clean = plant.simulate(300, noise, None, replication_rngs(2, "test", 2))
    direct = plant.simulate(300, noise, fault, replication_rngs(2, "test", 2))
    replayed = paper003.with_fault(clean, fault)
    np.testing.assert_array_equal(replayed.y, direct.y)
    np.testing.assert_array_equal(replayed.fault_mask, direct.fault_mask)


def _tiny_paper003(tmp_path, epochs=3):
    import torch  # noqa: F401  (a test dependency: a missing one fails, never skips)
    return _preset("paper003", "seed=4", "scenario.duration=50.0", "fault.onset=30.0", "estimator.window=3",
                   f"estimator.epochs={epochs}", f"estimator.cache_dir='{tmp_path / 'cache'}'",
                   "estimator.progress=false", "budget.n_calibration=2", "budget.n_train=2", "budget.n_test=2",
                   "budget.n_estimator=2")


def test_paper003_study_names_and_figures(tmp_path):
    experiment = _tiny_paper003(tmp_path)
    experiment.fit_estimator()
    # confirm=1: two flights of 20 faulty steps after 3 epochs need not hold 3 alarms in a row for N = 1
    study = paper003.Study(windows=[1, 3], rates=[0.5, 1.0], n_runs=2, trace_rate=1.0, confirm=1)
    metrics, files = study.run(experiment, _result(experiment.detector), tmp_path / "out")
    _finite(metrics, P003_NAMES | {"paper_far", "innovation_far"})
    assert all(math.isfinite(v) for v in metrics.values())  # an undefined number is left out, never NaN
    # the fault-free flights' first-alarm law (its mean step left out when none of the two flights alarms)
    assert {"chance_alarm_share", "paper_chance_alarm_share"} <= set(metrics)
    # the rule without the adaptive term, for both readings and every window
    for reading in (1, 2):
        for n in (1, 3):
            for key in ("detected", "point_rate", "chance_detected"):
                assert 0.0 <= metrics[f"kofm_reading{reading}_{key}_n{n}"] <= 1.0
    # with b = 0 the threshold is a·T_D: α and a are one number
    tuned = experiment.detector
    assert metrics["base_threshold"] == pytest.approx(tuned.a * float(tuned.chi2_threshold(tuned.alpha)))
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


def test_paper003_observer_of_another_window_keeps_every_other_setting():
    """What the study trains per window: the experiment's observer with only N replaced, its filter shared."""
    from mosd.estimators.neural_observer import MultiStepNeuralObserver

    base = MultiStepNeuralObserver(window=12, hidden=7, epochs=11, weighting="uniform", cache_dir=None)
    other = base.with_params(window=4)
    assert other.window == 4 and {**base.config(), "window": 4} == other.config()
    assert other.ekf is base.ekf and other.cache_dir is None and not hasattr(other, "params_")


# -- the study contract and the report commands ----------------------------------------------
@pytest.mark.parametrize("module", [paper000, paper001, paper002, paper003])
def test_every_study_keeps_the_contract_and_its_preset_names_it(module):
    name = module.__name__.rsplit(".", 1)[-1]
    assert issubclass(module.Study, base.Study) and module.Study.system == name
    setup = cli.preset(name)
    assert type(setup.study) is module.Study
    recorded = base.recorded_designs(name)
    # a recorded tuned design is a valid design of the preset's detector (validated by with_params)
    if "tuned" in recorded:
        tuned = setup.experiment.detector.with_params(**recorded["tuned"])
        assert {k: getattr(tuned, k) for k in recorded["tuned"]} == recorded["tuned"]
    with pytest.raises(ConfigError, match="study.figures"):
        module.Study(figures="yes")


def test_report_experiment_is_the_preset_with_the_command_line_overrides():
    setup = cli.preset("paper001", ["seed=7", "budget.n_test=30"])
    assert (setup.experiment.seed, setup.experiment.budget.n_test) == (7, 30)
    assert setup.study.n_runs == 500  # conf/experiment/paper001.yaml study.n_runs
    with pytest.raises(ConfigError, match="budget.n_tests"):
        cli.preset("paper001", ["budget.n_tests=30"])
    with pytest.raises(ConfigError, match="experiment"):
        cli.preset("paper999")


def test_recorded_designs_come_from_the_package_data():
    assert base.recorded_designs("paper001")["paper"] == {"mu_T": 0.5, "persistence": 1}
    assert set(base.recorded_designs("paper002")) == {"tuned", "midway"}
    assert all(not k.startswith("_") for k in base.recorded_designs("paper003"))
    with pytest.raises(ConfigError, match="paper999"):
        base.recorded_designs("paper999")


def test_report_parser_errors_are_one_line_and_exit_2(capsys):
    parser = cli.report_parser("python -m mosd.systems.x", "x", out="outputs/x")
    with pytest.raises(SystemExit) as stop:
        parser.parse_args(["--seed", "one"])
    assert stop.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("error:") and "--seed" in err


# -- the documented bars (slow: full Monte Carlo scale) --------------------------------------
@pytest.mark.slow
def test_paper001_bars_at_500_runs():
    experiment = _preset("paper001", "seed=0", "budget.n_test=500")
    study = paper001.Study(n_runs=500, figures=False)
    tuned = experiment.detector.with_params(**base.recorded_designs("paper001")["tuned"])
    metrics = study.metrics(study.compute(experiment, {"tuned": tuned}))
    verdicts = {name: met for name, met, _ in paper001.bars(metrics)}
    # sensor 1 against sensor 2 on the amplitude is inside its own CI at 500 runs: not resolved (issue 30)
    assert verdicts.pop("amplitude RMSE: sensor 1 < 2 < 3") is None
    assert all(verdicts.values()), verdicts


@pytest.mark.slow
def test_paper003_multi_step_window_detects_sooner_only_on_the_observer_residual(tmp_path):
    """Reading 2 shows the paper's window effect, reading 1 does not; FAR stays within 2α (about 1 min).

    Issue 20's definitions: a detection is a run of 3 alarms from the onset, which N = 1 rarely makes
    with the paper's lagged threshold (never at full scale), so the window effect is read off the
    flights detected and the post-onset points alarmed.
    """
    import torch  # noqa: F401  (a test dependency: a missing one fails, never skips)
    experiment = _preset("paper003", "seed=0", f"estimator.cache_dir='{tmp_path}'")
    study = paper003.Study(windows=[1, 8], rates=[0.2, 0.5], n_runs=10, trace_rate=0.2, figures=False)
    paper = base.recorded_designs("paper003")["paper"]
    data = study.compute(experiment, {"paper": experiment.detector.with_params(**paper)})
    observer = study.summary(data, "paper", "observer_chi2")
    innovation = study.summary(data, "paper", "chi2")
    assert observer["best_window"] == 8
    assert observer["run_detection_share_best"] >= observer["run_detection_share_n1"] + 0.3
    assert observer["detection_rate_best"] > observer["detection_rate_n1"] + 0.1
    assert observer["far"] <= 2 * paper["alpha"]
    assert observer["chance_detection_share"] == 0.0  # no fault-free flight makes a detection
    # the filter's innovation does not gain from the observer's window: it only raises the threshold
    i1, i8 = data["windows"].index(1), data["windows"].index(8)
    rate = data["table"]["paper"]["chi2"]["detection_rate"].mean(axis=1)
    assert rate[i8] <= rate[i1] + 0.02 and innovation["far"] <= 2 * paper["alpha"]


def test_the_wheel_ships_every_systems_package_and_designs_file():
    """setup.py finds each package under mosd/systems and the package data covers every designs file."""
    import fnmatch
    import importlib.util
    import tomllib
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    tool = tomllib.loads((root / "pyproject.toml").read_text())["tool"]["setuptools"]
    spec = importlib.util.spec_from_file_location("mosd_setup", root / "setup.py")
    setup_module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(setup_module)
    systems = root / "mosd" / "systems"
    packages = {".".join(p.parent.relative_to(root).parts) for p in systems.rglob("__init__.py")}
    assert packages <= set(setup_module.packages()), packages - set(setup_module.packages())
    patterns = tool["package-data"]["mosd.systems"]
    designs = sorted(p.relative_to(systems).as_posix() for p in (systems / "designs").glob("*"))
    assert designs and all(any(fnmatch.fnmatch(d, pat) for pat in patterns) for d in designs), designs
    # one designs file per system: each names a module or package of mosd/systems
    modules = {p.stem for p in systems.glob("*.py")} | {p.parent.name for p in systems.glob("*/__init__.py")}
    assert {Path(d).stem for d in designs} <= modules and "paper000" in {Path(d).stem for d in designs}


def test_paper001_report_command_writes_the_recorded_designs_study(tmp_path, capsys):
    import json

    assert paper001.main(["--n-runs", "20", "--seed", "3", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "### Scientific bars, tuned design" in out and "### Scientific bars, paper design" in out
    record = json.loads((tmp_path / "paper001_study.json").read_text())
    assert record["designs"] == {name: {k: float(v) for k, v in d.items()}
                                 for name, d in base.recorded_designs("paper001").items()}
    assert (record["n_runs"], record["seed"]) == (20, 3)
    assert record["metrics"]["paper_far"] >= record["metrics"]["far"]  # μ_T 0.5 < the tuned 0.83: more alarms
    assert len(list(tmp_path.glob("paper001_*.png"))) == 5  # Figs. 2-5 and the calibration curve
