"""The MLflow UI as a person sees it: a real ``mlflow server`` and headless Chromium (Selenium).

The browser test serves a store holding one small sweep (2 faults x 2 optimisers, 4 generations
each) with ``mlflow server --workers 1`` on 127.0.0.1, opens the UI in Debian's ``chromium``
driven by Debian's ``chromium-driver``, and checks the pages a person uses to compare runs: the
experiment's runs table, the sweep's parent run with its four children, the compare view of the
children (the swept params, FAR and MDR) and the per-generation hypervolume chart. Screenshots go
to ``$MOSD_UI_SHOTS`` (default: the test's temporary directory); ``docs/img/mlflow-compare.png``
is one of them.

Chromium, chromedriver and selenium are test dependencies (``.ci/run`` installs the first two
with apt, the ``test`` extra brings selenium): when one is missing the test fails, it does not skip.
"""
from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path

import pytest

from mosd.app.mlflow_client import MlflowStore
from mosd.app.settings import TrackingSettings

#: the tag MLflow reads for an experiment's kind, and the kind of a training-runs experiment
#: (MLflow's ExperimentKind.CUSTOM_MODEL_DEVELOPMENT; its UI labels it "Machine learning")
KIND_TAG, TRAINING_KIND = "mlflow.experimentKind", "custom_model_development"
CHROMIUM, CHROMEDRIVER = "/usr/bin/chromium", "/usr/bin/chromedriver"
#: root in a container: no sandbox; no connection to Google's services on a closed network
CHROMIUM_FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                  "--disable-background-networking", "--disable-component-update", "--disable-sync",
                  "--window-size=1400,900")
SWEEP = ["-m", "+fault=offset,variance", "optimizer=mopso,nsga2", "optimizer.pop_size=6", "optimizer.n_gen=4",
         "budget.n_test=2", "budget.n_train=2", "budget.n_calibration=2", "optimizer.n_jobs=1", "progress=false",
         "scenario.duration=3"]


def _experiment_tags(uri: str) -> dict:
    from mlflow.tracking import MlflowClient

    return MlflowClient(tracking_uri=uri).get_experiment_by_name("mosd").tags


def test_mosd_makes_its_experiment_a_training_runs_experiment(tmp_path):
    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    store = MlflowStore(TrackingSettings(uri, (tmp_path / "art").as_uri(), "mosd"))
    assert store.experiment_id()
    assert _experiment_tags(uri).get(KIND_TAG) == TRAINING_KIND


def test_an_experiment_made_before_gets_the_kind_and_a_chosen_kind_is_kept(tmp_path):
    from mlflow.tracking import MlflowClient

    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    settings = TrackingSettings(uri, (tmp_path / "art").as_uri(), "mosd")
    client = MlflowClient(tracking_uri=uri)
    client.create_experiment("mosd")  # as mosd made it before it set the kind
    MlflowStore(settings).experiment_id()
    assert _experiment_tags(uri).get(KIND_TAG) == TRAINING_KIND
    other = TrackingSettings(uri, (tmp_path / "art").as_uri(), "chosen")
    client.set_experiment_tag(client.create_experiment("chosen"), KIND_TAG, "genai_development")
    MlflowStore(other).experiment_id()
    assert client.get_experiment_by_name("chosen").tags[KIND_TAG] == "genai_development"
