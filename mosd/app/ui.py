"""``mosd ui``: the MLflow UI on the runs table, with FAR, MDR and the tuned parameters as columns.

MLflow 3.17's UI opens an experiment on its GenAI overview ("Traces 0") unless the
browser's switch at the top left says "Model training", and its runs table shows
no metric column until one is picked; the experiment list's link carries neither.
``mosd ui`` starts ``mlflow server`` with the README's settings (one worker,
MLflow's job runner off, on the loopback interface) against the default store and:

* tags each mosd experiment with a shared view (``mlflow.sharedViewState.mosd``,
  MLflow's own "share view" mechanism): the runs table with the columns FAR, MDR,
  accuracy and the tuned parameters of its runs; the printed address
  (:func:`runs_address`) opens it;
* serves the UI's page with a few lines of script that, in a browser that has not
  chosen yet, set the switch to "Model training" and give each mosd experiment's
  runs table those columns (the browser's own stored choices win), so that a click on
  the experiment in the list lands on that table too.

The server is MLflow's, unchanged: its FastAPI app with one middleware that adds the script to the HTML page
(:func:`create_app`), served as an MLflow app plugin (``mlflow server --app-name``, MLflow's documented
``mlflow.app`` entry points: :func:`serve`).
"""
from __future__ import annotations

import argparse
import json
import os
import sys
from typing import Iterable, Sequence

#: the experiment tag of the shared view (MLflow: ``mlflow.sharedViewState.<key>``, opened by ``viewStateShareKey``)
SHARE_KEY = "mosd"
SHARED_VIEW_TAG = f"mlflow.sharedViewState.{SHARE_KEY}"
#: the environment variable carrying the views to the server process (experiment id -> columns)
VIEWS_ENV = "MOSD_UI_VIEWS"
#: the test metrics shown first (metrics logged by every run: mosd.app.summary.final_metrics)
TEST_COLUMNS = ("far", "mdr", "accuracy")
#: the local-storage key of MLflow 3.17's workflow switch ("GenAI" / "Model training")
WORKFLOW_KEY = "mlflow.workflowType_v1"


def column(kind: str, name: str) -> str:
    """MLflow's runs-table column key (``metrics.`far```)."""
    return f"{kind}.`{name}`"


def view_columns(tuned: Iterable[str]) -> list[str]:
    """The runs table's columns: FAR, MDR, accuracy, then the tuned parameters (logged as metrics)."""
    return [column("metrics", name) for name in dict.fromkeys((*TEST_COLUMNS, *tuned))]


def runs_address(base: str, experiment_id: str) -> str:
    """The runs table of an experiment in the training-runs mode, opened on mosd's shared view."""
    return (f"{base.rstrip('/')}/#/experiments/{experiment_id}/runs?workflowType=machine_learning"
            f"&viewStateShareKey={SHARE_KEY}")


def list_address(base: str) -> str:
    return f"{base.rstrip('/')}/#/experiments?workflowType=machine_learning"


def tag_views(tracking_uri: str) -> dict[str, list[str]]:
    """Tag every experiment holding mosd runs with the shared view; its id -> the view's columns."""
    from mlflow.tracking import MlflowClient

    client = MlflowClient(tracking_uri=tracking_uri)
    views: dict[str, list[str]] = {}
    for experiment in client.search_experiments():
        runs = client.search_runs([experiment.experiment_id], "tags.`mosd.role` = 'job'", max_results=500)
        if not runs:
            continue
        tuned = [n for run in runs for n in run.data.tags.get("mosd.params", "").split(",") if n]
        views[experiment.experiment_id] = view_columns(tuned)
        state = json.dumps({"selectedColumns": views[experiment.experiment_id]})
        if experiment.tags.get(SHARED_VIEW_TAG) != state:
            client.set_experiment_tag(experiment.experiment_id, SHARED_VIEW_TAG, state)
    return views


