"""Issue 53 item 7: a tracking server that dies just after creating the run.

The store then holds the run RUNNING with no metrics; the app keeps the results on disk
(``mlflow_pending.json``) and ``mosd log`` completes THAT run (same run id) once the server is back, rather
than creating a second one. Before the fix, the run's start reply asked the server for the experiment id
after creating the run: a server gone in between lost the run id, and ``mosd log`` made a second,
FINISHED run beside the RUNNING one.

The end-to-end test runs a real ``mlflow server`` behind a small HTTP relay that kills the server (SIGKILL
to its process group) as soon as the server has answered ``runs/create``, and stops listening: the
same moment as a server killed about 2 s into a run, made deterministic (slow: two server starts).
"""
from __future__ import annotations

import http.client
import json
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
import urllib.request
from dataclasses import asdict
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import pytest

from mosd.app.serving import free_port
from mosd.app.settings import TrackingSettings

from test_app import PACKAGE_PARENT


# ---------------------------------------------------------------------------------------
# fast: the two mends, one by one
# ---------------------------------------------------------------------------------------
class _CountingClient:
    """Stands in for MlflowClient: counts the experiment look-ups."""

    def __init__(self):
        self.lookups = 0

    def get_experiment_by_name(self, name):
        self.lookups += 1

        class Found:
            experiment_id = "7"
            tags = {"mlflow.experimentKind": "custom_model_development"}

        return Found()


def test_the_experiment_id_is_asked_of_a_server_once(tmp_path):
    from mosd.app.mlflow_client import MlflowStore

    store = MlflowStore(TrackingSettings(f"http://127.0.0.1:{free_port()}", (tmp_path / "art").as_uri(), "mosd"))
    store.client = _CountingClient()
    assert store.experiment_id() == store.experiment_id() == "7"
    assert store.client.lookups == 1  # a second answer needs no server: the start reply cannot fail on it


def _pending_dir(tmp_path: Path, uri: str, run_id: str | None) -> Path:
    run_dir = tmp_path / "runs" / "r1"
    run_dir.mkdir(parents=True)
    (run_dir / "summary.json").write_text(json.dumps({"status": "finished", "test": {"far": 0.1}}))
    settings = TrackingSettings(uri, (tmp_path / "art").as_uri(), "mosd")
    pending = {"settings": asdict(settings), "run_id": run_id, "run_name": "r", "parent_run_id": None,
               "tags": {"mosd.run_dir": str(run_dir.resolve()), "mosd.role": "job"}, "params": {"a": "1"},
               "metrics": [["far", 0.1, 0]], "artifacts": [str(run_dir / "summary.json")], "model": None}
    (run_dir / "mlflow_pending.json").write_text(json.dumps(pending))
    return run_dir


def test_mosd_log_completes_the_run_the_store_created_when_the_app_never_learned_its_id(tmp_path):
    from mosd.app.mlflow_client import MlflowStore
    from mosd.app.pending import log_pending

    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    store = MlflowStore(TrackingSettings(uri, (tmp_path / "art").as_uri(), "mosd"))
    run_dir = _pending_dir(tmp_path, uri, run_id=None)
    # what the server did before it died: the run exists, RUNNING, tagged with the run directory
    created = store.create_run("r", {"mosd.run_dir": str(run_dir.resolve()), "mosd.role": "job"})
    run_id, now, gone, _ = log_pending(run_dir)
    assert (run_id, now, gone) == (created, True, [])
    runs = store.client.search_runs([store.experiment_id()])
    assert [(r.info.run_id, r.info.status) for r in runs] == [(created, "FINISHED")]
    assert runs[0].data.metrics["far"] == pytest.approx(0.1, abs=1e-12)
    assert json.loads((run_dir / "summary.json").read_text())["tracking"]["run_id"] == created


# ---------------------------------------------------------------------------------------
# slow: a real mlflow server killed just after it created the run
# ---------------------------------------------------------------------------------------
def _env(outputs: Path) -> dict:
    env = {k: v for k, v in os.environ.items() if not k.startswith("MOSD_") and k != "HYDRA_FULL_ERROR"}
    env["PYTHONPATH"] = os.pathsep.join(p for p in (PACKAGE_PARENT, env.get("PYTHONPATH")) if p)
    env["MOSD_OUTPUTS"] = str(outputs)
    return env


