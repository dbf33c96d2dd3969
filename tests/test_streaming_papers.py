"""Papers 001–003 deploy from their raw inputs (issue 28): each estimator's causal form reproduces its batch.

* paper 002's gain filters (their :class:`~mosd.estimators.step.EstimatorStage`): the raw output with NaN
  gaps in, every missing-value fill the batch has (``hold``, ``skip``; an ``em`` design refuses a gap);
* paper 001's asynchronous IMM (its :class:`~mosd.estimators.step.EstimatorStage`): raw packets per fusion row,
  lost packets absent, slots in any order (out-of-order arrival), a late packet counted and not fused;
* paper 003's neural observer (:class:`~mosd.estimators.neural_observer.ObserverStep`'s stage): the flight log with
  gaps in, the trained network run in NumPy from its saved weight arrays.

For each: the raw stream in one call, row by row and in arbitrary chunks (and after a save/load) gives the
batch estimate's outputs (to 1e-10; bit-identical across chunkings), and the whole pipeline (estimator →
monitor → detector) gives the batch detector's decisions on every row. The slow tests run each preset with
``debug=tiny``: its model takes the raw stream and ``mosd monitor`` reproduces the run's ``alarm`` column.
"""
from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from mosd import kernels
from mosd.detectors.adaptive_chi2 import AdaptiveChi2Detector
from mosd.detectors.mode_probability import ModeProbabilityDetector
from mosd.detectors.threshold import ThresholdDetector
from mosd.monitors.outputs import OutputMonitor
from mosd.scenario import Scenario
from mosd.streaming import OnlinePipeline, describe
from mosd.validation import ConfigError

CHUNKINGS = (1, 2, 5, 13)


def _same(a, b):
    a, b = np.asarray(a), np.asarray(b)
    return np.array_equal(a, b, equal_nan=a.dtype.kind == "f")


def _close(a, b, tol=1e-10):
    a, b = np.asarray(a, float), np.asarray(b, float)
    assert np.array_equal(np.isnan(a), np.isnan(b))
    assert np.nanmax(np.abs(a - b), initial=0.0) <= tol * max(1.0, np.nanmax(np.abs(b), initial=0.0))


def check_chunks(pipeline: OnlinePipeline, columns: dict, tmp_path, seed: int = 0, sizes=CHUNKINGS) -> dict:
    """One call == row by row == chunks of 2, 5, 13 (``sizes``) == random chunks == after save/load; the one
    call's output."""
    whole = pipeline.update(columns)
    rows = len(next(iter(columns.values())))
    loaded = OnlinePipeline.load(pipeline.save(tmp_path / "model"))
    cuts = np.sort(np.random.default_rng(seed).choice(np.arange(1, rows), size=min(6, rows - 1), replace=False))
    chunkings = [list(range(0, rows, size)) for size in sizes] + [[0, *cuts.tolist()]]
    for starts in chunkings:
        for model in (pipeline, loaded):
            state, parts = None, []
            for start, stop in zip(starts, [*starts[1:], rows]):
                out = model.update({k: v[start:stop] for k, v in columns.items()}, state)
                state = model.final_state(out, state)
                parts.append(out)
            for key in pipeline.outputs:
                assert _same(np.concatenate([p[key] for p in parts]), whole[key]), (key, starts[:3])
    return whole


def _pipeline(estimator, trace, model, plant, noise, monitor, detector, batch, calibration_z):
    """estimator → monitor → detector on the raw stream of ``trace``'s first replication."""
    source = {"plant": describe(plant), "noise": describe(noise), "input_names": tuple(plant.input_names)}
    stage = estimator.online(model, source, trace)
    columns = monitor.stream(batch, estimator.residual_columns(batch))
    stages = [stage, monitor.online(tuple(columns)), detector.online(calibration_z, tuple(columns))]
    return OnlinePipeline(stages), estimator.raw_stream(trace, model, tuple(plant.input_names))


def _expected_decisions(monitor, detector, batch, calibration_z):
    """The batch detector's decision on every row of replication 0 (0 in the monitor's burn-in)."""
    decided = detector.decide(calibration_z, monitor.transform(batch).z).decision[0]
    return np.concatenate([np.zeros(monitor.burn_in, decided.dtype), decided])


