"""Issue 51: ``kill PID`` (SIGTERM) or a closed terminal (SIGHUP) on ``mosd ui`` ends its MLflow server too.

Before, only Ctrl-C (the terminal's SIGINT reaches the whole foreground group) was clean: after ``kill PID`` the
server's processes kept answering on the port until they were SIGKILLed.
"""
from __future__ import annotations

import os
import signal
import time
import urllib.request

import pytest

from mosd.app.serving import stop_process_group
from test_mlflow_ui import _mosd_ui


def _answers(url: str) -> bool:
    try:
        with urllib.request.urlopen(f"{url}/health", timeout=2):
            return True
    except OSError:
        return False


@pytest.mark.slow
@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGHUP])
def test_a_signal_to_mosd_ui_alone_stops_its_server(tmp_path, signum):
    import mlflow

    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    mlflow.MlflowClient(uri).create_experiment("empty")
    ui, printed = _mosd_ui(tmp_path, uri)
    url = printed["experiments"].split("/#")[0]
    try:
        assert _answers(url)
        os.kill(ui.pid, signum)  # the mosd ui process only, as `kill PID` does: not its group
        assert ui.wait(timeout=30) == 128 + signum
        deadline = time.monotonic() + 15
        while _answers(url) and time.monotonic() < deadline:
            time.sleep(0.5)
        assert not _answers(url), "the server still answers after mosd ui ended"
    finally:
        if ui.poll() is None:
            stop_process_group(ui)
