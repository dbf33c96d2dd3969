"""Issue 51: the re-scoring command a run prints works as printed, from the directory the run was started in.

Before, it named the bare ``test_stream.parquet``, and typed as printed it failed with ``DATA='test_stream.parquet':
no such file``: the file is in the run directory.
"""
from __future__ import annotations

import re
import shlex

import pytest

from test_detector_model import _mosd


@pytest.mark.parametrize("mlflow_env", [False, True], ids=["default-store", "MLFLOW_TRACKING_URI-elsewhere"])
def test_the_printed_rescoring_command_runs_as_printed(tmp_path, monkeypatch, mlflow_env):
    """With ``MLFLOW_TRACKING_URI`` naming another store (which mosd monitor reads by default, and the run does
    not log to), the command names the run's store."""
    monkeypatch.delenv("MLFLOW_TRACKING_URI", raising=False)
    if mlflow_env:
        monkeypatch.setenv("MLFLOW_TRACKING_URI", f"sqlite:///{tmp_path / 'elsewhere.db'}")
    outputs = tmp_path / "out"
    run = _mosd(["+fault=offset", "debug=tiny", "progress=false"], tmp_path, outputs)
    assert run.returncode == 0, run.stderr[-3000:]
    printed = re.search(r"(python -m mosd monitor --model .*)$", run.stdout, re.M)
    assert printed, run.stdout[-3000:]
    words = shlex.split(printed.group(1))
    assert words[:4] == ["python", "-m", "mosd", "monitor"]
    stream = words[words.index("--tracking-uri") - 1] if "--tracking-uri" in words else words[-1]
    assert not stream.startswith("/") and (tmp_path / stream).is_file()  # relative to where the user stands
    assert ("--tracking-uri" in words) == mlflow_env
    again = _mosd(words[3:], tmp_path, outputs)
    assert again.returncode == 0, again.stderr[-2000:]
    assert re.search(r"the run's own alarms: (\d+) of \1 rows agree", again.stdout), again.stdout[-2000:]