# -- paper 002 ---------------------------------------------------------------------------------------
def _paper002(missing_rate=0.2, seed=3):
    from mosd.faults.random_amplitude import RandomAmplitudeFault
    from mosd.noise.bounded import BoundedNoise
    from mosd.plants.scalar_nonlinear import ScalarNonlinearPlant

    plant, noise = ScalarNonlinearPlant(missing_rate=missing_rate), BoundedNoise()
    trace = Scenario(plant, noise, RandomAmplitudeFault("sine", role="target"), 10.0).simulate(seed, 3, "test")
    return plant, noise, plant.model(noise), trace


@pytest.mark.parametrize("kind, missing", [("fixed", "hold"), ("fixed", "skip"), ("entropy", "hold"),
                                           ("entropy", "skip")])
def test_paper002_raw_stream_with_gaps_reproduces_the_batch(tmp_path, kind, missing):
    from mosd.estimators.entropy_filter import EntropyIsolationFilter, FixedGainFilter

    plant, noise, model, trace = _paper002()
    assert 5 < np.isnan(trace.y[0]).sum() < 50                     # gaps in the stream
    if kind == "fixed":
        estimator = FixedGainFilter(gain=0.3, missing=missing)
    else:
        estimator = EntropyIsolationFilter(n_particles=50, missing=missing)
        estimator.fit(trace, model, np.random.default_rng(0))
    batch = estimator.estimate(trace, model)
    monitor = OutputMonitor(outputs=["error"], burn_in=4)
    detector = ThresholdDetector(threshold=0.35, persistence=2)
    calibration_z = monitor.transform(batch).z
    pipeline, columns = _pipeline(estimator, trace, model, plant, noise, monitor, detector, batch, calibration_z)
    assert pipeline.inputs == ("y_y", "x_true") and np.isnan(columns["y_y"]).any()
    stage = pipeline.stages[0]
    alone = OnlinePipeline([stage])
    whole = check_chunks(alone, columns, tmp_path)
    _close(whole["residual_y"], batch.r[0, :, 0])
    for name in ("error", "x_hat", "gain", "y_filled", "innovation"):
        _close(whole[name], batch.extra[name][0])
    expected = _expected_decisions(monitor, detector, batch, calibration_z)
    scored = check_chunks(pipeline, columns, tmp_path / "pipeline", sizes=(1,))
    assert np.array_equal(scored["decision"], expected)
    assert 0 < (expected > 0).sum() < expected.size                       # alarms and quiet rows both


def test_paper002_em_design_streams_complete_outputs_and_refuses_a_gap():
    from mosd.estimators.entropy_filter import FixedGainFilter

    plant, noise, model, trace = _paper002(missing_rate=0.0)
    estimator = FixedGainFilter(gain=0.3, missing="em")
    source = {"plant": describe(plant), "noise": describe(noise)}
    pipeline = OnlinePipeline([estimator.online(model, source, trace)])
    columns = estimator.raw_stream(trace, model, ())
    batch = estimator.estimate(trace, model)
    out = pipeline.update(columns)
    _close(out["error"], batch.extra["error"][0])          # no gap: EM's fill is the identity, as in the batch
    columns["y_y"] = columns["y_y"].copy()
    columns["y_y"][17] = np.nan
    with pytest.raises(ConfigError, match=r"^input column 'y_y' row 17 is missing: .*allowed: no gap, or a design "
                                          r"with estimator.missing=hold or skip$"):
        pipeline.update(columns)


def test_paper002_em_design_on_gappy_data_has_no_raw_model_and_says_why():
    """The run deploys from the filter's outputs instead (mosd.app.deploy), never a model that refuses its data."""
    from mosd.estimators.entropy_filter import FixedGainFilter
    from mosd.streaming import NoStreamingForm

    plant, noise, model, trace = _paper002(missing_rate=0.1)
    source = {"plant": describe(plant), "noise": describe(noise)}
    with pytest.raises(NoStreamingForm, match=r"^the EM fill of missing outputs \(estimator.missing=em\) .*not causal"):
        FixedGainFilter(missing="em").online(model, source, trace)
    assert FixedGainFilter(missing="hold").online(model, source, trace).design["missing"] == "hold"


def test_paper002_stream_past_the_designed_schedule_is_one_line():
    from mosd.estimators.entropy_filter import EntropyIsolationFilter

    plant, noise, model, trace = _paper002()
    estimator = EntropyIsolationFilter(n_particles=50, missing="skip").fit(trace, model, np.random.default_rng(0))
    pipeline = OnlinePipeline([estimator.online(model, {"plant": describe(plant), "noise": describe(noise)}, trace)])
    columns = estimator.raw_stream(trace, model, ())
    out = pipeline.update(columns)
    with pytest.raises(ConfigError, match=r"longer than the designed gain schedule \(100 rows"):
        pipeline.update({k: v[:1] for k, v in columns.items()}, pipeline.final_state(out))


