"""The app end to end, as a user runs it: ``python -m mosd ...`` in a fresh directory.

Every subprocess runs with cwd = a tmp directory (outputs go to ``<tmp>/outputs``,
or to ``$MOSD_OUTPUTS``), so the repository's ``outputs/`` is never touched. Runs
use a reduced budget; the end-to-end tests are marked slow.
"""
from __future__ import annotations

import csv
import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import mosd as mosd_package
from mosd.app import CONFIG_DIR
from mosd.estimators import CESCKF
from mosd.plants.base import fault_classes

# subprocesses import the same mosd as this test process (a checkout or an install)
PACKAGE_PARENT = str(Path(mosd_package.__file__).resolve().parents[1])

REDUCED = ["optimizer.pop_size=10", "optimizer.n_gen=3", "budget.n_test=5", "budget.n_train=3",
           "budget.n_calibration=3", "optimizer.n_jobs=1"]
#: the fault options as the one-line errors list them, read from conf/fault/ (issue 50: no hand-kept list)
FAULTS = ", ".join(sorted(path.stem for path in (Path(CONFIG_DIR) / "fault").glob("*.yaml")))
#: the fault classes a sensor-fault plant takes, as its one-line refusal lists them (found from acts_on)
SENSOR_FAULTS = ", ".join(fault_classes(("sensor",)))
RUN_DIR_NAME = re.compile(r"^\d{4}-\d{2}-\d{2}_\d{2}-\d{2}-\d{2}-\d{6}$")
FINAL_METRICS = {"far", "far_ci", "mdr", "mdr_ci", "accuracy", "accuracy_ci", "delay", "delay_ci", "lam", "K",
                 "wall_time_s"}


def mosd(args, cwd, outputs=None, command=None, extra_path=None, timeout=600):
    env = {k: v for k, v in os.environ.items() if not k.startswith("MOSD_") and k != "HYDRA_FULL_ERROR"}
    env["PYTHONPATH"] = os.pathsep.join(p for p in (PACKAGE_PARENT, extra_path, env.get("PYTHONPATH")) if p)
    if outputs is not None:
        env["MOSD_OUTPUTS"] = str(outputs)
    cmd = command or [sys.executable, "-m", "mosd"]
    return subprocess.run([*cmd, *args], cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)


def client_for(outputs: Path):
    from mlflow.tracking import MlflowClient

    return MlflowClient(tracking_uri=f"sqlite:///{outputs.resolve() / 'mlflow.db'}")


def runs_of(outputs: Path, experiment: str = "mosd"):
    client = client_for(outputs)
    exp = client.get_experiment_by_name(experiment)
    assert exp is not None, "no MLflow experiment was created"
    return client, client.search_runs([exp.experiment_id], max_results=1000)


# ---------------------------------------------------------------------------------------
# errors: one line, exit 2, nothing written (fast)
# ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("args,expected", [
    ([], r"no fault chosen.*" + re.escape(FAULTS)),
    (["+faults=offset_var", "optimizer=mopso"], r"'faults'.*\+fault=NAME.*offset_var"),
    (["+fault=offset_var", "optimizer=foo"], r"optimizer=foo is not an option; allowed: mopso, (.*, )?nsga2"),
    (["+fault=nope"], r"fault=nope is not an option; allowed: " + re.escape(FAULTS)),
    (["+fault=offset_var", "detector.lam=1.5"], r"detector\.lam=1\.5 is out of range; allowed: \(0, 1\)"),
    (["+fault=offset_var", "optimizer.pop_size=0"], r"optimizer\.pop_size=0 is out of range; allowed: integers"),
    # a fault acting where the plant takes none (issue 50: a TypeError in the dry run before)
    (["+fault=actuator", "plant=two_tank", "noise=two_tank"], r"^mosd: error: fault=ActuatorFault acts on an "
     r"actuator, but plant two_tank takes faults acting on sensor only; allowed: " + re.escape(SENSOR_FAULTS)),
    # the preset's keys for its own sensor fault (fault.channel) are not the reason given (they were before)
    (["+experiment=two_tank", "fault=actuator"], r"^mosd: error: fault=ActuatorFault acts on an "
     r"actuator, but plant two_tank takes faults acting on sensor only; allowed: " + re.escape(SENSOR_FAULTS)),
])
def test_errors_are_one_line_exit_2_and_leave_nothing(tmp_path, args, expected):
    result = mosd(args, cwd=tmp_path)
    assert result.returncode == 2, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert re.search(expected, lines[0]), lines[0]
    assert "Traceback" not in result.stderr and result.stdout == ""
    assert not (tmp_path / "outputs").exists(), "a run directory or MLflow store was created"
    assert list(tmp_path.iterdir()) == []