def _start_server(tmp_path: Path, port: int, log_name: str) -> subprocess.Popen:
    mlflow_cli = shutil.which("mlflow", path=str(Path(sys.executable).parent)) or shutil.which("mlflow")
    assert mlflow_cli, "the mlflow command (a dependency) is missing"
    log = (tmp_path / log_name).open("w")
    server = subprocess.Popen([mlflow_cli, "server", "--workers", "1", "--host", "127.0.0.1", "--port", str(port),
                               "--backend-store-uri", f"sqlite:///{tmp_path / 'server.db'}"],
                              cwd=tmp_path, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
    deadline = time.monotonic() + 240
    while True:
        assert server.poll() is None, (tmp_path / log_name).read_text()[-3000:]
        try:
            with urllib.request.urlopen(f"http://127.0.0.1:{port}/health", timeout=2):
                return server
        except OSError:
            assert time.monotonic() < deadline, "the server did not come up"
            time.sleep(0.5)


def _kill_group(process: subprocess.Popen) -> None:
    if process.poll() is None:
        os.killpg(process.pid, signal.SIGKILL)  # the server's own group (start_new_session)
        process.wait(timeout=30)


def _relay(upstream_port: int, on_created=None, port: int = 0) -> ThreadingHTTPServer:
    """An HTTP relay on ``port`` (0: any free one) to 127.0.0.1:``upstream_port``; ``on_created()`` runs once the upstream has answered
    ``runs/create``, before the answer is passed on; from then on the relay answers nothing."""
    state = {"dead": False}

    class Relay(BaseHTTPRequestHandler):
        protocol_version = "HTTP/1.1"

        def log_message(self, *args):  # the test's output stays quiet
            pass

        def _relay(self):
            if state["dead"]:
                self.close_connection = True
                return
            body = self.rfile.read(int(self.headers.get("Content-Length") or 0))
            upstream = http.client.HTTPConnection("127.0.0.1", upstream_port, timeout=60)
            headers = {k: v for k, v in self.headers.items() if k.lower() not in ("host", "connection")}
            upstream.request(self.command, self.path, body=body or None, headers=headers)
            answer = upstream.getresponse()
            data = answer.read()
            upstream.close()
            if on_created is not None and "/runs/create" in self.path and answer.status == 200:
                state["dead"] = True
                on_created()
            self.send_response(answer.status)
            for key, value in answer.getheaders():
                if key.lower() not in ("transfer-encoding", "connection", "content-length"):
                    self.send_header(key, value)
            self.send_header("Content-Length", str(len(data)))
            self.end_headers()
            self.wfile.write(data)

        do_GET = do_POST = do_PUT = do_PATCH = do_DELETE = _relay

    server = ThreadingHTTPServer(("127.0.0.1", port), Relay)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    return server


@pytest.mark.slow
def test_a_server_killed_after_creating_the_run_leaves_one_run_that_mosd_log_completes(tmp_path):
    from mlflow.tracking import MlflowClient

    port = free_port()
    server = _start_server(tmp_path, port, "server.log")
    relays = []

    def kill_and_stop_listening():
        _kill_group(server)

        def stop():  # no listening socket left: the client's next connection is refused at once
            relays[0].shutdown()
            relays[0].server_close()

        threading.Thread(target=stop, daemon=True).start()

    relays.append(_relay(port, on_created=kill_and_stop_listening))
    relay_port = relays[0].server_address[1]
    uri = f"http://127.0.0.1:{relay_port}"
    outputs = tmp_path / "out"
    budget = ["optimizer.pop_size=6", "optimizer.n_gen=2", "budget.n_test=2", "budget.n_train=2",
              "budget.n_calibration=2", "optimizer.n_jobs=1", "progress=false", "scenario.duration=3"]
    try:
        result = subprocess.run([sys.executable, "-m", "mosd", "+fault=offset_var", *budget, f"tracking.uri={uri}"],
                                cwd=tmp_path, env=_env(outputs), capture_output=True, text=True, timeout=600)
    finally:
        _kill_group(server)
        relays[0].server_close()
    assert result.returncode == 3, result.stderr[-3000:]
    assert "Traceback" not in result.stderr and "python -m mosd log" in result.stderr
    (run_dir,) = [p.parent for p in outputs.glob("runs/*/mlflow_pending.json")]
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["status"] == "finished" and "test" in summary  # the results are kept
    pending = json.loads((run_dir / "mlflow_pending.json").read_text())
    assert pending["run_id"], "the app lost the id of the run the server created"

    # the server is back on the same store, reached at the same address (a relay that passes all through)
    port2 = free_port()
    server = _start_server(tmp_path, port2, "server2.log")
    relay = _relay(port2, port=relay_port)
    try:
        logged = subprocess.run([sys.executable, "-m", "mosd", "log", str(run_dir)], cwd=tmp_path,
                                env=_env(outputs), capture_output=True, text=True, timeout=600)
        assert logged.returncode == 0, logged.stderr[-3000:]
        client = MlflowClient(uri)
        experiment = client.get_experiment_by_name("mosd")
        runs = client.search_runs([experiment.experiment_id])
    finally:
        relay.shutdown()
        relay.server_close()
        _kill_group(server)
    assert [(r.info.run_id, r.info.status) for r in runs] == [(pending["run_id"], "FINISHED")]
    assert "far" in runs[0].data.metrics and runs[0].data.tags.get("mosd.logged_later") == "true"
