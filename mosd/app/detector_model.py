"""The one MLflow model of mosd: any fitted online pipeline as a pyfunc model (save, log, load, predict).

A finished run whose estimator → monitor → detector pipeline has a causal form
(:mod:`mosd.streaming`; :mod:`mosd.app.deploy` builds it) leaves it as the model ``detector`` of the run:
one ``pipeline.npz`` (each stage's fitted arrays and scalars, no pickles) behind one generic
``PythonModel``. ``predict(rows, params=state)`` scores the rows in order; the state to start from
comes as params named after the stages' state variables (default: a stream's start), each checked
against its declared domain (a value outside answers a one-line error naming the param, never a
decision computed from impossible state). Every output row carries the state after it, so a stream
scored row by row, each call given the previous row's state, equals the same rows scored in one call.

MLflow is imported only by the functions that log or wrap the model; the science core knows nothing of it.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..streaming import OnlinePipeline

#: the artifact name of the model in the run (``runs:/RUN_ID/detector``)
MODEL_NAME = "detector"
#: the file a pipeline is saved in
STATE_FILE = OnlinePipeline.FILE
#: model files of mosd before the one generic pipeline (still loaded: nothing a user logged is lost)
LEGACY_FILES = ("chart_detector.npz", "pca_detector.npz")


def predict(pipeline: OnlinePipeline, frame, state=None):
    """The pipeline's output for the rows of ``frame`` from ``state`` (:func:`mosd.app.model_state.predict`:
    strict JSON, a bad input or state an HTTP 400 with its one line)."""
    from .model_state import predict as checked

    return checked(pipeline, frame, state)


_WRAPPER: dict = {}


def _python_model_class():
    """The pyfunc wrapper class (defined on first use: MLflow is imported only here; once per process)."""
    import warnings

    if "class" in _WRAPPER:
        return _WRAPPER["class"]
    import mlflow.pyfunc

    with warnings.catch_warnings():
        # MLflow's advice to add type hints to predict, shown through its own "once" filter: the
        # signature is given explicitly; catch_warnings restores showwarning afterwards
        warnings.showwarning = lambda *args, **kwargs: None

        class MosdDetector(mlflow.pyfunc.PythonModel):
            """mosd's fitted detector; ``predict(rows, params=the state of the previous row)`` (state_names)."""

            def load_context(self, context):
                self.fitted = load_fitted(context.artifacts["state"])

            def predict(self, context, model_input, params=None):
                import pandas as pd

                frame = model_input if isinstance(model_input, pd.DataFrame) else pd.DataFrame(model_input)
                names = state_names(self.fitted)
                state = {k: v for k, v in (params or {}).items() if k in names}
                return predict(self.fitted, frame, state)  # state domains, strict JSON, 400s

    _WRAPPER["class"] = MosdDetector
    return MosdDetector


def warm_up() -> None:
    """Import now what :func:`log_model` will need (~1.5 s), in a process that waits for the run to end.

    The tracking side process (:mod:`mosd.app.channel`) calls it once it has created the run, so that
    logging the model at the end of the run does not start with these imports: MLflow's pyfunc and
    signature modules, the wrapper class, the scan of the installed distributions that MLflow's check of
    the pip requirements starts with, GitPython (MLflow looks for a git checkout when it creates the logged
    model) and mosd's stage modules a saved pipeline is built from. Not SciPy's signal processing: the
    two-row example is scored on the NumPy path (:func:`_example_path`), which needs none of it.
    """
    import mlflow.models.signature  # noqa: F401
    import mlflow.pyfunc  # noqa: F401
    from mlflow.utils.requirements_utils import warn_dependency_requirement_mismatches

    from .. import detectors, estimators, faults, monitors, noise, plants  # noqa: F401
    from . import model_state  # noqa: F401

    _python_model_class()
    # what log_model's check of its pip requirements calls (public name): its first call scans the installed
    # distributions (~1 s), kept for the process; numpy is installed, so it warns of nothing
    warn_dependency_requirement_mismatches(["numpy"])
    try:
        import git  # noqa: F401
    except ImportError:  # MLflow logs without it
        pass


def load_fitted(path) -> OnlinePipeline:
    """The fitted pipeline saved at ``path`` (a ``pipeline.npz``, or a model file of mosd before it: see :mod:`.legacy_models`)."""
    path = Path(path)
    if path.name in LEGACY_FILES:
        from .legacy_models import load_legacy

        return load_legacy(path)
    return OnlinePipeline.load(path)