def test_console_script_is_the_same_command(tmp_path):
    script = Path(sys.executable).with_name("mosd")
    if not script.exists():
        script = shutil.which("mosd")
    assert script is not None, "the mosd console script is missing: pip install . installs it"
    via_script = mosd([], cwd=tmp_path, command=[str(script)])
    via_module = mosd([], cwd=tmp_path)
    assert via_script.returncode == via_module.returncode == 2
    assert via_script.stderr == via_module.stderr


def test_wheel_layout_finds_conf_inside_the_package(tmp_path):
    # a wheel installs conf/ as mosd/conf: emulate that layout away from the checkout
    site = tmp_path / "site"
    shutil.copytree(Path(mosd_package.__file__).parent, site / "mosd",
                    ignore=shutil.ignore_patterns("__pycache__", "conf"))
    shutil.copytree(CONFIG_DIR, site / "mosd" / "conf")
    work = tmp_path / "work"
    work.mkdir()
    env = {k: v for k, v in os.environ.items() if not k.startswith("MOSD_")}
    env["PYTHONPATH"] = str(site)
    probe = subprocess.run([sys.executable, "-c", "import mosd.app as a; print(a.CONFIG_DIR)"], cwd=work, env=env,
                           capture_output=True, text=True, timeout=120)
    assert probe.stdout.strip() == str(site / "mosd" / "conf"), probe.stderr
    result = subprocess.run([sys.executable, "-m", "mosd", "+fault=offset", "detector.lam=2"], cwd=work, env=env,
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 2 and "detector.lam=2 is out of range" in result.stderr


def test_report_without_a_store_is_one_line(tmp_path):
    result = mosd(["report"], cwd=tmp_path)
    assert result.returncode == 2 and len(result.stderr.strip().splitlines()) == 1
    assert "no such database" in result.stderr and not (tmp_path / "outputs").exists()


# ---------------------------------------------------------------------------------------
# the main command end to end (slow)
# ---------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def main_run(tmp_path_factory):
    cwd = tmp_path_factory.mktemp("main")
    result = mosd(["+fault=offset_var", "optimizer=mopso", *REDUCED], cwd=cwd)
    assert result.returncode == 0, result.stderr[-3000:]
    return cwd, result


@pytest.mark.slow
def test_main_command_prints_the_summary(main_run):
    _, result = main_run
    out = result.stdout
    for needle in ("chosen", "lam =", "K =", "FAR", "MDR", "accuracy", "delay", "wall time", "95 % CI"):
        assert needle in out, needle
    assert re.search(r"FAR\s+\d\.\d+ ± \d\.\d+", out)
    assert "Traceback" not in result.stderr
    assert "\r" not in result.stderr and "gen 3/3" not in result.stderr  # no progress bar into a pipe
    assert json.loads(next((main_run[0] / "outputs" / "runs").iterdir()).joinpath("summary.json").read_text())[
        "status"] == "finished"


@pytest.mark.slow
def test_main_command_writes_the_run_directory(main_run):
    cwd, _ = main_run
    run_dirs = list((cwd / "outputs" / "runs").iterdir())
    assert len(run_dirs) == 1 and RUN_DIR_NAME.match(run_dirs[0].name)
    run_dir = run_dirs[0]
    for name in ("resolved_config.yaml", "pareto.csv", "pareto.png", "chart.png", "residual.png", "history.csv",
                 "summary.json", ".hydra/overrides.yaml"):
        assert (run_dir / name).is_file(), name
    for png in run_dir.glob("*.png"):
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 5000
    resolved = (run_dir / "resolved_config.yaml").read_text()
    assert "${" not in resolved and "pop_size: 10" in resolved and "kind: offset_var" in resolved
    rows = list(csv.DictReader((run_dir / "pareto.csv").open()))
    F = np.array([[float(r["far"]), float(r["mdr"])] for r in rows])
    assert ((F >= 0) & (F <= 1)).all()
    dominated = [(np.all(F[j] <= F[i]) and np.any(F[j] < F[i])) for i in range(len(F)) for j in range(len(F))]
    assert not any(dominated), "the Pareto set has a dominated member"
    assert sum(r["chosen"] == "1" for r in rows) == 1
    history = list(csv.DictReader((run_dir / "history.csv").open()))
    assert [int(float(r["generation"])) for r in history] == [1, 2, 3]


@pytest.mark.slow
def test_main_command_logs_to_mlflow(main_run):
    cwd, _ = main_run
    client, runs = runs_of(cwd / "outputs")
    assert len(runs) == 1
    run = runs[0]
    assert run.info.status == "FINISHED"
    metrics, params, tags = run.data.metrics, run.data.params, run.data.tags
    assert FINAL_METRICS <= set(metrics)
    assert metrics["accuracy"] == pytest.approx(1.0 - metrics["far"] - metrics["mdr"], abs=1e-9)
    assert 0.0 < metrics["lam"] < 1.0 and 0.0 <= metrics["K"] <= 10.0  # the default box, Fig. 1's
    steps = [m.step for m in client.get_metric_history(run.info.run_id, "hypervolume")]
    assert sorted(steps) == [1, 2, 3]
    assert len(client.get_metric_history(run.info.run_id, "archive_size")) == 3
    assert params["optimizer.pop_size"] == "10" and params["fault.kind"] == "offset_var"
    assert params["detector._target_"] == "mosd.detectors.mean_variance.SSDEWMA"
    assert "+fault=offset_var optimizer=mopso" in tags["mosd.overrides"]
    assert tags["mosd.fault"] == "offset_var" and tags["mosd.optimizer"] == "mopso"
    artifacts = {a.path for a in client.list_artifacts(run.info.run_id)}
    assert {"pareto.csv", "pareto.png", "chart.png", "residual.png", "resolved_config.yaml"} <= artifacts
    # the artifacts live under the outputs root, as does the store
    assert run.info.artifact_uri.startswith((cwd / "outputs").resolve().as_uri())
    # the chosen design in the CSV is the one logged
    run_dir = Path(tags["mosd.run_dir"])
    chosen = [r for r in csv.DictReader((run_dir / "pareto.csv").open()) if r["chosen"] == "1"][0]
    assert float(chosen["lam"]) == pytest.approx(metrics["lam"]) and float(chosen["K"]) == pytest.approx(metrics["K"])
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["test"]["far"]["mean"] == pytest.approx(metrics["far"])


@pytest.mark.slow
def test_report_reads_the_store(main_run):
    cwd, _ = main_run
    md = mosd(["report"], cwd=cwd)
    assert md.returncode == 0, md.stderr
    lines = md.stdout.strip().splitlines()
    assert lines[0].startswith("| preset | fault | detector | optimizer | MDR %") and len(lines) == 3
    assert lines[2].startswith("| – | offset_var | ss_dewma | mopso |")
    as_csv = mosd(["report", "--format", "csv", "--experiment", "mosd"], cwd=cwd)
    rows = list(csv.DictReader(as_csv.stdout.splitlines()))
    _, runs = runs_of(cwd / "outputs")
    assert len(rows) == 1 and rows[0]["run_id"] == runs[0].info.run_id
    assert float(rows[0]["far"]) == pytest.approx(runs[0].data.metrics["far"])
    missing = mosd(["report", "--experiment", "nope"], cwd=cwd)
    assert missing.returncode == 2 and "allowed: " in missing.stderr


# ---------------------------------------------------------------------------------------
# sweeps (slow)
# ---------------------------------------------------------------------------------------
@pytest.mark.slow
def test_sweep_gives_one_parent_and_one_child_per_job(tmp_path):
    outputs = tmp_path / "elsewhere"
    result = mosd(["-m", "+fault=offset,variance", "optimizer=mopso,nsga2", "progress=false", *REDUCED],
                  cwd=tmp_path, outputs=outputs)
    assert result.returncode == 0, result.stderr[-3000:]
    assert not (tmp_path / "outputs").exists()  # MOSD_OUTPUTS moved the outputs root
    sweeps = list((outputs / "multirun").iterdir())
    assert len(sweeps) == 1 and RUN_DIR_NAME.match(sweeps[0].name)
    assert sorted(p.name for p in sweeps[0].iterdir() if p.is_dir()) == ["0", "1", "2", "3"]
    _, runs = runs_of(outputs)
    parents = [r for r in runs if r.data.tags.get("mosd.role") == "sweep"]
    children = [r for r in runs if r.data.tags.get("mosd.role") == "job"]
    assert len(parents) == 1 and len(children) == 4
    parent = parents[0]
    assert parent.info.status == "FINISHED" and parent.info.end_time is not None
    assert {c.data.tags["mlflow.parentRunId"] for c in children} == {parent.info.run_id}
    assert all(c.info.status == "FINISHED" and FINAL_METRICS <= set(c.data.metrics) for c in children)
    combos = {(c.data.tags["mosd.fault"], c.data.tags["mosd.optimizer"]) for c in children}
    assert combos == {("offset", "mopso"), ("offset", "nsga2"), ("variance", "mopso"), ("variance", "nsga2")}


@pytest.mark.slow
def test_sweep_under_the_joblib_launcher(tmp_path):
    result = mosd(["-m", "hydra/launcher=joblib", "hydra.launcher.n_jobs=2", "+fault=offset", "optimizer=mopso,nsga2",
                   "progress=false", *REDUCED[:-1], "optimizer.n_jobs=2"], cwd=tmp_path)
    assert result.returncode == 0, result.stderr[-3000:]
    _, runs = runs_of(tmp_path / "outputs")
    parents = [r for r in runs if r.data.tags.get("mosd.role") == "sweep"]
    children = [r for r in runs if r.data.tags.get("mosd.role") == "job"]
    assert len(parents) == 1 and len(children) == 2 and parents[0].info.status == "FINISHED"
    assert all(c.data.tags["mlflow.parentRunId"] == parents[0].info.run_id for c in children)
    # nested joblib would silently become threads: jobs evaluate in-process
    assert {c.data.tags["mosd.n_jobs"] for c in children} == {"1"}


class ExplodingFilter(CESCKF):
    """A filter that constructs and passes preflight's one-replication dry run, and fails in the run."""

    def filter(self, model, y, u=None):
        if y.shape[0] > 1:
            raise RuntimeError("boom: the filter diverged")
        return super().filter(model, y, u)


@pytest.mark.slow
def test_a_failing_job_is_failed_and_the_parent_still_closes(tmp_path):
    # job 1 uses ExplodingFilter (importable as test_app.ExplodingFilter in the subprocess)
    result = mosd(["-m", "+fault=offset", "estimator.filter._target_=mosd.estimators.CESCKF,test_app.ExplodingFilter",
                   "progress=false", *REDUCED], cwd=tmp_path, extra_path=str(Path(__file__).parent))
    assert result.returncode == 1, result.stderr[-3000:]
    _, runs = runs_of(tmp_path / "outputs")
    parents = [r for r in runs if r.data.tags.get("mosd.role") == "sweep"]
    children = {r.data.tags["mosd.overrides"]: r for r in runs if r.data.tags.get("mosd.role") == "job"}
    assert len(parents) == 1 and len(children) == 2
    assert parents[0].info.end_time is not None and parents[0].info.status in ("FAILED", "FINISHED")
    failed = [r for o, r in children.items() if "ExplodingFilter" in o][0]
    ok = [r for o, r in children.items() if "CESCKF" in o][0]
    assert ok.info.status == "FINISHED" and FINAL_METRICS <= set(ok.data.metrics)
    assert failed.info.status == "FAILED" and failed.data.tags["error"] == "RuntimeError: boom: the filter diverged"
    assert "Traceback" in failed.data.tags["error.traceback"]
    # the failed job's directory says so instead of being a silent stub
    status = json.loads((Path(failed.data.tags["mosd.run_dir"]) / "summary.json").read_text())
    assert status["status"] == "failed" and status["error"] == "RuntimeError: boom: the filter diverged"
