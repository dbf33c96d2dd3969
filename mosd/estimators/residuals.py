"""Residual generators built on the cubature filters (paper 000, eq. 7; docs/DECISIONS.md §1).

:class:`InnovationResidual` is the paper's eq. 7 innovation with every sensor in the
update. :class:`DedicatedObserverResidual` (the default) updates the filter with the
*other* sensors only and compares the monitored sensor with its prediction, so a
sensor bias is not absorbed by the state estimate (see :mod:`mosd.estimators.cubature`).

Causal form (issue 28, :mod:`mosd.streaming`; one step, issue 50: :mod:`mosd.estimators.step`): the served
:class:`~mosd.estimators.step.EstimatorStage` of either residual takes the plant's raw
columns, one row per sample: ``y_<output>`` for every sensor and ``u_<input>`` for every input of the
model's f. For the main command (the mould oscillator in closed loop) the deployed model's inputs are
``y_x_p``, ``y_theta``, ``y_n`` and ``u_i_q``, the speed controller's current command (the run's
``test_stream.parquet`` holds exactly those), and its outputs ``residual_x_p``, ``residual_theta``,
``residual_n`` feed the monitor. Row k's residual uses u_{k−1} (carried), its own u_k drives row k+1's
prediction, as in the batch filter. Each chunk runs the estimator's ``residuals``, the batch
estimate's own arithmetic, from the carried :class:`~mosd.estimators.cubature.FilterStart` (the compiled
CESCKF kernel resumes from it; :meth:`FilterStep.scan`): the stream's residuals are the batch's bit for bit with the kernel
(``tests/test_streaming_cesckf.py``).
"""
from __future__ import annotations

import numpy as np

from ..model import StateSpaceModel
from ..streaming import COUNT, FINITE, NoStreamingForm, StateVar, describe
from ..types import Residuals, Trace
from ..validation import ConfigError, Interval, Param, check_int
from .base import plant_columns
from .step import StepEstimator
from .cubature import CESCKF, FilterResult, FilterStart, _CubatureFilterBase, _lower_sqrt


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


