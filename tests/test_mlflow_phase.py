"""What a tracked run waits for at its end, the MLflow phase (issue 32): only what it must, nothing lost.

* a new sqlite store starts as a copy of the empty store MLflow itself made once for this machine and
  these versions (:func:`mosd.app.mlflow_client.store_template`): no migration runs for it (MLflow's
  ``_initialize_tables`` is made to fail and the store still opens), and it holds what a store MLflow
  creates holds (the same tables, indexes, schema revision and experiments);
* logging the model in a process without numba (the tracking side process) neither imports numba nor
  loads the compiled kernels, and the logged signature is the one the compiled path gives; the warm-up
  imports no SciPy signal processing (slow: a run of the main command, ``debug=tiny``).
"""
from __future__ import annotations

import json
import os
import sqlite3
import subprocess
import sys
from pathlib import Path

import pytest

import mosd

PACKAGE_PARENT = str(Path(mosd.__file__).resolve().parents[1])


def _python(code: str, cwd: Path, **env) -> dict:
    """``code`` in a new interpreter on this checkout (``env`` added); its last line, as JSON."""
    full = {**os.environ, "PYTHONPATH": os.pathsep.join([PACKAGE_PARENT, os.environ.get("PYTHONPATH", "")]), **env}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600, env=full, cwd=cwd)
    assert out.returncode == 0, out.stderr[-3000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


OPEN_STORES = """
import json, os, sys
from pathlib import Path
from mosd.app.mlflow_client import MlflowStore
from mosd.app.settings import TrackingSettings

def store(name):
    return MlflowStore(TrackingSettings(uri=f"sqlite:///{Path(name).resolve()}", artifact_root="art", experiment="mosd"))

templates = os.environ["MOSD_STORE_TEMPLATES"]
os.environ["MOSD_STORE_TEMPLATES"] = "off"
store("by_mlflow.db")  # MLflow creates it: every migration
os.environ["MOSD_STORE_TEMPLATES"] = templates
store("first.db")  # builds the template (MLflow's migrations, once)
import mlflow.store.db.utils as db_utils

def no_migrations(engine):
    raise RuntimeError("a migration ran for a store copied from the template")

db_utils._initialize_tables = no_migrations
copied = store("copied.db")
run = copied.create_run("r", {"k": "v"})
copied.log(run, {"p": "1"}, [("m", 1.0, 0)])
copied.end(run)
print(json.dumps({"run": run}))
"""


def _contents(db: Path) -> dict:
    """What a store holds apart from its runs: schema, revision, experiments (without their timestamps)."""
    con = sqlite3.connect(db)
    try:
        # a table's columns and constraints as a set: alembic's table rebuilds list the constraints in an order
        # that differs from one creation to the next (two stores MLflow makes differ so, too)
        schema = sorted((kind, name, tuple(sorted(line.strip().rstrip(",") for line in (sql or "").splitlines())))
                        for kind, name, sql in con.execute("SELECT type, name, sql FROM sqlite_master "
                                                           "WHERE name NOT LIKE 'sqlite_%'"))
        revision = con.execute("SELECT version_num FROM alembic_version").fetchall()
        experiments = con.execute("SELECT experiment_id, name, artifact_location, lifecycle_stage FROM experiments "
                                  "ORDER BY experiment_id").fetchall()
        tags = con.execute("SELECT key, value, experiment_id FROM experiment_tags ORDER BY 1, 3").fetchall()
    finally:
        con.close()
    return dict(schema=schema, revision=revision, experiments=experiments, tags=tags)


def test_a_new_store_is_a_copy_of_the_empty_store_mlflow_made_once(tmp_path):
    templates = tmp_path / "templates"
    made = _python(OPEN_STORES, tmp_path, MOSD_STORE_TEMPLATES=str(templates))
    assert [p.name for p in templates.iterdir() if p.suffix == ".db"][0].startswith("empty_mlflow-")
    assert not list(templates.glob("*.partial-*"))
    copied, by_mlflow = _contents(tmp_path / "copied.db"), _contents(tmp_path / "by_mlflow.db")
    assert copied == by_mlflow
    assert [e[1] for e in copied["experiments"]] == ["Default", "mosd"]
    # the Default experiment's location is the copying process's (MLflow adds it on opening), not the template's
    assert copied["experiments"][0][2] == str(tmp_path / "mlruns" / "0")
    con = sqlite3.connect(tmp_path / "copied.db")
    assert con.execute("SELECT status FROM runs WHERE run_uuid = ?", (made["run"],)).fetchone() == ("FINISHED",)
    con.close()


def test_templates_off_or_unwritable_leave_the_store_to_mlflow(tmp_path, monkeypatch):
    from mosd.app import mlflow_client, store

    monkeypatch.setenv("MOSD_STORE_TEMPLATES", "off")
    assert store.template_directory() is None and mlflow_client.start_from_template(tmp_path / "a.db") is False
    assert not (tmp_path / "a.db").exists()
    blocked = tmp_path / "file"
    blocked.write_text("not a folder")
    monkeypatch.setenv("MOSD_STORE_TEMPLATES", str(blocked / "templates"))
    assert mlflow_client.start_from_template(tmp_path / "b.db") is False
    assert not (tmp_path / "b.db").exists()  # MLflow then creates it, as it always did


LOG_MODEL = """
import json, sys
from pathlib import Path
from mosd.app.channel import _warm_model_logging
from mosd.app.detector_model import log_model
from mosd.app.mlflow_client import MlflowStore
from mosd.app.settings import TrackingSettings

uri = f"sqlite:///{Path('logged.db').resolve()}"
store = MlflowStore(TrackingSettings(uri=uri, artifact_root="art", experiment="mosd"))
run = store.create_run("r", {})
_warm_model_logging()
warmed = sorted(m for m in ("numba", "scipy.signal") if m in sys.modules)
model = log_model(MODEL, uri, run)
store.end(run)
import mlflow.models
signature = mlflow.models.get_model_info(model).signature.to_dict()
print(json.dumps({"warmed": warmed, "numba": "numba" in sys.modules, "signature": signature, "uri": uri,
                  "model": model}))
"""


@pytest.mark.slow
def test_the_model_is_logged_with_the_compiled_path_s_signature(tmp_path):
    outputs = tmp_path / "out"
    run = subprocess.run([sys.executable, "-m", "mosd", "+fault=offset_var", "debug=tiny", "progress=false"],
                         capture_output=True, text=True, timeout=600, cwd=tmp_path,
                         env={**os.environ, "MOSD_OUTPUTS": str(outputs), "MOSD_STORE_TEMPLATES": str(tmp_path / "t"),
                              "PYTHONPATH": os.pathsep.join([PACKAGE_PARENT, os.environ.get("PYTHONPATH", "")])})
    assert run.returncode == 0, run.stderr[-3000:]
    assert "model models:/" in run.stdout, run.stdout[-2000:]
    state_file = next((outputs / "runs").glob("*/model/pipeline.npz"))
    logged = _python(LOG_MODEL.replace("MODEL", repr(str(state_file))), tmp_path,
                     MOSD_STORE_TEMPLATES=str(tmp_path / "t"))
    # the warm-up imports neither numba nor scipy.signal; scoring the example does load numba since the chart's
    # one step is compiled code (mosd.kernels.ewma.chart_recursion, issue 50: no NumPy copy to fall back on)
    assert logged["warmed"] == [] and logged["numba"] is True
    from mlflow.models import get_model_info

    from mosd import kernels
    from mosd.app.detector_model import load_fitted, signature

    assert kernels.enabled()  # the compiled path, in this process
    fitted = load_fitted(state_file)
    compiled = signature(fitted, fitted.example()).to_dict()
    assert logged["signature"] == compiled
    # the run's own model (logged by its side process) has that signature too
    summary = json.loads(next((outputs / "runs").glob("*/summary.json")).read_text())
    import mlflow

    mlflow.set_tracking_uri(f"sqlite:///{outputs / 'mlflow.db'}")
    assert get_model_info(summary["model"]).signature.to_dict() == compiled
