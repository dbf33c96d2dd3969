"""One step per monitor and per estimator (issue 50): the served stage runs the scan the batch ran.

For every converted monitor (:mod:`mosd.monitors.step`) and estimator (:mod:`mosd.estimators.step`): the
batch form (what the tuning and the test evaluation compute: ``transform``, ``estimate``) and one fitted
stage fed the same run whole, in chunks of random sizes with the state carried between them, and row by
row give the same points and outputs, to a relative 1e-12 (the same elementwise operations on batches of
different shapes; the chunked and row-by-row streams equal the whole stream bit for bit, their state
included). A model saved with a removed ``Online*`` class (the files under ``tests/data/legacy_stages``,
written by those classes before they were removed) loads through ``LEGACY_STAGES`` and scores what the
removed class scored, to the same 1e-12.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from mosd.monitors.outputs import OutputMonitor
from mosd.monitors.step import MonitorStage
from mosd.monitors.subgroups import SubgroupMonitor
from mosd.streaming import OnlinePipeline
from mosd.types import Residuals

#: the batch and the stream are the same elementwise operations on arrays of different shapes
RTOL = 1e-12
LEGACY = Path(__file__).parent / "data" / "legacy_stages"


def stream(stage, columns: dict, cuts) -> dict[str, np.ndarray]:
    """``stage`` over ``columns`` cut at ``cuts``, each part from the state the one before ended with (its
    internal outputs too: a monitor's points)."""
    rows = len(next(iter(columns.values())))
    pipeline = OnlinePipeline([stage])
    state, parts = None, []
    bounds = [0, *cuts, rows]
    for start, stop in zip(bounds[:-1], bounds[1:]):
        part = stage.update({k: v[start:stop] for k, v in columns.items()}, pipeline.check_state(state))
        state = pipeline.final_state({k: part[k] for k in pipeline.state_names}, state)
        parts.append(part)
    return {k: np.concatenate([np.broadcast_to(p[k], (len(p[stage.outputs[0]]),)) for p in parts]) for k in parts[0]}


def three_ways(stage, columns: dict, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """Whole, random chunks and row by row: equal bit for bit (state included); the whole stream's outputs."""
    rows = len(next(iter(columns.values())))
    whole = stream(stage, columns, [])
    chunks = sorted(rng.choice(np.arange(1, rows), size=min(7, rows - 1), replace=False).tolist())
    for cuts in (chunks, list(range(1, rows))):
        got = stream(stage, columns, cuts)
        assert set(got) == set(whole)
        for key in whole:
            assert np.array_equal(got[key], whole[key], equal_nan=True), (key, cuts[:3])
    return whole


def close(got, expected, rtol=RTOL, atol=0.0):
    np.testing.assert_allclose(np.asarray(got, float), np.asarray(expected, float), rtol=rtol, atol=atol, equal_nan=True)


def legacy(name: str):
    """(the pipeline a removed class saved, its input columns, the outputs it scored)."""
    folder = LEGACY / name
    with np.load(folder / "stream.npz") as saved:
        columns = {k[3:]: saved[k] for k in saved.files if k.startswith("in.")}
        expected = {k[4:]: saved[k] for k in saved.files if k.startswith("out.")}
    return OnlinePipeline.load(folder), columns, expected


def check_legacy(name: str, stage_type) -> OnlinePipeline:
    pipeline, columns, expected = legacy(name)
    assert isinstance(pipeline.stages[0], stage_type)
    got = pipeline.update(columns)
    assert set(got) == set(expected)
    for key, values in expected.items():
        if values.dtype.kind in "biu":
            assert np.array_equal(got[key], values), key
        else:
            close(got[key], values)
    return pipeline


# -- monitors ----------------------------------------------------------------------------------------
def _residuals(rng: np.random.Generator, runs: int = 3, rows: int = 57, m: int = 3) -> Residuals:
    r = rng.normal(0.2, 1.5, size=(runs, rows, m))
    mask = np.zeros((runs, rows), bool)
    mask[:, rows // 2:] = True
    extra = {"error": rng.normal(size=(runs, rows)), "mode_probabilities": rng.dirichlet([2, 1, 1], (runs, rows))}
    extra["error"][1, 9] = np.nan   # a missing output passes through a selection
    return Residuals(r=r, fault_mask=mask, channels=("a", "b", "c"), extra=extra, t=np.arange(rows) * 0.5)


MONITORS = {
    "select": lambda: OutputMonitor(outputs=["error", "mode_probabilities"], burn_in=4),
    "select-no-burn-in": lambda: OutputMonitor(outputs=["residual"], burn_in=0),
    "window": lambda: SubgroupMonitor(subgroup="window", n=5, channels=(1,), burn_in=7),
    "window-no-burn-in": lambda: SubgroupMonitor(subgroup="window", n=2, channels=(0,), burn_in=0),
    "channels": lambda: SubgroupMonitor(subgroup="channels", channels=(0, 2), burn_in=3),
}


def _run_columns(monitor, outputs: Residuals, run: int) -> dict[str, np.ndarray]:
    """Run ``run``'s monitored columns, as :meth:`stream` names those of the first run."""
    one = Residuals(r=outputs.r[run:run + 1], fault_mask=outputs.fault_mask[run:run + 1], channels=outputs.channels,
                    extra={k: v[run:run + 1] for k, v in outputs.extra.items()})
    return monitor.stream(one, tuple(f"residual_{c}" for c in outputs.channels))


@pytest.mark.parametrize("name", sorted(MONITORS))
def test_a_monitor_stream_whole_chunked_and_row_by_row_gives_its_batch_points(name):
    rng = np.random.default_rng(11)
    outputs = _residuals(rng)
    monitor = MONITORS[name]()
    if isinstance(monitor, SubgroupMonitor):
        monitor.fit(Residuals(r=rng.normal(0.2, 1.5, (2, 40, 3)), fault_mask=np.zeros((2, 40), bool),
                              channels=outputs.channels))
    batch = monitor.transform(outputs)
    assert batch.z.shape[1] > 3
    columns = _run_columns(monitor, outputs, 0)
    stage = monitor.online(tuple(columns))
    assert isinstance(stage, MonitorStage)
    for run in range(outputs.r.shape[0]):
        whole = three_ways(stage, _run_columns(monitor, outputs, run), rng)
        at = np.flatnonzero(whole["point"] > 0)
        assert np.array_equal(whole["point"][at], np.arange(1, batch.z.shape[1] + 1))
        # a point's row is the one whose fault truth and time the batch gives the point
        assert np.array_equal(outputs.fault_mask[run, at], batch.fault_mask[run])
        assert np.array_equal(outputs.t[at], batch.t)
        z = np.column_stack([whole[f"z_{j}"][at] for j in range(1, batch.z.shape[-1] + 1)])
        close(z, batch.z[run])
        off = np.setdiff1d(np.arange(len(whole["point"])), at)
        assert all(np.isnan(whole[f"z_{j}"][off]).all() for j in range(1, batch.z.shape[-1] + 1))
        if isinstance(monitor, SubgroupMonitor):
            assert np.array_equal(whole["subgroup"], whole["point"])


def test_a_monitor_stage_saves_its_fitted_arrays_as_arrays(tmp_path):
    rng = np.random.default_rng(2)
    monitor = SubgroupMonitor(n=4, burn_in=2).fit(Residuals(r=rng.normal(size=(1, 30, 1)),
                                                            fault_mask=np.zeros((1, 30), bool), channels=("a",)))
    pipeline = OnlinePipeline([monitor.online(("residual_a",))])
    with np.load(pipeline.save(tmp_path)) as saved:
        assert {"s0.fitted.mean", "s0.fitted.std"} <= set(saved.files)
    loaded = OnlinePipeline.load(tmp_path)
    columns = {"residual_a": rng.normal(size=23)}
    a, b = pipeline.update(columns), loaded.update(columns)
    assert loaded.state_names == ("samples_seen", "pending_1", "pending_2", "pending_3")
    assert all(np.array_equal(a[k], b[k], equal_nan=True) for k in pipeline.outputs)


def test_a_subgroup_stage_refuses_a_missing_residual_in_one_line():
    monitor = SubgroupMonitor(n=2, burn_in=0)
    monitor.mean_, monitor.std_ = np.array([0.0]), np.array([1.0])
    pipeline = OnlinePipeline([monitor.online(("residual_a",))])
    import pandas as pd

    from mosd.validation import ConfigError

    with pytest.raises(ConfigError, match=r"^input column 'residual_a' row 1 is .*nan.*, not a finite number; allowed: numbers"):
        pipeline.rows(pd.DataFrame({"residual_a": [0.0, np.nan]}))


@pytest.mark.parametrize("name", ["OnlineSelect", "OnlineSubgroups_window", "OnlineSubgroups_channels"])
def test_a_monitor_saved_with_its_removed_class_loads_and_scores_the_same(name):
    check_legacy(name, MonitorStage)


# -- estimators --------------------------------------------------------------------------------------
def _two_tank():
    from mosd.estimators.luenberger import LuenbergerObserver
    from mosd.faults.sensor import SensorFault
    from mosd.noise.gaussian import GaussianNoise
    from mosd.plants.two_tank import TwoTank
    from mosd.scenario import Scenario

    plant = TwoTank()
    noise = GaussianNoise(process_cov=[1e-8, 1e-8], measurement_cov=[1e-6, 1e-6], n_x=2, n_y=2)
    fault = SensorFault(kind="offset", channel=1, a=0.01, onset=60.0)
    trace = Scenario(plant, noise, fault, 150.0).simulate(3, 3, stream="test", fault_scale=1.0)
    return plant, noise, trace, LuenbergerObserver(poles=(0.9, 0.95))


def _source(plant, noise):
    from mosd.streaming import describe

    return {"plant": describe(plant), "noise": describe(noise), "input_names": tuple(plant.input_names)}


def _plant_run(trace, model, input_names, run: int) -> dict[str, np.ndarray]:
    """Run ``run``'s raw measurements and inputs as a plant stage's columns (``y_<output>``, ``u_<input>``)."""
    columns = {f"y_{n}": np.asarray(trace.y, float)[run, :, j] for j, n in enumerate(model.output_names)}
    columns.update({f"u_{n}": np.asarray(trace.u, float)[run, :, j] for j, n in enumerate(input_names)})
    return columns


def _check_plant_stage(estimator, plant, noise, trace, extras=(), rtol=RTOL, atol=0.0):
    """The batch estimate of every run == its stage fed the run whole, in random chunks and row by row."""
    from mosd.estimators.step import EstimatorStage

    model = plant.model(noise)
    batch = estimator.estimate(trace, model)
    stage = estimator.online(model, _source(plant, noise), trace)
    assert isinstance(stage, EstimatorStage)
    rng = np.random.default_rng(5)
    for run in range(trace.y.shape[0]):
        whole = three_ways(stage, _plant_run(trace, model, plant.input_names, run), rng)
        for j, name in enumerate(model.output_names):
            close(whole[f"residual_{name}"], batch.r[run, :, j], rtol, atol)
        for name in extras:
            close(whole[name], batch.extra[name][run], rtol, atol)
    return batch, stage


def test_the_luenberger_observer_stream_is_its_batch_estimate():
    plant, noise, trace, estimator = _two_tank()
    batch, stage = _check_plant_stage(estimator, plant, noise, trace)
    assert stage.inputs == ("y_h1", "y_h2", "u_q")
    assert tuple(stage.state_vars()) == ("x_hat_0", "x_hat_1")
    # the offset on h2 from 60 s is in the residual: the comparison is of residuals that mean something
    fault = trace.fault_mask[0]
    assert abs(batch.r[0, fault, 1].mean()) > 5 * abs(batch.r[0, ~fault & (np.arange(fault.size) > 20), 1].mean())


def test_a_luenberger_observer_saved_with_its_removed_class_loads_and_scores_the_same():
    from mosd.estimators.step import EstimatorStage

    check_legacy("OnlineLuenberger", EstimatorStage)


def test_the_pca_residual_stream_is_its_batch_estimate():
    from types import SimpleNamespace

    from mosd.estimators.pca import PCAResidual
    from mosd.estimators.step import EstimatorStage

    rng = np.random.default_rng(4)
    mixing = rng.normal(size=(3, 6))
    fit = rng.normal(size=(1, 300, 3)) @ mixing + 0.2 * rng.normal(size=(1, 300, 6))
    estimator = PCAResidual(n_components=3).fit(SimpleNamespace(y=fit, meta={"variables": tuple("abcdef")}))
    Y = rng.normal(size=(3, 80, 3)) @ mixing + 0.2 * rng.normal(size=(3, 80, 6))
    Y[1, 17, 2] = np.nan                  # a missing tag: that row's outputs are NaN, the next rows are not
    Y[2, 40:, 0] += 3.0                   # a shift: T² and SPE move
    trace = SimpleNamespace(y=Y, fault_mask=np.zeros((3, 80), bool), fault_label=None, fault_roles=("target",), t=None)
    batch = estimator.estimate(trace)
    stage = estimator.online()
    assert isinstance(stage, EstimatorStage) and stage.state_vars() == {} and stage.inputs == tuple("abcdef")
    for run in range(3):
        whole = three_ways(stage, {t: Y[run, :, j] for j, t in enumerate("abcdef")}, rng)
        close(np.column_stack([whole[f"residual_{t}"] for t in "abcdef"]), batch.r[run])
        for name in ("t2", "spe"):
            close(whole[name], batch.extra[name][run])
        close(np.column_stack([whole[f"scores_{j}"] for j in range(3)]), batch.extra["scores"][run])
    assert np.isnan(batch.extra["t2"][1, 17]) and np.isfinite(batch.extra["t2"][1, 18])
    assert batch.extra["spe"][2, 40:].mean() > 3 * batch.extra["spe"][2, :40].mean()


def test_a_pca_residual_saved_with_its_removed_class_loads_and_scores_the_same():
    from mosd.estimators.step import EstimatorStage

    check_legacy("OnlinePCAResidual", EstimatorStage)


def _paper002(missing_rate: float):
    from mosd.faults.random_amplitude import RandomAmplitudeFault
    from mosd.noise.bounded import BoundedNoise
    from mosd.plants.scalar_nonlinear import ScalarNonlinearPlant
    from mosd.scenario import Scenario

    plant, noise = ScalarNonlinearPlant(missing_rate=missing_rate), BoundedNoise()
    trace = Scenario(plant, noise, RandomAmplitudeFault("sine", role="target"), 10.0).simulate(3, 3, "test")
    return plant, noise, trace


@pytest.mark.parametrize("kind, missing", [("fixed", "hold"), ("fixed", "skip"), ("fixed", "em"), ("entropy", "hold"),
                                           ("entropy", "skip")])
def test_the_gain_filter_stream_is_its_batch_estimate(kind, missing):
    from mosd.estimators.entropy_filter import EntropyIsolationFilter, FixedGainFilter

    plant, noise, trace = _paper002(0.0 if missing == "em" else 0.2)   # EM streams complete outputs only
    model = plant.model(noise)
    if kind == "fixed":
        estimator = FixedGainFilter(gain=0.3, missing=missing)
    else:
        estimator = EntropyIsolationFilter(n_particles=50, missing=missing).fit(trace, model, np.random.default_rng(0))
    batch = estimator.estimate(trace, model)
    stage = estimator.online(model, _source(plant, noise), trace)
    assert stage.inputs == ("y_y", "x_true")
    rng = np.random.default_rng(6)
    for run in range(3):
        columns = {"y_y": trace.y[run, :, 0], "x_true": trace.x[run, :, 0]}
        assert missing == "em" or np.isnan(columns["y_y"]).any()      # gaps in the stream
        whole = three_ways(stage, columns, rng)
        close(whole["residual_y"], batch.r[run, :, 0])
        for name in ("error", "x_hat", "gain", "y_filled", "innovation"):
            close(whole[name], batch.extra[name][run])
    assert np.isnan(whole["residual_y"]).any() == (missing != "em")


@pytest.mark.parametrize("name", ["OnlineGainFilter_fixed_hold", "OnlineGainFilter_entropy_skip"])
def test_a_gain_filter_saved_with_its_removed_class_loads_and_scores_the_same(name):
    from mosd.estimators.step import EstimatorStage

    check_legacy(name, EstimatorStage)


@pytest.mark.parametrize("path", ["compiled", "numpy"])
@pytest.mark.parametrize("kind", ["dedicated_observer", "innovation"])
def test_the_cubature_filter_residual_stream_is_its_batch_estimate(kind, path):
    """The CESCKF residuals (paper 000's estimator): compiled, the stream is the batch kernel resumed from the
    carried FilterStart (relative 1e-12); on the NumPy path a batch of three runs and a stream of one take
    different BLAS products, 1e-10 of the residuals' scale apart (as tests/test_streaming_cesckf.py)."""
    import contextlib

    from mosd import kernels
    from mosd.estimators.residuals import DedicatedObserverResidual, InnovationResidual
    from mosd.faults.sensor import SensorFault
    from mosd.noise.gaussian import GaussianNoise
    from mosd.plants.mould_oscillator import MouldOscillator
    from mosd.scenario import Scenario

    if path == "compiled" and not kernels.enabled():
        pytest.fail("numba kernels are off: the compiled path is not tested")
    plant, noise = MouldOscillator(), GaussianNoise()
    trace = Scenario(plant, noise, SensorFault(kind="offset", channel=0, a=0.5, onset=0.05), 0.1).simulate(
        3, 3, stream="test", fault_scale=1.0)
    estimator = DedicatedObserverResidual() if kind == "dedicated_observer" else InnovationResidual()
    with kernels.disabled() if path == "numpy" else contextlib.nullcontext():
        scale = np.nanmax(np.abs(estimator.estimate(trace, plant.model(noise)).r))
        batch, stage = _check_plant_stage(estimator, plant, noise, trace,
                                          atol=0.0 if path == "compiled" else 1e-10 * scale)
    assert stage.inputs == ("y_x_p", "y_theta", "y_n", "u_i_q")
    assert len(stage.state_vars()) == 1 + 3 + 6 + 1     # step, x̂, lower root of P, u_{k−1}
    fault = trace.fault_mask[0]
    assert abs(batch.r[0, fault, 0].mean()) > 2 * abs(batch.r[0, ~fault, 0].mean())   # the offset is seen


@pytest.mark.parametrize("name", ["OnlineDedicatedObserver", "OnlineDedicatedObserver_innovation"])
def test_a_cubature_filter_residual_saved_with_its_removed_class_loads_and_scores_the_same(name):
    from mosd.estimators.step import EstimatorStage

    pipeline = check_legacy(name, EstimatorStage)
    expected = "DedicatedObserverResidual" if name == "OnlineDedicatedObserver" else "InnovationResidual"
    assert pipeline.stages[0].estimator == f"mosd.estimators.residuals.{expected}"


@pytest.mark.parametrize("path", ["compiled", "numpy"])
@pytest.mark.parametrize("fusion", ["equivalent_measurement", "sequential"])
def test_the_imm_stream_is_its_batch_estimate(fusion, path):
    """Paper 001's IMM on raw packets, one row per fusion instant: each run's stream is the batch (the time loop
    is the batch's, compiled or NumPy; probabilities and states to 1e-12 relative, 1e-12 absolute near 0)."""
    import contextlib

    from mosd import kernels
    from mosd.estimators.async_imm import AsyncIMMFusion, IntervalMeasurements, packet_columns
    from mosd.estimators.step import EstimatorStage
    from mosd.faults.actuator import ActuatorFault
    from mosd.noise.continuous import ContinuousWhiteNoise
    from mosd.plants.networked_target import NetworkedTarget
    from mosd.scenario import Scenario

    plant, noise = NetworkedTarget(), ContinuousWhiteNoise()
    trace = Scenario(plant, noise, ActuatorFault(), 41.0).simulate(4, 3, "test")
    model = plant.model(noise)
    estimator = AsyncIMMFusion(transition=[[0.975, 0.0125, 0.0125], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], fusion=fusion)
    with kernels.disabled() if path == "numpy" else contextlib.nullcontext():
        batch = estimator.estimate(trace, model)
        stage = estimator.online(model, _source(plant, noise), trace)
        assert isinstance(stage, EstimatorStage)
        grouped = IntervalMeasurements.of(trace, model.sensor_names, np.asarray(trace.t, float))
        rng = np.random.default_rng(8)
        for run in range(3):
            one = IntervalMeasurements(*(np.asarray(a)[run:run + 1] for a in (grouped.t, grouped.y, grouped.sensor,
                                                                                 grouped.valid)))
            columns = packet_columns(one, int(stage.fitted["slots"]), int(stage.fitted["n_y"]))
            whole = three_ways(stage, columns, rng)
            mu = np.column_stack([whole[f"mode_probabilities_{m}"] for m in range(3)])
            close(mu, batch.extra["mode_probabilities"][run], atol=1e-12)
            close(np.column_stack([whole[f"x_filt_{i}"] for i in range(model.n_x)]), batch.extra["x_filt"][run],
                  atol=1e-12)
            close(np.column_stack([whole[f"fault_amplitudes_{m}"] for m in range(2)]),
                  batch.extra["fault_amplitudes"][run], atol=1e-12)
            assert np.array_equal(whole["n_measurements"], batch.extra["n_measurements"][run])
    assert batch.extra["mode_probabilities"][..., 1:].max() > 0.5    # a fault model wins somewhere


def test_an_imm_saved_with_its_removed_class_loads_and_scores_the_same():
    from mosd.estimators.step import EstimatorStage

    check_legacy("OnlineIMM", EstimatorStage)


def test_the_neural_observer_stream_is_its_batch_estimate():
    """Paper 003 (torch trains; the served ObserverStep runs the same rollout and filter step in NumPy): every run
    of a gappy flight log streamed whole, in chunks and row by row gives the batch's outputs. The batch rolls all
    windows out at once and the stream one window a row, so the rollout's products have different batch shapes:
    relative 1e-10."""
    import dataclasses

    pytest.importorskip("torch")
    from mosd.estimators.neural_observer import MultiStepNeuralObserver
    from mosd.estimators.step import EstimatorStage
    from mosd.faults.ramp import RampFault
    from mosd.noise.gaussian import GaussianNoise
    from mosd.plants.flapping_wing import FlappingWingMAV
    from mosd.scenario import Scenario

    plant = FlappingWingMAV()
    noise = GaussianNoise(process_cov=0.0, measurement_cov=[0.0025, 0.0025, 2.5e-5, 1.0e-6, 1.0e-6], n_x=6, n_y=5)
    model = plant.model(noise)
    training = Scenario(plant, noise, None, 30.0).simulate(1, 2, "estimator")
    trace = Scenario(plant, noise, RampFault(rate=1.0, onset=15.0), 30.0).simulate(1, 2, "test")
    y = trace.y.copy()
    y[0, 40, 0] = y[1, 41, 1] = y[0, 100, 2] = np.nan             # gaps in the log
    trace = dataclasses.replace(trace, y=y)
    estimator = MultiStepNeuralObserver(window=3, epochs=3, cache_dir=None, progress=False)
    estimator.fit(training, model, np.random.default_rng(0))
    batch = estimator.estimate(trace, model)
    stage = estimator.online(model, _source(plant, noise), trace)
    assert isinstance(stage, EstimatorStage) and stage.plant is None   # served without the plant: weights only
    rng = np.random.default_rng(9)
    for run in range(2):
        whole = three_ways(stage, {f"y_{n}": y[run, :, j] for j, n in enumerate(model.output_names)}, rng)
        close(whole["residual_gps_altitude"], batch.r[run, :, 0], 1e-10, 1e-12)
        for name in ("chi2", "observer_residual", "observer_residual_scaled", "observer_chi2", "h_hat", "h_filtered"):
            close(whole[name], batch.extra[name][run], 1e-10, 1e-12)
    assert np.isnan(batch.extra["h_hat"][:, :3]).all() and np.isfinite(batch.extra["h_hat"][1, 3:40]).all()


def test_a_neural_observer_saved_with_its_removed_class_loads_and_scores_the_same():
    from mosd.estimators.step import EstimatorStage

    check_legacy("OnlineObserver", EstimatorStage)


def test_files_naming_removed_classes_load_in_a_fresh_process():
    """A process that has imported no monitor or estimator yet loads the saved files of a removed monitor and a
    removed estimator class (the module each names registers what replaced it) and scores what they scored."""
    import subprocess
    import sys

    code = ("import sys, numpy as np; from mosd.streaming import OnlinePipeline as P\n"
            "for name in sys.argv[1:]:\n"
            "    p = P.load(name); s = np.load(name + '/stream.npz')\n"
            "    out = p.update({k[3:]: s[k] for k in s.files if k.startswith('in.')})\n"
            "    ok = all(np.allclose(out[k[4:]], s[k], rtol=1e-12, atol=0, equal_nan=True) for k in s.files\n"
            "             if k.startswith('out.'))\n"
            "    print(type(p.stages[0]).__name__, ok)\n")
    names = [str(LEGACY / n) for n in ("OnlineSubgroups_window", "OnlineLuenberger", "OnlineIMM")]
    done = subprocess.run([sys.executable, "-c", code, *names], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.split() == ["MonitorStage", "True", "EstimatorStage", "True", "EstimatorStage", "True"]


@pytest.mark.parametrize("name", sorted(p.name for p in LEGACY.iterdir() if p.is_dir()))
def test_an_empty_chunk_scores_no_row_and_keeps_the_state(name):
    """An empty request (a poll that found no new row) to any converted stage: no output row, the state unchanged
    (the old IMM stage failed on it)."""
    pipeline, columns, _ = legacy(name)
    state = pipeline.final_state(pipeline.update({k: v[:5] for k, v in columns.items()}))
    out = pipeline.update({k: v[:0] for k, v in columns.items()}, state)
    assert all(len(v) == 0 for v in out.values()) and set(out) == set(pipeline.outputs)
    assert pipeline.final_state(out, state) == pipeline.check_state(state)