# -- paper 001 ---------------------------------------------------------------------------------------
def _paper001(seed=4, n_reps=3):
    from mosd.faults.actuator import ActuatorFault
    from mosd.noise.continuous import ContinuousWhiteNoise
    from mosd.plants.networked_target import NetworkedTarget

    plant, noise = NetworkedTarget(), ContinuousWhiteNoise()
    trace = Scenario(plant, noise, ActuatorFault(), 41.0).simulate(seed, n_reps, "test")
    return plant, noise, plant.model(noise), trace


PAPER001_TRANSITION = [[0.975, 0.0125, 0.0125], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]


@pytest.mark.parametrize("fusion", ["equivalent_measurement", "sequential"])
def test_paper001_raw_packets_reproduce_the_batch(tmp_path, fusion):
    from mosd.estimators.async_imm import AsyncIMMFusion

    plant, noise, model, trace = _paper001()
    estimator = AsyncIMMFusion(transition=PAPER001_TRANSITION, fusion=fusion)
    batch = estimator.estimate(trace, model)
    monitor = OutputMonitor(outputs=["mode_probabilities"], burn_in=0)
    detector = ModeProbabilityDetector(mu_T=0.6, persistence=2)
    calibration_z = monitor.transform(batch).z
    pipeline, columns = _pipeline(estimator, trace, model, plant, noise, monitor, detector, batch, calibration_z)
    lost = ~trace.sensors["s1"].arrived[0] & np.isfinite(trace.sensors["s1"].t[0])
    assert lost.any()                                              # packet loss in the stream: absent packets
    alone = OnlinePipeline([pipeline.stages[0]])
    whole = check_chunks(alone, columns, tmp_path)
    mu = np.column_stack([whole[f"mode_probabilities_{m}"] for m in range(3)])
    _close(mu, batch.extra["mode_probabilities"][0])
    _close(np.column_stack([whole[f"x_filt_{i}"] for i in range(2)]), batch.extra["x_filt"][0])
    _close(np.column_stack([whole[f"fault_amplitudes_{m}"] for m in range(2)]), batch.extra["fault_amplitudes"][0])
    assert np.array_equal(whole["n_measurements"], batch.extra["n_measurements"][0])
    assert not whole["late_packets"].any()
    expected = _expected_decisions(monitor, detector, batch, calibration_z)
    scored = check_chunks(pipeline, columns, tmp_path / "pipeline", sizes=(1,))
    assert np.array_equal(scored["decision"], expected) and 0 < (expected > 0).sum() < expected.size
    # the NumPy reference (kernels off) is the same loop for the batch and the stream
    with kernels.disabled():
        reference = estimator.estimate(trace, model)
        _close(np.column_stack([alone.update(columns)[f"mode_probabilities_{m}"] for m in range(3)]),
               reference.extra["mode_probabilities"][0])


