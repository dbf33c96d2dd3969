"""The tuned recorded-data detector as an MLflow pyfunc model, and ``python -m mosd monitor`` (issues 24, 28).

* the served PCA (``PCADetector.online``: the generic :class:`~mosd.detectors.latent_stage.LatentStage`) alarms
  where :class:`PCADetector.decide` alarms (EWMA and persistence included), bit for bit, in one call, in chunks
  and row by row with the state carried;
* a missing or extra column is a one-line error naming it; column order does not matter;
* end to end: a ``data=table`` run logs the model, its URI is in the summary, and ``mosd monitor`` on the
  test split's rows gives the run's own test FAR and MDR and the detector's alarms row by row.
"""
from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from mosd.detectors.pca import PCADetector, PCAModel
from mosd.monitors.outputs import OutputMonitor
from mosd.streaming import OnlinePipeline
from mosd.validation import ConfigError

PACKAGE_PARENT = str(Path(__file__).resolve().parents[1])
TAGS = tuple(f"tag{i}" for i in range(6))


def plant(n=1200, seed=0):
    """Correlated tags (two latent factors) with a shift of tag2 in two labelled fault windows."""
    rng = np.random.default_rng(seed)
    X = rng.normal(size=(n, 2)) @ rng.normal(size=(2, len(TAGS))) + 0.3 * rng.normal(size=(n, len(TAGS)))
    label = np.zeros(n, int)
    for a, b in [(700, 800), (950, 1100)]:
        label[a:b] = 1
        X[a:b, 2] += 1.5
    return X, label


def _same(a, b):
    return np.array_equal(a, b, equal_nan=a.dtype.kind == "f")


class FittedPCA:
    """The pipeline a PCA run deploys (the selection monitor → the PCA's generic stage), scored on tag rows."""

    def __init__(self, detector, calibration, tags=TAGS):
        self.pipeline = OnlinePipeline([OutputMonitor(burn_in=0).online(tuple(tags)), detector.online(calibration, tags)])
        self.pca = self.pipeline.stages[-1]

    def score(self, X, state=None, top=True):
        if top:
            return self.pipeline.update({t: X[:, j] for j, t in enumerate(self.pipeline.inputs)}, state)
        columns = {"point": np.ones(len(X), np.int64), **{f"z_{j + 1}": X[:, j] for j in range(X.shape[1])}}
        return self.pca.update(columns, {**self.pca.initial_state(), **(state or {})}, top=False)

    def state(self, out):
        return {k: out[k][-1] for k in self.pipeline.state_names}


DESIGNS = [dict(n_components=2, alpha=0.01, lam=1.0, persistence=1),
           dict(n_components=3, alpha=0.05, lam=0.3, persistence=3),
           dict(n_components=2, alpha=0.1, lam=0.7, persistence=2, statistic="spe")]


@pytest.mark.parametrize("design", DESIGNS)
def test_scoring_equals_the_detector_in_one_call_in_chunks_and_row_by_row(design):
    X, _ = plant()
    calibration = np.stack([X[:300], X[300:600]])        # run 0 fits, run 1 holds back (empirical limits)
    test = X[600:][None]
    detector = PCADetector(fit_runs=1, max_components=5, **design)
    expected = detector.decide(calibration, test).decision[0].astype(bool)
    fitted = FittedPCA(detector, calibration)
    whole = fitted.score(test[0])
    assert np.array_equal(whole["alarm"], expected)
    assert 0 < expected.sum() < expected.size               # something to get wrong either way
    # the detector's own statistic: the ratio to the limit, bit for bit (one arithmetic)
    ratio = detector.population(calibration, test, detector.design()).statistic[0, 0]
    assert np.array_equal(whole["ratio"], ratio)
    # row by row, each call from the previous row's state: the same bits
    state, parts = None, []
    for row in test[0]:
        out = fitted.score(row[None], state)
        state = fitted.state(out)
        parts.append(out)
    for key in whole:
        assert _same(np.concatenate([p[key] for p in parts]), whole[key]), key
    # chunks of 7 rows
    state, parts = None, []
    for start in range(0, len(test[0]), 7):
        out = fitted.score(test[0][start:start + 7], state)
        state = fitted.state(out)
        parts.append(out)
    for key in whole:
        assert _same(np.concatenate([p[key] for p in parts]), whole[key]), key


