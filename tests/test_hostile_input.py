"""Nothing lost, third pass (issue 34): recorded data, ``mosd monitor`` and the served model under bad input.

Every test here failed on main at 954534b:

* recorded data is validated before any work: a time column that goes back (a shuffled export gave a
  720 s step for a 60 s one) is refused, or sorted with ``sort=True`` and said on stdout; a malformed
  timestamp, a header-only or one-row table, a one-row split and a calibration with no more rows than
  tags are one line each; ``data=table`` without the measured-signals pipeline names the pipeline;
* ``mosd monitor`` checks ``--out`` and the store before scoring, creates nothing when the store is
  mistyped, reads ``-`` from stdin, keeps the ``--keep`` order;
* the model's state params are checked against their declared domains (mosd.app.model_state): the
  served model answers 400 naming the param, and its answers are strict JSON (``null``, not ``NaN``);
* the model's ``.npz`` is written atomically; a half-upload's FAILED model record is removed.
"""
from __future__ import annotations

import json
import re
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from mosd.app import model_state
from mosd.data.table import Table
from mosd.detectors.pca import PCADetector
from mosd.detectors.step import StepStage
from mosd.monitors.outputs import OutputMonitor
from mosd.monitors.step import MonitorStage
from mosd.streaming import OnlinePipeline
from mosd.validation import ConfigError

#: the PCA model's carried state
STATE = ("ewma_t2", "ewma_spe", "run_length")


def pca_pipeline(detector, calibration, tags, fill="none") -> OnlinePipeline:
    """What a PCA run deploys: its tags selected, the tuned PCA (mosd.app.deploy builds the same)."""
    return OnlinePipeline([OutputMonitor(burn_in=0).online(tuple(tags)), detector.online(calibration, tuple(tags))],
                          fill=fill)


def score(pipeline, X, state=None):
    return pipeline.update({t: X[:, j] for j, t in enumerate(pipeline.inputs)}, state)

ROOT = Path(__file__).resolve().parents[1]
TAGS = tuple(f"TI-{i}" for i in range(6))


def plant(n=1200, seed=0) -> pd.DataFrame:
    """Correlated tags, one-minute timestamps, a labelled shift of two tags in two windows."""
    rng = np.random.default_rng(seed)
    tags = rng.normal(size=(n, 2)) @ rng.normal(size=(2, len(TAGS))) + 0.3 * rng.normal(size=(n, len(TAGS)))
    label = np.zeros(n, int)
    for start in (700, 1000):
        label[start:start + 120] = 3
    tags[label == 3, 0] += 1.5
    tags[label == 3, 4] -= 1.5
    frame = pd.DataFrame(tags, columns=TAGS)
    frame.insert(0, "time", pd.date_range("2024-01-01", periods=n, freq="1min"))
    frame["fault"] = label
    return frame


def one_line(text: str) -> str:
    lines = [line for line in text.strip().splitlines() if line.strip()]
    assert len(lines) == 1, text
    return lines[0]


def _env(outputs: Path) -> dict:
    env = {k: v for k, v in os.environ.items() if not k.startswith(("MOSD_", "MLFLOW_"))}
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(ROOT), env.get("PYTHONPATH")) if p)
    env["MOSD_OUTPUTS"] = str(outputs)
    return env


def mosd(args, cwd: Path, stdin: bytes | None = None, timeout: float = 600) -> subprocess.CompletedProcess:
    out = subprocess.run([sys.executable, "-m", "mosd", *args], cwd=cwd, env=_env(cwd / "outputs"),
                         capture_output=True, input=stdin, timeout=timeout)
    out.stdout, out.stderr = out.stdout.decode(), out.stderr.decode()
    return out


# -- 1. recorded data validated before any work ----------------------------------------------------------
def test_a_shuffled_time_column_is_refused_naming_the_row(tmp_path):
    path = tmp_path / "shuffled.csv"
    plant().sample(frac=1.0, random_state=1).to_csv(path, index=False)
    with pytest.raises(ConfigError) as info:
        Table(str(path), time_column="time", label_column="fault")
    message = str(info.value)
    assert "\n" not in message and "column 'time' goes back at row" in message and "data.sort=true" in message