def page_script(views: dict[str, list[str]]) -> str:
    """The script added to the UI's page: defaults for a browser that has not chosen (module docstring).

    The per-experiment state is MLflow 3.17's runs-page state as it stores it, with
    mosd's columns; a key the browser already holds is left alone.
    """
    defaults = {"searchFilter": "", "orderByKey": "attributes.start_time", "orderByAsc": False, "startTime": "ALL",
                "lifecycleFilter": "Active", "datasetsFilter": [], "modelVersionFilter": "All Runs",
                "columnOrder": [], "columnWidths": {}, "runsExpanded": {}, "runsPinned": [], "runsHidden": [],
                "runsVisibilityMap": {}, "runsHiddenMode": "FIRST_10_RUNS", "viewMaximized": False,
                "runListHidden": False, "isAccordionReordered": False, "useGroupedValuesInCharts": True,
                "hideEmptyCharts": True, "groupBy": None, "groupsExpanded": {}, "autoRefreshEnabled": True,
                "globalLineChartConfig": {"xAxisKey": "step", "lineSmoothness": 0, "selectedXAxisMetricKey": ""}}
    states = {f'MLflowLocalStorage-1.1-ExperimentPage-["{eid}"]-ReactComponentState':
              json.dumps({**defaults, "selectedColumns": columns}) for eid, columns in views.items()}
    states[WORKFLOW_KEY] = json.dumps("machine_learning")
    return ("<script>(function(){try{var s=window.localStorage,d=" + json.dumps(states) +
            ";for(var k in d){if(s.getItem(k)===null){s.setItem(k,d[k]);}}}catch(e){}})();</script>")


def _wrapped_app():
    """MLflow's FastAPI app with the page script added to its HTML page (:data:`app`)."""
    from mlflow.server.fastapi_app import app as mlflow_app
    from starlette.responses import Response

    views = json.loads(os.environ.get(VIEWS_ENV) or "{}")
    script = page_script(views).encode()

    @mlflow_app.middleware("http")
    async def add_defaults(request, call_next):
        response = await call_next(request)
        if request.method != "GET" or not response.headers.get("content-type", "").startswith("text/html"):
            return response
        body = b"".join([chunk async for chunk in response.body_iterator])
        if b"<head>" in body:
            body = body.replace(b"<head>", b"<head>" + script, 1)
        headers = {k: v for k, v in response.headers.items() if k.lower() not in ("content-length", "content-encoding")}
        return Response(body, status_code=response.status_code, headers=headers, media_type="text/html")

    return mlflow_app


def create_app():
    """MLflow's FastAPI app with the page script (:func:`_wrapped_app`): the factory uvicorn calls (``--factory``)."""
    return _wrapped_app()


def __getattr__(name: str):
    # ``mosd.app.ui:app``: the wrapped app, built on first access so that importing this module is cheap
    if name == "app":
        globals()["app"] = _wrapped_app()
        return globals()["app"]
    raise AttributeError(name)


#: the name of mosd's app among MLflow's app plugins (the ``mlflow.app`` entry point group), and its factory
APP_NAME = "mosd-ui"
APP_FACTORY = "mosd.app.ui:create_app"


def _entry_point_folder() -> str | None:
    """A folder to put on ``sys.path`` that declares :data:`APP_NAME` in the ``mlflow.app`` entry points (a
    distribution's metadata, the packaging standard MLflow reads plugins from); None when an installed
    distribution declares it already.

    One folder per user in the temporary directory, its two small files rewritten whole (a temporary file
    renamed into place) each time: servers started together read one or the other, both the same, and a server
    killed never leaves a folder behind.
    """
    import importlib.metadata
    import tempfile
    from pathlib import Path

    if any(ep.name == APP_NAME for ep in importlib.metadata.entry_points(group="mlflow.app")):
        return None
    uid = os.getuid() if hasattr(os, "getuid") else "user"
    folder = Path(tempfile.gettempdir()) / f"mosd-ui-app-{uid}"
    info = folder / "mosd_ui_app-1.0.dist-info"
    info.mkdir(parents=True, exist_ok=True)
    for name, text in (("METADATA", "Metadata-Version: 2.1\nName: mosd-ui-app\nVersion: 1.0\n"),
                       ("entry_points.txt", f"[mlflow.app]\n{APP_NAME} = {APP_FACTORY}\n")):
        part = info / f".{name}.{os.getpid()}"
        part.write_text(text)
        os.replace(part, info / name)
    return str(folder)


def serve(argv: Sequence[str]) -> int:
    """``python -m mosd.app.ui serve ARGS``: ``mlflow server --app-name mosd-ui ARGS``, serving :func:`create_app`.

    MLflow finds the app among its ``mlflow.app`` entry points; where mosd's installed metadata does not declare
    it, a folder declaring it is put on ``sys.path`` for this process (:func:`_entry_point_folder`). The server
    process is MLflow's own; uvicorn calls the factory in its worker.
    """
    folder = _entry_point_folder()
    if folder is not None:
        sys.path.insert(0, folder)
    from mlflow.cli import cli

    return cli.main(["server", "--app-name", APP_NAME, *argv], prog_name="mlflow", standalone_mode=True)


