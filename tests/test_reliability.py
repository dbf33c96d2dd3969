"""Nothing a user runs is lost (issue 8): store creation under a lock, preflight checks of the store and
the outputs directory, values valid alone but not together, signals, late tracking failures.

Fast tests call the app's functions in-process or run ``python -m mosd`` only up to preflight; the
multi-process ones (concurrent first runs, signals, a real ``mlflow server``) are marked slow. Every
subprocess runs in a tmp directory; servers bind 127.0.0.1 only.
"""
from __future__ import annotations

import contextlib
import csv
import json
import os
import re
import signal
import socket
import sqlite3
import subprocess
import sys
import textwrap
import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import numpy as np
import pytest

from mosd.app import preflight as preflight_module
from mosd.app import checks, mlflow_client, store
from mosd.app.serving import free_port
from mosd.app.settings import TrackingSettings
from mosd.app.config import UsageError
from mosd.validation import ConfigError

from test_app import FINAL_METRICS, mosd

SMALL = ["optimizer.pop_size=10", "optimizer.n_gen=3", "budget.n_test=3", "budget.n_train=3",
         "budget.n_calibration=3", "optimizer.n_jobs=1", "progress=false"]


def one_line_exit_2(result) -> str:
    assert result.returncode == 2, result.stderr[-3000:]
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in result.stderr, result.stderr[-3000:]
    return lines[0]


def make_store(path: Path, *, tables=("experiments", "runs", "alembic_version"), version=True, n_runs=0,
               leftover=False) -> Path:
    """A sqlite file shaped like an MLflow store (or a damaged one) without importing MLflow."""
    con = sqlite3.connect(path)
    for table in tables:
        con.execute(f"CREATE TABLE {table} (id TEXT)")
    if version and "alembic_version" in tables:
        con.execute("INSERT INTO alembic_version VALUES ('head')")
    for i in range(n_runs):
        con.execute("INSERT INTO runs VALUES (?)", (str(i),))
    if leftover:
        con.execute("CREATE TABLE _alembic_tmp_runs (id TEXT)")
    con.commit()
    con.close()
    return path


# ---------------------------------------------------------------------------------------
# 1. the store: health, recovery of a killed creation, the lock
# ---------------------------------------------------------------------------------------
def test_sqlite_paths_follow_sqlalchemy():
    assert store.sqlite_path("sqlite:////abs/outputs/mlflow.db") == Path("/abs/outputs/mlflow.db")
    assert store.sqlite_path("sqlite:///relative/mlflow.db") == Path("relative/mlflow.db")
    assert store.sqlite_path("sqlite://") is None and store.sqlite_path("http://127.0.0.1:5000") is None


def test_store_state_tells_healthy_incomplete_and_corrupt_apart(tmp_path):
    assert store.sqlite_store_state(tmp_path / "none.db").state == "missing"
    (tmp_path / "empty.db").touch()
    assert store.sqlite_store_state(tmp_path / "empty.db").state == "empty"
    assert store.sqlite_store_state(make_store(tmp_path / "ok.db", n_runs=2)) == store.StoreState("ok", "", 2)
    half = store.sqlite_store_state(make_store(tmp_path / "half.db", leftover=True))
    assert half.state == "incomplete" and "_alembic_tmp_runs" in half.detail and half.n_runs == 0
    no_version = store.sqlite_store_state(make_store(tmp_path / "nv.db", version=False, n_runs=1))
    assert no_version.state == "incomplete" and no_version.n_runs == 1
    (tmp_path / "junk.db").write_bytes(np.random.default_rng(0).bytes(8192))
    assert store.sqlite_store_state(tmp_path / "junk.db").state == "corrupt"


def test_a_killed_creation_is_moved_aside_and_a_damaged_store_with_runs_refused(tmp_path):
    half = make_store(tmp_path / "mlflow.db", tables=("experiments",), leftover=True)
    note = store.prepare_sqlite_store(half)
    assert "moved an unfinished store aside" in note and not half.exists()
    assert len(list(tmp_path.glob("mlflow.db.incomplete-*"))) == 1
    damaged = make_store(tmp_path / "mlflow.db", leftover=True, n_runs=3)
    with pytest.raises(store.TrackingError, match=r"mlflow\.db is damaged .*_alembic_tmp_runs.*move the file aside"):
        store.prepare_sqlite_store(damaged)
    assert damaged.exists()  # runs are never moved or deleted


def test_store_lock_excludes_other_processes(tmp_path):
    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    holder = subprocess.Popen([sys.executable, "-c", (
        "import sys, time; from mosd.app.store import store_lock\n"
        "with store_lock(sys.argv[1]) as held:\n    print(held, flush=True); time.sleep(3)"), uri],
        stdout=subprocess.PIPE, text=True, env={**os.environ, "PYTHONPATH": str(Path(store.__file__).parents[2])})
    try:
        assert holder.stdout.readline().strip() == "True"
        t0 = time.monotonic()
        with store.store_lock(uri, timeout=0.3) as held:
            assert not held and time.monotonic() - t0 < 2
        with store.store_lock(uri, timeout=10) as held:  # released when the holder ends
            assert held
    finally:
        holder.kill()
        holder.wait()


def test_mlflow_store_recovers_a_store_a_killed_migration_left(tmp_path):
    import mlflow  # noqa: F401  (a test dependency: a missing one fails, never skips)
    db = make_store(tmp_path / "mlflow.db", tables=("experiments", "metrics"), leftover=True)
    settings = TrackingSettings(f"sqlite:///{db}", (tmp_path / "art").as_uri(), "mosd")
    mlstore = mlflow_client.MlflowStore(settings)
    assert mlstore.note and "moved an unfinished store aside" in mlstore.note
    run_id = mlstore.create_run("r", {"mosd.role": "job"})
    mlstore.end(run_id)
    assert store.sqlite_store_state(db).state == "ok"
    assert mlstore.client.get_run(run_id).info.status == "FINISHED"


# ---------------------------------------------------------------------------------------
# 2. preflight: store and outputs checked before any work (one line, exit 2, nothing written)
# ---------------------------------------------------------------------------------------
def test_unreachable_tracking_server_fails_in_preflight_within_seconds(tmp_path):
    port = free_port()  # nothing listens there
    t0 = time.monotonic()
    result = mosd(["+fault=offset_var", f"tracking.uri=http://127.0.0.1:{port}", *SMALL], cwd=tmp_path, timeout=60)
    elapsed = time.monotonic() - t0
    line = one_line_exit_2(result)
    assert f"tracking.uri=http://127.0.0.1:{port} is not reachable" in line and "tracking=none" in line
    assert elapsed < 15, elapsed
    assert list(tmp_path.iterdir()) == []


class _NotMlflow(BaseHTTPRequestHandler):
    """Any web server: 404 with an HTML page for every path (or a proxy answering every host)."""

    def do_GET(self):
        self.send_error(404)

    def log_message(self, *args):
        pass


class _MlflowWithoutTheExperiment(BaseHTTPRequestHandler):
    """Answers ``experiments/get-by-name`` as MLflow 3 does for a name it does not hold (server/handlers.py)."""

    def _send(self, status: int, body: bytes, kind: str = "application/json") -> None:
        self.send_response(status)
        self.send_header("Content-Type", kind)
        self.end_headers()
        self.wfile.write(body)

    def _reply(self):
        if self.command == "GET" and self.path == "/api/2.0/mlflow/experiments/get-by-name?experiment_name=deleted":
            self._send(200, b'{"experiment": {"experiment_id": "7", "name": "deleted", "lifecycle_stage": "deleted"}}')
        elif self.command == "GET" and self.path.startswith("/api/2.0/mlflow/experiments/get-by-name?experiment_name="):
            self._send(404, b'{"error_code": "RESOURCE_DOES_NOT_EXIST", "message": "Could not find experiment"}')
        else:
            self._other()

    def _other(self):
        self._send(404, b'{"error_code": "ENDPOINT_NOT_FOUND", "message": "no such endpoint"}')

    do_GET = do_POST = _reply

    def log_message(self, *args):
        pass


@contextlib.contextmanager
def http_server(handler):
    server = ThreadingHTTPServer(("127.0.0.1", 0), handler)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    try:
        yield f"http://127.0.0.1:{server.server_address[1]}"
    finally:
        server.shutdown()
        server.server_close()


@contextlib.contextmanager
def tcp_server(answer: bytes | None):
    """A plain TCP service on 127.0.0.1: accepts, then sends ``answer`` (None: nothing) and keeps the connection."""
    listener = socket.create_server(("127.0.0.1", 0))
    held = []

    def serve():
        while True:
            try:
                conn, _ = listener.accept()
            except OSError:  # closed: the test is over
                return
            held.append(conn)
            if answer is not None:
                conn.sendall(answer)

    threading.Thread(target=serve, daemon=True).start()
    try:
        yield f"tcp://127.0.0.1:{listener.getsockname()[1]}"
    finally:
        listener.close()
        for conn in held:
            conn.close()


def test_a_web_server_that_is_not_mlflow_fails_in_preflight(tmp_path):
    with http_server(_NotMlflow) as uri:
        t0 = time.monotonic()
        with_password = uri.replace("http://", "http://alice:s3cret@")
        result = mosd(["+fault=offset_var", f"tracking.uri={with_password}", *SMALL], cwd=tmp_path, timeout=120)
        elapsed = time.monotonic() - t0
    line = one_line_exit_2(result)
    masked = uri.replace("http://", "http://alice:***@")
    assert f"tracking.uri={masked} answers HTTP but not as an MLflow tracking server" in line, line
    assert "HTTP 404" in line and "tracking=none" in line
    assert elapsed < 20, elapsed
    assert list(tmp_path.iterdir()) == []


def test_an_mlflow_server_passes_the_check_unless_its_experiment_is_deleted():
    with http_server(_MlflowWithoutTheExperiment) as uri:
        checks.check_mlflow_server(uri, "mosd", timeout=3)  # the run creates the experiment
        with pytest.raises(ConfigError, match=r"tracking.experiment='deleted' is deleted .*--experiment-id 7\)$"):
            checks.check_mlflow_server(uri, "deleted", timeout=3)  # MLflow refuses runs in a deleted experiment


@pytest.mark.parametrize("answer", [None, b"\xff" * 64, b"HTTP/1.1 200 OK\r\n\r\nhello"],
                         ids=["silent", "garbage", "http"])
