"""The main command's estimator streams raw measurements and inputs (issue 28): the CESCKF dedicated observer.

* the dedicated observer's :class:`~mosd.estimators.step.EstimatorStage` fed the raw ``y_<output>``/``u_<input>`` columns
  gives the batch estimator's residuals (bit for bit with the compiled filter, ~1e-12 on the NumPy path), in
  one call, in chunks of any size and row by row, and after a save/load with its state through JSON;
* the batch filter going on from a :class:`~mosd.estimators.cubature.FilterStart` is the one call's filter;
* a ``debug=tiny`` main command deploys a model whose inputs are those raw columns and whose alarms are the
  run's own on every row, in-process and through ``python -m mosd monitor``.
"""
from __future__ import annotations

import json

import numpy as np
import pytest

from mosd import kernels
from mosd.estimators.cubature import CESCKF, CubatureKalmanFilter, FilterStart
from mosd.estimators.residuals import DedicatedObserverResidual
from mosd.estimators.step import EstimatorStage
from mosd.faults.sensor import SensorFault
from mosd.noise.gaussian import GaussianNoise
from mosd.plants.mould_oscillator import MouldOscillator
from mosd.scenario import Scenario
from mosd.streaming import OnlinePipeline, describe
from mosd.validation import ConfigError

from test_streaming import check_chunks  # one call == chunks of 1, 2, 5, 13 rows

PLANT, NOISE = MouldOscillator(), GaussianNoise()
RAW = ("y_x_p", "y_theta", "y_n", "u_i_q")


def _scenario(duration=0.3):
    fault = SensorFault(kind="offset", channel=0, a=0.5, onset=duration / 2)
    return Scenario(PLANT, NOISE, fault, duration)


def _stage(estimator, first):
    model = PLANT.model(NOISE)
    source = {"plant": describe(PLANT), "noise": describe(NOISE), "input_names": PLANT.input_names}
    return model, estimator.online(model, source, first)


def _residuals(out, model):
    return np.column_stack([out[f"residual_{n}"] for n in model.output_names])


@pytest.mark.parametrize("path,flt", [("compiled", CESCKF()), ("numpy", CESCKF()),
                                      ("compiled", CESCKF(rule="spherical_radial")), ("numpy", CubatureKalmanFilter())],
                         ids=["cesckf-compiled", "cesckf-numpy", "srckf-compiled", "ckf-numpy"])
def test_raw_stream_gives_the_batch_residuals_in_any_chunks(path, flt):
    scenario = _scenario(0.2 if path == "compiled" else 0.12)
    trace = scenario.simulate(3, 3, stream="test", fault_scale=1.0)
    first = scenario.simulate(3, 1, stream="test", fault_scale=1.0)
    estimator = DedicatedObserverResidual(filter=flt)
    if path == "compiled" and not kernels.enabled():
        pytest.fail("numba kernels are off: the compiled path is not tested")
    with kernels.disabled() if path == "numpy" else _nothing():
        model, stage = _stage(estimator, first)
        batch = estimator.estimate(trace, model).r[0]
        pipeline = OnlinePipeline([stage])
        columns = estimator.raw_stream(first, model, PLANT.input_names)
        assert tuple(columns) == RAW and stage.inputs == RAW
        whole = check_chunks(pipeline, columns)   # bit for bit in chunks of 1, 2, 5 and 13 rows
    r = _residuals(whole, model)
    np.testing.assert_allclose(r, batch, rtol=0, atol=1e-10)
    if path == "compiled" and isinstance(flt, CESCKF):
        assert np.array_equal(r, batch)          # the kernel is the one arithmetic: not a rounding apart
    fault_rows = first.fault_mask[0]
    assert abs(r[fault_rows, 0].mean()) > 5 * abs(r[~fault_rows, 0].mean())  # the offset is in the residual


class _nothing:
    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False


def test_the_filter_goes_on_from_a_carried_state_as_one_call():
    """FilterStart after a chunk, fed the next chunk, continues the one call exactly (compiled and NumPy)."""
    model = PLANT.model(NOISE)
    trace = _scenario(0.1).simulate(5, 1, stream="test", fault_scale=1.0)
    y, u = trace.y, trace.u
    y = y.copy()
    y[0, 40, 1] = np.nan   # a missing channel crosses the chunk boundary's prediction
    for context in (_nothing(), kernels.disabled()):
        with context:
            for flt in (CESCKF(), CubatureKalmanFilter()):
                whole = flt.filter(model, y, u)
                head = flt.filter(model, y[:, :41], u[:, :41])
                tail = flt.filter(model, y[:, 41:], u[:, 41:], start=FilterStart.after(head, u[0, 40]))
                for name in ("x_pred", "x_filt", "sqrt_cov_pred", "sqrt_cov_filt", "innovation"):
                    joined = np.concatenate([getattr(head, name), getattr(tail, name)], axis=1)
                    assert np.array_equal(joined, getattr(whole, name), equal_nan=True), (type(flt).__name__, name)


def test_state_survives_save_load_and_json(tmp_path):
    """The pipeline.npz and the state as JSON numbers (MLflow's params): the rest of the stream is unchanged."""
    first = _scenario(0.1).simulate(4, 1, stream="test", fault_scale=1.0)
    estimator = DedicatedObserverResidual()
    model, stage = _stage(estimator, first)
    pipeline = OnlinePipeline([stage])
    columns = estimator.raw_stream(first, model, PLANT.input_names)
    whole = pipeline.update(columns)
    head = pipeline.update({k: v[:37] for k, v in columns.items()})
    state = json.loads(json.dumps(pipeline.final_state(head)))
    assert state["filter_step"] == 37 and len(state) == 1 + 3 + 6 + 1   # step, x̂, lower root of P, u_{k−1}
    loaded = OnlinePipeline.load(pipeline.save(tmp_path))
    assert isinstance(loaded.stages[0], EstimatorStage) and loaded.stages[0].estimator.endswith(".DedicatedObserverResidual")
    tail = loaded.update({k: v[37:] for k, v in columns.items()}, state)
    for key in pipeline.outputs:
        assert np.array_equal(np.concatenate([head[key], tail[key]]), whole[key]), key