def test_sort_true_sorts_the_rows_by_time_and_says_so_on_stdout(tmp_path, capsys):
    frame = plant()
    frame.sample(frac=1.0, random_state=1).to_csv(tmp_path / "shuffled.csv", index=False)
    frame.to_csv(tmp_path / "ordered.csv", index=False)
    ordered = Table(str(tmp_path / "ordered.csv"), time_column="time", label_column="fault")
    assert "sorted" not in capsys.readouterr().out
    table = Table(str(tmp_path / "shuffled.csv"), time_column="time", label_column="fault", sort=True)
    said = capsys.readouterr().out
    assert "rows of" in said and "were out of time order; sorted by column 'time' (data.sort=true)" in said
    assert table.dt == 60.0  # the shuffled file gave a 720 s step
    for split in ("calibration", "training", "test"):
        np.testing.assert_array_equal(table.trace(split).y, ordered.trace(split).y)
        np.testing.assert_array_equal(table.trace(split).fault_label, ordered.trace(split).fault_label)


def test_a_repeated_time_is_refused_even_with_sort(tmp_path):
    frame = plant(200)
    frame.loc[50, "time"] = frame.loc[49, "time"]
    frame.to_csv(tmp_path / "twice.csv", index=False)
    for sort in (False, True):
        with pytest.raises(ConfigError, match=r"column 'time' row 50 repeats the time of row 49"):
            Table(str(tmp_path / "twice.csv"), time_column="time", sort=sort)


@pytest.mark.parametrize("bad,shown", [("2024-13-45 99:00", "'2024-13-45 99:00'"), ("", "an empty cell"),
                                       ("Bad", "'Bad'")])
def test_a_malformed_timestamp_is_one_line_naming_the_row_and_the_value(tmp_path, bad, shown):
    frame = plant(200).astype({"time": str})
    frame.loc[17, "time"] = bad
    frame.to_csv(tmp_path / "stamps.csv", index=False)
    with pytest.raises(ConfigError) as info:
        Table(str(tmp_path / "stamps.csv"), time_column="time")
    message = str(info.value)
    assert "\n" not in message and f"column 'time' row 17 holds {shown}, not a time" in message


def test_numeric_seconds_with_a_gap_are_refused_naming_the_row(tmp_path):
    frame = plant(200)
    frame["time"] = np.arange(200) * 60.0
    frame.loc[33, "time"] = np.nan
    frame.to_csv(tmp_path / "seconds.csv", index=False)
    with pytest.raises(ConfigError, match=r"column 'time' row 33 holds an empty cell, not a time"):
        Table(str(tmp_path / "seconds.csv"), time_column="time")


@pytest.mark.parametrize("rows,what", [(0, "a header and no data row"), (1, "1 data row"), (5, "5 data rows")])
def test_too_short_a_table_is_one_line(tmp_path, rows, what):
    plant(rows + 1).iloc[:rows].to_csv(tmp_path / "short.csv", index=False)
    with pytest.raises(ConfigError) as info:
        Table(str(tmp_path / "short.csv"), time_column="time", label_column="fault")
    message = str(info.value)
    assert "\n" not in message and f"has {what}; allowed: a table with at least 6 rows (2 per split" in message


def test_a_split_of_one_row_is_refused(tmp_path):
    plant(200).to_csv(tmp_path / "plant.csv", index=False)
    with pytest.raises(ConfigError, match=r"data.splits.test=\[199, 200\] gives 1 row \(row 199\) of 200; "
                                          r"allowed: at least 2 rows per split"):
        Table(str(tmp_path / "plant.csv"), time_column="time",
              splits={"calibration": [0, 150], "training": [150, 199], "test": [199, 200]})


def test_more_tags_than_calibration_rows_is_refused_and_few_rows_per_tag_warn(tmp_path, caplog):
    rng = np.random.default_rng(1)
    wide = pd.DataFrame(rng.normal(size=(240, 150)), columns=[f"tag{i}" for i in range(150)])
    wide.to_csv(tmp_path / "wide.csv", index=False)
    with pytest.raises(ConfigError) as info:  # 120 calibration rows, 150 tags
        Table(str(tmp_path / "wide.csv"))
    message = str(info.value)
    assert "\n" not in message
    assert "120 fault-free complete rows" in message and "for 150 tags" in message and "singular" in message
    # 120 rows for 60 tags: accepted, with one warning line (2 per tag < 5)
    with caplog.at_level("WARNING", logger="mosd.data"):
        Table(str(tmp_path / "wide.csv"), tags=[f"tag{i}" for i in range(60)])
    lines = [r.getMessage() for r in caplog.records if "per tag" in r.getMessage()]
    assert len(lines) == 1 and "\n" not in lines[0] and "120 fault-free complete rows" in lines[0]
    caplog.clear()
    with caplog.at_level("WARNING", logger="mosd.data"):  # 120 rows for 20 tags: no warning
        Table(str(tmp_path / "wide.csv"), tags=[f"tag{i}" for i in range(20)])
    assert not [r for r in caplog.records if "per tag" in r.getMessage()]


