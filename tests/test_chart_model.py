"""The main command's tuned chart as the run's deployed pipeline on a residual stream (issues 24 and 28).

* the pipeline (:class:`~mosd.monitors.step.MonitorStage` of the subgroup monitor → the chart's
  :class:`~mosd.detectors.step.StepStage`, built by the components' ``online``) gives the statistics, limits
  and alarms of :meth:`Chart.decide` (bit for bit, its limit included), for every mean–variance chart and
  limit, in one call, in chunks and row by row with the state carried;
* end to end (slow): the main command (small budget) logs a loadable model, and the model, in-process chunk
  by chunk through MLflow's params, through ``mosd monitor`` and through ``mlflow models serve``, alarms on
  the run's own raw test replications (the sensors and the controller's command: the CESCKF residual
  streams, ``tests/test_streaming_cesckf.py``) where the run's test evaluation alarmed (its FAR and MDR in
  summary.json).
"""
from __future__ import annotations

import json
import re
import subprocess

import numpy as np
import pytest

from mosd.detectors.ewma_chart import EWMA, MSOEWMA
from mosd.detectors.mean_variance import MDEWMA, SSDEWMA, SSEWMA, MaxEWMA
from mosd.monitors.subgroups import SubgroupMonitor
from mosd.streaming import NoStreamingForm, OnlinePipeline
from mosd.types import Residuals
from mosd.validation import ConfigError
from test_detector_model import _mosd  # the same subprocess helper

BURN_IN, N = 20, 5


def residual_runs(n_runs, length=420, seed=0, shift_at=None):
    rng = np.random.default_rng(seed)
    r = 0.3 + 2.0 * rng.standard_normal((n_runs, length))
    if shift_at is not None:
        r[:, shift_at:] = 1.6 * r[:, shift_at:] + 1.0
    return r


def _residuals(r):
    r = r if r.ndim == 3 else r[..., None]
    return Residuals(r=r, fault_mask=np.zeros(r.shape[:2], bool), channels=tuple("abc"[:r.shape[-1]]))


def fitted_and_decisions(chart, subgroup="window"):
    """The pipeline the components build from Phase-I runs, and the chart's own decisions on test runs."""
    calibration, test = residual_runs(3, seed=1), residual_runs(2, seed=2, shift_at=250)
    if subgroup == "window":
        monitor = SubgroupMonitor(subgroup="window", n=N, channels=(0,), burn_in=BURN_IN)
        streams = test[..., None]
    else:  # three channels, each row one subgroup
        calibration = np.stack([calibration, residual_runs(3, seed=3), residual_runs(3, seed=4)], axis=-1)
        streams = np.stack([test, residual_runs(2, seed=5), residual_runs(2, seed=6, shift_at=250)], axis=-1)
        monitor = SubgroupMonitor(subgroup="channels", channels=(0, 1, 2), burn_in=BURN_IN)
    calibration_z = monitor.fit(_residuals(calibration)).transform(_residuals(calibration)).z
    decided = chart.decide(calibration_z, monitor.transform(_residuals(streams)).z)
    columns = tuple(f"residual_{c}" for c in "abc"[:streams.shape[-1]])
    pipeline = OnlinePipeline([monitor.online(columns), chart.online(calibration_z)])
    return pipeline, decided, streams


def score(pipeline, stream, state=None):
    """The pipeline's outputs for a stream (rows, channels)."""
    return pipeline.update({name: stream[:, j] for j, name in enumerate(pipeline.inputs)}, state)


CASES = [(SSDEWMA, "phase1", "window"), (SSDEWMA, "theoretical", "window"), (SSDEWMA, "normalised", "window"),
         (MDEWMA, "phase1", "window"), (SSEWMA, "theoretical", "window"), (MaxEWMA, "normalised", "window"),
         (SSDEWMA, "phase1", "channels"), (EWMA, "phase1", "window"), (EWMA, "asymptotic", "window"),
         (EWMA, "time_varying", "window"), (EWMA, "time_varying", "channels")]


def _causal_wavelet():
    from mosd.denoisers.wavelet import WaveletDenoiser

    return WaveletDenoiser(window=48)   # 80 subgroups a run: prefixes (k < 47) and full windows both


@pytest.mark.parametrize("cls, limit, subgroup, denoiser", [(*case, None) for case in CASES]
                         + [(SSDEWMA, "phase1", "window", "causal"), (EWMA, "phase1", "channels", "causal"),
                            (MaxEWMA, "normalised", "window", "causal")])
