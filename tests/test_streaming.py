"""The causal streaming contract (issue 28, :mod:`mosd.streaming`).

* every stage's causal form gives bit-identical outputs and states in one call, in chunks of any size and
  row by row, and after a save/load round trip;
* each one decides exactly what its detector's population decides (the tuning's and the test evaluation's
  arithmetic);
* state params are checked against their declared domains (a one-line error naming the param);
* the pieces of arithmetic exist once: ``ewma()`` is the population's recursion, the kernels import no component;
* a detector written as one module with ``online`` is deployed by :mod:`mosd.app.deploy` with no app change.
"""
from __future__ import annotations

import ast
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from mosd.detectors.adaptive_chi2 import AdaptiveChi2Detector
from mosd.detectors.mode_probability import ModeProbabilityDetector
from mosd.detectors.pca import PCADetector
from mosd.detectors.threshold import ThresholdDetector
from mosd.monitors.outputs import OutputMonitor
from mosd.streaming import OnlinePipeline
from mosd.types import Residuals
from mosd.validation import ConfigError

PACKAGE = Path(__file__).resolve().parents[1] / "mosd"


def _outputs(extra, r=None):
    first = next(iter(extra.values())) if extra else r
    return Residuals(r=np.zeros(first.shape[:2] + (0,)) if r is None else r, fault_mask=np.zeros(first.shape[:2], bool),
                     channels=(), extra=extra)


def _same(a, b):
    a, b = np.asarray(a), np.asarray(b)
    return np.array_equal(a, b, equal_nan=a.dtype.kind == "f")


def check_chunks(pipeline: OnlinePipeline, columns: dict) -> dict:
    """One call == chunks of 1, 2, 5 and 13 rows == after save/load; returns the one call's output."""
    whole = pipeline.update(columns)
    rows = len(next(iter(columns.values())))
    for size in (1, 2, 5, 13):
        state, parts = None, []
        for start in range(0, rows, size):
            out = pipeline.update({k: v[start:start + size] for k, v in columns.items()}, state)
            state = pipeline.final_state(out, state)
            parts.append(out)
        for key in pipeline.outputs:
            assert _same(np.concatenate([p[key] for p in parts]), whole[key]), (key, size)
    return whole


def _pipeline(monitor, detector, outputs, calibration_z):
    columns = monitor.stream(outputs)
    return OnlinePipeline([monitor.online(tuple(columns)), detector.online(calibration_z, tuple(columns))]), columns


@pytest.mark.parametrize("burn_in", [0, 7])
def test_threshold_detector_stream_equals_its_population(burn_in):
    rng = np.random.default_rng(1)
    error = np.abs(rng.standard_normal((1, 300)))
    error[:, 150:] += 1.0
    outputs = _outputs({"error": error})
    monitor = OutputMonitor(outputs=["error"], burn_in=burn_in)
    detector = ThresholdDetector(threshold=1.2, persistence=3)
    z = monitor.transform(outputs).z
    expected = detector.decide(z, z).decision[0]
    pipeline, columns = _pipeline(monitor, detector, outputs, z)
    whole = check_chunks(pipeline, columns)
    assert np.array_equal(whole["decision"][burn_in:], expected) and not whole["decision"][:burn_in].any()
    assert 0 < expected.sum() < expected.size


def test_mode_probability_detector_stream_equals_its_population():
    rng = np.random.default_rng(2)
    mu = rng.dirichlet([5.0, 1.0, 1.0], size=(1, 400))
    mu[0, 200:260] = [0.1, 0.8, 0.1]
    mu[0, 300:340] = [0.1, 0.1, 0.8]
    outputs = _outputs({"mode_probabilities": mu})
    monitor = OutputMonitor(outputs=["mode_probabilities"], burn_in=3)
    detector = ModeProbabilityDetector(mu_T=0.5, persistence=4, labels=[2, 1])
    z = monitor.transform(outputs).z
    expected = detector.decide(z, z).decision[0]
    pipeline, columns = _pipeline(monitor, detector, outputs, z)
    assert tuple(columns) == ("mode_probabilities_0", "mode_probabilities_1", "mode_probabilities_2")
    whole = check_chunks(pipeline, columns)
    assert np.array_equal(whole["decision"][3:], expected)
    assert set(np.unique(expected)) == {0, 1, 2}       # both faults declared somewhere, with their labels


