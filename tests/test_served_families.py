"""The served model of a non-PCA family reproduces its run's alarms (issue 50: "mosd monitor and the served model
reproduce a run's alarms for every family").

``mosd monitor`` re-scores every family's run in ``tests/test_reliability_53.py``; here ``mlflow models serve``
(``--env-manager local``, 127.0.0.1) scores the run's own ``test_stream.parquet`` in requests of 37 rows, the state
carried between requests as the model's params (their names are the model signature's params), and must give the
run's own alarm on every row: for CVA (a dynamic family: its lagged rows are state) and the per-tag EWMA charts
(each tag's EWMA is state).
"""
from __future__ import annotations

import re

import numpy as np
import pytest

from test_reliability_53 import build_family_run


@pytest.mark.slow
@pytest.mark.parametrize("family", ["cva", "tag_ewma"])
def test_the_served_model_gives_the_runs_own_alarms(family, stop_process_group, shared_build):
    import pandas as pd
    from mlflow import MlflowClient
    from mlflow.models import get_model_info

    from mosd.app.serving import predict_served, start_model_server

    # the run tests/test_reliability_53.py re-scores with mosd monitor: trained once, shared (read only)
    folder = shared_build(f"table-run-{family}", build_family_run(family))
    model = re.search(r"model (models:/\S+)", (folder / "stdout.txt").read_text()).group(1)
    tracking = f"sqlite:///{folder / 'outputs' / 'mlflow.db'}"
    MlflowClient(tracking)  # the store the model's URI resolves in
    import mlflow

    mlflow.set_tracking_uri(tracking)
    state_names = [p.name for p in get_model_info(model).signature.params.params]
    assert state_names, "the model declares its state as params"
    stream = pd.read_parquet(folder / "run" / "test_stream.parquet")
    reference = stream.attrs.get("mosd_reference") or ["time", "decision", "alarm"]
    inputs = stream.drop(columns=[c for c in stream.columns if c in set(reference) | {"time", "decision", "alarm"}])
    server, port = start_model_server(model, tracking, timeout=300)
    try:
        state, alarms = None, []
        for start in range(0, len(inputs), 37):
            chunk = inputs.iloc[start:start + 37]
            rows = predict_served(port, list(chunk.columns), chunk.to_numpy().tolist(), state)
            alarms += [bool(row["alarm"]) for row in rows]
            state = {k: rows[-1][k] for k in state_names}
    finally:
        stop_process_group(server)
    expected = stream["alarm"].to_numpy(bool)
    assert expected.any() and not expected.all(), "the comparison needs alarms and quiet rows"
    assert np.array_equal(alarms, expected)