def test_paper001_out_of_order_and_late_packets_are_fused_as_the_batch_would():
    from mosd.estimators.async_imm import AsyncIMMFusion

    plant, noise, model, trace = _paper001(n_reps=1)
    estimator = AsyncIMMFusion(transition=PAPER001_TRANSITION)
    source = {"plant": describe(plant), "noise": describe(noise)}
    stage = estimator.online(model, source, trace)
    slots = int(stage.fitted["slots"])              # packet slots per row
    pipeline = OnlinePipeline([stage])
    columns = estimator.raw_stream(trace, model, ())
    ordered = pipeline.update(columns)
    # out-of-order arrival: each row's packets in a shuffled slot order
    rng = np.random.default_rng(7)
    shuffled = {k: v.copy() for k, v in columns.items()}
    fields = ["sensor", "time", "y0", "y1"]
    for row in range(len(columns["packet0_time"])):
        order = rng.permutation(slots)
        for field in fields:
            values = np.array([columns[f"packet{j}_{field}"][row] for j in range(slots)])
            for j, source_slot in enumerate(order):
                shuffled[f"packet{j}_{field}"][row] = values[source_slot]
    assert not _same(shuffled["packet0_time"], columns["packet0_time"])
    out = pipeline.update(shuffled)
    assert all(_same(out[k], ordered[k]) for k in pipeline.outputs)
    # a packet that arrives one fusion interval late: counted, not fused; the batch with that packet lost
    row = 20
    slot = int(np.flatnonzero([np.isfinite(columns[f"packet{j}_time"][row]) for j in range(slots)])[0])
    sensor, tau = int(columns[f"packet{slot}_sensor"][row]), columns[f"packet{slot}_time"][row]
    late = {k: v.copy() for k, v in columns.items()}
    free = int(np.flatnonzero([np.isnan(late[f"packet{j}_time"][row + 1]) for j in range(slots)])[0])
    for field in fields:
        late[f"packet{free}_{field}"][row + 1] = late[f"packet{slot}_{field}"][row]
        late[f"packet{slot}_{field}"][row] = np.nan
    name = model.sensor_names[sensor]
    index = int(np.flatnonzero(np.isclose(trace.sensors[name].t[0], tau))[0])
    arrived = trace.sensors[name].arrived.copy()
    arrived[0, index] = False
    lossy = dataclasses.replace(trace, sensors={**trace.sensors, name: dataclasses.replace(trace.sensors[name],
                                                                                           arrived=arrived)})
    batch = estimator.estimate(lossy, model)
    out = pipeline.update(late)
    assert out["late_packets"][row + 1] == 1 and out["late_packets"].sum() == 1
    _close(np.column_stack([out[f"mode_probabilities_{m}"] for m in range(3)]),
           batch.extra["mode_probabilities"][0])
    # a packet sampled after its row's fusion instant is refused in one line
    future = {k: v.copy() for k, v in columns.items()}
    future[f"packet{slot}_time"][row] = row + 0.5
    with pytest.raises(ConfigError, match=rf"^input column 'packet{slot}_time' row {row} is 20.5, after the row's "
                                          r"fusion instant 20.0"):
        pipeline.update(future)


# -- paper 003 ---------------------------------------------------------------------------------------
def test_paper003_flight_log_with_gaps_reproduces_the_batch_without_torch_at_serving(tmp_path):
    from mosd.estimators.neural_observer import MultiStepNeuralObserver
    from mosd.estimators.step import EstimatorStage
    from mosd.faults.ramp import RampFault
    from mosd.noise.gaussian import GaussianNoise
    from mosd.plants.flapping_wing import FlappingWingMAV

    plant = FlappingWingMAV()
    noise = GaussianNoise(process_cov=0.0, measurement_cov=[0.0025, 0.0025, 2.5e-5, 1.0e-6, 1.0e-6], n_x=6, n_y=5)
    model = plant.model(noise)
    training = Scenario(plant, noise, None, 30.0).simulate(1, 2, "estimator")
    trace = Scenario(plant, noise, RampFault(rate=1.0, onset=15.0), 30.0).simulate(1, 1, "test")
    y = trace.y.copy()
    y[0, 40, 0] = y[0, 41, 1] = y[0, 100, 2] = np.nan             # gaps in the log
    trace = dataclasses.replace(trace, y=y)
    estimator = MultiStepNeuralObserver(window=3, epochs=3, cache_dir=None, progress=False)
    estimator.fit(training, model, np.random.default_rng(0))
    batch = estimator.estimate(trace, model)
    monitor = OutputMonitor(outputs=["observer_chi2", "observer_residual_scaled"], burn_in=3)
    detector = AdaptiveChi2Detector(alpha=0.05, a=1.0, b=0.5, lag=1, persistence=2)
    calibration_z = monitor.transform(batch).z
    pipeline, columns = _pipeline(estimator, trace, model, plant, noise, monitor, detector, batch, calibration_z)
    assert isinstance(pipeline.stages[0], EstimatorStage)
    assert pipeline.stages[0].estimator == "mosd.estimators.neural_observer.ObserverStep"
    assert pipeline.inputs == tuple(f"y_{n}" for n in plant.output_names)
    saved = pipeline.save(tmp_path / "saved")
    with np.load(saved, allow_pickle=False) as arrays:               # the network travels as weight arrays
        assert {f"s0.fitted.{k}" for k in ("w1", "b1", "w2", "b2", "w3", "b3")} <= set(arrays.files)
    whole = check_chunks(OnlinePipeline([pipeline.stages[0]]), columns, tmp_path)
    _close(whole["residual_gps_altitude"], batch.r[0, :, 0])
    for name in ("chi2", "observer_residual", "observer_residual_scaled", "observer_chi2", "h_hat", "h_filtered"):
        _close(whole[name], batch.extra[name][0])
    expected = _expected_decisions(monitor, detector, batch, calibration_z)
    scored = check_chunks(pipeline, columns, tmp_path / "pipeline", sizes=(1,))
    assert np.array_equal(scored["decision"], expected) and 0 < (expected > 0).sum() < expected.size