def test_top_contributors_are_the_largest_of_the_model_s_contributions():
    """The blocked scoring names the variables PCAModel.contributions ranks first; top=False changes nothing else."""
    X, _ = plant()
    calibration = np.stack([X[:300], X[300:600]])
    fitted = FittedPCA(PCADetector(fit_runs=1, max_components=5, n_components=2), calibration)
    rows = np.concatenate([X[600:]] * 8)
    out = fitted.score(rows)
    c_t2, c_spe = PCAModel.from_fitted(fitted.pca.fitted).contributions(rows, 2)
    for name, c in (("t2", c_t2), ("spe", c_spe)):
        expected = [";".join(TAGS[j] for j in order[:3]) for order in np.argsort(-c, axis=1, kind="stable")]
        assert list(out[f"top_{name}"]) == expected
    bare = fitted.score(rows, top=False)
    for key in bare.keys() & out.keys():
        if key.startswith("top_"):
            assert set(bare[key]) == {""}
        else:
            np.testing.assert_array_equal(bare[key], out[key])


def test_spe_includes_what_lies_outside_the_loadings_when_fewer_fit_rows_than_tags():
    from mosd.detectors.pca import _Projected

    X, _ = plant()
    fitted = FittedPCA(PCADetector(fit_runs=1, max_components=3, n_components=2), np.stack([X[:5], X[5:10]]))
    assert fitted.pca.fitted["loadings"].shape[1] < len(TAGS)               # 5 rows, 6 tags: rank 5
    model = PCAModel.from_fitted(fitted.pca.fitted)
    expected = _Projected.of(model, X[None, 600:]).spe[0, :, 1]
    assert np.array_equal(fitted.score(X[600:])["spe"], expected)
    # SPE is the squared norm of the residual (I − Pₐ Pₐᵀ) z, the part outside the loadings included
    np.testing.assert_allclose(expected, model.spe(X[600:], 2), rtol=1e-10)


def test_without_the_carried_state_chunks_differ():
    """The state matters: restarting every chunk from the in-control start changes the alarms."""
    X, _ = plant()
    calibration = np.stack([X[:300], X[300:600]])
    detector = PCADetector(fit_runs=1, max_components=5, **DESIGNS[1])
    fitted = FittedPCA(detector, calibration)
    expected = fitted.score(X[600:])["alarm"]
    restarted = np.concatenate([fitted.score(X[600 + s:600 + s + 3])["alarm"] for s in range(0, 600, 3)])
    assert not np.array_equal(restarted, expected)


def test_columns_any_order_missing_or_extra_is_one_line_naming_it(tmp_path):
    import pandas as pd

    X, _ = plant()
    detector = PCADetector(fit_runs=1, max_components=5, n_components=2)
    fitted = OnlinePipeline.load(FittedPCA(detector, X[None, :600]).pipeline.save(tmp_path))
    frame = pd.DataFrame(X[600:700], columns=TAGS)
    out = fitted.predict_frame(frame)
    shuffled = fitted.predict_frame(frame[list(TAGS[::-1])])
    pd.testing.assert_frame_equal(out, shuffled)
    with pytest.raises(ConfigError, match=r"^input column 'tag3' is missing"):
        fitted.predict_frame(frame.drop(columns=["tag3"]))
    with pytest.raises(ConfigError, match=r"^input column 'extra' is not an input of the model"):
        fitted.predict_frame(frame.assign(extra=1.0))
    # a historian error code: no alarm on that row, the others are scored
    text = frame.astype(object)
    text.iloc[5, 1] = "Bad"
    scored = fitted.predict_frame(text)
    assert not scored["alarm"].iloc[5] and np.isnan(scored["t2"].iloc[5])
    assert np.isfinite(scored["t2"].drop(index=scored.index[5])).all()


def _mosd(args, cwd, outputs):
    env = {k: v for k, v in os.environ.items() if not k.startswith("MOSD_")}
    env["PYTHONPATH"] = os.pathsep.join(p for p in (PACKAGE_PARENT, env.get("PYTHONPATH")) if p)
    env["MOSD_OUTPUTS"] = str(outputs)
    return subprocess.run([sys.executable, "-m", "mosd", *args], cwd=cwd, env=env, capture_output=True, text=True,
                          timeout=600)


def plant_table():
    """:func:`plant` as the table a run reads: time (s), the tags, the fault label."""
    import pandas as pd

    X, label = plant()
    table = pd.DataFrame(X, columns=TAGS)
    table.insert(0, "time", np.arange(len(X)) * 60.0)
    table["fault"] = label
    return table