def server_command(uri: str, host: str, port: int) -> list[str]:
    """The README's server (one worker; MLflow's job runner off by the environment) serving :data:`app`."""
    return [sys.executable, "-m", "mosd.app.ui", "serve", "--workers", "1", "--host", host, "--port", str(port),
            "--backend-store-uri", uri]


def main(argv: Sequence[str] | None = None) -> int:
    """``mosd ui [--tracking-uri URI] [--host H] [--port P] [--print-only]``."""
    from .settings import default_tracking_uri, redacted

    default_uri = default_tracking_uri()
    parser = argparse.ArgumentParser(prog="mosd ui", description="The MLflow UI on the runs table of mosd's runs "
                                     "(FAR, MDR and the tuned parameters as columns).")
    parser.add_argument("--tracking-uri", default=default_uri, help=f"the store (default: {default_uri})")
    parser.add_argument("--host", default="127.0.0.1", help="interface to serve on (default: loopback only)")
    parser.add_argument("--port", type=int, default=5000, help="port (default 5000)")
    parser.add_argument("--print-only", action="store_true", help="tag the views and print the addresses, no server")
    args = parser.parse_args(list(sys.argv[1:] if argv is None else argv))
    if args.tracking_uri.startswith("sqlite:///"):
        from .store import sqlite_path

        db = sqlite_path(args.tracking_uri)
        if db is None or not db.is_file():
            print(f"mosd ui: error: --tracking-uri={redacted(args.tracking_uri)!r}: no such database (run mosd "
                  f"first)", file=sys.stderr)
            return 2
    views = tag_views(args.tracking_uri)
    base = f"http://{args.host}:{args.port}"
    print(f"experiments  {list_address(base)}")
    for eid in views:
        print(f"runs table   {runs_address(base, eid)}")
    if args.print_only:
        return 0
    env = {**os.environ, VIEWS_ENV: json.dumps(views), "MLFLOW_SERVER_ENABLE_JOB_EXECUTION": "false"}
    print("mosd ui: serving (Ctrl-C or kill stops it)", flush=True)
    return run_server(server_command(args.tracking_uri, args.host, args.port), env)


#: the signals that stop ``mosd ui`` and, with it, the whole server (MLflow's CLI and the uvicorn it starts)
STOP_SIGNALS = ("SIGINT", "SIGTERM", "SIGHUP")
#: seconds the server has to end after the signal before its group is SIGKILLed
SERVER_GRACE_S = 10.0


def run_server(command: list[str], env: dict) -> int:
    """Run the server in a process group of its own and end that group when this process is told to stop.

    ``kill PID`` (SIGTERM) or a closed terminal (SIGHUP) used to end ``mosd ui`` alone: MLflow's server and its
    uvicorn process, children that never heard the signal, kept answering on the port until SIGKILLed. The
    signal is passed on to the server's group; the exit code is 128 + the signal's number.
    """
    import signal
    import subprocess
    import time

    child = subprocess.Popen(command, env=env, start_new_session=True)
    received: list[tuple[int, float]] = []

    def stop(signum, _frame):
        received.append((signum, time.monotonic()))
        try:
            os.killpg(child.pid, signal.SIGINT if signum == signal.SIGINT else signal.SIGTERM)
        except ProcessLookupError:  # already gone
            pass

    previous = {name: signal.signal(getattr(signal, name), stop) for name in STOP_SIGNALS if hasattr(signal, name)}
    try:
        while True:
            try:
                code = child.wait(timeout=0.5)
                break
            except subprocess.TimeoutExpired:
                if received and time.monotonic() - received[0][1] > SERVER_GRACE_S:  # it ignored the signal
                    os.killpg(child.pid, signal.SIGKILL)
    finally:
        for name, handler in previous.items():
            signal.signal(getattr(signal, name), handler)
    return 128 + received[0][0] if received else code


if __name__ == "__main__":
    if sys.argv[1:2] == ["serve"]:
        sys.exit(serve(sys.argv[2:]))
    sys.exit(main())