def test_paper003_model_is_served_without_torch(tmp_path):
    """The saved observer loads and scores in a process where ``import torch`` fails."""
    import subprocess
    import sys
    from pathlib import Path

    from mosd.estimators.neural_observer import ObserverStep, observer_outputs

    window, channels, width = 2, ("a", "b", "c"), 4
    rng = np.random.default_rng(1)
    weights = {"w1": rng.normal(size=(window, 3, width)), "b1": rng.normal(size=(window, width)),
               "w2": rng.normal(size=(window, width, width)), "b2": rng.normal(size=(window, width)),
               "w3": rng.normal(size=(window, width, 1)), "b3": rng.normal(size=(window, 1)),
               "input_mean": np.zeros(3), "input_std": np.ones(3), "step_mean": np.array(0.0),
               "step_std": np.array(1.0)}
    fitted = {**weights, "residual_mean": np.array(0.0), "residual_std": np.array(1.0), "dt": np.array(0.2),
              "q": np.array(0.01), "r_var": np.array(0.01)}
    stage = ObserverStep(window=window, altitude_channel=0).stage(None, None, tuple(f"y_{n}" for n in channels),
                                                                  observer_outputs(channels, 0), fitted=fitted)
    pipeline = OnlinePipeline([stage])
    columns = {f"y_{n}": rng.normal(size=20) for n in channels}
    expected = pipeline.update(columns)["h_hat"]
    model = pipeline.save(tmp_path / "model")
    code = ("import sys; sys.modules['torch'] = None\n"
            "import numpy as np; from mosd.streaming import OnlinePipeline\n"
            f"p = OnlinePipeline.load({str(model)!r})\n"
            f"cols = dict(np.load({str(tmp_path / 'cols.npz')!r}))\n"
            "np.save(sys.argv[1], p.update(cols)['h_hat'])\n")
    np.savez(tmp_path / "cols.npz", **columns)
    root = Path(__file__).resolve().parents[1]
    run = subprocess.run([sys.executable, "-c", code, str(tmp_path / "out.npy")], capture_output=True, text=True,
                         cwd=root, env={"PYTHONPATH": str(root), "PATH": ""}, timeout=120)
    assert run.returncode == 0, run.stderr[-2000:]
    # without torch the observer's layers run in NumPy, with it in torch: two code paths (issue 50), so equal
    # within 1e-10 relative (a three-layer network of width 4: a few hundred flops a row), not bit for bit
    _close(np.load(tmp_path / "out.npy"), expected)
    assert np.isfinite(expected[window:]).all()


# -- the presets, end to end -------------------------------------------------------------------------
RAW_INPUTS = {"paper001": "packet0_time", "paper002": "y_y", "paper003": "y_gps_altitude"}


@pytest.mark.slow
@pytest.mark.parametrize("preset", list(RAW_INPUTS))
def test_preset_model_takes_the_raw_stream_and_reproduces_the_run(tmp_path, preset):
    import pandas as pd

    from test_detector_model import _mosd

    outputs = tmp_path / "out"
    run = _mosd([f"+experiment={preset}", "debug=tiny", "progress=false", "study=null"], tmp_path, outputs)
    assert run.returncode == 0, run.stderr[-3000:]
    run_dir = next((outputs / "runs").glob("*"))
    summary = json.loads((run_dir / "summary.json").read_text())
    uri = summary["model"]
    assert uri and uri.startswith("models:/"), summary.get("deployment")
    assert "input" not in summary["deployment"], summary["deployment"]     # not the estimator's outputs: raw
    stream = pd.read_parquet(run_dir / "test_stream.parquet")
    assert RAW_INPUTS[preset] in stream.columns
    out = tmp_path / "scored.csv"
    scored = _mosd(["monitor", "--model", uri, str(run_dir / "test_stream.parquet"), "--out", str(out),
                    "--tracking-uri", f"sqlite:///{outputs / 'mlflow.db'}", "--chunk", "7"], tmp_path, outputs)
    assert scored.returncode == 0, scored.stderr[-2000:]
    assert f"the run's own alarms: {len(stream)} of {len(stream)} rows agree" in scored.stdout
    assert np.array_equal(pd.read_csv(out)["alarm"].to_numpy(bool), stream["alarm"].to_numpy(bool))