def build_logged_run(folder: Path) -> None:
    """A data=table run of the generated plant (tracking on) in ``folder``: plant.csv, out/ (runs, mlflow.db) and
    the run's stdout (stdout.txt); the tiny tuned run tests/test_opcua.py monitors too (``shared_build``)."""
    csv = folder / "plant.csv"
    plant_table().to_csv(csv, index=False)
    run = _mosd([f"data.path={csv}", "data=table", "data.time_column=time", "data.label_column=fault",
                 "estimator=measured", "monitor=signals", "detector=pca", "detector.max_components=4",
                 "detector.n_components=2", "optimizer.pop_size=8", "optimizer.n_gen=2", "progress=false"],
                folder, folder / "out")
    assert run.returncode == 0, run.stderr[-2000:]
    (folder / "stdout.txt").write_text(run.stdout)


@pytest.fixture(scope="module")
def logged_run(tmp_path_factory, shared_build):
    """The data=table run of :func:`build_logged_run` (shared, read only), its model URI and summary; ``tmp`` is
    this module's own folder for what the tests write."""
    import mlflow  # noqa: F401  (a test dependency: a missing one fails, never skips)
    built = shared_build("pca-table-run", build_logged_run)
    tmp_path = tmp_path_factory.mktemp("logged")
    X, _ = plant()
    csv = built / "plant.csv"
    table = plant_table()
    outputs = built / "out"
    stdout = (built / "stdout.txt").read_text()
    uri = re.search(r"model (models:/\S+) \(runs:/(\w+)/detector\)", stdout)
    assert uri, stdout[-2000:]
    summary = json.loads(next((outputs / "runs").glob("*/summary.json")).read_text())
    params = summary["params"]
    detector = PCADetector(max_components=4, **{k: params[k] for k in ("n_components", "alpha", "lam",
                                                                       "persistence")})
    # the run's test split is rows 900-1199 (splits 0.5/0.25/0.25): the tuned design refitted on rows 0-599
    expected = detector.decide(X[None, :600], X[None, 900:]).decision[0].astype(bool)
    return dict(tmp=tmp_path, outputs=outputs, csv=csv, table=table, model=uri.group(1), run_id=uri.group(2),
                tracking=f"sqlite:///{outputs / 'mlflow.db'}", summary=summary, expected=expected)


def test_run_logs_the_model_and_monitor_reproduces_its_test_evaluation(logged_run):
    import pandas as pd

    r = logged_run
    tmp_path, summary, tracking = r["tmp"], r["summary"], r["tracking"]
    test = r["table"].iloc[900:]
    test.to_csv(tmp_path / "test.csv", index=False)
    for model in (r["model"], f"runs:/{r['run_id']}/detector"):
        scored = _mosd(["monitor", "--model", model, str(tmp_path / "test.csv"), "--keep", "time", "--keep", "fault",
                        "--out", str(tmp_path / "alarms.csv"), "--tracking-uri", tracking, "--chunk", "13"],
                       tmp_path, r["outputs"])
        assert scored.returncode == 0, scored.stderr[-2000:]
        assert re.search(r"300 rows, \d+ alarms", scored.stdout)
        alarms = pd.read_csv(tmp_path / "alarms.csv")
        alarm = alarms["alarm"].to_numpy(bool)
        labels = alarms["fault"].to_numpy()
        # the run's own test evaluation (summary.json), and row by row the tuned design's decisions
        assert np.mean(alarm[labels == 0]) == pytest.approx(summary["test"]["far"]["mean"], abs=1e-12)
        assert 1 - np.mean(alarm[labels != 0]) == pytest.approx(summary["test"]["mdr"]["mean"], abs=1e-12)
        assert np.array_equal(alarm, r["expected"])
        # the first-alarm line shows the statistics the limits apply to (smoothed when λ < 1), not the raw ones
        first = re.search(r"first alarm at row (\d+): T² (\S+) \(limit (\S+)\), SPE (\S+)", scored.stdout)
        row = alarms.iloc[int(first.group(1))]
        assert first.group(2) == f"{row['t2_smoothed']:.4g}" and first.group(4) == f"{row['spe_smoothed']:.4g}"
    # a historian error code: the run's data.fill (hold) fills it as training did, with the previous row's value
    coded = test.astype(object)
    coded.iloc[40, 3] = "Bad"
    coded.to_csv(tmp_path / "coded.csv", index=False)
    held = test.copy()
    held.iloc[40, 3] = held.iloc[39, 3]
    held.to_csv(tmp_path / "held.csv", index=False)
    outs = []
    for name in ("coded", "held"):
        scored = _mosd(["monitor", "--model", r["model"], str(tmp_path / f"{name}.csv"), "--keep", "time", "--keep",
                        "fault", "--out", str(tmp_path / f"{name}_alarms.csv"), "--tracking-uri", tracking],
                       tmp_path, r["outputs"])
        assert scored.returncode == 0, scored.stderr[-2000:]
        outs.append(pd.read_csv(tmp_path / f"{name}_alarms.csv"))
    pd.testing.assert_frame_equal(outs[0], outs[1])
    assert np.isfinite(outs[0]["t2"].iloc[40])
    # one-line errors, exit 2: an extra column, an unknown model
    bad = _mosd(["monitor", "--model", r["model"], str(r["csv"]), "--tracking-uri", tracking], tmp_path, r["outputs"])
    assert bad.returncode == 2 and bad.stderr.strip().count("\n") == 0
    assert "column 'time'" in bad.stderr
    bad = _mosd(["monitor", "--model", "runs:/0123/detector", str(r["csv"]), "--tracking-uri", tracking], tmp_path,
                r["outputs"])
    assert bad.returncode == 2 and bad.stderr.strip().count("\n") == 0 and "runs:/0123/detector" in bad.stderr