def test_scoring_equals_the_chart_in_one_call_in_chunks_and_row_by_row(cls, limit, subgroup, denoiser):
    width = {"L": 1.0} if cls is EWMA else {"K": 1.0}
    chart = cls(lam=0.25, limit=limit, denoiser=_causal_wavelet() if denoiser else None, **width)
    pipeline, decided, streams = fitted_and_decisions(chart, subgroup)
    for run, stream in enumerate(streams):
        whole = score(pipeline, stream)
        at = whole["subgroup"] > 0
        assert np.array_equal(whole["subgroup"][at], np.arange(1, decided.statistic.shape[-1] + 1))
        assert np.array_equal(whole["statistic"][at], decided.statistic[run])        # bit for bit
        assert np.array_equal(whole["limit"][at], np.broadcast_to(decided.threshold, decided.statistic.shape)[run])
        assert np.array_equal(whole["alarm"], at & np.isin(whole["subgroup"], 1 + np.flatnonzero(decided.decision[run])))
        assert 0 < decided.decision[run].sum() < decided.decision[run].size     # something to get wrong either way
        for size in (1, 3, 7, 100):
            state, parts = None, []
            for start in range(0, len(stream), size):
                out = score(pipeline, stream[start:start + size], state)
                state = pipeline.final_state(out, state)
                parts.append(out)
            for key in pipeline.outputs:  # every output, the state of every row included
                assert np.array_equal(np.concatenate([p[key] for p in parts]), whole[key], equal_nan=True), (key, size)


def test_without_the_carried_state_chunks_differ():
    pipeline, decided, streams = fitted_and_decisions(SSDEWMA(lam=0.25, K=1.0))
    expected = score(pipeline, streams[0])["alarm"]
    # each chunk from a stream's start: the burn-in, the subgroups and the EWMA all restart
    restarted = np.concatenate([score(pipeline, streams[0][s:s + 60], {"samples_seen": BURN_IN})["alarm"]
                                for s in range(0, len(streams[0]), 60)])
    assert not np.array_equal(restarted, expected)


def test_columns_any_order_missing_extra_or_not_a_number_is_one_line(tmp_path):
    import pandas as pd

    pipeline, _, streams = fitted_and_decisions(SSDEWMA(lam=0.25, K=1.0), "channels")
    pipeline = OnlinePipeline.load(pipeline.save(tmp_path))
    frame = pd.DataFrame(streams[0], columns=pipeline.inputs)
    pd.testing.assert_frame_equal(pipeline.predict_frame(frame),
                                  pipeline.predict_frame(frame[list(pipeline.inputs[::-1])]))
    with pytest.raises(ConfigError, match=r"^input column 'residual_b' is missing"):
        pipeline.predict_frame(frame.drop(columns=["residual_b"]))
    with pytest.raises(ConfigError, match=r"^input column 'time' is not an input of the model"):
        pipeline.predict_frame(frame.assign(time=1.0))
    text = frame.astype(object)
    text.iloc[7, 2] = "Bad"
    with pytest.raises(ConfigError, match=r"^input column 'residual_c' row 7 is 'Bad', not a finite number"):
        pipeline.predict_frame(text)


def test_no_causal_form_for_a_whole_series_filter_and_the_state_names():
    """The paper's whole-series wavelet decides nothing before the series ends: no streaming form, one line why."""
    from mosd.denoisers.wavelet import WaveletDenoiser

    calibration_z = np.random.default_rng(0).standard_normal((2, 40, N))
    with pytest.raises(NoStreamingForm, match="filters the whole series"):
        SSDEWMA(denoiser=WaveletDenoiser()).online(calibration_z)
    with pytest.raises(NoStreamingForm, match="whole residual series"):
        MSOEWMA().online(calibration_z)   # its wavelet prefilter filters the whole residual series
    chart = EWMA(lam=0.2, L=2.5, limit="time_varying").online(calibration_z)   # the EWMA chart: L is its width
    assert (chart.design["L"], np.isnan(chart.step["limit"])) == (2.5, True)
    monitor = SubgroupMonitor(n=N)
    monitor.mean_, monitor.std_ = np.zeros(1), np.ones(1)
    pipeline = OnlinePipeline([monitor.online(("residual_y",)), chart])
    assert pipeline.state_names == ("samples_seen", "pending_1", "pending_2", "pending_3", "pending_4", "smooth_u_1")
    with pytest.raises(ConfigError, match=r"^param samples_seen=-5 is out of range; allowed: integers in"):
        pipeline.update({"residual_y": np.zeros(3)}, {"samples_seen": -5})
    with pytest.raises(ConfigError, match=r"^param smooth_u_1=1e\+308 is out of range"):
        pipeline.update({"residual_y": np.zeros(3)}, {"smooth_u_1": 1e308})


