"""The state a logged model carries from row to row: its declared domains, the check, and strict-JSON output.

A served model (``mlflow models serve``) and ``mosd monitor`` pass the state of the previous
row as ``params`` (:mod:`mosd.app.detector_model`, :mod:`mosd.app.chart_model`). A state that
no stream can reach (a negative count, a NaN, an EWMA of 1e308) would otherwise give a decision
computed from it: ``run_length = -5`` delays every alarm by five points, ``ewma_t2 = 1e308``
makes the statistic 1e306 times its limit. :func:`checked_state` refuses such a state before any
scoring, with one line naming the param, its value and its domain; the model's wrapper turns
that into an HTTP 400 (:func:`bad_request`).

The domains (:data:`DOMAINS`, matched by name or by the name's prefix):

* ``run_length`` (consecutive points above the limit) and ``samples_seen`` (rows since the
  stream's start): integers in ``[0, 2**53]`` (a float carries every integer up to 2**53);
* ``ewma_t2``, ``ewma_spe`` (the EWMA of T² and SPE, both sums of squares): finite, in
  ``[0, 1e300]``; the model's own rows stay within it unless an input is ~1e150 standard
  deviations out (such a row's T² overflows and is not scored), and the ratio to a limit stays finite;
* ``smooth_*`` (the smoothed U_k and V_k of a chart) and ``pending_*`` (residuals of the
  unfinished subgroup): finite, in ``[-1e150, 1e150]``, so that the square the SS combination
  (eq. 21) and the subgroup variance take stays finite.

Strict JSON. A row that completes no subgroup, or a row with a missing value, has no statistic:
NaN in the model's DataFrame, which MLflow's scoring server would write as the bare token ``NaN``
(not JSON). :func:`strict_json` gives those cells as None, written ``null``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping

from ..validation import ConfigError

#: the largest integer a float param carries exactly
MAX_COUNT = 2**53


@dataclass(frozen=True)
class Domain:
    """The allowed values of one state param."""

    integer: bool
    low: float
    high: float
    why: str

    def describe(self) -> str:
        kind = "integers" if self.integer else "finite numbers"
        high = "2**53" if self.high == MAX_COUNT else f"{self.high:g}"
        return f"{kind} in [{self.low:g}, {high}] ({self.why})"

    def problem(self, value) -> str | None:
        """None when ``value`` is in the domain, else what is wrong with it."""
        if isinstance(value, bool):
            return "is not a number"
        if not isinstance(value, (int, float)):
            try:
                value = float(value)
            except (TypeError, ValueError):
                return "is not a number"
        if not math.isfinite(value):
            return "is not finite"
        if self.integer and not float(value).is_integer():
            return "is not an integer"
        if not self.low <= value <= self.high:
            return "is out of range"
        return None


#: state name (or prefix ending in ``_``) → domain (module docstring)
DOMAINS: dict[str, Domain] = {
    "run_length": Domain(True, 0, MAX_COUNT, "consecutive points above the limit"),
    "samples_seen": Domain(True, 0, MAX_COUNT, "rows since the stream's start"),
    "ewma_t2": Domain(False, 0.0, 1e300, "an EWMA of T², a sum of squares"),
    "ewma_spe": Domain(False, 0.0, 1e300, "an EWMA of SPE, a sum of squares"),
    "smooth_": Domain(False, -1e150, 1e150, "a smoothed chart feature; its square stays finite"),
    "pending_": Domain(False, -1e150, 1e150, "a residual of the unfinished subgroup; its square stays finite"),
}


def domain_of(name: str) -> Domain:
    """The declared domain of state ``name`` (a KeyError names a state without one: declare it here)."""
    if name in DOMAINS:
        return DOMAINS[name]
    for prefix, domain in DOMAINS.items():
        if prefix.endswith("_") and name.startswith(prefix):
            return domain
    raise KeyError(f"state {name!r} has no declared domain in mosd.app.model_state.DOMAINS")


def checked_state(fitted, state: Mapping | None) -> dict:
    """The fitted model's initial state updated with ``state``, each value checked against its domain.

    Parameters
    ----------
    fitted : FittedPCA or FittedChart
        Anything with ``initial_state()``.
    state : mapping or None
        The params given to ``predict`` (the previous row's state); None values and names that are
        not states of the model are left out (MLflow passes every declared param).

    Raises
    ------
    ConfigError
        One line: the param, its value and its domain. An integer state given as a float
        (2.0, as JSON may carry it) is taken as the integer.
    """
    start = fitted.initial_state()
    out = dict(start)
    for name, value in (state or {}).items():
        if name not in start or value is None:
            continue
        domain = domain_of(name)
        problem = domain.problem(value)
        if problem is not None:
            raise ConfigError(f"param {name}={value!r} {problem}; allowed: {domain.describe()}")
        out[name] = int(float(value)) if domain.integer else float(value)
    return out


def strict_json(frame):
    """``frame`` with every missing float cell as None (JSON ``null``), the other cells unchanged."""
    import numpy as np

    columns = {}
    for name in frame.columns:
        column = frame[name]
        if column.dtype.kind == "f" and not np.isfinite(column.to_numpy()).all():
            column = column.astype(object).where(np.isfinite(column.to_numpy()), None)
        columns[name] = column
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
    """The served model's answer: the rows scored (the model's ``score`` checks the state with
    :func:`checked_state`), missing cells as JSON ``null``, no NumPy overflow warnings.

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