@pytest.mark.slow
def test_mlflow_models_serve_gives_the_same_alarms(logged_run, stop_process_group):
    """``mlflow models serve --env-manager local`` on 127.0.0.1: requests of 100 rows, state carried in params."""
    from mosd.app.serving import predict_served, start_model_server

    r = logged_run
    server, port = start_model_server(r["model"], r["tracking"], timeout=300, stderr=subprocess.PIPE)
    try:
        test = r["table"].iloc[900:].drop(columns=["time", "fault"])
        state, alarms = None, []
        for start in range(0, len(test), 100):
            chunk = test.iloc[start:start + 100]
            rows = predict_served(port, list(chunk.columns), chunk.to_numpy().tolist(), state)
            alarms += [bool(row["alarm"]) for row in rows]
            state = {k: rows[-1][k] for k in ("ewma_t2", "ewma_spe", "run_length", "samples_seen")}
        assert np.array_equal(alarms, r["expected"])
    finally:
        stop_process_group(server)


@pytest.mark.slow
def test_tep_run_logs_a_model_whose_monitor_alarms_give_the_run_s_test_rates(tmp_path):
    """+experiment=tep: the logged model scores the test files' rows 160-959 as the run's evaluation did."""
    import pandas as pd

    from mosd.data.tep import TennesseeEastman, bibmon_directory

    assert bibmon_directory() is not None, 'the TE files are a test dependency: pip install ".[test]"'
    outputs = tmp_path / "out"
    run = _mosd(["+experiment=tep", "optimizer.pop_size=8", "optimizer.n_gen=2", "optimizer.n_jobs=1",
                 "progress=false", "study.figures=false"], tmp_path, outputs)
    assert run.returncode == 0, run.stderr[-2000:]
    model = re.search(r"model (models:/\S+) \(runs:/\w+/detector\)", run.stdout).group(1)
    summary = json.loads(next((outputs / "runs").glob("*/summary.json")).read_text())
    te = TennesseeEastman()
    test = te.trace("test")
    labels = test.fault_label.max(axis=1)
    for fault in (0, 1, 10):
        r = int(np.flatnonzero(labels == fault)[0])
        path = tmp_path / f"te{fault}.parquet"
        pd.DataFrame(test.y[r], columns=list(te.output_names)).to_parquet(path)
        scored = _mosd(["monitor", "--model", model, str(path), "--out", str(tmp_path / "alarms.csv"),
                        "--tracking-uri", f"sqlite:///{outputs / 'mlflow.db'}"], tmp_path, outputs)
        assert scored.returncode == 0, scored.stderr[-2000:]
        rate = pd.read_csv(tmp_path / "alarms.csv")["alarm"].mean()
        if fault == 0:
            assert rate == pytest.approx(summary["test"]["far"]["mean"], abs=1e-12)
            assert rate == pytest.approx(summary["study"]["tuned_far_combined"], abs=1e-12)
        else:
            assert rate == pytest.approx(summary["study"][f"tuned_fdr_combined_idv{fault}"], abs=1e-12)