def test_a_tcp_service_that_is_not_a_dask_scheduler_fails_in_preflight(tmp_path, answer):
    with tcp_server(answer) as address:
        t0 = time.monotonic()
        result = mosd(["+fault=offset_var", "optimizer.backend=dask", f"optimizer.dask_address={address}",
                       "tracking=none", *SMALL], cwd=tmp_path, timeout=120)
        elapsed = time.monotonic() - t0
    line = one_line_exit_2(result)
    assert f"optimizer.dask_address='{address}' accepts connections but is not a Dask scheduler" in line, line
    assert elapsed < 30, elapsed
    assert not (tmp_path / "outputs" / "runs").exists()


@pytest.mark.parametrize("text,masked,bare", [
    ("postgresql://mlflow:pw@127.0.0.1:5432/db", "postgresql://mlflow:***@127.0.0.1:5432/db",
     "postgresql://mlflow@127.0.0.1:5432/db"),
    ("x tracking.uri=mysql+pymysql://root:p%40ss@db/m y", "x tracking.uri=mysql+pymysql://root:***@db/m y",
     "x tracking.uri=mysql+pymysql://root@db/m y"),
    (r"tracking.uri=http\://alice\:pw@host\:5000", r"tracking.uri=http\://alice\:***@host\:5000",
     r"tracking.uri=http\://host\:5000"),  # Hydra's escaped override (its launcher log, overrides.yaml)
    ("http://host:5000/a?b=c@d", "http://host:5000/a?b=c@d", "http://host:5000/a?b=c@d"),
    ("sqlite:////tmp/a:b@c/mlflow.db", "sqlite:////tmp/a:b@c/mlflow.db", "sqlite:////tmp/a:b@c/mlflow.db"),
])
def test_uri_passwords_are_masked_and_can_be_left_to_the_driver(text, masked, bare):
    from mosd.app.settings import redacted, without_password

    assert redacted(text) == masked and redacted(masked) == masked
    assert without_password(masked) == bare


@pytest.mark.parametrize("answer", [b"\xff" * 64, b"HTTP/1.1 200 OK\r\n\r\n"], ids=["garbage", "http"])
def test_a_database_port_that_takes_no_login_fails_in_preflight(tmp_path, answer):
    """An open port is not a database: MLflow would retry for ~100 s after the work, then not log the run."""
    with tcp_server(answer) as address:
        uri = address.replace("tcp://", "postgresql://mlflow:s3cret@") + "/mlflow"
        t0 = time.monotonic()
        result = mosd(["+fault=offset_var", f"tracking.uri={uri}", *SMALL], cwd=tmp_path, timeout=120)
        elapsed = time.monotonic() - t0
    line = one_line_exit_2(result)
    assert line.startswith(f"mosd: error: tracking.uri={uri.replace(':s3cret@', ':***@')}: the postgresql database "
                           f"does not take a login (OperationalError: "), line
    assert "s3cret" not in result.stderr + result.stdout and elapsed < 30, elapsed
    assert list(tmp_path.iterdir()) == []


def test_corrupt_store_fails_in_preflight_naming_the_file(tmp_path):
    outputs = tmp_path / "outputs"
    outputs.mkdir()
    junk = np.random.default_rng(1).bytes(20000)
    (outputs / "mlflow.db").write_bytes(junk)
    line = one_line_exit_2(mosd(["+fault=offset_var", *SMALL], cwd=tmp_path, timeout=120))
    assert f"tracking store {outputs / 'mlflow.db'} is damaged" in line
    assert sorted(p.name for p in outputs.iterdir()) == ["mlflow.db"]  # no run directory, no lock file
    assert (outputs / "mlflow.db").read_bytes() == junk


def test_unwritable_outputs_root_fails_in_preflight(tmp_path):
    (tmp_path / "a_file").write_text("x")
    with pytest.raises(ConfigError) as info:
        preflight_module.preflight(["+fault=offset_var", f"outputs_root={tmp_path / 'a_file' / 'out'}", *SMALL])
    line = str(info.value)
    assert re.search(r"outputs_root=.*a_file/out cannot be written: .*a_file is not a directory", line), line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a_file"]


def test_read_only_outputs_root_fails_in_preflight(tmp_path):
    ro = tmp_path / "ro"
    ro.mkdir(mode=0o555)
    if os.geteuid() == 0:  # root writes into a 0o555 directory; sysfs refuses a new directory even to root
        ro = Path("/sys/mosd-read-only")
    with pytest.raises(ConfigError, match="cannot be written"):
        checks.check_outputs(ro / "outputs")


# ---------------------------------------------------------------------------------------
# 4. values valid one by one but not together: refused in preflight with the derived bound
# ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("overrides,pattern", [
    (["plant.dt=0.1"], r"monitor\.burn_in=200 leaves fewer than 2 subgroups of a 52-point run \(scenario\.duration="
                       r"5\.2 s at plant\.dt=0\.1 s\); allowed: 0 <= monitor\.burn_in <= 42"),
    (["monitor.burn_in=6000"], r"monitor\.burn_in=6000 leaves fewer than 2 subgroups of a 5200-point run .*<= 5190"),
    # one subgroup per run: the chart's Phase-I spread of the dry run would be NaN
    (["monitor.burn_in=5195"], r"monitor\.burn_in=5195 leaves fewer than 2 subgroups .*allowed: 0 <= monitor\.burn_in "
                               r"<= 5190"),
    (["denoise=wavelet", "denoise.level=12"], r"denoise\.level=12 needs at least 20480 chart points per run for db3; "
                                              r"the run has 1000 .*allowed: denoise\.level <= 7"),
    (["fault.onset=10"], r"fault\.onset=10 is past the end of the run \(scenario\.duration=5\.2\)"),
    (["fault.onset=5.1999"], r"fault\.onset=5\.1999 leaves no faulty chart point.*allowed: 0\.204 < fault\.onset <= 5\.199"),
])
def test_values_that_do_not_fit_together_are_refused_with_the_bound(overrides, pattern):
    with pytest.raises((ConfigError, UsageError)) as info:
        preflight_module.preflight(["+fault=offset_var", "tracking=none", *overrides])
    message = str(info.value)
    assert "\n" not in message and re.search(pattern, message), message


@pytest.mark.parametrize("overrides", [["fault.onset=0.2045"], ["fault.onset=5.199"], ["monitor.burn_in=5190", "fault.onset=5.199"],
                                       ["denoise=wavelet"]])
def test_values_at_the_bound_pass_the_dry_run(overrides, monkeypatch):
    """At the bound the dry run runs to its end and scores the design with a finite limit and finite rates."""
    from mosd.experiment import Experiment

    scored = []
    evaluate = Experiment.evaluate

    def recording(self, *args, **kwargs):
        scored.append(evaluate(self, *args, **kwargs))
        return scored[-1]

    monkeypatch.setattr(Experiment, "evaluate", recording)
    preflight_module.preflight(["+fault=offset_var", "tracking=none", *overrides])
    assert len(scored) == 1, "the dry run did not score the design"
    report, example = scored[0]
    assert example["statistic"].size >= 2 and np.all(np.isfinite(example["ucl"])), example["ucl"]
    # the dry run scores its one training run: a fault-free and a faulty chart point at least (issue 22)
    assert 0.0 <= report.summary()["mdr"].mean <= 1.0 and 0.0 <= report.summary()["far"].mean <= 1.0, report.summary()


def test_the_dry_run_leaves_the_components_as_built():
    """Preflight hands the run its components as built: the dry run works on copies (no fitted monitor or limit)."""
    import pickle

    from hydra import compose, initialize_config_dir

    from mosd.app.build import build
    from mosd.app.config import CONFIG_DIR

    overrides = ["+fault=offset_var", "tracking=none", "denoise=wavelet", *SMALL]
    checked = preflight_module.preflight(overrides)
    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3", job_name="mosd"):
        cfg = compose("config", overrides=overrides, return_hydra_config=True)
    taken, fresh = checked.take(cfg), build(cfg)
    assert taken is not None and checked.take(cfg) is None  # one job, handed out once
    for kind in ("plant", "noise", "fault", "estimator", "monitor", "detector"):
        assert pickle.dumps(vars(getattr(taken.experiment, kind))) == \
            pickle.dumps(vars(getattr(fresh.experiment, kind))), kind
    assert not hasattr(taken.experiment.monitor, "mean_")


def test_a_sweep_checks_each_distinct_shape_once(monkeypatch):
    calls = []
    real = preflight_module.dry_run
    monkeypatch.setattr(preflight_module, "dry_run", lambda setup: calls.append(setup) or real(setup))
    preflight_module.preflight(["-m", "+fault=offset", "optimizer=mopso,nsga2", "seed=1,2", "tracking=none"])
    assert len(calls) == 1  # optimiser and seed do not change the shapes
    with pytest.raises(ConfigError, match="monitor.burn_in=6000"):
        preflight_module.preflight(["-m", "+fault=offset", "monitor.burn_in=10,6000", "tracking=none"])


# ---------------------------------------------------------------------------------------
# 5. every documented command works after the documented install
# ---------------------------------------------------------------------------------------
def test_runtime_dependencies_cover_the_documented_commands():
    tomllib = pytest.importorskip("tomllib")
    root = Path(__file__).resolve().parents[1]
    deps = tomllib.loads((root / "pyproject.toml").read_text())["project"]["dependencies"]
    names = {re.split(r"[<>=!~ \[;]", d, maxsplit=1)[0].lower() for d in deps}
    readme = (root / "README.md").read_text()
    # the README's own install is `pip install .`: what its commands and those of the pages its sections moved
    # to (issue 51) use must be a runtime dependency
    sweeps, ui = ((root / "docs" / "how-to" / page).read_text() for page in ("sweeps.md", "mlflow-ui.md"))
    assert "pip install . &&" in readme and "hydra/launcher=joblib" in sweeps and "mlflow server" in ui
    assert "the plain `pip install .`" in sweeps  # the sweeps page says the launcher comes with the plain install
    assert {"hydra-joblib-launcher", "mlflow", "tqdm"} <= names  # tqdm: mosd.app.progress


#: the README and the site's pages that hold the README's former sections' commands (issue 51 item 1)
DOCUMENTED_COMMAND_PAGES = ["README.md", "docs/getting-started.md", "docs/systems/index.md", "docs/how-to/sweeps.md",
                            "docs/how-to/scale-out.md", "docs/how-to/team-store.md", "docs/how-to/mlflow-ui.md",
                            "docs/how-to/deploy.md", "docs/how-to/benchmarks.md", "docs/explanation/outputs.md",
                            "docs/explanation/arl.md"]