def state_names(fitted) -> tuple[str, ...]:
    """The state a fitted pipeline carries from row to row (output columns and params of the same names)."""
    return tuple(fitted.state_names)


def signature(fitted, example):
    """Input columns by name (doubles), output columns, and the state params with their defaults."""
    from mlflow.models import infer_signature

    out = fitted.predict_frame(example)
    return infer_signature(example, out, params=fitted.initial_state())


def _example_path():
    """Where :func:`log_model` scores its two-row example: the NumPy path unless numba is loaded already.

    Logging scores the example twice (the signature's output columns, MLflow's check that the input example
    serves). In the tracking side process nothing else needs numba: its import and the load of the compiled
    filter from its cache cost ~1.3 s there, on the run's last wait, for two rows that the NumPy reference
    path scores in ~0.02 s with the same columns and dtypes (values within ~1e-13, :mod:`mosd.kernels`; the
    signature records only names and types). A stage whose one step is compiled code (a chart's
    :func:`mosd.kernels.ewma.chart_recursion`) still loads numba and its cached kernel. A process that has the
    kernels loaded (a sweep's jobs log in-process) keeps them: :func:`mosd.kernels.disabled` is a process-wide
    switch, for one caller only.
    """
    import contextlib
    import sys

    if "numba" in sys.modules:
        return contextlib.nullcontext()
    from .. import kernels

    return kernels.disabled()


def log_model(state_file: str, tracking_uri: str, run_id: str) -> str:
    """Log ``state_file`` as the pyfunc model ``detector`` of ``run_id``; returns its ``models:/`` URI."""
    with _example_path():
        return _log_model(state_file, tracking_uri, run_id)


def _log_model(state_file: str, tracking_uri: str, run_id: str) -> str:
    import mlflow

    import logging
    import os
    import warnings

    fitted = load_fitted(state_file)
    example = fitted.example()
    mlflow.set_tracking_uri(tracking_uri)
    nested = mlflow.active_run() is not None
    # MLflow's hints while logging (type hints, integer columns, cloudpickle, validating the example, a progress
    # bar) are for its own authors' models: in a run (a sweep logs in-process) they would be noise on stderr
    os.environ.setdefault("MLFLOW_ENABLE_ARTIFACTS_PROGRESS_BAR", "false")
    quiet = [logging.getLogger(name) for name in ("mlflow", "mlflow.pyfunc", "mlflow.models", "mlflow.types")]
    levels = [logger.level for logger in quiet]
    try:
        for logger in quiet:
            logger.setLevel(logging.ERROR)
        with warnings.catch_warnings(), mlflow.start_run(run_id=run_id, nested=nested):
            # not a filter: MLflow's helpers set their own ("once"); catch_warnings restores showwarning
            warnings.showwarning = lambda *args, **kwargs: None
            info = mlflow.pyfunc.log_model(name=MODEL_NAME, python_model=_python_model_class()(),
                                           artifacts={"state": str(state_file)}, signature=signature(fitted, example),
                                           input_example=example, pip_requirements=["mosd", "pandas", "numpy", "scipy"])
    finally:
        for logger, level in zip(quiet, levels):
            logger.setLevel(level)
    return info.model_uri


def logged_model_uri(tracking_uri: str, run_id: str) -> str | None:
    """The ``models:/`` URI of the model ``detector`` that ``run_id`` logged completely, or None.

    A model whose upload failed (a full artifact store) is left PENDING or FAILED by MLflow: not counted,
    so that ``mosd log`` logs it again (:func:`mosd.app.pending.log_pending`).
    """
    from mlflow import MlflowClient
    from mlflow.entities import LoggedModelStatus

    client = MlflowClient(tracking_uri)
    models = client.search_logged_models([client.get_run(run_id).info.experiment_id],
                                         filter_string=f"source_run_id = '{run_id}' AND name = '{MODEL_NAME}'")
    return next((m.model_uri for m in models if m.status == LoggedModelStatus.READY), None)


def save_pipeline(pipeline: OnlinePipeline, directory) -> Path:
    """Write ``pipeline`` under ``directory`` (atomically); returns the file :func:`log_model` takes."""
    return pipeline.save(directory)