def test_data_table_without_the_measured_signals_pipeline_names_it(tmp_path):
    path = tmp_path / "plant.csv"
    plant().to_csv(path, index=False)
    data = ["data=table", f"data.path={path}", "data.time_column=time", "data.label_column=fault"]
    run = mosd([*data, "estimator=dedicated_observer", "tracking=none", "progress=false"], tmp_path)
    line = one_line(run.stderr)
    assert run.returncode == 2 and "Traceback" not in run.stderr and "AttributeError" not in line
    assert "estimator=measured monitor=signals detector=pca" in line and "estimator=dedicated_observer" in line


# -- 3. the served model's state -------------------------------------------------------------------
@pytest.fixture(scope="module")
def fitted_pca() -> tuple[OnlinePipeline, pd.DataFrame]:
    frame = plant()
    X = frame[list(TAGS)].to_numpy()
    detector = PCADetector(n_components=2, alpha=0.01, lam=0.3, persistence=2, max_components=4)
    return pca_pipeline(detector, X[None, :600], TAGS, fill="hold"), frame


@pytest.mark.parametrize("name,value,problem", [
    ("run_length", -5, "is out of range"), ("run_length", 2.5, "is not an integer"),
    ("ewma_t2", 1e308, "is out of range"), ("ewma_t2", float("nan"), "is not finite"),
    ("ewma_spe", -1.0, "is out of range"), ("ewma_spe", float("inf"), "is not finite"),
    ("run_length", "five", "is not a number"), ("run_length", True, "is not a number"),
])
def test_impossible_pca_state_is_refused_naming_the_param(fitted_pca, name, value, problem):
    fitted, frame = fitted_pca
    rows = frame[list(TAGS)].iloc[700:720]
    with pytest.raises(ConfigError) as info:
        fitted.predict_frame(rows, {name: value})
    message = str(info.value)
    assert "\n" not in message and message.startswith(f"param {name}={value!r} {problem}; allowed: ")
    assert fitted.state_var(name).describe() in message


def test_the_domains_hold_every_state_the_model_itself_gives(fitted_pca):
    """Chunked scoring passes each chunk's last state back: every such state is in its domain, and the
    boundary values (0, an integer float) are accepted."""
    fitted, frame = fitted_pca
    rows = frame[list(TAGS)]
    whole = fitted.predict_frame(rows)
    assert whole["alarm"].any()
    for name in STATE:
        for value in whole[name]:
            assert fitted.state_var(name).problem(value) is None
    state = {"ewma_t2": 0.0, "ewma_spe": 0.0, "run_length": 3.0}
    assert fitted.predict_frame(rows.iloc[:5], state)["run_length"].dtype.kind == "i"


def test_impossible_chart_state_is_refused_naming_the_param():
    chart = OnlinePipeline([
        MonitorStage(monitor="mosd.monitors.subgroups.SubgroupMonitor", design={"n": 5, "burn_in": 10},
                     fitted={"mean": np.array([0.0]), "std": np.array([1.0])}, columns=("residual_x",)),
        StepStage(detector="mosd.detectors.mean_variance.SSDEWMA", design={"lam": 0.2, "K": 3.0, "limit": "phase1"},
                  step={"lam": 0.2, "width": 3.0, "limit": 2.0}, n=5)])
    rows = pd.DataFrame({"residual_x": np.random.default_rng(0).normal(size=40)})
    assert chart.predict_frame(rows)["subgroup"].max() == 6
    for name, value, problem in [("samples_seen", -1, "is out of range"), ("smooth_u_1", float("inf"), "is not finite"),
                                 ("pending_2", 1e200, "is out of range"), ("samples_seen", 3.5, "is not an integer")]:
        with pytest.raises(ConfigError, match=rf"^param {name}={re.escape(repr(value))} {problem}; allowed: "):
            chart.predict_frame(rows, {name: value})


def test_strict_json_gives_null_for_missing_cells(fitted_pca):
    fitted, frame = fitted_pca
    rows = frame[list(TAGS)].iloc[:10].astype(object)
    rows.iloc[3, 1] = "Bad"
    out = model_state.strict_json(fitted.predict_frame(rows))
    text = json.dumps(out.to_dict(orient="records"), allow_nan=False)  # raises on a NaN
    record = json.loads(text)[3]
    assert record["t2"] is None and record["alarm"] is False and record["top_t2"] == ""
    assert json.loads(text)[2]["t2"] == pytest.approx(out["t2"].iloc[2])