@pytest.mark.parametrize("b, lag", [(1.0, 1), (0.0, 1), (2.0, 3), (0.5, 0)])
def test_adaptive_chi2_detector_stream_equals_its_population(b, lag):
    rng = np.random.default_rng(3)
    chi2 = rng.chisquare(1, size=(1, 500))
    chi2[:, 300:] *= 6.0
    observer = rng.standard_normal((1, 500))
    observer[:, 10:14] = np.nan                       # no prediction yet somewhere: NaN points never alarm
    outputs = _outputs({"chi2": chi2, "observer_residual_scaled": observer})
    monitor = OutputMonitor(outputs=["chi2", "observer_residual_scaled"], burn_in=5)
    detector = AdaptiveChi2Detector(alpha=0.05, a=1.0, b=b, lag=lag, persistence=2)
    z = monitor.transform(outputs).z
    decided = detector.decide(z, z)
    pipeline, columns = _pipeline(monitor, detector, outputs, z)
    whole = check_chunks(pipeline, columns)
    assert np.array_equal(whole["decision"][5:], decided.decision[0])
    # exact: the stream and the population run the same scan (a χ² quantile per design, b·E², a sum: elementwise
    # IEEE operations that round alike in any shape), so the same limits and decisions
    assert np.array_equal(whole["limit"][5:], np.broadcast_to(decided.threshold, decided.statistic.shape)[0],
                          equal_nan=True)
    assert 0 < decided.decision.sum() < decided.decision.size


def test_pca_stream_with_missing_rows_equals_its_population():
    rng = np.random.default_rng(4)
    X = rng.normal(size=(700, 2)) @ rng.normal(size=(2, 5)) + 0.3 * rng.normal(size=(700, 5))
    X[550:, 1] += 1.2
    X[520, 3] = np.nan                                  # a missing value: no scores, no alarm on that row
    monitor = OutputMonitor(outputs=["residual"])
    calibration = X[None, :400]
    detector = PCADetector(n_components=2, alpha=0.02, lam=0.4, persistence=2, fit_runs=None, max_components=4)
    expected = detector.decide(calibration, X[None, 400:]).decision[0]
    columns = monitor.stream(Residuals(r=X[None, 400:], fault_mask=np.zeros((1, 300), bool), channels=tuple("abcde")),
                             tuple("abcde"))
    pipeline = OnlinePipeline([monitor.online(tuple(columns)), detector.online(calibration, tuple(columns))])
    whole = check_chunks(pipeline, columns)
    assert np.array_equal(whole["alarm"], expected.astype(bool))
    assert not whole["alarm"][120] and np.isnan(whole["t2"][120])
    assert 0 < expected.sum() < expected.size


def test_save_and_load_keep_every_output(tmp_path):
    rng = np.random.default_rng(5)
    outputs = _outputs({"chi2": rng.chisquare(1, size=(1, 80)), "observer_residual_scaled": rng.normal(size=(1, 80))})
    monitor = OutputMonitor(outputs=["chi2", "observer_residual_scaled"], burn_in=2)
    z = monitor.transform(outputs).z
    pipeline, columns = _pipeline(monitor, AdaptiveChi2Detector(lag=2), outputs, z)
    loaded = OnlinePipeline.load(pipeline.save(tmp_path / "model"))
    assert [type(s) for s in loaded.stages] == [type(s) for s in pipeline.stages]
    a, b = pipeline.update(columns), loaded.update(columns)
    assert all(_same(a[k], b[k]) for k in pipeline.outputs)
    assert not list((tmp_path / "model").glob(".*"))    # written whole: no temporary file left


def test_state_params_are_checked_against_their_declared_domains():
    outputs = _outputs({"chi2": np.ones((1, 10)), "observer_residual_scaled": np.ones((1, 10))})
    monitor = OutputMonitor(outputs=["chi2", "observer_residual_scaled"])
    pipeline, columns = _pipeline(monitor, AdaptiveChi2Detector(lag=1), outputs, monitor.transform(outputs).z)
    for state, message in (({"run_length": -5}, r"^param run_length=-5 is out of range; allowed: integers in \[0, 2\*\*53\]"),
                           ({"run_length": 2.5}, r"^param run_length=2.5 is not an integer"),
                           ({"observer_1": 1e308}, r"^param observer_1=1e\+308 is out of range"),
                           ({"observer_1": "x"}, r"^param observer_1='x' is not a number"),
                           ({"ewma_t2": 1.0}, r"^param 'ewma_t2' is not a state of the model; allowed: "
                                              r"samples_seen, observer_1, run_length")):
        with pytest.raises(ConfigError, match=message):
            pipeline.update(columns, state)
    # a lagged value not seen yet is the one state that may be null
    out = pipeline.update(columns, {"observer_1": None, "run_length": 1})
    assert out["run_length"][-1] >= 0


