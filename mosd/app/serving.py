"""A logged detector model behind ``mlflow models serve`` on loopback: start it, post rows, stop it.

One place for what the bench's ``serve`` section and the tests that compare served alarms with a
run's own need: a free loopback port, the server started with mosd importable (``--env-manager
local``) and waited for until ``/ping`` answers, requests in ``dataframe_split`` JSON with the
model's state in ``params``, and the server's whole process group stopped (its gunicorn/uvicorn
workers too).
"""
from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path
from typing import Mapping, Sequence

#: the directory that holds the ``mosd`` package: on the server's PYTHONPATH so that a checkout serves too
PACKAGE_PARENT = str(Path(__file__).resolve().parents[2])


def free_port() -> int:
    """A loopback port nothing listens on now (bound and released)."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def stop_process_group(process: subprocess.Popen, timeout: float = 20.0) -> None:
    """SIGTERM to a process started with ``start_new_session=True`` and its children; SIGKILL after ``timeout`` s."""
    os.killpg(process.pid, signal.SIGTERM)
    try:
        process.wait(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(process.pid, signal.SIGKILL)
        process.wait()


def start_model_server(model_uri: str, tracking_uri: str, timeout: float = 180.0,
                       stderr=subprocess.DEVNULL) -> tuple[subprocess.Popen, int]:
    """``mlflow models serve -m MODEL_URI --host 127.0.0.1 --env-manager local`` on a free port, once ``/ping`` answers.

    Returns the server process (its own session: stop it with :func:`stop_process_group`) and its port.
    Raises ``RuntimeError`` if the server exits first (with the end of its stderr when ``stderr`` is
    ``subprocess.PIPE``) or does not answer within ``timeout`` seconds; the server is stopped then.
    """
    port = free_port()
    env = {**os.environ, "MLFLOW_TRACKING_URI": tracking_uri,
           "PYTHONPATH": os.pathsep.join(p for p in (PACKAGE_PARENT, os.environ.get("PYTHONPATH")) if p)}
    server = subprocess.Popen([sys.executable, "-m", "mlflow", "models", "serve", "-m", model_uri, "--host",
                               "127.0.0.1", "--port", str(port), "--env-manager", "local"], env=env,
                              stdout=subprocess.DEVNULL, stderr=stderr, start_new_session=True)
    deadline = time.monotonic() + timeout
    while True:
        if server.poll() is not None:
            said = server.stderr.read().decode()[-2000:] if server.stderr is not None else ""
            raise RuntimeError(f"mlflow models serve exited with {server.returncode}\n{said}".rstrip())
        try:
            urllib.request.urlopen(f"http://127.0.0.1:{port}/ping", timeout=2)
            return server, port
        except OSError:
            if time.monotonic() > deadline:
                stop_process_group(server)
                raise RuntimeError(f"mlflow models serve did not answer /ping within {timeout:g} s") from None
            time.sleep(0.5)


def invocation(port: int, columns: Sequence[str], data: list, params: Mapping | None = None) -> urllib.request.Request:
    """The POST of rows to the served model's ``/invocations`` (``dataframe_split``; the state in ``params``)."""
    body = {"dataframe_split": {"columns": list(columns), "data": data}}
    if params:
        body["params"] = dict(params)
    return urllib.request.Request(f"http://127.0.0.1:{port}/invocations", json.dumps(body).encode(),
                                  {"Content-Type": "application/json"})


def predictions(request: urllib.request.Request) -> list[dict]:
    """Send an :func:`invocation`: the served model's predictions, one dict per row."""
    return json.loads(urllib.request.urlopen(request, timeout=60).read())["predictions"]


def predict_served(port: int, columns: Sequence[str], data: list, params: Mapping | None = None) -> list[dict]:
    """:func:`predictions` of :func:`invocation`: rows in, the served model's per-row outputs back."""
    return predictions(invocation(port, columns, data, params))