def test_the_model_file_is_written_atomically(fitted_pca, tmp_path, monkeypatch):
    """A write that fails half-way (a full disk) keeps the previous file whole and leaves no temporary file."""
    from mosd import streaming

    fitted, _ = fitted_pca
    saved = fitted.save(tmp_path)
    before = saved.read_bytes()

    def full_disk(out, *args, **kwargs):
        out.write(b"PK\x03\x04 half")
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(streaming.np, "savez", full_disk)
    with pytest.raises(OSError, match="No space left"):
        fitted.save(tmp_path)
    assert saved.read_bytes() == before and sorted(p.name for p in tmp_path.iterdir()) == [saved.name]
    monkeypatch.undo()
    assert OnlinePipeline.load(saved).stages[-1].limits == fitted.stages[-1].limits


# -- 2. mosd monitor: --out and the store checked before scoring; stdin; --keep order ------------------
@pytest.fixture(scope="module")
def logged_model(tmp_path_factory, fitted_pca):
    """The fitted PCA logged as a run's model ``detector`` in a sqlite store, and a file of rows to score."""
    from mlflow import MlflowClient

    from mosd.app.detector_model import log_model

    tmp = tmp_path_factory.mktemp("logged")
    fitted, frame = fitted_pca
    state_file = fitted.save(tmp / "model")
    tracking = f"sqlite:///{tmp / 'mlflow.db'}"
    client = MlflowClient(tracking)
    run_id = client.create_run(client.create_experiment("hostile")).info.run_id
    uri = log_model(str(state_file), tracking, run_id)
    client.set_terminated(run_id)
    rows = tmp / "rows.csv"
    frame.iloc[600:900].to_csv(rows, index=False)
    return dict(tmp=tmp, uri=uri, tracking=tracking, rows=rows, fitted=fitted, frame=frame)


def _monitor_in_process(monkeypatch, capsys, args):
    """``mosd monitor`` in this process with scoring and model loading made to fail: a check must come first."""
    from mosd.app import monitor

    def never(*args, **kwargs):
        raise AssertionError("scored or loaded before the check")

    monkeypatch.setattr(monitor, "score_file", never)
    monkeypatch.setattr(monitor, "_load", never)
    code = monitor.main(args)
    return code, capsys.readouterr()


@pytest.mark.parametrize("where,said", [
    ("directory", "is a directory"), ("missing parent", "does not exist"), ("proc", "is not writable"),
    ("sysfs", "is not writable"), ("parent is a file", "is not a directory")])
def test_monitor_refuses_an_output_path_it_cannot_write_before_scoring(tmp_path, monkeypatch, capsys, where, said):
    rows = tmp_path / "rows.csv"
    plant(50).to_csv(rows, index=False)
    (tmp_path / "file").write_text("x")
    out = {"directory": str(tmp_path), "missing parent": str(tmp_path / "nowhere" / "alarms.csv"),
           "proc": "/proc/mosd-alarms.csv", "sysfs": "/sys/mosd-alarms.csv",
           "parent is a file": str(tmp_path / "file" / "alarms.csv")}[where]
    code, captured = _monitor_in_process(monkeypatch, capsys, [str(rows), "--model", "models:/m-0", "--out", out,
                                                                "--tracking-uri", f"sqlite:///{tmp_path / 'x.db'}"])
    line = one_line(captured.err)
    assert code == 2 and line.startswith(f"mosd monitor: error: --out={out!r}") and said in line
    assert not (tmp_path / "x.db").exists() and not (tmp_path / "nowhere").exists()


@pytest.mark.parametrize("kind", ["sqlite", "file", "bare path", "empty directory"])
def test_a_mistyped_tracking_uri_creates_nothing_and_names_the_store(tmp_path, monkeypatch, capsys, kind):
    rows = tmp_path / "rows.csv"
    plant(50).to_csv(rows, index=False)
    (tmp_path / "empty").mkdir()
    store = {"sqlite": tmp_path / "mlrunz" / "mlflow.db", "file": tmp_path / "mlrunz", "bare path": tmp_path / "mlrunz",
             "empty directory": tmp_path / "empty"}[kind]
    uri = {"sqlite": f"sqlite:///{store}", "file": store.as_uri()}.get(kind, str(store))
    before = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*"))
    code, captured = _monitor_in_process(monkeypatch, capsys, [str(rows), "--model", "models:/m-0123",
                                                                "--tracking-uri", uri])
    line = one_line(captured.err)
    assert code == 2 and f"tracking store {store}" in line and ("does not exist" in line or "holds no MLflow" in line)
    assert sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*")) == before  # nothing created


