"""What the served model adds to its pipeline's answer: strict JSON, HTTP 400s, no NumPy warnings.

A served model (``mlflow models serve``) and ``mosd monitor`` pass the state of the previous row as
``params`` (:mod:`mosd.app.detector_model`). Each stage declares its state once with its domain
(:class:`mosd.streaming.StateVar`): counts are integers in [0, 2**53], the EWMA of T² and SPE in
[0, 1e300] (sums of squares whose ratio to a limit stays finite), smoothed chart features, pending
residuals and filter states in [-1e150, 1e150] (their squares stay finite). A state no stream can reach
(``run_length = -5``, ``ewma_t2 = 1e308``) is refused before any scoring, with one line naming the
param, its value and its domain; :func:`predict` turns that into an HTTP 400 (:func:`bad_request`).

Strict JSON. A row that completes no subgroup, or a row with a missing value, has no statistic:
NaN in the model's DataFrame, which MLflow's scoring server would write as the bare token ``NaN``
(not JSON). :func:`strict_json` gives those cells as None, written ``null``.
"""
from __future__ import annotations

from typing import Mapping

from ..validation import ConfigError

def strict_json(frame):
    """``frame`` with every missing float cell as None (JSON ``null``), the other cells unchanged."""
    import numpy as np

    columns = {}
    for name, dtype in zip(frame.columns, frame.dtypes):
        if dtype.kind != "f":
            continue
        values = frame[name].to_numpy()
        finite = np.isfinite(values)
        if not finite.all():  # only these columns change (re-setting every column cost a served request ~1 ms)
            columns[name] = frame[name].astype(object).where(finite, None)
    return frame.assign(**columns) if columns else frame


def bad_request(exc: BaseException) -> BaseException:
    """An MLflow error with HTTP status 400 and mosd's one line, for a :class:`ConfigError` raised in predict."""
    if not isinstance(exc, ConfigError):
        return exc
    try:
        from mlflow.exceptions import MlflowException
        from mlflow.protos.databricks_pb2 import INVALID_PARAMETER_VALUE
    except ImportError:  # pragma: no cover - the wrapper exists only with MLflow
        return exc
    error = MlflowException(str(exc), error_code=INVALID_PARAMETER_VALUE)
    error.__cause__ = exc  # mosd monitor finds the ConfigError behind it
    return error


def predict(fitted, frame, params: Mapping | None):
    """The served model's answer: the rows scored (the pipeline checks the state against its declared
    domains), missing cells as JSON ``null``, no NumPy overflow warnings.

    A :class:`ConfigError` (a state out of its domain, a missing or an extra column) becomes MLflow's
    INVALID_PARAMETER_VALUE: the scoring server answers 400 with the one line.
    """
    import numpy as np

    try:
        # a row whose statistic overflows (an input near 1e308) is not scored (non-finite: no alarm, the EWMA
        # holds its in-control mean): NumPy's overflow warnings on the way say nothing a client can act on
        with np.errstate(over="ignore", invalid="ignore"):
            return strict_json(fitted.predict_frame(frame, params))
    except ConfigError as exc:
        raise bad_request(exc) from exc