@pytest.mark.slow
@pytest.mark.parametrize("detector", ["ss_dewma", "ewma"])
def test_main_command_logs_a_model_that_reproduces_its_test_evaluation(tmp_path, stop_process_group, detector):
    import mlflow
    import pandas as pd
    from omegaconf import OmegaConf

    from mosd.app.build import build
    from mosd.metrics import DetectionReport

    outputs = tmp_path / "out"
    run = _mosd(["+fault=offset_var", f"detector={detector}", "optimizer=mopso", "optimizer.pop_size=8",
                 "optimizer.n_gen=2", "budget.n_calibration=3", "budget.n_train=3", "budget.n_test=4", "progress=false"],
                tmp_path, outputs)
    assert run.returncode == 0, run.stderr[-2000:]
    uri = re.search(r"model (models:/\S+) \(runs:/(\w+)/detector\)", run.stdout)
    assert uri, run.stdout[-2000:]
    run_dir = next((outputs / "runs").glob("*"))
    summary = json.loads((run_dir / "summary.json").read_text())
    tracking = f"sqlite:///{outputs / 'mlflow.db'}"
    # the run's own test residuals and decisions, rebuilt from its resolved config (same seeds)
    setup = build(OmegaConf.load(run_dir / "resolved_config.yaml"))
    experiment = setup.experiment
    data = experiment.prepare()
    subgroups, residuals = experiment.test_data(data)
    expected = experiment.detector.with_params(**summary["params"]).decide(data.phase1.z, subgroups.z).decision
    mlflow.set_tracking_uri(tracking)
    model = mlflow.pyfunc.load_model(uri.group(1))
    names = [p.name for p in model.metadata.get_params_schema().params]
    columns = model.metadata.get_input_schema().input_names()
    assert columns == ["y_x_p", "y_theta", "y_n", "u_i_q"]   # the raw sensors and the controller's command
    trace = experiment.simulate(experiment.fault, residuals.r.shape[0], "test")   # the same test runs, raw

    def raw(r):
        return pd.DataFrame({**{f"y_{n}": trace.y[r, :, j] for j, n in enumerate(experiment.model.output_names)},
                             **{f"u_{n}": trace.u[r, :, j] for j, n in enumerate(experiment.plant.input_names)}})

    decisions = []
    for r in range(residuals.r.shape[0]):
        stream = raw(r)
        state, parts = None, []
        for start in range(0, len(stream), 100):   # 100 rows a request, the state through MLflow's params
            out = model.predict(stream.iloc[start:start + 100], params=state)
            state = {k: out[k].iloc[-1].item() for k in names}
            parts.append(out)
        out = pd.concat(parts)
        decisions.append(out["alarm"].to_numpy()[out["subgroup"].to_numpy() > 0])
    decisions = np.array(decisions)
    assert np.array_equal(decisions, expected.astype(bool))
    report = DetectionReport.of(decisions.astype(np.int8), subgroups, ("far", "mdr")).summary()
    assert report["far"].mean == summary["test"]["far"]["mean"]
    assert report["mdr"].mean == summary["test"]["mdr"]["mean"]
    # mosd monitor on run 0's raw file, in chunks of 37 rows
    path = tmp_path / "raw.csv"
    raw(0).assign(t=residuals.t).to_csv(path, index=False)
    scored = _mosd(["monitor", "--model", uri.group(1), str(path), "--keep", "t", "--out", str(tmp_path / "a.csv"),
                    "--tracking-uri", tracking, "--chunk", "37"], tmp_path, outputs)
    assert scored.returncode == 0, scored.stderr[-2000:]
    assert f"{int(expected[0].sum())} alarms in {expected.shape[1]} subgroups" in scored.stdout
    alarms = pd.read_csv(tmp_path / "a.csv")
    assert np.array_equal(alarms["alarm"].to_numpy()[alarms["subgroup"].to_numpy() > 0], expected[0].astype(bool))
    # mlflow models serve, as logged: requests of 100 rows of run 1, the state in the request's params
    assert np.array_equal(_served_alarms(uri.group(1), tracking, raw(1), names, stop_process_group),
                          expected[1].astype(bool))


def _served_alarms(model, tracking, frame, names, stop_process_group):
    from mosd.app.serving import predict_served, start_model_server

    server, port = start_model_server(model, tracking, timeout=300, stderr=subprocess.PIPE)
    try:
        state, alarms = None, []
        for start in range(0, len(frame), 100):
            rows = predict_served(port, list(frame.columns), frame.iloc[start:start + 100].to_numpy(float).tolist(),
                                  state)
            alarms += [bool(row["alarm"]) for row in rows if row["subgroup"] > 0]
            state = {k: rows[-1][k] for k in names}
        return np.array(alarms)
    finally:
        stop_process_group(server)