def test_a_model_that_does_not_load_creates_nothing(logged_model, tmp_path):
    r = logged_model
    before = sorted(str(p) for p in r["tmp"].rglob("*"))
    run = mosd(["monitor", "--model", "models:/m-0123456789", str(r["rows"]), "--tracking-uri", r["tracking"],
                "--out", str(tmp_path / "alarms.csv")], tmp_path)
    line = one_line(run.stderr)
    assert run.returncode == 2 and "models:/m-0123456789" in line
    assert sorted(str(p) for p in r["tmp"].rglob("*")) == before and not list(tmp_path.iterdir())


def test_monitor_reads_stdin_and_keeps_the_keep_order(logged_model, tmp_path):
    r = logged_model
    common = ["--model", r["uri"], "--tracking-uri", r["tracking"], "--keep", "fault", "--keep", "time", "--chunk", "7"]
    from_file = mosd(["monitor", str(r["rows"]), *common, "--out", str(tmp_path / "file.csv")], tmp_path)
    assert from_file.returncode == 0, from_file.stderr
    piped = mosd(["monitor", "-", *common, "--out", str(tmp_path / "stdin.csv")], tmp_path,
                 stdin=r["rows"].read_bytes())
    assert piped.returncode == 0, piped.stderr
    assert piped.stdout.startswith("stdin: 300 rows, ") and piped.stderr == ""
    a, b = pd.read_csv(tmp_path / "file.csv"), pd.read_csv(tmp_path / "stdin.csv")
    assert list(a.columns[:3]) == ["fault", "time", "t2"]  # the order given, before the model's columns
    pd.testing.assert_frame_equal(a, b)
    assert a["alarm"].any() and (a["fault"] == r["frame"]["fault"].iloc[600:900].to_numpy()).all()


# -- 3. the served model: 400 naming the param, strict JSON ---------------------------------------------
def test_the_scoring_server_answers_400_naming_the_param_and_strict_json(logged_model):
    """MLflow's scoring server (``invocations``, what ``mlflow models serve`` runs per request): an impossible
    state is HTTP 400 with the one line naming the param; an answer with a missing cell is strict JSON."""
    import mlflow
    from mlflow.exceptions import MlflowException
    from mlflow.pyfunc import scoring_server

    r = logged_model
    mlflow.set_tracking_uri(r["tracking"])
    model = mlflow.pyfunc.load_model(r["uri"])
    rows = r["frame"][list(TAGS)].iloc[700:705].astype(object)
    rows.iloc[2, 1] = None  # a missing value (JSON null): no statistic on that row

    def post(params):
        body = {"dataframe_split": {"columns": list(TAGS), "data": rows.to_numpy().tolist()}, "params": params}
        return scoring_server.invocations(json.dumps(body), "application/json", model, None)

    for params, name in [({"run_length": -5}, "run_length"), ({"ewma_t2": 1e308}, "ewma_t2")]:
        with pytest.raises(MlflowException) as info:
            post({"ewma_t2": 1.0, "ewma_spe": 1.0, "run_length": 0, **params})
        assert info.value.get_http_status_code() == 400
        assert f"param {name}={params[name]!r} is out of range; allowed: " in info.value.message
    answer = post({"ewma_t2": 1.0, "ewma_spe": 1.0, "run_length": 0})
    assert answer.status == 200

    def refuse(token):
        raise ValueError(f"{token} is not JSON")

    records = json.loads(answer.response, parse_constant=refuse)["predictions"]
    assert records[2]["t2"] is None and records[2]["alarm"] is False and records[1]["t2"] > 0


# -- 5. the documented promise for chunked scoring is what is measured ---------------------------------
# (the README's section on the deployed model moved to docs/how-to/deploy.md, issue 51; the README keeps a line)
README_CHUNK_PROMISE = "the same bits"
DEPLOY_PAGE = ROOT / "docs" / "how-to" / "deploy.md"


