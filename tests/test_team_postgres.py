"""The team set-up on a real PostgreSQL server: mosd writing to it directly and through ``mlflow server``.

A throw-away PostgreSQL cluster (Debian's ``postgresql`` package: ``initdb`` and ``pg_ctl``) is
created in a temporary directory and started on a free port of 127.0.0.1, with a password user
``mlflow`` and one database per case. As root (CI) the server runs as the ``postgres`` user:
``initdb`` and ``postgres`` refuse to run as root. Each case runs 6 single runs and a 4-job sweep
at the same time, then checks the store: 10 FINISHED job runs with their artifacts, the sweep's
parent FINISHED with its 4 children linked, and ``mosd report`` reading them all back.

These are the commands of docs/how-to/team-store.md (the README's "Tracking server" section until
issue 51 moved it to the site). PostgreSQL and the driver (psycopg2-binary,
in the ``test`` and ``team`` extras) are test dependencies: when one is missing the test fails,
it does not skip (``.ci/run`` installs the server).
"""
from __future__ import annotations

import contextlib
import csv
import glob
import io
import os
import pwd
import secrets
import shutil
import subprocess
import sys
import tempfile
import time
import urllib.parse
import urllib.request
from pathlib import Path

import pytest

from mosd.app.serving import free_port
from test_app import FINAL_METRICS, PACKAGE_PARENT

pytestmark = pytest.mark.slow

BUDGET = ["optimizer.pop_size=6", "optimizer.n_gen=2", "budget.n_test=2", "budget.n_train=2", "budget.n_calibration=2",
          "optimizer.n_jobs=1", "progress=false", "scenario.duration=3"]
#: the unprivileged user that runs the server when the tests run as root
SERVER_USER = "postgres"


def _bindir() -> Path:
    """Where Debian keeps initdb and pg_ctl (not on PATH): the newest /usr/lib/postgresql/*/bin."""
    found = sorted(glob.glob("/usr/lib/postgresql/*/bin/initdb"), key=lambda p: int(Path(p).parts[-3]))
    if found:
        return Path(found[-1]).parent
    initdb = shutil.which("initdb")
    assert initdb, "PostgreSQL is not installed: apt-get install postgresql (.ci/run does)"
    return Path(initdb).resolve().parent


def _as_server_user(cmd: list[str], **kwargs) -> subprocess.CompletedProcess:
    if os.geteuid() == 0:  # initdb and postgres refuse root
        cmd = ["runuser", "-u", SERVER_USER, "--", *cmd]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=120, **kwargs)


@contextlib.contextmanager
def throwaway_postgres(databases: tuple[str, ...] = ("direct", "server", "masked")):
    """``postgresql://mlflow:PASSWORD@127.0.0.1:PORT``: a fresh cluster, stopped and deleted afterwards."""
    bindir = _bindir()
    home = Path(tempfile.mkdtemp(prefix="mosd-pg-"))  # under /tmp: the server user can reach it
    data, port, password = home / "data", free_port(), secrets.token_hex(12)
    try:
        (home / "pw").write_text(password + "\n")
        if os.geteuid() == 0:
            user = pwd.getpwnam(SERVER_USER)
            for path in (home, home / "pw"):
                os.chown(path, user.pw_uid, user.pw_gid)
        init = _as_server_user([str(bindir / "initdb"), "-D", str(data), "-U", "mlflow", f"--pwfile={home / 'pw'}",
                                "--auth=scram-sha-256", "-E", "UTF8", "--no-instructions"])
        assert init.returncode == 0, init.stderr[-2000:]
        # a throw-away server: no fsync; listening on the loopback only, its socket in our directory
        options = f"-h 127.0.0.1 -p {port} -k {home} -c fsync=off -c synchronous_commit=off -c full_page_writes=off"
        start = _as_server_user([str(bindir / "pg_ctl"), "-D", str(data), "-l", str(home / "server.log"),
                                 "-o", options, "-w", "-t", "60", "start"])
        assert start.returncode == 0, start.stderr[-2000:] + (home / "server.log").read_text()[-2000:]
        base = f"postgresql://mlflow:{password}@127.0.0.1:{port}"
        for name in databases:
            made = subprocess.run([str(bindir / "createdb"), "-h", "127.0.0.1", "-p", str(port), "-U", "mlflow", name],
                                  env={**os.environ, "PGPASSWORD": password}, capture_output=True, text=True,
                                  timeout=60)
            assert made.returncode == 0, made.stderr[-2000:]
        yield base
    finally:
        if (data / "postmaster.pid").exists():
            _as_server_user([str(bindir / "pg_ctl"), "-D", str(data), "-m", "immediate", "-w", "stop"])
        shutil.rmtree(home, ignore_errors=True)