def test_every_documented_mosd_command_passes_the_cheap_checks():
    """Each ``python -m mosd ...`` line of the README and of the pages its sections moved to parses and names
    existing options."""
    from hydra.core.override_parser.overrides_parser import OverridesParser

    from mosd.app.config import with_debug_last

    root = Path(__file__).resolve().parents[1]
    commands = [line for page in DOCUMENTED_COMMAND_PAGES for line in
                re.findall(r"^(?:\$ )?python -m mosd (?!report|log|\.)([^#\n]*)", (root / page).read_text(), re.M)]
    assert len(commands) >= 40
    for line in commands:
        args = [a for a in line.split() if a not in ("-m", "--multirun")]
        if not any(a.startswith(("+fault", "+experiment", "fault=")) for a in args):
            continue  # the README's deliberate mistakes
        # as the app composes them: debug=NAME last, with a plus (mosd.app.config.with_debug_last)
        parsed = OverridesParser.create().parse_overrides(with_debug_last(args))
        preflight_module.check_group_overrides(parsed)


# ---------------------------------------------------------------------------------------
# 2 (late): MLflow fails after the work -> summary, complete run directory, one line, exit 3
# ---------------------------------------------------------------------------------------
class _HealthyButBroken(_MlflowWithoutTheExperiment):
    """Answers preflight's call like an MLflow server and fails every other call (a store that breaks late)."""

    def _other(self):
        self._send(503, b"down", "text/plain")


@pytest.mark.slow
def test_a_late_tracking_failure_keeps_the_result_and_logs_later(tmp_path):
    server = ThreadingHTTPServer(("127.0.0.1", 0), _HealthyButBroken)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    try:
        uri = f"http://127.0.0.1:{server.server_address[1]}"
        result = mosd(["+fault=offset_var", f"tracking.uri={uri}", *SMALL], cwd=tmp_path, timeout=300)
    finally:
        server.shutdown()
    assert result.returncode == 3, result.stderr[-3000:]
    assert "Traceback" not in result.stderr
    errors = [ln for ln in result.stderr.splitlines() if ln.startswith("mosd:")]
    assert len(errors) == 1 and "the run was not logged to MLflow" in errors[0] and "python -m mosd log" in errors[0]
    assert "FAR" in result.stdout and "NOT LOGGED" in result.stdout  # the summary is printed all the same
    run_dir = next((tmp_path / "outputs" / "runs").iterdir())
    for name in ("summary.json", "pareto.csv", "chart.png", "mlflow_pending.json"):
        assert (run_dir / name).is_file(), name
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["status"] == "finished" and summary["tracking"]["logged"] is False
    # ... and `mosd log` puts it into a store later
    store = f"sqlite:///{tmp_path / 'later.db'}"
    logged = mosd(["log", str(run_dir), "--tracking-uri", store], cwd=tmp_path, timeout=300)
    assert logged.returncode == 0, logged.stderr[-3000:]
    from mlflow.tracking import MlflowClient

    client = MlflowClient(tracking_uri=store)
    runs = client.search_runs([client.get_experiment_by_name("mosd").experiment_id])
    assert len(runs) == 1 and runs[0].info.status == "FINISHED" and FINAL_METRICS <= set(runs[0].data.metrics)
    assert {"pareto.csv", "chart.png"} <= {a.path for a in client.list_artifacts(runs[0].info.run_id)}
    assert json.loads((run_dir / "summary.json").read_text())["tracking"]["logged"] is True


# ---------------------------------------------------------------------------------------
# 1 (end to end): six concurrent first runs on a fresh outputs directory
# ---------------------------------------------------------------------------------------
def _env(outputs: Path | None = None) -> dict:
    from test_app import PACKAGE_PARENT

    env = {k: v for k, v in os.environ.items() if not k.startswith("MOSD_") and k != "HYDRA_FULL_ERROR"}
    env["PYTHONPATH"] = os.pathsep.join(p for p in (PACKAGE_PARENT, env.get("PYTHONPATH")) if p)
    if outputs is not None:
        env["MOSD_OUTPUTS"] = str(outputs)
    return env


def _runs(uri: str):
    from mlflow.tracking import MlflowClient

    client = MlflowClient(tracking_uri=uri)
    experiment = client.get_experiment_by_name("mosd")
    return client, ([] if experiment is None else client.search_runs([experiment.experiment_id], max_results=1000))


@pytest.mark.slow
def test_six_concurrent_first_runs_give_six_finished_runs_and_a_healthy_store(tmp_path):
    budget = ["optimizer.pop_size=6", "optimizer.n_gen=2", "budget.n_test=2", "budget.n_train=2",
              "budget.n_calibration=2", "optimizer.n_jobs=1", "progress=false", "scenario.duration=3"]
    procs = [subprocess.Popen([sys.executable, "-m", "mosd", "+fault=offset_var", f"seed={i}", *budget], cwd=tmp_path,
                              env=_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
             for i in range(6)]
    outs = [p.communicate(timeout=600) for p in procs]
    assert [p.returncode for p in procs] == [0] * 6, [o[1][-1500:] for o in outs]
    db = tmp_path / "outputs" / "mlflow.db"
    assert store.sqlite_store_state(db).state == "ok"
    client, runs = _runs(f"sqlite:///{db}")
    assert len(runs) == 6 and {r.info.status for r in runs} == {"FINISHED"}
    assert all(FINAL_METRICS <= set(r.data.metrics) for r in runs)
    assert mosd(["report"], cwd=tmp_path).returncode == 0


# ---------------------------------------------------------------------------------------
# 3. signals
# ---------------------------------------------------------------------------------------
def _text(data) -> str:
    return data.decode(errors="replace") if isinstance(data, bytes) else (data or "")


def _where_they_wait(pid: int) -> str:
    """Each process of the tree (``pid`` and its descendants): command, state and each thread's kernel wait."""
    lines = []
    for p in sorted({pid, *_descendants(pid)}):
        try:
            command = Path(f"/proc/{p}/cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")[:160]
            state = Path(f"/proc/{p}/stat").read_text().split()[2]
            waits = sorted(f"{t.name}:{(t / 'wchan').read_text() or '-'}" for t in Path(f"/proc/{p}/task").iterdir())
        except OSError:
            continue
        lines.append(f"  {p} {state} {command} | threads {', '.join(waits)[:400]}")
    return "\n".join(lines)


def _descendants(pid: int) -> set[int]:
    found, todo = set(), [pid]
    while todo:
        p = todo.pop()
        for task in Path(f"/proc/{p}/task").glob("*"):
            try:
                children = (task / "children").read_text().split()
            except OSError:
                continue
            for c in map(int, children):
                if c not in found:
                    found.add(c)
                    todo.append(c)
    return found


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state not in ("Z", "X")  # a zombie has ended; only its parent's wait is missing


def _start_long_run(tmp_path: Path, *extra: str) -> subprocess.Popen:
    # far more generations than the test waits for: the signal lands mid-optimisation
    args = ["+fault=offset_var", "optimizer.pop_size=20", "optimizer.n_gen=100000", "budget.n_test=3",
            "budget.n_train=3", "budget.n_calibration=3", "optimizer.n_jobs=2", "progress=false", *extra]
    return subprocess.Popen([sys.executable, "-m", "mosd", *args], cwd=tmp_path, env=_env(), text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True)


def _wait_until_optimising(proc: subprocess.Popen, db: Path, timeout: float = 240, children: int = 1) -> None:
    """Until the MLflow run exists (RUNNING) and ``children`` processes are up (the tracking process, workers).

    The default chart's evaluation runs on threads of the run's own process (no
    worker processes); an objective the compiled kernel lacks runs on loky
    processes (tracking process + worker + loky's resource tracker: 3).
    """
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        assert proc.poll() is None, proc.communicate()[1][-3000:]
        if db.exists() and store.sqlite_store_state(db).state == "ok":
            con = sqlite3.connect(db)
            try:
                running = con.execute("SELECT count(*) FROM runs WHERE status = 'RUNNING'").fetchone()[0]
            except sqlite3.Error:
                running = 0
            finally:
                con.close()
            if running and len(_descendants(proc.pid)) >= children:
                time.sleep(1.5)
                return
        time.sleep(0.2)
    pytest.fail("the run did not reach the optimisation")


@pytest.mark.serial  # signals and seconds: run after the parallel phase, one at a time (README)
@pytest.mark.slow
@pytest.mark.parametrize("workers", ["threads", "processes"])
def test_sigterm_mid_optimisation_kills_the_run_and_leaves_no_process(tmp_path, workers):
    extra = () if workers == "threads" else ("optimizer.objectives=[far,mdr,delay]",)
    proc = _start_long_run(tmp_path, *extra)
    db = tmp_path / "outputs" / "mlflow.db"
    _wait_until_optimising(proc, db, children=1 if workers == "threads" else 3)
    children = _descendants(proc.pid)
    t0 = time.monotonic()
    proc.send_signal(signal.SIGTERM)
    out, err = proc.communicate(timeout=60)
    elapsed = time.monotonic() - t0
    assert proc.returncode == 143, err[-3000:]
    assert elapsed < 5, elapsed
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "stopped by SIGTERM" in lines[0] and "Traceback" not in err, err[-3000:]
    deadline = time.monotonic() + 5
    while time.monotonic() < deadline and any(_alive(c) for c in children):
        time.sleep(0.1)
    assert not [c for c in children if _alive(c)], "child processes survived"
    _, runs = _runs(f"sqlite:///{db}")
    assert [r.info.status for r in runs] == ["KILLED"]
    run_dir = next((tmp_path / "outputs" / "runs").iterdir())
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["status"] == "killed" and summary["error"] == "stopped by SIGTERM"


@pytest.mark.serial  # signals and seconds: run after the parallel phase, one at a time (README)
@pytest.mark.slow
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["ctrl_c", "sigterm"])
def test_a_signal_to_the_process_group_is_one_line_and_a_killed_run(tmp_path, sig):
    proc = _start_long_run(tmp_path)
    db = tmp_path / "outputs" / "mlflow.db"
    _wait_until_optimising(proc, db)
    children = _descendants(proc.pid)
    os.killpg(proc.pid, sig)  # Ctrl-C in a terminal; SIGTERM from a job scheduler to the whole group
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 128 + sig, err[-3000:]
    lines = err.strip().splitlines()
    assert len(lines) == 1 and f"stopped by {signal.Signals(sig).name}" in lines[0], err[-3000:]
    time.sleep(3)
    assert not [c for c in children if _alive(c)]
    _, runs = _runs(f"sqlite:///{db}")
    assert [r.info.status for r in runs] == ["KILLED"]


