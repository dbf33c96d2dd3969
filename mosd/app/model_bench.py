"""Speed of the deployed model: its scoring beside BibMon's, and ``mlflow models serve``'s latency (``python -m mosd.bench``).

The benchmarks of :mod:`mosd.app.detector_model`'s generic model on the Tennessee Eastman rows.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .detector_model import log_model


def _pca_pipeline(calibration, tags):
    """The literature's design (9 components, α = 0.01) on ``calibration`` as a deployable pipeline."""
    from ..detectors.pca import PCADetector
    from ..monitors.outputs import OutputMonitor
    from ..streaming import OnlinePipeline

    detector = PCADetector(n_components=9, alpha=0.01, fit_runs=1)
    return OnlinePipeline([OutputMonitor(burn_in=0).online(tuple(tags)), detector.online(calibration, tags)])


def monitor_benchmark(quick: bool = False) -> dict:
    """Rows per second of the logged model's scoring beside BibMon's ``PCA.predict`` (``python -m mosd.bench --only tep``).

    The literature's design (9 components, α = 0.01) fitted on the calibration rows; the rows of the
    TE test files as one DataFrame through :meth:`~mosd.streaming.OnlinePipeline.predict_frame` (what the pyfunc model's
    ``predict`` runs, in-process): with the top contributors (``monitor_rows_per_s``) and without
    (``monitor_no_top_rows_per_s``). With bibmon installed, its ``PCA.predict`` on the same DataFrame,
    fitted on the same rows with 9 components (standardised with the same mean and ddof = 1
    deviation): SPE and its contributions |x (x − x̂)| of every variable, the SPE limit's alarm; no
    T², no EWMA, no ranking. ``t2_spe_floor_rows_per_s``: the least any T²/SPE scoring does (standardise,
    one projection, two sums per row on a float array, no DataFrame). All are timed in turns, best of
    ``repeats`` each, so that load from other processes hits all of them;
    ``bibmon_spe_max_relative_difference`` compares the SPE.
    """
    import os
    import time
    import warnings

    import pandas as pd

    from ..data.tep import TennesseeEastman
    from ..detectors.pca import _one_blas_thread

    te = TennesseeEastman(variables="literature")
    calibration, test = te.trace("calibration").y, te.trace("test").y
    frame = pd.DataFrame(test.reshape(-1, test.shape[-1]), columns=list(te.output_names))
    pipeline = _pca_pipeline(calibration, te.output_names)
    pca = pipeline.stages[-1]
    repeats = 5 if quick else 25
    X = frame.to_numpy()
    a, fitted = pca.design["n_components"], pca.fitted   # the generic stage's design and PCA model
    P = np.ascontiguousarray(np.asarray(fitted["loadings"]).T)
    inverse = 1.0 / np.asarray(fitted["eigenvalues"])[:a, None]

    def floor():
        # the least any T² and SPE scoring does: standardise, one projection, two sums per row
        # (one BLAS thread, the whole array at once, no DataFrame in or out, no EWMA, no alarm)
        with _one_blas_thread():
            Z = (X - fitted["mean"]) / fitted["scale"]
            squares = P @ Z.T
            squares *= squares
            return np.sum(squares[:a] * inverse, axis=0), np.sum(squares[a:], axis=0)

    def no_top():
        columns = {"point": np.ones(len(X), np.int64), **{f"z_{j + 1}": X[:, j] for j in range(X.shape[1])}}
        return pca.update(columns, pca.initial_state(), top=False)

    contenders = {"monitor": lambda: pipeline.predict_frame(frame), "monitor_no_top": no_top, "floor": floor}
    out = {"rows": len(frame), "load_average_1min_before": os.getloadavg()[0]}
    model = None
    try:
        import bibmon
    except ImportError:
        bibmon = None
    if bibmon is not None:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            model = bibmon.PCA(ncomp=9)
            model.fit(pd.DataFrame(calibration[0], columns=list(te.output_names)))

        def bibmon_predict():
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                model.predict(frame)
        contenders["bibmon"] = bibmon_predict
    best = {name: float("inf") for name in contenders}
    names = list(contenders)
    for i in range(repeats):
        # in turns, a burst of load hits every contender alike; the order rotates, so that none always
        # follows bibmon, whose two OpenBLAS threads go on spinning for a while after its products
        for name in names[i % len(names):] + names[:i % len(names)]:
            t0 = time.perf_counter()
            contenders[name]()
            best[name] = min(best[name], time.perf_counter() - t0)
    out["load_average_1min_after"] = os.getloadavg()[0]
    out["monitor_rows_per_s"] = len(frame) / best["monitor"]
    out["monitor_no_top_rows_per_s"] = len(frame) / best["monitor_no_top"]
    out["t2_spe_floor_rows_per_s"] = len(frame) / best["floor"]
    if model is not None:
        out["bibmon_rows_per_s"] = len(frame) / best["bibmon"]
        ours = no_top()["spe"]
        theirs = np.asarray(model.SPE_test, float)
        out["bibmon_spe_max_relative_difference"] = float(np.max(np.abs(ours - theirs) / np.abs(theirs)))
    return out