class FilterStep(StepEstimator):
    """The step of a cubature-filter residual (:mod:`mosd.estimators.step`): the estimator's ``residuals`` (the
    batch estimate's arithmetic, the compiled CESCKF kernel where the batch uses it) from the carried
    :class:`~mosd.estimators.cubature.FilterStart`:

    * ``filter_step``: rows seen (0: the next row is the first sample, predicted by x̂_0, P_0);
    * ``x_filt_<i>``: x̂_{k|k} of state i (eq. 12);
    * ``sqrt_cov_filt_<i>_<j>`` (j ≤ i): the lower square root S_{k|k} of P_{k|k} (eq. 18), carried as the
      root, not as P, so that a chunked stream is bit for bit one call (diagonal ≥ 0);
    * ``u_last_<input>``: the row's input u_k, which drives the next row's prediction (eqs. 4–5).

    Before the first row the state holds the prior (x̂_0, chol(P_0), u = 0), which ``filter_step = 0``
    ignores. A missing measurement (NaN) is left out of the update as in the batch; an input must be a
    finite number (the state would become NaN).
    """

    def residuals(self, model: StateSpaceModel, y: np.ndarray, u, start: FilterStart | None = None):
        raise NotImplementedError

    def step_params(self, model: StateSpaceModel, trace: Trace | None = None) -> dict[str, np.ndarray]:
        """x̂_0 and the lower root of P_0: the state before the first row."""
        return {"x0": np.asarray(model.x0, float), "sqrt_p0": _lower_sqrt(np.asarray(model.P0, float))}

    def step_state(self, params: dict, reads: tuple = ()) -> dict:
        x0, root = np.asarray(params["x0"], float), np.asarray(params["sqrt_p0"], float)
        out = {"filter_step": (StateVar("Rows the filter has seen (0: start from x̂_0, P_0).", COUNT), 0)}
        out.update({f"x_filt_{i}": (StateVar(f"x̂_k|k of state {i} (eq. 12).", FINITE), float(v))
                    for i, v in enumerate(x0)})
        for i, j, name in _root_names(len(x0)):
            out[name] = (StateVar(f"Entry ({i}, {j}) of the lower root S_k|k of P_k|k (eq. 18).",
                                  _ROOT_DIAGONAL if i == j else FINITE), float(root[i, j]))
        out.update({f"u_last_{n[2:]}": (StateVar(f"The last row's input {n[2:]} (drives the next prediction).", FINITE),
                                        0.0) for n in reads if n.startswith("u_")})
        return out

    def scan(self, model, params: dict, state: dict, columns: dict, trajectory: bool = False) -> dict:
        """The residual of every output (:meth:`StepEstimator.scan`): the columns are the outputs ``y_*`` then the
        inputs ``u_*``, in the model's order; out ``residual_<output>``."""
        names = list(columns)
        ys, us = names[:model.n_y], names[model.n_y:]
        y = np.stack([np.asarray(columns[n], float) for n in ys], axis=-1)
        runs, rows, n_x = y.shape[0], y.shape[1], model.n_x
        u = np.stack([np.asarray(columns[n], float) for n in us], axis=-1) if us else np.zeros((runs, rows, 0))
        bad = ~np.isfinite(u)
        if bad.any():
            _, row, col = np.argwhere(bad)[0]
            raise ConfigError(f"input column {us[col]!r} row {row} is {float(u[0, row, col])!r}, not a finite number; "
                              f"allowed: numbers (the filter's prediction needs every input)")
        step = int(np.ravel(state["filter_step"])[0])
        if rows == 0:
            r, x_filt, root = np.empty((runs, 0, len(ys))), np.empty((runs, 0, n_x)), np.empty((runs, 0, n_x, n_x))
        elif step == 0:   # from the prior: every run in one call, as the batch estimate
            r, _, res, _ = self.residuals(model, y, u)
            x_filt, root = res.x_filt, res.sqrt_cov_filt
        else:
            parts = [self.residuals(model, y[k:k + 1], u[k:k + 1], _start(state, k, n_x, us)) for k in range(runs)]
            r = np.concatenate([p[0] for p in parts])
            x_filt = np.concatenate([p[2].x_filt for p in parts])
            root = np.concatenate([p[2].sqrt_cov_filt for p in parts])
        out = {f"residual_{n[2:]}": r[..., c] for c, n in enumerate(ys)}
        if trajectory:
            out["filter_step"] = np.broadcast_to(step + 1 + np.arange(rows), (runs, rows))
            out.update({f"x_filt_{i}": x_filt[..., i] for i in range(n_x)})
            out.update({name: root[..., i, j] for i, j, name in _root_names(n_x)})
            out.update({f"u_last_{n[2:]}": u[..., c] for c, n in enumerate(us)})
        return out

    def example_row(self, model, params: dict, reads: tuple) -> np.ndarray:
        """h(x̂_0) and zero inputs."""
        outputs = np.asarray(model.h(np.asarray(params["x0"], float)[None]))[0]
        return np.concatenate([outputs, np.zeros(len(reads) - len(outputs))])

    def raw_stream(self, trace: Trace, model: StateSpaceModel, input_names) -> dict[str, np.ndarray]:
        """The first replication's measurements and inputs as the causal form's columns."""
        return plant_columns(trace, model, input_names)


def _root_names(n_x: int) -> list[tuple[int, int, str]]:
    return [(i, j, f"sqrt_cov_filt_{i}_{j}") for i in range(n_x) for j in range(i + 1)]


def _start(state: dict, run: int, n_x: int, inputs) -> FilterStart:
    """The :class:`FilterStart` of run ``run`` of the carried ``state``."""
    def value(name):
        return float(np.broadcast_to(np.asarray(state[name], float), (run + 1,))[run])

    root = np.zeros((n_x, n_x))
    for i, j, name in _root_names(n_x):
        root[i, j] = value(name)
    return FilterStart(np.array([value(f"x_filt_{i}") for i in range(n_x)]), root,
                       np.array([value(f"u_last_{n[2:]}") for n in inputs]))


class InnovationResidual(FilterStep):
    """The paper's residual: the innovation r_k = y_k − ŷ_{k|k−1} of a filter using every sensor (eq. 7)."""

    params = {"filter": _FILTER}

    def __init__(self, filter=None):  # noqa: A002 - the config key is "filter"
        self._assign(locals())

    def estimate(self, trace: Trace, model: StateSpaceModel) -> Residuals:
        """Filter the trace and return the innovations of all channels with their predicted covariance."""
        _check_trace(trace, model)
        r, cov, res, y_pred = self.residuals(model, np.asarray(trace.y, float), trace.u)
        return Residuals.of(
            trace,
            r=r,
            channels=model.output_names,
            cov=cov,
            extra={"x_pred": res.x_pred, "x_filt": res.x_filt, "y_pred": y_pred, "generator": "innovation"},
        )

    def residuals(self, model: StateSpaceModel, y: np.ndarray, u, start: FilterStart | None = None):
        """(r, cov, the filter's result, ŷ) of ``y`` (R, N, n_y): the one arithmetic of :meth:`estimate` and of
        the causal form (:meth:`FilterStep.scan`, from the carried ``start``)."""
        res = (self.filter.filter(model, y, u) if start is None
               else self.filter.filter(model, y, u, start=start))
        return res.innovation, res.innovation_cov, res, res.y_pred

    def online(self, model: StateSpaceModel = None, source=None, trace: Trace | None = None):
        """The innovation as a stream of the plant's raw measurements and inputs: ``y_<output>`` and
        ``u_<input>`` in, ``residual_<output>`` out (:class:`FilterStep`'s stage)."""
        if source is None or trace is None or type(self).estimate is not InnovationResidual.estimate:
            return super().online(model)
        return _online_filter(self, model, source, trace)