def _python(code: str, timeout: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", textwrap.dedent(code)], capture_output=True, text=True,
                          timeout=timeout, env=_env())


def _signals_inside_numbas_hook(tracer: str, timeout: float = 120) -> subprocess.CompletedProcess:
    """Run compiled code that boxes its results through numba's unpickling hook for up to 5 s under the stop-signal
    handlers, traced by ``tracer`` (source of ``tracer(frame, event, arg)``, which sends the signals; ``hook``,
    ``handler``, ``sent`` and ``inside(frame, code)`` are defined for it); prints ``stopped by SIGNUM SENT`` or
    ``not stopped``."""
    return _python(textwrap.dedent("""
        import os, signal, sys, time
        import numba
        import numpy as np
        from numba.core import serialize
        from mosd.app import signals

        @numba.njit
        def pair(x):
            return x + 1.0, x * 2.0

        x = np.ones(3)
        pair(x)
        signals.install_signal_handlers()
        hook, handler, sent = serialize._numba_unpickle.__code__, signals._on_signal.__code__, []

        def inside(frame, code):
            while frame is not None and frame.f_code is not code:
                frame = frame.f_back
            return frame is not None
    """) + textwrap.dedent(tracer) + textwrap.dedent("""
        sys.settrace(tracer)
        try:
            end = time.monotonic() + 5
            while time.monotonic() < end:
                pair(x)
            print("not stopped")
        except signals.Interrupted as exc:
            sys.settrace(None)
            print("stopped by", exc.signum, len(sent))
    """), timeout=timeout)


def test_a_signal_inside_numbas_unpickling_hook_is_raised_once_out_of_it():
    """Compiled code calls ``numba.core.serialize._numba_unpickle`` to box the arrays it returns; an exception
    raised there comes out as a SystemError or crashes the process (the segmentation fault of issue 22)."""
    out = _signals_inside_numbas_hook("""
        def tracer(frame, event, arg):  # the signal arrives while the hook runs
            if event == "call" and frame.f_code is hook and not sent:
                sent.append(1)
                os.kill(os.getpid(), signal.SIGINT)
    """)
    assert out.returncode == 0 and out.stdout.split() == ["stopped", "by", "2", "1"], out.stderr[-2000:]


def test_stop_signals_that_arrive_while_the_handler_runs_inside_numbas_hook_stop_the_process_once():
    """A process group's Ctrl-C and the launcher passing it on reach a joblib sweep's job worker together: the
    handler ran again inside its own wake-up of the retry thread (``threading.Event.set``), waited for the lock it
    held and the worker never marked its run (test_a_signal_during_a_sweep_..., 1 run in 20-40).

    The first signal is handled inside numba's hook with tracing on, then a second one arrives at every call the
    handler makes. (Sent from a tracer, the first signal is handled inside the tracer, where nothing is traced;
    only the retry thread's later interrupt could then run the handler traced inside the hook, and whether it
    lands there is a matter of timing: the test failed in about half of its runs, having sent one signal.) The
    hook is numba's own code object, the one the handler looks for, with a memo that misses so that it calls
    ``loads``, where the first signal is raised.
    """
    out = _python("""
        import os, signal, sys, time, types
        from numba.core import serialize
        from mosd.app import signals

        signals.install_signal_handlers()
        handler, sent = signals._on_signal.__code__, []

        def loads(bytedata):
            signal.raise_signal(signal.SIGINT)  # handled here, in the hook's frame, before this returns
            return bytedata

        hook = types.FunctionType(serialize._numba_unpickle.__code__, {
            "_unpickled_memo": {}, "KeyError": KeyError, "cloudpickle": types.SimpleNamespace(loads=loads)})

        def inside(frame, code):
            while frame is not None and frame.f_code is not code:
                frame = frame.f_back
            return frame is not None

        def tracer(frame, event, arg):
            # a second signal at every call the handler makes: the handler runs again wherever the first one is
            if event == "call" and len(sent) < 40 and inside(frame, handler):
                sent.append(1)
                os.kill(os.getpid(), signal.SIGINT)
            return tracer

        sys.settrace(tracer)
        try:
            end = time.monotonic() + 5
            while time.monotonic() < end:
                hook(0, b"", b"")  # then the retry thread's interrupt raises, out of the hook
            print("not stopped")
        except signals.Interrupted as exc:
            sys.settrace(None)
            print("stopped by", exc.signum, len(sent))
    """, timeout=60)
    assert out.returncode == 0, out.stderr[-2000:]
    stopped, by, signum, sent = out.stdout.split()
    assert (stopped, by, signum) == ("stopped", "by", "2") and int(sent) > 1, out.stdout


def test_the_launcher_waits_until_every_job_worker_has_marked_its_run(tmp_path):
    """loky SIGKILLs every worker as soon as one ends: a job that ends after marking its run used to take
    down the others still marking theirs. Two jobs, one slow to mark; both have marked when the launcher raises."""
    out = _python(f"""
        import json, os, signal, time
        from pathlib import Path
        from mosd.app import signals
        from mosd.optim import workers

        tmp = Path({str(tmp_path)!r})

        def job(i, marking_s):
            signals.install_signal_handlers(job_worker=True)
            (tmp / f"started-{{i}}").touch()
            try:
                while True:
                    time.sleep(0.01)
            except signals.Interrupted as exc:
                time.sleep(marking_s)  # MLflow and summary.json
                (tmp / f"marked-{{i}}").write_text(str(exc.signum))
                signals.end_job_worker(exc.signum)

        signals.jobs_run_in_pool()
        executor = workers.memmapping_executor(2, timeout=60)
        futures = [executor.submit(job, i, s) for i, s in enumerate((0.0, 2.0))]
        while len(list(tmp.glob("started-*"))) < 2:
            time.sleep(0.05)
        signals.install_signal_handlers()
        try:
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(60)
        except signals.Interrupted as exc:
            marked = sorted(p.name + "=" + p.read_text() for p in tmp.glob("marked-*"))
            print(json.dumps({{"signum": exc.signum, "marked": marked}}))
        workers.shutdown_pool()
    """)
    assert out.returncode == 0, out.stderr[-2000:]
    found = json.loads(out.stdout.strip().splitlines()[-1])
    assert found == {"signum": 15, "marked": ["marked-0=15", "marked-1=15"]}


def _runs_by_status(db: Path) -> dict[str, int]:
    if not (db.exists() and store.sqlite_store_state(db).state == "ok"):
        return {}
    con = sqlite3.connect(db)
    try:
        return dict(con.execute("SELECT status, count(*) FROM runs GROUP BY status").fetchall())
    except sqlite3.Error:
        return {}
    finally:
        con.close()


# the joblib sweep of docs/how-to/sweeps.md (the README's until issue 51), small: two short jobs that finish,
# then long ones that the signal stops
SWEEP = ["optimizer.n_gen=2,100000", "seed=0,1", "+fault=offset_var", "optimizer.pop_size=10", "budget.n_test=3",
         "budget.n_train=3", "budget.n_calibration=3", "scenario.duration=3", "progress=false"]
LAUNCHERS = {"basic": [], "joblib": ["hydra/launcher=joblib", "hydra.launcher.n_jobs=2"]}
FIGURES = {"chart.png", "residual.png", "history.png", "pareto.png", "summary.json", "history.csv", "pareto.csv"}


def _default_stop_signals() -> None:
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        signal.signal(sig, signal.SIG_DFL)


@pytest.mark.serial  # signals and seconds: run after the parallel phase, one at a time (README)
@pytest.mark.slow
@pytest.mark.parametrize("launcher, delivery, sig", [
    ("basic", "pid", signal.SIGTERM), ("basic", "group", signal.SIGINT),
    ("joblib", "pid", signal.SIGTERM), ("joblib", "group", signal.SIGINT), ("joblib", "group", signal.SIGHUP),
], ids=["basic-pid-sigterm", "basic-group-ctrl_c", "joblib-pid-sigterm", "joblib-group-ctrl_c", "joblib-group-sighup"])
def test_a_signal_during_a_sweep_kills_the_started_jobs_and_keeps_the_finished_ones(tmp_path, launcher, delivery, sig):
    """Issue 22: under the joblib launcher the jobs were left RUNNING, with a segmentation-fault dump."""
    # the stop signals at their default disposition in the sweep, whatever this test runs under: mosd keeps a
    # signal its parent ignores ignored (nohup's SIGHUP), and a suite started with nohup passes that on
    proc = subprocess.Popen([sys.executable, "-m", "mosd", "-m", *LAUNCHERS[launcher], *SWEEP], cwd=tmp_path,
                            env=_env(), text=True, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            start_new_session=True, preexec_fn=_default_stop_signals)
    db = tmp_path / "outputs" / "mlflow.db"
    running_jobs = 2 if launcher == "joblib" else 1
    try:
        deadline = time.monotonic() + 300
        while True:  # the two short jobs finished, the long ones optimising
            assert proc.poll() is None, proc.communicate()[1][-3000:]
            assert time.monotonic() < deadline, "the sweep did not reach its long jobs"
            counts = _runs_by_status(db)
            if counts.get("FINISHED", 0) >= 2 and counts.get("RUNNING", 0) >= 1 + running_jobs:  # + the sweep's run
                break
            time.sleep(0.2)
        time.sleep(1.5)
        children = _descendants(proc.pid)
        if delivery == "group":
            os.killpg(proc.pid, sig)  # Ctrl-C in a terminal signals the whole foreground process group
        else:
            proc.send_signal(sig)
        try:
            out, err = proc.communicate(timeout=120)
        except subprocess.TimeoutExpired as exc:  # a hang: say which processes are left and where they wait
            raise AssertionError(f"the sweep was still running 120 s after {signal.Signals(sig).name}:\n"
                                 f"{_where_they_wait(proc.pid)}\nits output: {_text(exc.output)[-1500:]}\n"
                                 f"its errors: {_text(exc.stderr)[-1500:]}") from None
    finally:  # a failed check must not leave a 100,000-generation sweep running beside the other tests
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    assert proc.returncode == 128 + sig, err[-3000:]
    assert "Fatal Python error" not in err and "Traceback" not in err, err[-3000:]
    # one line per stopped job, one more for the sweep under joblib, and nothing else (issue 34: no cut-off
    # traceback of an evaluation worker, no resource tracker's leaked-semaphore warning)
    ours = [line for line in err.splitlines() if line.startswith("mosd:")]
    assert len(ours) == running_jobs + (launcher == "joblib"), err[-3000:]
    assert [line for line in err.splitlines() if line.strip()] == ours, err[-3000:]
    assert all(line.startswith(f"mosd: stopped by {signal.Signals(sig).name}") for line in ours), err[-3000:]
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline and any(_alive(c) for c in children):
        time.sleep(0.2)
    assert not [c for c in children if _alive(c)], "child processes survived"
    _, runs = _runs(f"sqlite:///{db}")
    sweep = [r for r in runs if r.data.tags.get("mosd.role") == "sweep"]
    jobs = [r for r in runs if r.data.tags.get("mosd.role") == "job"]
    assert [r.info.status for r in sweep] == ["KILLED"]
    statuses = sorted(r.info.status for r in jobs)
    assert statuses == ["FINISHED"] * 2 + ["KILLED"] * running_jobs, statuses
    for run in jobs:
        run_dir = Path(run.data.tags["mosd.run_dir"])
        summary = json.loads((run_dir / "summary.json").read_text())
        if run.info.status == "FINISHED":
            assert summary["status"] == "finished" and FIGURES <= {f.name for f in run_dir.iterdir()}
        else:
            assert summary["status"] == "killed" and summary["error"] == f"stopped by {signal.Signals(sig).name}"