@pytest.mark.parametrize("m,lam", [(6, 1.0), (33, 0.3), (108, 0.05)])
def test_chunked_scoring_agrees_within_the_readme_s_tolerance(m, lam):
    """The projection sums over the variables in order whatever the rows (mosd.kernels.projection): chunks of
    1, 7, 13 and 1000 rows give the statistics of one call bit for bit (before, a one-row BLAS product and a
    block's differed by up to 1.9e-14 relative; the hostile battery saw 1.25e-14 against a promised 1e-15)."""
    assert README_CHUNK_PROMISE in DEPLOY_PAGE.read_text() and README_CHUNK_PROMISE in (ROOT / "README.md").read_text()
    rng = np.random.default_rng(m)
    X = rng.normal(size=(2400, 3)) @ rng.normal(size=(3, m)) + 0.3 * rng.normal(size=(2400, m))
    X[2000:2200, 0] += 3.0  # a shift of one tag: alarms to agree on
    detector = PCADetector(n_components=3, alpha=0.01, lam=lam, persistence=2, max_components=min(20, m - 1),
                           fit_runs=1)
    fitted = pca_pipeline(detector, np.stack([X[:800], X[800:1600]]), [f"t{i}" for i in range(m)])
    test = X[1600:]
    whole = score(fitted, test)
    assert 0 < whole["alarm"].sum() < len(test)
    for chunk in (1, 7, 13, 1000):
        state, parts = None, []
        for start in range(0, len(test), chunk):
            out = score(fitted, test[start:start + chunk], state)
            state = fitted.final_state(out, state)
            parts.append(out)
        assert np.array_equal(np.concatenate([p["alarm"] for p in parts]), whole["alarm"])
        for key in ("t2", "spe", "t2_smoothed", "spe_smoothed", "ratio"):
            assert np.array_equal(np.concatenate([p[key] for p in parts]), whole[key], equal_nan=True), key


def test_a_half_upload_in_mosd_log_leaves_no_failed_model_record(tmp_path, fitted_pca, monkeypatch, capsys):
    """``mosd log`` whose model upload fails (a full artifact store) leaves MLflow a FAILED model record; the
    next ``mosd log`` logs the model whole and removes that record: the run shows one model, READY."""
    from mlflow import MlflowClient
    from mlflow.entities import LoggedModelStatus
    from mlflow.store.artifact.local_artifact_repo import LocalArtifactRepository

    from mosd.app import pending
    from mosd.app.mlflow_client import MlflowStore
    from mosd.app.settings import TrackingSettings

    fitted, _ = fitted_pca
    run_dir = tmp_path / "run"
    model = fitted.save(run_dir / "model")
    settings = TrackingSettings(f"sqlite:///{tmp_path / 'mlflow.db'}", (tmp_path / "artifacts").as_uri(), "mosd")
    store = MlflowStore(settings)
    run_id = store.create_run("r", {"mosd.role": "job", "mosd.run_dir": str(run_dir)})
    store.end(run_id, "FAILED", "the artifact store was full")
    request = {"settings": {"uri": settings.uri, "artifact_root": settings.artifact_root, "experiment": "mosd"},
               "run_id": run_id, "run_name": "r", "tags": {"mosd.role": "job", "mosd.run_dir": str(run_dir)},
               "parent_run_id": None, "params": {"seed": "0"}, "metrics": [["far", 0.01, 0]], "artifacts": [],
               "model": str(model)}
    (run_dir / pending.PENDING_FILE).write_text(json.dumps(request))
    original = LocalArtifactRepository.log_artifacts

    def half_then_full(self, local_dir, artifact_path=None):
        names = sorted(p.name for p in Path(local_dir).iterdir())
        (Path(self.artifact_dir) / (artifact_path or "")).mkdir(parents=True, exist_ok=True)
        (Path(self.artifact_dir) / (artifact_path or "") / names[0]).write_bytes(b"half")
        raise OSError(28, "No space left on device", self.artifact_dir)

    monkeypatch.setattr(LocalArtifactRepository, "log_artifacts", half_then_full)
    assert pending.log_main([str(run_dir)]) != 0
    client = MlflowClient(settings.uri)

    def statuses():
        experiment = client.get_run(run_id).info.experiment_id
        return sorted(str(m.status) for m in client.search_logged_models([experiment]) if m.source_run_id == run_id)

    assert statuses() and LoggedModelStatus.READY not in statuses()  # the half-upload's record
    monkeypatch.setattr(LocalArtifactRepository, "log_artifacts", original)
    capsys.readouterr()
    assert pending.log_main([str(run_dir)]) == 0, capsys.readouterr().err
    assert statuses() == [str(LoggedModelStatus.READY)]
    assert client.get_run(run_id).info.status == "FINISHED"


def test_hydra_cfg_output_masks_the_tracking_password(tmp_path):
    for mode in (["--cfg", "job"], ["--cfg", "all"], ["--info", "config"]):
        run = mosd([*mode, "+fault=offset", "tracking.uri=postgresql://mosd:s3cret@localhost/db"], tmp_path)
        assert run.returncode == 0, run.stderr
        assert "s3cret" not in run.stdout + run.stderr and "postgresql://mosd:***@localhost/db" in run.stdout