def test_bad_state_and_bad_inputs_are_one_line_errors():
    first = _scenario(0.02).simulate(4, 1, stream="test", fault_scale=1.0)
    estimator = DedicatedObserverResidual()
    model, stage = _stage(estimator, first)
    pipeline = OnlinePipeline([stage])
    columns = estimator.raw_stream(first, model, PLANT.input_names)
    with pytest.raises(ConfigError, match=r"param sqrt_cov_filt_1_1=-1\.0 is out of range; allowed: finite numbers "
                                          r"in \[0, 1e\+150\]"):
        pipeline.update(columns, {"filter_step": 3, "sqrt_cov_filt_1_1": -1.0})
    with pytest.raises(ConfigError, match="param filter_step=2.5 is not an integer"):
        pipeline.update(columns, {"filter_step": 2.5})
    columns["u_i_q"] = columns["u_i_q"].copy()
    columns["u_i_q"][3] = np.nan
    with pytest.raises(ConfigError, match="input column 'u_i_q' row 3 is nan"):
        pipeline.update(columns)
    # a missing measurement is the filter's business, as in the batch: no error, the row's residual is NaN
    columns = estimator.raw_stream(first, model, PLANT.input_names)
    columns["y_x_p"] = columns["y_x_p"].copy()
    columns["y_x_p"][5] = np.nan
    out = pipeline.update(columns)
    assert np.isnan(out["residual_x_p"][5]) and np.isfinite(out["residual_x_p"][6:]).all()


def test_a_subclass_that_changes_the_arithmetic_or_lives_outside_mosd_has_no_streaming_form():
    from mosd.streaming import NoStreamingForm

    class Shifted(DedicatedObserverResidual):
        def estimate(self, trace, model):
            return super().estimate(trace, model)

    class OwnFilter(CESCKF):
        def filter(self, model, y, u=None):
            return super().filter(model, y, u)

    first = _scenario(0.02).simulate(4, 1, stream="test", fault_scale=1.0)
    with pytest.raises(NoStreamingForm, match="Shifted has no streaming form"):
        _stage(Shifted(), first)
    with pytest.raises(NoStreamingForm, match="the filter OwnFilter overrides filter()"):
        _stage(DedicatedObserverResidual(filter=OwnFilter()), first)
    # a filter subclass that keeps mosd's arithmetic but lives elsewhere: a saved model would not load it
    with pytest.raises(NoStreamingForm, match=r"the filter test_streaming_cesckf\..*Quiet is not mosd's"):
        _stage(DedicatedObserverResidual(filter=Quiet()), first)
    # the batch estimate still calls a user's filter(model, y, u) as before (no start keyword)
    model = PLANT.model(NOISE)
    assert np.isfinite(DedicatedObserverResidual(filter=OwnFilter()).estimate(first, model).r).all()


class Quiet(CESCKF):
    """A CESCKF subclass outside mosd (module level: describe() names it)."""


@pytest.mark.slow
def test_main_command_deploys_raw_inputs_and_mosd_monitor_reproduces_its_alarms(tmp_path):
    """``python -m mosd +fault=offset_var debug=tiny``: the model starts at the plant's raw columns."""
    import pandas as pd

    from test_deploy_presets import _run
    from test_detector_model import _mosd

    run, run_dir, summary, tracking = _run(tmp_path, ["+fault=offset_var", "optimizer=mopso"])
    assert summary["model"].startswith("models:/"), summary.get("deployment")
    assert "input" not in summary["deployment"]        # no "model input: the estimator's outputs" note
    stream = pd.read_parquet(run_dir / "test_stream.parquet")
    assert list(stream.columns) == ["t", *RAW, "decision", "alarm"] and stream["alarm"].any()
    loaded = OnlinePipeline.load(run_dir / "model")
    assert loaded.inputs == RAW
    # in-process, the saved pipeline in irregular chunks (row by row through the first fault rows)
    columns = {k: stream[k].to_numpy() for k in RAW}
    rows, bounds = len(stream), [0]
    sizes = iter([*([1] * 40), 7, 250, 3, 1000, 61])
    while bounds[-1] < rows:
        bounds.append(min(rows, bounds[-1] + next(sizes, 997)))
    state, alarms = None, []
    for a, b in zip(bounds[:-1], bounds[1:]):
        part = loaded.update({k: v[a:b] for k, v in columns.items()}, state)
        state = json.loads(json.dumps(loaded.final_state(part, state)))
        alarms.append(part["alarm"])
    assert np.array_equal(np.concatenate(alarms), stream["alarm"].to_numpy(bool))
    out = tmp_path / "scored.csv"
    scored = _mosd(["monitor", "--model", summary["model"], str(run_dir / "test_stream.parquet"), "--out", str(out),
                    "--tracking-uri", tracking, "--chunk", "333", "--no-progress"], tmp_path, tmp_path / "out")
    assert scored.returncode == 0, scored.stderr[-2000:]
    assert f"the run's own alarms: {len(stream)} of {len(stream)} rows agree" in scored.stdout
    assert np.array_equal(pd.read_csv(out)["alarm"].to_numpy(bool), stream["alarm"].to_numpy(bool))