class DedicatedObserverResidual(FilterStep):
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
        r, cov, res, y_pred = self.residuals(model, np.asarray(trace.y, float), trace.u)
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

    def residuals(self, model: StateSpaceModel, y: np.ndarray, u, start: FilterStart | None = None):
        """(r, cov, the filter's result, ŷ) of ``y`` (R, N, n_y): the one arithmetic of :meth:`estimate`
        and of the causal form (:meth:`FilterStep.scan`, which passes the carried ``start``)."""
        n_y = model.n_y
        if max(self.monitored) >= n_y or len(self.monitored) >= n_y:
            raise ConfigError(
                f"estimator.monitored={self.monitored} is not allowed for {n_y} outputs; "
                f"allowed: distinct channels in 0..{n_y - 1}, leaving at least one for the update"
            )
        others = [c for c in range(n_y) if c not in self.monitored]
        restricted = model.restrict_outputs(others)
        # the batch call is the filter's plain filter(model, y, u): a user's filter subclass need not know start
        res = (self.filter.filter(restricted, y[..., others], u) if start is None
               else self.filter.filter(restricted, y[..., others], u, start=start))
        y_pred, cov = _output_prediction(self.filter, model, res)
        r = np.empty_like(y)
        mon = list(self.monitored)
        r[..., mon] = y[..., mon] - y_pred[..., mon]
        r[..., others] = res.innovation
        return r, cov, res, y_pred

    # -- the causal form ----------------------------------------------------------------
    def online(self, model: StateSpaceModel = None, source=None, trace: Trace | None = None):
        """The residual generator as a stream of the plant's raw measurements and inputs.

        ``y_<output>`` for every output (the monitored ones too: they are compared, never fed back) and
        ``u_<input>`` for every input the model's f takes (the mould oscillator's controller current
        ``u_i_q``) per row; out: ``residual_<output>`` for every output. ``source`` describes the plant
        and noise the model is rebuilt from (:func:`mosd.streaming.describe`); ``trace`` the first test
        replication (its number of inputs when the plant names none).
        """
        if source is None or trace is None:
            return super().online(model)
        if type(self).estimate is not DedicatedObserverResidual.estimate:
            # a subclass that changes the estimate would deploy an arithmetic its run did not use
            return super().online(model)
        _check_monitored("estimator.monitored", self.monitored, self)
        return _online_filter(self, model, source, trace)


def _online_filter(estimator, model: StateSpaceModel, source, trace: Trace):
    """The causal form of a cubature-filter residual (:class:`FilterStep`), its plant, noise and filter rebuilt from
    their descriptions where it runs."""
    if type(estimator.filter).filter is not _CubatureFilterBase.filter:
        raise NoStreamingForm(f"the filter {type(estimator.filter).__name__} overrides filter(): its stream would not "
                              f"be the run's arithmetic")
    parts = {"plant": source["plant"], "noise": source["noise"], "filter": describe(estimator.filter)}
    foreign = [f"{key} {d['class']}" for key, d in parts.items() if not d["class"].startswith("mosd.")]
    if foreign:
        raise NoStreamingForm(f"the {foreign[0]} is not mosd's: a deployed model rebuilds mosd's classes only")
    inputs = tuple(source.get("input_names") or (f"u{i}" for i in range(np.shape(trace.u)[-1])))
    return estimator.stage(model, source, (*(f"y_{n}" for n in model.output_names), *(f"u_{n}" for n in inputs)),
                           tuple(f"residual_{n}" for n in model.output_names), trace)


#: a diagonal entry of a Cholesky factor: non-negative, finite
_ROOT_DIAGONAL = Interval(0.0, FINITE.high)


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