# -- 5. tls:// Dask addresses are checked like tcp:// ones ----------------------------------------------
def _self_signed(tmp_path: Path) -> tuple[str, str]:
    """A self-signed certificate for 127.0.0.1 and its key (cryptography: a dependency of MLflow)."""
    import datetime
    import ipaddress

    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import NameOID

    key = ec.generate_private_key(ec.SECP256R1())
    name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "mosd-test")])
    now = datetime.datetime.now(datetime.timezone.utc)
    cert = (x509.CertificateBuilder().subject_name(name).issuer_name(name).public_key(key.public_key())
            .serial_number(x509.random_serial_number()).not_valid_before(now - datetime.timedelta(minutes=5))
            .not_valid_after(now + datetime.timedelta(hours=1))
            .add_extension(x509.BasicConstraints(ca=True, path_length=None), critical=True)
            .add_extension(x509.SubjectAlternativeName([x509.IPAddress(ipaddress.ip_address("127.0.0.1")),
                                                        x509.DNSName("localhost")]), critical=False)
            .sign(key, hashes.SHA256()))
    cert_file, key_file = tmp_path / "cert.pem", tmp_path / "key.pem"
    cert_file.write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    key_file.write_bytes(key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                                           serialization.NoEncryption()))
    return str(cert_file), str(key_file)


def test_tls_dask_addresses_are_checked_like_tcp_ones(tmp_path):
    import socket
    import threading

    import dask.config

    from mosd.optim.backends import check_scheduler

    with pytest.raises(ConfigError, match=r"'tls://127.0.0.1' has no host and port; allowed: .*tls://host:8786"):
        check_scheduler("tls://127.0.0.1")
    closed = socket.create_server(("127.0.0.1", 0))
    port = closed.getsockname()[1]
    closed.close()
    with pytest.raises(ConfigError, match=rf"'tls://127.0.0.1:{port}': no Dask scheduler answers there"):
        check_scheduler(f"tls://127.0.0.1:{port}", timeout=2)
    # something listens, speaking HTTP: without the Dask config's TLS settings, one line says what is missing
    listener = socket.create_server(("127.0.0.1", 0))

    def answer():
        while True:
            try:
                conn, _ = listener.accept()
            except OSError:
                return
            conn.sendall(b"HTTP/1.1 200 OK\r\n\r\nhello")

    threading.Thread(target=answer, daemon=True).start()
    address = f"tls://127.0.0.1:{listener.getsockname()[1]}"
    try:
        with pytest.raises(ConfigError, match=r"is a TLS address but the Dask config has no TLS settings"):
            check_scheduler(address, timeout=2)
        cert, key = _self_signed(tmp_path)
        tls = {"distributed.comm.tls.ca-file": cert, "distributed.comm.tls.client.cert": cert,
               "distributed.comm.tls.client.key": key}
        with dask.config.set(tls):
            with pytest.raises(ConfigError) as info:
                check_scheduler(address, timeout=2)
    finally:
        listener.close()
    assert "\n" not in str(info.value) and f"'{address}' accepts connections but is not a Dask scheduler" in str(info.value)
    # a Dask scheduler over TLS, the client's settings in the Dask config: passes
    from distributed import LocalCluster
    from distributed.security import Security

    security = Security(tls_ca_file=cert, tls_scheduler_cert=cert, tls_scheduler_key=key, tls_client_cert=cert,
                        tls_client_key=key, tls_worker_cert=cert, tls_worker_key=key, require_encryption=True)
    with LocalCluster(n_workers=0, processes=False, protocol="tls", security=security, dashboard_address=None) as c:
        assert c.scheduler_address.startswith("tls://")
        with dask.config.set(tls):
            check_scheduler(c.scheduler_address, timeout=10)


# -- 4. stderr carries only mosd's own lines --------------------------------------------------------------
LEAK = """
import multiprocessing as mp, os, sys
from multiprocessing import resource_tracker
if sys.argv[1] == "quiet":
    from mosd.app.sweep import quiet_resource_trackers
    with quiet_resource_trackers():
        resource_tracker.ensure_running()
lock = mp.get_context("spawn").Lock()   # a named semaphore, registered with the tracker
os._exit(0)                             # ended as joblib's abort ends a job worker: never unregistered
"""