@pytest.fixture(scope="module")
def postgres():
    with throwaway_postgres() as base:
        yield base


def _env(outputs: Path, **extra: str) -> dict:
    env = {k: v for k, v in os.environ.items() if not k.startswith("MOSD_") and k != "HYDRA_FULL_ERROR"}
    env.update(extra)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (PACKAGE_PARENT, env.get("PYTHONPATH")) if p)
    env["MOSD_OUTPUTS"] = str(outputs)
    return env


def _sweep_and_six_runs(where: Path, tracking: list[str], **env: str) -> None:
    """A 4-job sweep and 6 single runs, all at once, all exit 0."""
    sweep = subprocess.Popen([sys.executable, "-m", "mosd", "-m", "+fault=offset,variance", "optimizer=mopso,nsga2",
                              *BUDGET, *tracking], cwd=where, env=_env(where / "sweep", **env), text=True,
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    singles = [subprocess.Popen([sys.executable, "-m", "mosd", "+fault=offset_var", f"seed={i}", *BUDGET, *tracking],
                                cwd=where, env=_env(where / f"single{i}", **env), text=True,
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE) for i in range(6)]
    done = [(p, p.communicate(timeout=1200)) for p in (sweep, *singles)]
    assert [p.returncode for p, _ in done] == [0] * 7, [err[-1500:] for p, (_, err) in done if p.returncode]


def _check_store(uri: str, where: Path) -> None:
    """10 FINISHED jobs with metrics and artifacts, the sweep's 4 linked to its FINISHED parent; the report reads all."""
    from mlflow.tracking import MlflowClient

    client = MlflowClient(tracking_uri=uri)
    experiment = client.get_experiment_by_name("mosd")
    assert experiment.tags.get("mlflow.experimentKind") == "custom_model_development"
    runs = client.search_runs([experiment.experiment_id], max_results=1000)
    jobs = [r for r in runs if r.data.tags.get("mosd.role") == "job"]
    parents = [r for r in runs if r.data.tags.get("mosd.role") == "sweep"]
    assert len(runs) == 11 and len(jobs) == 10 and len(parents) == 1
    assert {r.info.status for r in runs} == {"FINISHED"}
    children = [r for r in jobs if r.data.tags.get("mlflow.parentRunId") == parents[0].info.run_id]
    assert sorted((r.data.tags["mosd.fault"], r.data.tags["mosd.optimizer"]) for r in children) == [
        ("offset", "mopso"), ("offset", "nsga2"), ("variance", "mopso"), ("variance", "nsga2")]
    assert sorted(r.data.params["seed"] for r in jobs if r not in children) == [str(i) for i in range(6)]
    for r in jobs:
        assert FINAL_METRICS <= set(r.data.metrics), r.info.run_id
        assert len(client.get_metric_history(r.info.run_id, "hypervolume")) == 2  # one point per generation
        assert {"summary.json", "pareto.csv", "chart.png"} <= {a.path for a in client.list_artifacts(r.info.run_id)}
    out = subprocess.run([sys.executable, "-m", "mosd", "report", "--all", "--format", "csv", "--experiment", "mosd",
                          "--tracking-uri", uri], cwd=where, env=_env(where / "report"), capture_output=True,
                         text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    rows = list(csv.DictReader(io.StringIO(out.stdout)))
    assert sorted(row["run_id"] for row in rows) == sorted(r.info.run_id for r in jobs)
    for row in rows:
        assert 0.0 <= float(row["far"]) <= 100.0 and 0.0 <= float(row["mdr"]) <= 100.0


def _mlflow_cli() -> str:
    found = shutil.which("mlflow", path=str(Path(sys.executable).parent)) or shutil.which("mlflow")
    assert found is not None, "the mlflow command is not installed"
    return found


def test_mosd_writes_directly_to_postgresql(postgres, tmp_path, monkeypatch):
    # the password in PGPASSWORD, not in the URI: mosd logs tracking.uri as a param and prints it
    password = urllib.parse.urlparse(postgres).password
    uri = f"{postgres}/direct".replace(f":{password}@", "@")
    # MLflow creates its tables on first use without a lock: runs that start together on an empty
    # database race (duplicate alembic_version), so the set-up creates them once (docs/how-to/team-store.md)
    made = subprocess.run([_mlflow_cli(), "db", "upgrade", uri], capture_output=True, text=True, timeout=300,
                          env={**os.environ, "PGPASSWORD": password})
    assert made.returncode == 0, made.stderr[-2000:]
    _sweep_and_six_runs(tmp_path, [f"tracking.uri={uri}", f"tracking.artifact_root={tmp_path / 'artifacts'}"],
                        PGPASSWORD=password)
    monkeypatch.setenv("PGPASSWORD", password)  # for this process's MLflow client and the report
    _check_store(uri, tmp_path)


def test_a_password_in_the_uri_is_masked_everywhere_mosd_prints_or_records_it(postgres, tmp_path):
    password = urllib.parse.urlparse(postgres).password
    uri = f"{postgres}/masked"
    run = subprocess.run([sys.executable, "-m", "mosd", "+fault=offset_var", *BUDGET, f"tracking.uri={uri}",
                          f"tracking.artifact_root={tmp_path / 'artifacts'}"], cwd=tmp_path, env=_env(tmp_path / "out"),
                         capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr[-2000:]
    masked = uri.replace(f":{password}@", ":***@")
    assert password not in run.stdout + run.stderr and f"store {masked}" in run.stdout
    # a wrong password: refused by preflight's login, in one line, before any work
    wrong = subprocess.run([sys.executable, "-m", "mosd", "+fault=offset_var", *BUDGET,
                            f"tracking.uri={uri.replace(password, 'not-' + password)}"], cwd=tmp_path,
                           env=_env(tmp_path / "wrong"), capture_output=True, text=True, timeout=120)
    assert wrong.returncode == 2 and len(wrong.stderr.strip().splitlines()) == 1, wrong.stderr[-2000:]
    assert "password authentication failed" in wrong.stderr and password not in wrong.stderr
    assert not (tmp_path / "wrong").exists()
    leaks = [str(f) for f in tmp_path.rglob("*") if f.is_file() and password.encode() in f.read_bytes()]
    assert leaks == []  # summary, resolved config, Hydra's .hydra/*.yaml, the logged artifacts
    from mlflow.tracking import MlflowClient

    client = MlflowClient(tracking_uri=uri)
    (found,) = client.search_runs([client.get_experiment_by_name("mosd").experiment_id])
    assert found.data.params["tracking.uri"] == masked
    assert not [k for k, v in {**found.data.params, **found.data.tags}.items() if password in v]


def test_mosd_writes_through_an_mlflow_server_on_postgresql(postgres, tmp_path, stop_process_group):
    mlflow_cli = _mlflow_cli()
    port = free_port()
    url = f"http://127.0.0.1:{port}"
    log = tmp_path / "server.log"
    server = subprocess.Popen([mlflow_cli, "server", "--workers", "1", "--host", "127.0.0.1", "--port", str(port),
                               "--backend-store-uri", f"{postgres}/server",
                               "--artifacts-destination", str(tmp_path / "server-artifacts")],
                              stdout=log.open("w"), stderr=subprocess.STDOUT, start_new_session=True)
    try:
        deadline = time.monotonic() + 180
        while True:
            assert server.poll() is None, log.read_text()[-3000:]
            try:
                with urllib.request.urlopen(f"{url}/health", timeout=2):
                    break
            except OSError:
                assert time.monotonic() < deadline, f"mlflow server did not come up:\n{log.read_text()[-3000:]}"
                time.sleep(0.5)
        # artifacts through the server (mlflow-artifacts:), as for team members on other machines
        _sweep_and_six_runs(tmp_path, [f"tracking.uri={url}", "tracking.artifact_root=mlflow-artifacts:/"])
        _check_store(url, tmp_path)
        stored = list((tmp_path / "server-artifacts").rglob("summary.json"))
        assert len(stored) == 10, stored
    finally:
        stop_process_group(server)