def test_ewma_is_the_population_recursion():
    """ewma() of one λ is bit for bit the column of the tuning's population recursion (one arithmetic)."""
    from mosd.detectors.statistics import ewma, ewma_time_major

    x = np.random.default_rng(6).standard_normal((3, 2, 200))
    for order in (1, 2):
        population = ewma_time_major(x, np.array([0.1, 0.37, 0.9]), order=order)      # (K, P, M)
        for p, lam in enumerate((0.1, 0.37, 0.9)):
            assert np.array_equal(ewma(x, lam, order).reshape(-1, 200), population[:, p, :].T)


def test_kernels_import_no_component():
    """The compiled kernels are the bottom layer: they import nothing of mosd but other kernels."""
    for path in sorted((PACKAGE / "kernels").glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.level:
                assert node.level == 1, f"{path.name} imports {'.' * node.level}{node.module}"
            elif isinstance(node, ast.ImportFrom) and (node.module or "").startswith("mosd"):
                assert node.module.startswith("mosd.kernels"), f"{path.name} imports {node.module}"


def test_a_new_detector_in_one_module_is_deployed_without_the_app_knowing_it(tmp_path):
    """A detector the app has never heard of: its ``online`` is all :mod:`mosd.app.deploy` needs."""
    from dataclasses import dataclass

    from mosd.app.deploy import deployable
    from mosd.detectors.base import Decisions, Detector, persistent, run_lengths
    from mosd.streaming import COUNT, FINITE, OnlineStage, StateVar, points_of, spread
    from mosd.validation import Interval, Param

    @dataclass
    class OnlineUpperCusum(OnlineStage):
        k: float
        h: float
        n: int

        inputs = property(lambda self: ("point", "z_1"))
        outputs = property(lambda self: ("statistic", "limit", "decision", "alarm"))

        def state_vars(self):
            return {"cusum": StateVar("S_{k−1}.", FINITE), "run_length": StateVar("Points above h.", COUNT)}

        def initial_state(self):
            return {"cusum": 0.0, "run_length": 0}

        def update(self, columns, state):
            rows, at, z = points_of(columns, 1)
            s, values = float(state["cusum"]), []
            for x in z[:, 0]:
                s = max(0.0, s + x - self.k)
                values.append(s)
            values = np.asarray(values)
            run = run_lengths(values > self.h, int(state["run_length"]))
            return spread(rows, at, {"statistic": values, "limit": np.full(len(at), self.h),
                                     "decision": (run >= 1).astype(np.int64), "alarm": run >= 1, "cusum": values,
                                     "run_length": run}, state)

    class UpperCusum(Detector):
        params = {"k": Param(Interval(0.0, 5.0), "Allowance.", tunable=True),
                  "h": Param(Interval(0.0, 50.0, open_low=True), "Decision interval.", tunable=True)}

        def __init__(self, k=0.5, h=5.0):
            self._assign(locals())

        def population(self, calibration_features, features, X):
            stats = []
            for k, h in np.atleast_2d(X):
                s, out = np.zeros(features.shape[0]), []
                for x in np.moveaxis(features[..., 0], -1, 0):
                    s = np.maximum(0.0, s + x - k)
                    out.append(s)
                stats.append(np.stack(out, axis=-1))
            statistic = np.stack(stats)
            threshold = np.atleast_2d(X)[:, 1].reshape(-1, 1, 1)
            return Decisions(statistic, threshold, persistent(statistic > threshold, 1).astype(np.int8))

        def online(self, calibration_z, inputs=None):
            return OnlineUpperCusum(k=float(self.k), h=float(self.h), n=1)

    rng = np.random.default_rng(7)
    error = rng.standard_normal((2, 200))
    error[:, 120:] += 1.5
    outputs = _outputs({"error": error})
    monitor = OutputMonitor(outputs=["error"])
    detector = UpperCusum(k=0.5, h=4.0)
    z = monitor.transform(outputs).z
    decided = detector.decide(z[:1], z)
    from mosd.experiment import first_replication

    result = SimpleNamespace(detector=detector, example={"calibration_z": z[:1], "first_outputs": first_replication(outputs),
                                                          "decision": decided.decision[0]})
    setup = SimpleNamespace(experiment=SimpleNamespace(estimator=SimpleNamespace(
        online=lambda model: None, residual_columns=lambda outputs: ()), monitor=monitor, model=None))
    found = deployable(setup, result)
    assert found.reason is None and found.pipeline is not None
    assert np.array_equal(found.stream["decision"], decided.decision[0])
    assert np.array_equal(found.pipeline.update({"error": error[0]})["decision"], decided.decision[0])


def test_an_estimator_streams_raw_measurements_and_inputs_as_its_batch_estimate():
    """The two-tank Luenberger observer: y and u in, the batch residuals out, bit for bit, in any chunks."""
    from mosd.estimators.luenberger import LuenbergerObserver
    from mosd.faults.sensor import SensorFault
    from mosd.noise.gaussian import GaussianNoise
    from mosd.plants.two_tank import TwoTank
    from mosd.scenario import Scenario
    from mosd.streaming import describe

    plant = TwoTank()
    noise = GaussianNoise(process_cov=[1e-8, 1e-8], measurement_cov=[1e-6, 1e-6], n_x=2, n_y=2)
    fault = SensorFault(kind="offset", channel=1, a=0.01, onset=60.0)
    trace = Scenario(plant, noise, fault, 200.0).simulate(3, 2, stream="test", fault_scale=1.0)
    model, observer = plant.model(noise), LuenbergerObserver(poles=(0.9, 0.95))
    batch = observer.estimate(trace, model).r
    source = {"plant": describe(plant), "noise": describe(noise), "input_names": plant.input_names}
    first = Scenario(plant, noise, fault, 200.0).simulate(3, 1, stream="test", fault_scale=1.0)
    stage = observer.online(model, source, first)
    pipeline = OnlinePipeline([stage])
    columns = observer.raw_stream(first, model, plant.input_names)
    assert set(columns) == {"y_h1", "y_h2", "u_q"}
    whole = check_chunks(pipeline, columns)
    # exact: the stream and the batch both step observer_step (elementwise operations and sqrt, correctly
    # rounded; the correction summed in a fixed order, no BLAS), one run or three
    assert np.array_equal(np.column_stack([whole["residual_h1"], whole["residual_h2"]]), batch[0])


def test_model_files_written_before_the_pipeline_still_load(tmp_path):
    """Nothing a user logged is lost: an old chart_detector.npz / pca_detector.npz loads as the same stages."""
    import json

    from mosd.app.detector_model import load_fitted
    from mosd.detectors.mean_variance import SSDEWMA
    from mosd.monitors.subgroups import SubgroupMonitor

    rng = np.random.default_rng(8)
    mean, std = np.array([0.3]), np.array([2.0])
    (tmp_path / "chart").mkdir()
    np.savez(tmp_path / "chart" / "chart_detector.npz", meta=np.array(json.dumps(
        {"subgroup": "window", "n": 5, "burn_in": 20, "chart": "SSDEWMA", "lam": 0.25, "K": 1.0, "limit": "phase1",
         "limit_value": 2.5, "fill": "none"})), mean=mean, std=std, columns=np.array(["residual_a"]))
    old = load_fitted(tmp_path / "chart" / "chart_detector.npz")
    monitor = SubgroupMonitor(n=5, burn_in=20)
    monitor.mean_, monitor.std_ = mean, std
    chart = SSDEWMA(lam=0.25, K=1.0).online(rng.standard_normal((2, 50, 5)))
    chart.step["limit"] = 2.5
    new = OnlinePipeline([monitor.online(("residual_a",)), chart])
    stream = {"residual_a": 0.3 + 2.0 * rng.standard_normal(400)}
    a, b = old.update(stream), new.update(stream)
    assert old.state_names == new.state_names and all(_same(a[k], b[k]) for k in new.outputs)

    detector = PCADetector(n_components=2, alpha=0.05, max_components=3)
    X = rng.normal(size=(300, 4))
    pca = detector.online(X[None], tuple("abcd"))
    (tmp_path / "pca").mkdir()
    # the fields the old OnlinePCA wrote, from the generic stage that replaced it
    limits, starts = dict(zip(pca.names, pca.limits)), dict(zip(pca.names, pca.starts))
    meta = {"n_fit": int(pca.fitted["n"]), **{k: pca.design[k] for k in ("n_components", "alpha", "lam", "persistence",
                                                                         "statistic")},
            "t2_limit": limits["t2"], "spe_limit": limits["spe"], "t2_start": starts["t2"], "spe_start": starts["spe"]}
    np.savez(tmp_path / "pca" / "pca_detector.npz", meta=np.array(json.dumps({**meta, "fill": "hold"})),
             **{k: pca.fitted[k] for k in ("mean", "scale", "loadings", "eigenvalues")}, tags=np.array(list("abcd")))
    old = load_fitted(tmp_path / "pca" / "pca_detector.npz")
    assert old.fill == "hold" and old.inputs == tuple("abcd")
    rows = {t: X[:, j] for j, t in enumerate("abcd")}
    # exact: the old file loads as the same generic stage with the same arrays: one code path
    assert np.array_equal(old.update(rows)["ratio"], OnlinePipeline([OutputMonitor().online(tuple("abcd")), pca])
                          .update(rows)["ratio"])