# ---------------------------------------------------------------------------------------
# 6. the report never merges or hides different set-ups
# ---------------------------------------------------------------------------------------
def test_report_keeps_one_row_per_set_up_and_shows_what_differs(tmp_path):
    import mlflow  # noqa: F401  (a test dependency: a missing one fails, never skips)
    from mosd.app import report

    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    mlstore = mlflow_client.MlflowStore(TrackingSettings(uri, (tmp_path / "art").as_uri(), "mosd"))

    def job(estimator, n_test, far, seed=0, n_jobs=2):
        tags = {"mosd.role": "job", "mosd.fault": "offset", "mosd.detector": "ss_dewma", "mosd.optimizer": "mopso",
                "mosd.estimator": estimator, "mosd.denoise": "none", "mosd.params": "lam,K", "mosd.online": "true"}
        run_id = mlstore.create_run("r", tags)
        params = {"estimator._target_": f"mosd.estimators.{estimator}", "budget.n_test": str(n_test),
                  "seed": str(seed), "optimizer.n_jobs": str(n_jobs), "outputs_root": str(tmp_path)}
        metrics = [(k, v, 0) for k, v in {"far": far, "mdr": 0.1, "accuracy": 0.9 - far, "lam": 0.5, "K": 3.0,
                                          "n_test": float(n_test)}.items()]
        mlstore.log(run_id, params, metrics)
        mlstore.end(run_id)
        time.sleep(0.01)  # distinct start times: "latest" is well defined
        return run_id

    job("innovation", 100, 0.01)
    job("dedicated_observer", 100, 0.02)
    job("dedicated_observer", 5, 0.03)
    latest = job("dedicated_observer", 5, 0.04, n_jobs=1)  # same set-up as the one before: replaces it
    rows = report.collect(uri)
    assert len(rows) == 3
    assert report.extra_columns(rows) == ["estimator", "budget.n_test"]
    assert {(r["estimator"], r["budget.n_test"]) for r in rows} == {
        ("innovation", "100"), ("dedicated_observer", "100"), ("dedicated_observer", "5")}
    assert [r["run_id"] for r in rows if r["budget.n_test"] == "5"] == [latest]
    table = report.to_markdown(rows)
    assert table.splitlines()[0].startswith("| preset | fault | detector | optimizer | estimator | budget.n_test | MDR %")
    assert "budget.n_test" in report.to_csv(rows).splitlines()[0]
    assert len(report.collect(uri, latest_only=False)) == 4