@pytest.mark.parametrize("mode", ["plain", "quiet"])
def test_the_resource_tracker_of_a_stopped_sweep_does_not_warn(mode):
    """``plain`` is the tracker as before (the warning a stopped joblib sweep printed); ``quiet`` as the sweep
    starts it now (mosd.app.sweep.quiet_resource_trackers): the semaphore is cleaned up all the same."""
    out = subprocess.run([sys.executable, "-c", LEAK, mode], env=_env(Path("/nonexistent")), capture_output=True,
                         text=True, timeout=60)
    assert out.returncode == 0
    if mode == "plain":
        assert "leaked semaphore objects to clean up at shutdown" in out.stderr  # what the test guards against
    else:
        assert out.stderr == ""


WORKER_SIGINT = """
import os, signal, time
from mosd.optim.workers import memmapping_executor, pool_pids
executor = memmapping_executor(2, 60)
seen, t0 = set(), time.time()
while len(seen) < 2 and time.time() - t0 < 60:  # under load the second worker may start late
    seen |= {f.result() for f in [executor.submit(lambda: (time.sleep(0.5), os.getpid())[1]) for _ in range(2)]}
assert len(seen) == 2
before = sorted(pool_pids())  # both workers started and idle, as between two generations
for pid in before:
    os.kill(pid, signal.SIGINT)          # a Ctrl-C reaches the whole process group
time.sleep(1.0)
print(executor.submit(sum, [1, 2]).result(), sorted(pool_pids()) == before)
"""


def test_evaluation_workers_ignore_a_ctrl_c_to_the_process_group():
    """The run's handler stops its workers with SIGTERM; a KeyboardInterrupt in each worker printed a
    traceback on stderr (cut off by that SIGTERM) and broke the pool."""
    out = subprocess.run([sys.executable, "-c", WORKER_SIGINT], env=_env(Path("/nonexistent")), capture_output=True,
                         text=True, timeout=120)
    assert out.returncode == 0 and out.stdout.split() == ["3", "True"], out.stderr[-2000:]
    assert "Traceback" not in out.stderr and "KeyboardInterrupt" not in out.stderr, out.stderr[-2000:]


def test_the_rows_per_tag_rule_is_what_the_far_measures():
    """docs/systems/tep.md, "How many calibration rows": 20 tags, 3 latent factors, 30 seeds. At 1.1 rows per
    tag the in-control test FAR is far above its target; from 5 (WARN_ROWS_PER_TAG) it is within 10 %."""
    from mosd.data.table import WARN_ROWS_PER_TAG

    nominal = 1 - 0.99**2  # T² or SPE above its α = 0.01 limit

    def mean_far(rows_per_tag: float, m: int = 20) -> float:
        fars = []
        for seed in range(30):
            rng = np.random.default_rng(seed)
            W = rng.normal(size=(3, m))
            W /= np.linalg.norm(W, axis=0)

            def draw(n):
                return rng.normal(size=(n, 3)) @ W + 0.3 * rng.normal(size=(n, m))

            n = int(rows_per_tag * m)
            detector = PCADetector(n_components=3, alpha=0.01, max_components=min(m - 1, n - 1))
            fars.append(detector.decide(draw(n)[None], draw(4000)[None]).decision[0].mean())
        return float(np.mean(fars))

    assert mean_far(1.1) > 2.5 * nominal
    assert abs(mean_far(WARN_ROWS_PER_TAG) / nominal - 1) < 0.1


def test_values_near_1e308_are_error_codes_not_overflows(tmp_path, fitted_pca):
    """An export's 1e308 (or -1.7e308) is read as a missing value (and filled) or, with errors=strict, one line;
    the served model scores a row holding one without a NumPy warning (the row has no statistic)."""
    import warnings

    frame = plant(300)
    frame.loc[[10, 200], "TI-1"] = [1e308, -1.7e308]
    frame.to_csv(tmp_path / "huge.csv", index=False)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # an overflow warning fails the test
        table = Table(str(tmp_path / "huge.csv"), time_column="time", fill="hold")
    values = table.values(str(tmp_path / "huge.csv"))
    column = list(table.output_names).index("TI-1")
    assert np.isfinite(values).all() and values[10, column] == values[9, column]
    with pytest.raises(ConfigError, match=r"column 'TI-1' row 10 holds '1e\+308', not a number within ±1e\+150"):
        Table(str(tmp_path / "huge.csv"), time_column="time", errors="strict")
    fitted, rows = fitted_pca
    rows = rows[list(TAGS)].iloc[600:610].copy()
    rows.iloc[3, 2] = 1e308
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        out = model_state.predict(fitted, rows, None)
    assert out["t2"].iloc[3] is None and out["t2"].iloc[4] is not None and not out["alarm"].iloc[3]
