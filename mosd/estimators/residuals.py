"""Residual generators built on the cubature filters (paper 000, eq. 7; docs/DECISIONS.md §1).

:class:`InnovationResidual` is the paper's eq. 7 innovation with every sensor in the
update. :class:`DedicatedObserverResidual` (the default) updates the filter with the
*other* sensors only and compares the monitored sensor with its prediction, so a
sensor bias is not absorbed by the state estimate (see :mod:`mosd.estimators.cubature`).
"""
from __future__ import annotations

import numpy as np

from ..model import StateSpaceModel
from ..types import Residuals, Trace
from ..validation import ConfigError, Param, check_int
from .base import Estimator
from .cubature import CESCKF, FilterResult, _CubatureFilterBase


def _check_filter(key: str, flt, estimator):
    if flt is None:
        return CESCKF()
    if not isinstance(flt, _CubatureFilterBase):
        raise ConfigError(f"{key}={flt!r} is not a filter; allowed: CESCKF, CubatureKalmanFilter")
    return flt


def _check_monitored(key: str, monitored, estimator) -> tuple[int, ...]:
    if isinstance(monitored, (int, np.integer)):
        monitored = (monitored,)
    try:
        monitored = tuple(monitored)
    except TypeError:
        raise ConfigError(f"{key}={monitored!r} is not a list of channels; allowed: e.g. [0]") from None
    if not monitored:
        raise ConfigError(f"{key}=() is empty; allowed: at least one output channel")
    channels = tuple(check_int(key, m, 0) for m in monitored)
    if len(set(channels)) != len(channels):
        raise ConfigError(f"{key}={monitored!r} repeats a channel; allowed: distinct channels")
    return channels


_FILTER = Param(_check_filter, "The filter (None: CESCKF()).", kind="CESCKF or CubatureKalmanFilter")


def _check_trace(trace: Trace, model: StateSpaceModel) -> None:
    if trace.y.shape[-1] != model.n_y:
        raise ValueError(f"trace has {trace.y.shape[-1]} output channels but the model {model.n_y}")


class InnovationResidual(Estimator):
    """The paper's residual: the innovation r_k = y_k − ŷ_{k|k−1} of a filter using every sensor (eq. 7)."""

    params = {"filter": _FILTER}

    def __init__(self, filter=None):  # noqa: A002 - the config key is "filter"
        self._assign(locals())

    def estimate(self, trace: Trace, model: StateSpaceModel) -> Residuals:
        """Filter the trace and return the innovations of all channels with their predicted covariance."""
        _check_trace(trace, model)
        res = self.filter.filter(model, trace.y, trace.u)
        return Residuals.of(
            trace,
            r=res.innovation,
            channels=model.output_names,
            cov=res.innovation_cov,
            extra={"x_pred": res.x_pred, "x_filt": res.x_filt, "y_pred": res.y_pred, "generator": "innovation"},
        )


class DedicatedObserverResidual(Estimator):
    """Residual of a filter that never sees the monitored sensors (docs/DECISIONS.md §1).

    The filter updates with the other channels only (``model.restrict_outputs``);
    the monitored channels' residual is y_m − ŷ_{m,k|k−1}, where ŷ_m is the
    cubature mean of h_m over the predicted density N(x̂_{k|k−1}, P_{k|k−1}) —
    the eq. 6 prediction, equal to h_m(x̂_{k|k−1}) for a linear h_m as on the
    mould oscillator. Because y_m is never used in an update, a sensor bias is
    not absorbed by the state estimate.

    Notes
    -----
    The output has all n_y channels in the model's order: monitored channels
    carry this residual, the others the filter's innovations. ``cov`` is the
    joint predicted covariance of the whole output vector at N(x̂_{k|k−1},
    P_{k|k−1}) plus R (eq. 15 over all channels); both kinds of residual are
    y − ŷ_{k|k−1} at that one prediction, so cov is exact for the cross terms too.
    """

    params = {"filter": _FILTER,
              "monitored": Param(_check_monitored, "Output channels left out of the update (paper 000: the x_p "
                                 "sensor, 0).", kind="sequence of int >= 0")}

    def __init__(self, filter=None, monitored=(0,)):  # noqa: A002
        self._assign(locals())

    def estimate(self, trace: Trace, model: StateSpaceModel) -> Residuals:
        """Filter with the unmonitored sensors and return the residuals of all channels."""
        _check_trace(trace, model)
        n_y = model.n_y
        if max(self.monitored) >= n_y or len(self.monitored) >= n_y:
            raise ConfigError(
                f"estimator.monitored={self.monitored} is not allowed for {n_y} outputs; "
                f"allowed: distinct channels in 0..{n_y - 1}, leaving at least one for the update"
            )
        others = [c for c in range(n_y) if c not in self.monitored]
        res = self.filter.filter(model.restrict_outputs(others), trace.y[..., others], trace.u)
        y_pred, cov = _output_prediction(self.filter, model, res)
        r = np.empty_like(trace.y)
        mon = list(self.monitored)
        r[..., mon] = trace.y[..., mon] - y_pred[..., mon]
        r[..., others] = res.innovation
        return Residuals.of(
            trace,
            r=r,
            channels=model.output_names,
            cov=cov,
            extra={
                "x_pred": res.x_pred,
                "x_filt": res.x_filt,
                "y_pred": y_pred,
                "monitored": self.monitored,
                "generator": "dedicated_observer",
            },
        )


def _output_prediction(flt, model: StateSpaceModel, res: FilterResult, time_chunk: int = 1000):
    """ŷ_{k|k−1} and its covariance for every output of ``model`` from stored predictions (eqs. 6, 8, 15).

    Vectorised over replications and a chunk of samples at once; the stored
    S_{k|k−1} give the filter's own points (up to rounding). Compiled
    (:func:`mosd.kernels.cubature.output_prediction`, ~1e-15 relative to this)
    when the model has a compiled form (``model.pointwise``).
    """
    eps, w = flt._rule.points(model.n_x)
    if model.pointwise is not None:  # h is a choice of states: the compiled form applies
        from .. import kernels

        if kernels.enabled():
            from ..kernels.cubature import output_prediction

            return output_prediction(res.x_pred, res.sqrt_cov_pred, eps, w, model.pointwise.outputs, model.R)
    sqrt_w = np.sqrt(w)[:, None]
    n_reps, n_steps, _ = res.x_pred.shape
    n_y = model.n_y
    y_pred = np.empty((n_reps, n_steps, n_y))
    cov = np.empty((n_reps, n_steps, n_y, n_y))
    R = np.asarray(model.R, float)
    for start in range(0, n_steps, time_chunk):
        sl = slice(start, min(start + time_chunk, n_steps))
        pts = res.x_pred[:, sl, None, :] + np.swapaxes(res.sqrt_cov_pred[:, sl] @ eps.T, -1, -2)
        out = model.h(pts)
        yp = w @ out
        centred = sqrt_w * (out - yp[..., None, :])
        y_pred[:, sl] = yp
        cov[:, sl] = np.swapaxes(centred, -1, -2) @ centred + R
    return y_pred, cov