def test_report_groups_its_columns_and_shows_the_ones_metrics_picks(tmp_path, capsys):
    from mosd.app import report

    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    mlstore = mlflow_client.MlflowStore(TrackingSettings(uri, (tmp_path / "art").as_uri(), "mosd"))

    def job(preset, seed, n_runs, test, study):
        tags = {"mosd.role": "job", "mosd.experiment": preset, "mosd.fault": "ramp", "mosd.detector": "chi2",
                "mosd.optimizer": "mopso", "mosd.params": "alpha", "mosd.online": "true",
                **report.study_metric_tags(study)}
        run_id = mlstore.create_run("r", tags)
        logged = {**test, **{report.logged_study_name(k, test): v for k, v in study.items()}}
        mlstore.log(run_id, {"seed": str(seed), "study.n_runs": str(n_runs)}, [(k, v, 0) for k, v in logged.items()])
        mlstore.end(run_id)

    test = {"far": 0.01, "far_ci": 0.001, "mdr": 0.1, "mdr_ci": 0.01, "accuracy": 0.89, "alpha": 0.5, "n_test": 20.0}
    job("paper001", 0, 100, test, {"isolation_rate": 0.97, "far": 0.02})
    job("paper001", 1, 100, test, {"isolation_rate": 0.95, "far": 0.03})
    job("paper003", 0, 50, test, {"detection_step_best": 4.4, "far": 0.14})  # the study's own FAR, not the test's
    rows = report.collect(uri)
    assert len(rows) == 3 and report.extra_columns(rows) == ["seed", "study.n_runs"]
    # by default one table per system: seed where it differs (within paper001), not study.n_runs (it differs
    # only between the presets), and no column empty on all of a table's rows (no "detected" here)
    lines = report.to_markdown(rows).splitlines()
    assert lines[0] == "### paper001 (2 runs)" and lines[2] == (
        "| preset | fault | detector | optimizer | seed | MDR % | FAR % | accuracy % | n_test | design | online | run |")
    assert lines[lines.index("### paper003 (1 run)") + 2].startswith("| preset | fault | detector | optimizer | MDR %")
    paper003 = next(r for r in rows if r["preset"] == "paper003")
    assert paper003["far"] == 0.01 and paper003["paper003:far"] == 0.14 and paper003["paper001:far"] == "–"
    assert report.select_columns(rows, "far,setup") == ["far", "seed", "study.n_runs"]
    assert report.select_columns(rows, "paper003") == ["paper003:detection_step_best", "paper003:far"]
    assert report.select_columns(rows, "far,detection_rate,isolation_rate") == [
        "far", "detected", "paper001:isolation_rate"]  # a bare study metric: every system that has it
    assert report.to_markdown(rows, report.select_columns(rows, "paper003:far")).splitlines()[-1].endswith("| 0.14 |")
    # the CSV holds every column by default, the picked ones (with their CIs) otherwise
    fields = report.to_csv(rows).splitlines()[0].split(",")
    assert {"far", "far_ci", "seed", "study.n_runs", "paper001:isolation_rate", "paper003:far"} <= set(fields)
    assert report.to_csv(rows, ["far"]).splitlines()[0] == "preset,fault,detector,optimizer,far,far_ci"
    assert report.main(["--tracking-uri", uri, "--metrics", "far,nope"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("mosd report: error: --metrics='nope' is not a group or column of this report; allowed: "
                          "the groups test, design, setup, study, paper001, paper003;") and "\n" not in err
    assert report.main(["--tracking-uri", uri, "--metrics", "test,paper001"]) == 0
    assert capsys.readouterr().out.splitlines()[2].endswith("| n_test | paper001:far | paper001:isolation_rate |")


@pytest.mark.slow
def test_a_study_metric_never_replaces_the_test_metric_of_its_name(tmp_path):
    """paper 000's study scores the tuned design on its own runs (study.n_runs != budget.n_test)."""
    result = mosd(["+experiment=paper000", "study.n_runs=6", "budget.n_test=4", "budget.n_train=2",
                   "budget.n_calibration=2", "optimizer.pop_size=6", "optimizer.n_gen=2", "optimizer.n_jobs=1",
                   "progress=false"], cwd=tmp_path, timeout=600)
    assert result.returncode == 0, result.stderr[-3000:]
    summary = json.loads(next((tmp_path / "outputs" / "runs").glob("*/summary.json")).read_text())
    _, (run,) = _runs(f"sqlite:///{tmp_path / 'outputs' / 'mlflow.db'}")
    for name in ("far", "mdr", "accuracy"):
        assert run.data.metrics[name] == pytest.approx(summary["test"][name]["mean"], rel=1e-12)
        assert run.data.metrics[f"study_{name}"] == pytest.approx(summary["study"][name], rel=1e-12)
    report = mosd(["report", "--format", "csv", "--metrics", "far,paper000:far"], cwd=tmp_path, timeout=300)
    assert report.returncode == 0, report.stderr
    (row,) = csv.DictReader(report.stdout.splitlines())
    assert float(row["far"]) == pytest.approx(summary["test"]["far"]["mean"], rel=1e-12)
    assert float(row["paper000:far"]) == pytest.approx(summary["study"]["far"], rel=1e-12)


def test_study_metric_names_survive_the_tag_length():
    from mosd.app import report

    names = [f"metric_{i:04d}_of_a_long_study" for i in range(600)]
    tags = report.study_metric_tags(names)
    assert len(tags) > 1 and max(len(v) for v in tags.values()) <= mlflow_client.MAX_TAG_LENGTH
    assert report.study_metric_names(tags) == names


# ---------------------------------------------------------------------------------------
# a real tracking server: a sweep and concurrent runs against http://127.0.0.1:PORT
# ---------------------------------------------------------------------------------------
@pytest.mark.slow
def test_a_real_mlflow_server_takes_a_sweep_and_concurrent_runs(tmp_path, stop_process_group):
    import shutil
    import urllib.request

    mlflow_cli = shutil.which("mlflow", path=str(Path(sys.executable).parent)) or shutil.which("mlflow")
    assert mlflow_cli is not None, "the mlflow command (a dependency) is missing"
    port = free_port()
    uri = f"http://127.0.0.1:{port}"
    log = (tmp_path / "server.log").open("w")
    server = subprocess.Popen([mlflow_cli, "server", "--workers", "1", "--host", "127.0.0.1", "--port", str(port),
                               "--backend-store-uri", f"sqlite:///{tmp_path / 'server.db'}"],
                              cwd=tmp_path, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
    try:
        deadline = time.monotonic() + 180
        while True:
            assert server.poll() is None, (tmp_path / "server.log").read_text()[-3000:]
            try:
                with urllib.request.urlopen(f"{uri}/health", timeout=2):
                    break
            except OSError:
                assert time.monotonic() < deadline, "the server did not come up"
                time.sleep(0.5)
        # a password in the URI (basic authentication, which this server ignores) is never printed or recorded
        secret = "s3cret-" + os.urandom(4).hex()
        budget = ["optimizer.pop_size=6", "optimizer.n_gen=2", "budget.n_test=2", "budget.n_train=2",
                  "budget.n_calibration=2", "optimizer.n_jobs=1", "progress=false", "scenario.duration=3",
                  f"tracking.uri=http://alice:{secret}@127.0.0.1:{port}"]
        sweep = subprocess.Popen([sys.executable, "-m", "mosd", "-m", "+fault=offset,variance", "optimizer=mopso,nsga2",
                                  *budget], cwd=tmp_path / ".", env=_env(tmp_path / "sweep_out"), text=True,
                                 stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        singles = [subprocess.Popen([sys.executable, "-m", "mosd", "+fault=offset_var", f"seed={i}", *budget],
                                    cwd=tmp_path, env=_env(tmp_path / f"out{i}"), text=True,
                                    stdout=subprocess.PIPE, stderr=subprocess.PIPE) for i in range(4)]
        results = [(p, p.communicate(timeout=900)) for p in (sweep, *singles)]
        assert [p.returncode for p, _ in results] == [0] * 5, [err[-1500:] for _, (_, err) in results]
        client, runs = _runs(uri)
        jobs = [r for r in runs if r.data.tags.get("mosd.role") == "job"]
        parents = [r for r in runs if r.data.tags.get("mosd.role") == "sweep"]
        assert len(parents) == 1 and parents[0].info.status == "FINISHED"
        assert len(jobs) == 8 and {r.info.status for r in jobs} == {"FINISHED"}
        assert sum(r.data.tags.get("mlflow.parentRunId") == parents[0].info.run_id for r in jobs) == 4
        for r in jobs:
            assert FINAL_METRICS <= set(r.data.metrics), r.info.run_id
            assert {"summary.json", "pareto.csv", "chart.png"} <= {a.path for a in client.list_artifacts(r.info.run_id)}
            assert r.data.params["tracking.uri"] == f"http://alice:***@127.0.0.1:{port}"
        for _, (out, err) in results:  # the console: Hydra's launcher lists each job's overrides
            assert secret not in out + err and "alice:***@" in out + err
        stop_process_group(server)  # its store on disk is read below
        leaks = [str(f) for f in tmp_path.rglob("*") if f.is_file() and secret.encode() in f.read_bytes()]
        assert leaks == []  # run files, Hydra's config files, the sweep's multirun.yaml, the server's store
    finally:
        if server.poll() is None:
            stop_process_group(server)
        log.close()


# ---------------------------------------------------------------------------------------
# 9. plots that show what matters
# ---------------------------------------------------------------------------------------
def _capture_figures(monkeypatch):
    from mosd.app import figures as plots

    figures = []
    real = plots._save
    monkeypatch.setattr(plots, "_save", lambda fig, path: figures.append(fig) or real(fig, path))
    return plots, figures


def test_chart_png_keeps_the_in_control_part_readable(tmp_path, monkeypatch):
    plots, figures = _capture_figures(monkeypatch)
    rng = np.random.default_rng(0)
    t = np.arange(500) * 0.01
    mask = t >= 2.7
    statistic = np.where(mask, 40 + 10 * rng.random(500), rng.random(500))  # up to 60 after the onset, UCL 2
    statistic[100] = 3.0  # one false alarm before the onset
    plots.chart_trace(tmp_path / "chart.png", t, statistic, np.full(500, 2.0), mask, title="t")
    ax = figures[-1].axes[0]
    assert ax.get_yscale() == "log" and "1 false alarms in 270 fault-free points" in ax.get_title()
    statistic[0] = 0.0  # a statistic that touches zero gets a symmetric log axis, linear below the limit
    plots.chart_trace(tmp_path / "chart.png", t, statistic, np.full(500, 2.0), mask)
    assert figures[-1].axes[0].get_yscale() == "symlog"
    plots.chart_trace(tmp_path / "chart.png", t, np.minimum(statistic, 5.0), np.full(500, 2.0), mask)
    assert figures[-1].axes[0].get_yscale() == "linear"  # no large excursion: nothing to compress


def test_history_png_has_a_title_and_does_not_magnify_tiny_changes(tmp_path, monkeypatch):
    plots, figures = _capture_figures(monkeypatch)
    records = [{"generation": g, "n_eval": 10 * g, "archive_size": 5 + g, "hypervolume": 1.2090 + 0.00024 * g,
                "best_accuracy": 0.9970 + 0.0001 * g} for g in (1, 2, 3)]
    plots.optimisation_history(tmp_path / "history.png", records)
    fig = figures[-1]
    assert "3 generations, 30 evaluations" in fig._suptitle.get_text()
    low, high = fig.axes[0].get_ylim()
    assert high - low >= 0.05 and high <= 1.21 + 0.01  # a 0.04 % change stays a small change
    low, high = fig.axes[2].get_ylim()
    assert high - low >= 0.02 and high <= 1.0 + 0.001


def test_pareto_png_zooms_on_the_best_trade_offs(tmp_path, monkeypatch):
    plots, figures = _capture_figures(monkeypatch)
    F = np.array([[0.0, 0.031], [0.0018, 0.0062], [0.002, 0.0016], [0.0022, 0.0008], [0.0034, 0.0006],
                  [0.046, 0.0004], [0.13, 0.0001], [0.35, 0.0]])
    plots.pareto_front(tmp_path / "pareto.png", F, chosen=3)
    ax = figures[-1].axes[0]
    assert ax.get_xlim()[1] < 0.01 and ax.get_ylim()[1] < 0.01  # zoomed on the knee
    assert ax.get_xlim()[0] > -0.001 and ax.get_ylim()[0] > -0.001
    assert len(ax.child_axes) == 1 and ax.child_axes[0].get_title() == "whole archive"
    plots.pareto_front(tmp_path / "pareto.png", F[1:5], chosen=2)
    assert not figures[-1].axes[0].child_axes  # nothing far away: no zoom, no inset


def test_report_on_a_damaged_store_is_one_line(tmp_path, capsys):
    from mosd.app import report

    make_store(tmp_path / "mlflow.db", leftover=True, n_runs=2)
    assert report.main(["--tracking-uri", f"sqlite:///{tmp_path / 'mlflow.db'}"]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and "is damaged" in lines[0] and "_alembic_tmp_runs" in lines[0]


# ---------------------------------------------------------------------------------------
# a full disk (issue 22, item 4): the artifact store, then the outputs directory
# ---------------------------------------------------------------------------------------
def _run_dir_with_results(run_dir: Path) -> list[Path]:
    run_dir.mkdir()
    files = [run_dir / "summary.json", run_dir / "pareto.csv", run_dir / "chart.png"]
    files[0].write_text(json.dumps({"status": "finished"}))
    files[1].write_text("lam,K,far,mdr,chosen\n0.5,3,0.01,0.02,1\n")
    files[2].write_bytes(np.random.default_rng(2).bytes(50_000))
    return files


def test_a_run_whose_artifacts_did_not_fit_is_failed_and_mosd_log_completes_it_once(tmp_path, monkeypatch, capsys):
    """The artifact store fills up while a run's files are copied in: the run is FAILED and tagged, not
    FINISHED; ``mosd log`` completes that same run, and a second ``mosd log`` adds nothing. The run's
    model, which the store took at the time, is not logged a second time.

    The full disk is injected where MLflow writes an artifact: the copy of a PNG starts, leaves a file
    cut short and fails with ENOSPC, as ``shutil.copy`` does on a full file system.
    """
    import errno

    from mlflow.store.artifact.local_artifact_repo import LocalArtifactRepository
    from mlflow.tracking import MlflowClient

    from mlflow.entities import LoggedModelStatus

    from mosd.app import pending
    from mosd.app.tracker import RunTracker
    from mosd.detectors.step import StepStage
    from mosd.monitors.step import MonitorStage
    from mosd.streaming import OnlinePipeline

    run_dir = tmp_path / "run"
    files = _run_dir_with_results(run_dir)
    model = OnlinePipeline([
        MonitorStage(monitor="mosd.monitors.subgroups.SubgroupMonitor", design={"n": 5, "burn_in": 20},
                     fitted={"mean": np.array([0.3]), "std": np.array([2.0])}, columns=("residual_a",)),
        StepStage(detector="mosd.detectors.mean_variance.SSDEWMA", design={"lam": 0.25, "K": 1.0,
                                                                           "limit": "theoretical"},
                  step={"lam": 0.25, "width": 1.0, "limit": float("nan")}, n=5)]).save(run_dir / "model")
    copy = LocalArtifactRepository.log_artifact

    def disk_full(self, local_file, artifact_path=None):
        if not str(local_file).endswith(".png"):
            return copy(self, local_file, artifact_path)
        target = Path(self.artifact_dir, artifact_path or "", Path(local_file).name)
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_bytes(Path(local_file).read_bytes()[:4096])
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(target))

    monkeypatch.setattr(LocalArtifactRepository, "log_artifact", disk_full)
    settings = TrackingSettings(f"sqlite:///{tmp_path / 'mlflow.db'}", (tmp_path / "art").as_uri(), "mosd")
    tracker = RunTracker(settings, "r", {"mosd.role": "job", "mosd.run_dir": str(run_dir)}, in_process=True).start()
    params = {"optimizer.n_gen": "3"}
    metrics = [("far", 0.01, 0), ("hypervolume", 0.5, 1), ("hypervolume", 0.6, 2), ("delay", float("nan"), 0)]
    tracker.log(params=params, metrics=metrics, artifacts=files)
    tracker.log_model(model)
    with pytest.raises(store.TrackingError, match="No space left on device"):
        tracker.finish("FINISHED")
    client = MlflowClient(tracking_uri=settings.uri)
    run = client.get_run(tracker.run_id)
    assert run.info.status == "FAILED" and tracker.status == "FAILED"
    pending.mark_not_logged(run_dir, "disk full", pending.pending_request(tracker, params, metrics, files, model),
                            tracker.status)
    assert "No space left on device" in run.data.tags["mosd.logging_error"]
    assert f"python -m mosd log {run_dir}" in run.data.tags["mosd.logging_error"]
    summary = json.loads((run_dir / "summary.json").read_text())["tracking"]
    assert summary["run_id"] == tracker.run_id and summary["mlflow_status"] == "FAILED"

    # still full: `mosd log` fails in one line, keeps the pending file and makes no second run
    assert pending.log_main([str(run_dir)]) == 1
    assert "No space left on device" in capsys.readouterr().err
    assert (run_dir / pending.PENDING_FILE).is_file()
    monkeypatch.setattr(LocalArtifactRepository, "log_artifact", copy)  # room again
    assert pending.log_main([str(run_dir)]) == 0
    assert pending.log_main([str(run_dir)]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0].endswith(f"-> MLflow run {tracker.run_id}") and "logged already" in out[2], out
    assert tracker.model_uri and out[1] == out[3] and f"model {tracker.model_uri} (runs:/" in out[1], out
    ready = [m.model_uri for m in client.search_logged_models([run.info.experiment_id])
             if m.status == LoggedModelStatus.READY]
    assert ready == [tracker.model_uri]

    runs = client.search_runs([client.get_experiment_by_name("mosd").experiment_id])
    assert [r.info.run_id for r in runs] == [tracker.run_id]
    run = runs[0]
    assert run.info.status == "FINISHED" and run.data.tags["mosd.logged_later"] == "true"
    assert "mosd.logging_error" not in run.data.tags and "error" not in run.data.tags
    assert run.data.params == params
    history = {key: sorted((m.step, m.value) for m in client.get_metric_history(tracker.run_id, key))
               for key in ("far", "hypervolume")}
    assert history == {"far": [(0, 0.01)], "hypervolume": [(1, 0.5), (2, 0.6)]}
    assert len(client.get_metric_history(tracker.run_id, "delay")) == 1  # NaN is logged once too
    # the copy the full disk cut short is replaced by the whole file
    assert {a.path: a.file_size for a in client.list_artifacts(tracker.run_id)} == {
        f.name: f.stat().st_size for f in files}
    assert json.loads((run_dir / "summary.json").read_text())["tracking"]["run_id"] == tracker.run_id


def _limited_file_size(limit: int):
    """``preexec_fn`` of a child whose writes beyond ``limit`` bytes per file fail with EFBIG (RLIMIT_FSIZE).

    A full disk without root: the kernel refuses the write as a full file system does (Python ignores
    SIGXFSZ, so the write raises ``OSError`` instead of ending the process).
    """
    import resource

    return lambda: resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))


def test_a_write_that_does_not_fit_leaves_the_file_complete_or_absent(tmp_path):
    from mosd.app import files

    (tmp_path / "big.png").write_bytes(b"old")
    script = ("import sys; from mosd.app.atomic import write_atomically\n"
              "for name, size in (('small.csv', 100), ('big.png', 50_000)):\n"
              "    try:\n"
              "        write_atomically(sys.argv[1] + '/' + name, lambda out: out.write(b'x' * size), binary=True)\n"
              "    except OSError as exc:\n"
              "        print(name, exc.errno)\n")
    result = subprocess.run([sys.executable, "-c", script, str(tmp_path)], env=_env(), capture_output=True,
                            text=True, timeout=60, preexec_fn=_limited_file_size(20_000))
    assert result.stdout.split() == ["big.png", "27"], result.stderr[-2000:]  # EFBIG
    assert sorted(p.name for p in tmp_path.iterdir()) == ["big.png", "small.csv"]  # no temporary file left
    assert (tmp_path / "big.png").read_bytes() == b"old" and (tmp_path / "small.csv").stat().st_size == 100
    assert files.lacking(tmp_path, [tmp_path / "small.csv", tmp_path / "chart.png"]) == ["chart.png"]


def test_preflight_refuses_an_outputs_directory_that_takes_no_bytes(tmp_path, monkeypatch):
    """A full disk still creates an empty file: the check writes bytes (and asks for room for a run)."""
    script = ("import sys; from pathlib import Path; from mosd.app.checks import writable_dir_problem\n"
              "print(writable_dir_problem(Path(sys.argv[1])))")
    result = subprocess.run([sys.executable, "-c", script, str(tmp_path / "out")], env=_env(), capture_output=True,
                            text=True, timeout=60, preexec_fn=_limited_file_size(0))
    assert result.stdout.strip() == f"{tmp_path} is not writable (File too large)", result.stderr[-2000:]
    assert list(tmp_path.iterdir()) == []

    class AlmostFull:
        f_bavail, f_frsize = 100, 1024

    monkeypatch.setattr(checks.os, "statvfs", lambda path: AlmostFull)
    with pytest.raises(ConfigError, match=r"outputs_root=.* cannot be written: .* has 100 kB free; a run needs about "
                                          r"4 MB \(disk full\?\)"):
        checks.check_outputs(tmp_path / "out")


@pytest.mark.slow
def test_a_full_outputs_disk_is_one_line_and_a_run_directory_that_says_what_it_lacks(tmp_path):
    """The run directory's disk fills up after the text files: the PNGs do not fit (RLIMIT_FSIZE of 20 kB:
    the CSVs, the YAML and JSON files are smaller, every PNG larger)."""
    args = [sys.executable, "-m", "mosd", "+fault=offset_var", "tracking=none", *SMALL]
    # a complete run first: what a run directory holds, and numba's kernel cache written (a cache
    # file is larger than the limit: under it, a cold cache fails at compilation, before the run)
    complete = subprocess.run(args, cwd=tmp_path, env=_env(), capture_output=True, text=True, timeout=600)
    assert complete.returncode == 0, complete.stderr[-3000:]
    whole, = (tmp_path / "outputs" / "runs").iterdir()
    pngs = sorted(p.name for p in whole.glob("*.png"))
    assert len(pngs) == 4 and all(p.stat().st_size > 20_000 for p in whole.glob("*.png"))

    result = subprocess.run(args, cwd=tmp_path, env=_env(), capture_output=True, text=True, timeout=600,
                            preexec_fn=_limited_file_size(20_000))
    assert result.returncode == 1, result.stderr[-3000:]
    # the kernel cache cannot take its 1 MiB probe under this limit either: one warning line says so (the NumPy
    # path is used, mosd.kernels.cache.usable_place); the error itself is one line
    lines = [ln for ln in result.stderr.strip().splitlines() if not ln.startswith("mosd: warning: kernel cache")]
    assert len(lines) == 1 and "Traceback" not in result.stderr, result.stderr[-3000:]
    assert "the run directory could not be written" in lines[0] and "File too large" in lines[0]
    run_dir, = set((tmp_path / "outputs" / "runs").iterdir()) - {whole}
    assert f"{run_dir} lacks {', '.join(sorted(pngs, key=lambda n: lines[0].index(n)))};" in lines[0]
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["status"] == "failed" and sorted(summary["missing"]) == pngs
    assert summary["params"] == json.loads((whole / "summary.json").read_text())["params"]  # the results are kept
    # nothing cut short: every file there is whole, no temporary file is left
    present = sorted(p.relative_to(run_dir).as_posix() for p in run_dir.rglob("*") if p.is_file())
    # (the deployed model and the test stream come after the run's own files: a full disk stops before them)
    assert present == sorted(p.relative_to(whole).as_posix() for p in whole.rglob("*")
                             if p.is_file() and p.suffix != ".png" and p.name != "test_stream.parquet"
                             and p.parent.name != "model")
    for name in ("pareto.csv", "resolved_config.yaml"):
        assert (run_dir / name).read_text() == (whole / name).read_text()

    def without_elapsed(path):  # history.csv's last column is elapsed_s: the rest is the same run
        return [line.rsplit(",", 1)[0] for line in path.read_text().splitlines()]

    assert without_elapsed(run_dir / "history.csv") == without_elapsed(whole / "history.csv")


def _artifact_server(tmp_path: Path, port: int, file_size_limit: int | None = None) -> subprocess.Popen:
    """``mlflow server --artifacts-only`` on 127.0.0.1:``port``, storing under ``tmp_path / 'artifacts'``; with
    ``file_size_limit``, a disk that takes no file larger than that (RLIMIT_FSIZE: EFBIG, an HTTP 500)."""
    import shutil
    import urllib.request

    mlflow_cli = shutil.which("mlflow", path=str(Path(sys.executable).parent)) or shutil.which("mlflow")
    assert mlflow_cli, "the mlflow command is not installed"
    server = subprocess.Popen(
        [mlflow_cli, "server", "--artifacts-only", "--artifacts-destination", str(tmp_path / "artifacts"),
         "--host", "127.0.0.1", "--port", str(port), "--workers", "1"],
        cwd=tmp_path, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True,
        preexec_fn=None if file_size_limit is None else _limited_file_size(file_size_limit))
    deadline = time.monotonic() + 180
    while True:
        assert server.poll() is None, "the artifact server ended"
        try:
            with urllib.request.urlopen(f"http://127.0.0.1:{port}/health", timeout=2):
                return server
        except OSError:
            assert time.monotonic() < deadline, "the artifact server did not come up"
            time.sleep(0.5)


@pytest.mark.slow
def test_a_full_artifact_store_gives_a_failed_run_that_mosd_log_completes(tmp_path, stop_process_group):
    """End to end, the issue's case: the app and its tracking process against a real MLflow artifact server
    whose disk takes no file over 20 kB (the PNGs); then the disk has room and ``mosd log`` runs twice."""
    port = free_port()
    artifacts = f"http://127.0.0.1:{port}/api/2.0/mlflow-artifacts/artifacts"
    server = _artifact_server(tmp_path, port, file_size_limit=20_000)
    try:
        result = mosd(["+fault=offset_var", f"tracking.artifact_root={artifacts}", *SMALL], cwd=tmp_path, timeout=600)
    finally:
        stop_process_group(server)
    assert result.returncode == 3, result.stderr[-3000:]
    errors = [ln for ln in result.stderr.splitlines() if ln.startswith("mosd:")]
    assert len(errors) == 1 and "python -m mosd log" in errors[0] and "Traceback" not in result.stderr
    run_dir = next((tmp_path / "outputs" / "runs").iterdir())
    client, runs = _runs(f"sqlite:///{tmp_path / 'outputs' / 'mlflow.db'}")
    assert len(runs) == 1 and runs[0].info.status == "FAILED", [r.info.status for r in runs]
    run_id = runs[0].info.run_id
    assert f"python -m mosd log {run_dir}" in runs[0].data.tags["mosd.logging_error"]
    assert json.loads((run_dir / "mlflow_pending.json").read_text())["run_id"] == run_id

    server = _artifact_server(tmp_path, port)  # the disk has room again
    try:
        first = mosd(["log", str(run_dir)], cwd=tmp_path, timeout=300)
        second = mosd(["log", str(run_dir)], cwd=tmp_path, timeout=300)
        assert first.returncode == 0 and second.returncode == 0, (first.stderr + second.stderr)[-3000:]
        assert "logged already" in second.stdout
        client, runs = _runs(f"sqlite:///{tmp_path / 'outputs' / 'mlflow.db'}")
        assert [r.info.run_id for r in runs] == [run_id] and runs[0].info.status == "FINISHED"
        assert FINAL_METRICS <= set(runs[0].data.metrics)
        assert all(len(client.get_metric_history(run_id, key)) == 1 for key in FINAL_METRICS)
        stored = {a.path for a in client.list_artifacts(run_id)}
        assert {p.name for p in run_dir.glob("*.png")} | {"summary.json", "pareto.csv"} <= stored
    finally:
        stop_process_group(server)


#: ``python -c`` of the main command with an artifact store that takes no file: every write MLflow's local
#: artifact repository makes (the run's files and the model's) fails with ENOSPC, as on a full disk
FULL_ARTIFACT_STORE = """
import errno, os, sys
from mlflow.store.artifact.local_artifact_repo import LocalArtifactRepository

def disk_full(self, *args, **kwargs):
    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), self.artifact_dir)

LocalArtifactRepository.log_artifact = LocalArtifactRepository.log_artifacts = disk_full
from mosd.app import main
main()
"""


@pytest.mark.parametrize("model_entry", ["named", "absent"])
def test_mosd_log_logs_the_detector_model_the_full_artifact_store_did_not_take(tmp_path, capsys, model_entry):
    """The main command's chart model (issue 24) did not fit in the artifact store either: ``mosd log``
    logs it to the same run from the run directory, prints its URI as the run's summary does, and a
    second ``mosd log`` logs nothing; ``runs:/ID/detector`` then scores as the run's fitted chart.
    ``absent``: a pending file written before it had a ``model`` entry; the model saved under
    ``model/`` in the run directory is logged all the same."""
    import mlflow
    import pandas as pd
    from mlflow.entities import LoggedModelStatus

    from mosd.app import model_state, pending
    from mosd.app.detector_model import load_fitted

    run = mosd(["+fault=offset_var", "optimizer=mopso", "optimizer.pop_size=8", "optimizer.n_gen=2",
                "budget.n_test=2", "budget.n_train=2", "budget.n_calibration=2", "progress=false"], cwd=tmp_path,
               command=[sys.executable, "-c", FULL_ARTIFACT_STORE])
    assert run.returncode == 3 and "No space left on device" in run.stdout, run.stderr[-3000:]
    run_dir = next((tmp_path / "outputs" / "runs").iterdir())
    tracking = f"sqlite:///{tmp_path / 'outputs' / 'mlflow.db'}"
    client, runs = _runs(tracking)
    run_id = runs[0].info.run_id

    def ready_models():
        return [m for m in client.search_logged_models([runs[0].info.experiment_id])
                if m.source_run_id == run_id and m.status == LoggedModelStatus.READY]

    assert [r.info.status for r in runs] == ["FAILED"] and not ready_models()
    if model_entry == "absent":
        request = json.loads((run_dir / pending.PENDING_FILE).read_text())
        assert request.pop("model").endswith("pipeline.npz")
        (run_dir / pending.PENDING_FILE).write_text(json.dumps(request))

    assert pending.log_main([str(run_dir)]) == 0
    first = capsys.readouterr().out
    assert pending.log_main([str(run_dir)]) == 0
    second = capsys.readouterr().out
    uri = re.search(rf"model (models:/\S+) \(runs:/{run_id}/detector\): python -m mosd monitor --model \1 ", first)
    assert uri and "logged already" in second and uri.group(0) in second, first + second
    assert [m.model_uri for m in ready_models()] == [uri.group(1)]  # twice run, once logged
    # and no FAILED record of the upload the full store cut short beside it (issue 34)
    assert [m.status for m in client.search_logged_models([runs[0].info.experiment_id])
            if m.source_run_id == run_id] == [LoggedModelStatus.READY]
    assert client.get_run(run_id).info.status == "FINISHED"

    fitted = load_fitted(run_dir / "model" / "pipeline.npz")
    rows = pd.DataFrame(np.random.default_rng(0).normal(size=(300, len(fitted.inputs))) + 0.4,
                        columns=list(fitted.inputs))
    mlflow.set_tracking_uri(tracking)
    scored = mlflow.pyfunc.load_model(f"runs:/{run_id}/detector").predict(rows)
    # the served answer is strict JSON: None, not NaN, on the rows that complete no subgroup (issue 34)
    pd.testing.assert_frame_equal(scored, model_state.strict_json(fitted.predict_frame(rows)))
    assert scored["alarm"].any()  # a comparison that alarms somewhere: not two empty answers


def test_mosd_log_completes_the_run_an_older_pending_file_left_finished_and_empty(tmp_path, capsys):
    """A pending file from before the run id was recorded: ``mosd log`` finds the run made for the same
    run directory (the issue's FINISHED run with 0 artifacts) and completes it instead of making a second."""
    from mosd.app import pending

    run_dir = tmp_path / "run"
    files = _run_dir_with_results(run_dir)
    settings = TrackingSettings(f"sqlite:///{tmp_path / 'mlflow.db'}", (tmp_path / "art").as_uri(), "mosd")
    mlstore = mlflow_client.MlflowStore(settings)
    tags = {"mosd.role": "job", "mosd.run_dir": str(run_dir)}
    other = mlstore.create_run("another directory", {"mosd.role": "job", "mosd.run_dir": str(tmp_path / "other")})
    left = mlstore.create_run("r", tags)
    mlstore.log(left, {"seed": "0"}, [("far", 0.01, 0)])
    mlstore.end(left, "FINISHED")
    old = {"settings": {"uri": settings.uri, "artifact_root": settings.artifact_root, "experiment": "mosd"},
           "run_name": "r", "tags": tags, "parent_run_id": None, "params": {"seed": "0"},
           "metrics": [["far", 0.01, 0], ["mdr", 0.02, 0]],
           "artifacts": [*(str(f) for f in files), str(run_dir / "residual.png")]}  # one removed since
    (run_dir / pending.PENDING_FILE).write_text(json.dumps(old))
    assert pending.log_main([str(run_dir)]) == 0
    assert f"not logged, no longer in {run_dir}: {run_dir / 'residual.png'}" in capsys.readouterr().err
    runs = mlstore.client.search_runs([mlstore.experiment_id()])
    assert sorted(r.info.run_id for r in runs) == sorted([left, other])
    assert len(mlstore.client.get_metric_history(left, "far")) == 1 and "mdr" in mlstore.client.get_run(left).data.metrics
    assert {a.path for a in mlstore.client.list_artifacts(left)} == {f.name for f in files}
    assert not list(mlstore.client.list_artifacts(other))


@pytest.mark.slow
@pytest.mark.parametrize("launcher", ["basic", "joblib"])
def test_a_full_outputs_disk_in_a_sweep_is_one_line_per_job_and_exit_1(tmp_path, launcher):
    """Each job of a sweep reports its run directory in one line and the sweep goes on (as with any failing
    job); the exit code is 1 under both launchers (a joblib job runs in another process: its summary.json
    tells the launching process). RLIMIT_FSIZE of 20 kB: no PNG fits."""
    args = [sys.executable, "-m", "mosd", "+fault=offset_var", "tracking=none", *SMALL]
    warm = subprocess.run(args, cwd=tmp_path, env=_env(tmp_path / "warm"), capture_output=True, text=True, timeout=600)
    assert warm.returncode == 0, warm.stderr[-3000:]  # numba's kernel cache written (its files exceed the limit)
    extra = ["hydra/launcher=joblib", "hydra.launcher.n_jobs=2"] if launcher == "joblib" else []
    result = subprocess.run([*args[:3], "-m", *args[3:], "seed=0,1", *extra], cwd=tmp_path, env=_env(), text=True,
                            capture_output=True, timeout=600, preexec_fn=_limited_file_size(20_000))
    assert result.returncode == 1, result.stderr[-3000:]
    assert "Traceback" not in result.stderr, result.stderr[-3000:]
    lines = [ln for ln in result.stderr.splitlines()  # the kernel cache's own warning aside (the test above)
             if ln.startswith("mosd:") and not ln.startswith("mosd: warning: kernel cache")]
    assert len(lines) == 2 and all("the run directory could not be written" in ln for ln in lines), lines
    jobs = sorted(p for p in next((tmp_path / "outputs" / "multirun").iterdir()).iterdir() if p.is_dir())
    assert [j.name for j in jobs] == ["0", "1"]
    for job in jobs:
        summary = json.loads((job / "summary.json").read_text())
        assert summary["status"] == "failed" and len(summary["missing"]) == 4, summary
        assert not list(job.glob("*.png")) and not list(job.glob(".*-*"))


def test_the_launching_process_learns_a_worker_jobs_outcome_from_its_summary(tmp_path, monkeypatch):
    """A joblib-launcher job runs in another process: a job that could not write its run directory, or whose
    run MLflow did not take, reaches the exit code through its summary.json."""
    from mosd.app import files, pending, sweep

    monkeypatch.setattr(files, "NOT_WRITTEN", [])
    monkeypatch.setattr(pending, "NOT_LOGGED", [])
    outcomes = {"0": {"status": "finished"}, "1": {"status": "failed", "missing": ["chart.png"]},
                "2": {"status": "finished", "tracking": {"logged": False}}, "3": {"status": "failed", "error": "boom"}}
    for job, summary in outcomes.items():
        (tmp_path / job).mkdir()
        (tmp_path / job / "summary.json").write_text(json.dumps(summary))
    assert sweep.record_job_outcomes(tmp_path) is True
    assert sweep.record_job_outcomes(tmp_path) is True  # again: nothing twice
    assert files.NOT_WRITTEN == [tmp_path / "1"] and pending.NOT_LOGGED == [tmp_path / "2"]
    (tmp_path / "1" / "summary.json").write_text(json.dumps({"status": "finished"}))
    files.NOT_WRITTEN.clear()
    assert sweep.record_job_outcomes(tmp_path) is False and files.NOT_WRITTEN == []