def serve_benchmark(quick: bool = False, rows_per_request: int = 100) -> dict:
    """Latency of ``mlflow models serve`` per request of ``rows_per_request`` rows (``python -m mosd.bench --only serve``).

    Logs a model (the TE literature design when the TE files are installed, else the same design on a
    generated 33-tag plant) to a throw-away sqlite store, starts ``mlflow models serve -m MODEL_URI --host
    127.0.0.1 --env-manager local`` on a free loopback port, posts ``n_requests`` requests of consecutive
    rows in ``dataframe_split`` JSON with the state carried in ``params`` (one unmeasured request first),
    and reports the median and the 90th percentile of the round trip in ms. The server's process group
    is stopped and the store removed whatever happens.
    """
    import os
    import tempfile
    import time

    import pandas as pd

    from .serving import invocation, predictions, start_model_server, stop_process_group

    try:
        from ..data.tep import TennesseeEastman, bibmon_directory

        te = TennesseeEastman(variables="literature") if bibmon_directory() is not None else None
    except ImportError:
        te = None
    if te is not None:
        calibration, test, tags = te.trace("calibration").y, te.trace("test").y, list(te.output_names)
        source = "TE test rows"
    else:
        rng = np.random.default_rng(0)
        mixing = rng.normal(size=(5, 33))
        calibration = rng.normal(size=(2, 500, 5)) @ mixing + 0.3 * rng.normal(size=(2, 500, 33))
        test = rng.normal(size=(1, 6000, 5)) @ mixing + 0.3 * rng.normal(size=(1, 6000, 33))
        tags, source = [f"tag{i}" for i in range(33)], "generated rows"
    pipeline = _pca_pipeline(calibration, tags)
    frame = pd.DataFrame(test.reshape(-1, len(tags)), columns=tags)
    n_requests = 20 if quick else 60
    import logging
    import warnings

    os.environ.setdefault("MLFLOW_ENABLE_ARTIFACTS_PROGRESS_BAR", "false")
    with tempfile.TemporaryDirectory(prefix="mosd-serve-bench-") as tmp, warnings.catch_warnings():
        warnings.simplefilter("ignore")  # MLflow's hints on logging (type hints, integer columns)
        import mlflow

        for name in ("mlflow", "mlflow.store.db.utils", "mlflow.pyfunc", "alembic"):
            logging.getLogger(name).setLevel(logging.ERROR)

        tracking = f"sqlite:///{tmp}/mlflow.db"
        mlflow.set_tracking_uri(tracking)
        client = mlflow.MlflowClient(tracking)
        experiment = client.create_experiment("serve-bench", artifact_location=Path(tmp, "artifacts").as_uri())
        run_id = client.create_run(experiment).info.run_id
        uri = log_model(str(pipeline.save(Path(tmp) / "model")), tracking, run_id)
        client.set_terminated(run_id)
        t0 = time.monotonic()
        server, port = start_model_server(uri, tracking)
        try:
            started = time.monotonic() - t0
            state, times = None, []
            for i in range(n_requests + 1):
                start = (i * rows_per_request) % (len(frame) - rows_per_request)
                request = invocation(port, tags, frame.iloc[start:start + rows_per_request].to_numpy().tolist(), state)
                t1 = time.perf_counter()
                answer = predictions(request)
                if i:  # the first request loads what the server defers: not measured
                    times.append(time.perf_counter() - t1)
                state = {k: answer[-1][k] for k in pipeline.state_names}
        finally:
            stop_process_group(server)
    return {"serve_latency_ms": float(np.median(times)) * 1e3, "serve_latency_p90_ms": float(np.percentile(times, 90)) * 1e3,
            "serve_requests": n_requests, "serve_rows_per_request": rows_per_request, "serve_start_s": started,
            "serve_source": source, "load_average_1min": os.getloadavg()[0]}
