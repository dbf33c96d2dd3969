"""Residual generators built on the cubature filters (paper 000, eq. 7; docs/DECISIONS.md §1).

:class:`InnovationResidual` is the paper's eq. 7 innovation with every sensor in the
update. :class:`DedicatedObserverResidual` (the default) updates the filter with the
*other* sensors only and compares the monitored sensor with its prediction, so a
sensor bias is not absorbed by the state estimate (see :mod:`mosd.estimators.cubature`).

Causal form (issue 28, :mod:`mosd.streaming`): :class:`OnlineDedicatedObserver` takes the plant's raw
columns, one row per sample: ``y_<output>`` for every sensor and ``u_<input>`` for every input of the
model's f. For the main command (the mould oscillator in closed loop) the deployed model's inputs are
``y_x_p``, ``y_theta``, ``y_n`` and ``u_i_q``, the speed controller's current command (the run's
``test_stream.parquet`` holds exactly those), and its outputs ``residual_x_p``, ``residual_theta``,
``residual_n`` feed the monitor. Row k's residual uses u_{k−1} (carried), its own u_k drives row k+1's
prediction, as in the batch filter. Each chunk runs :meth:`DedicatedObserverResidual.residuals`, the batch
estimate's own arithmetic, from the carried :class:`~mosd.estimators.cubature.FilterStart` (the compiled
CESCKF kernel resumes from it): the stream's residuals are the batch's bit for bit with the kernel
(``tests/test_streaming_cesckf.py``).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..model import StateSpaceModel
from ..streaming import COUNT, FINITE, NoStreamingForm, StateVar, build, describe
from ..types import Residuals, Trace
from ..validation import ConfigError, Interval, Param, check_int
from .base import Estimator, PlantStage, plant_columns
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


class InnovationResidual(Estimator):
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
        the causal form (:class:`OnlineDedicatedObserver` with no channel left out, from the carried ``start``)."""
        res = (self.filter.filter(model, y, u) if start is None
               else self.filter.filter(model, y, u, start=start))
        return res.innovation, res.innovation_cov, res, res.y_pred

    def online(self, model: StateSpaceModel = None, source=None, trace: Trace | None = None):
        """The innovation as a stream of the plant's raw measurements and inputs: ``y_<output>`` and
        ``u_<input>`` in, ``residual_<output>`` out (:class:`OnlineDedicatedObserver` with ``monitored=()``)."""
        if source is None or trace is None or type(self).estimate is not InnovationResidual.estimate:
            return super().online(model)
        return _online_filter(self, model, source, trace, monitored=())

    def raw_stream(self, trace: Trace, model: StateSpaceModel, input_names) -> dict[str, np.ndarray]:
        """The first replication's measurements and inputs as the causal form's columns."""
        return plant_columns(trace, model, input_names)


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
        and of the causal form (:class:`OnlineDedicatedObserver`, which passes the carried ``start``)."""
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
        return _online_filter(self, model, source, trace, monitored=tuple(int(m) for m in self.monitored))

    def raw_stream(self, trace: Trace, model: StateSpaceModel, input_names) -> dict[str, np.ndarray]:
        """The first replication's measurements and inputs as the causal form's columns."""
        return plant_columns(trace, model, input_names)


def _online_filter(estimator, model: StateSpaceModel, source, trace: Trace, monitored: tuple) -> "OnlineDedicatedObserver":
    """The causal form of a cubature-filter residual (``monitored``: the channels left out of the update; none:
    the innovation), its plant, noise and filter rebuilt from their descriptions."""
    if type(estimator.filter).filter is not _CubatureFilterBase.filter:
        raise NoStreamingForm(f"the filter {type(estimator.filter).__name__} overrides filter(): its stream would not "
                              f"be the run's arithmetic")
    parts = {"plant": source["plant"], "noise": source["noise"], "filter": describe(estimator.filter)}
    foreign = [f"{key} {d['class']}" for key, d in parts.items() if not d["class"].startswith("mosd.")]
    if foreign:
        raise NoStreamingForm(f"the {foreign[0]} is not mosd's: a deployed model rebuilds mosd's classes only")
    inputs = tuple(source.get("input_names") or (f"u{i}" for i in range(np.shape(trace.u)[-1])))
    sqrt_p0 = _lower_sqrt(np.asarray(model.P0, float))
    return OnlineDedicatedObserver(
        plant=parts["plant"], noise=parts["noise"], filter=parts["filter"], monitored=monitored,
        x0=np.asarray(model.x0, float), sqrt_p0=sqrt_p0, outputs_of_plant=tuple(model.output_names),
        inputs_of_plant=inputs)


@dataclass
class OnlineDedicatedObserver(PlantStage):
    """:class:`DedicatedObserverResidual`'s causal form: ``y_<output>``, ``u_<input>`` in, ``residual_<output>`` out
    (with ``monitored=()``, :class:`InnovationResidual`'s: the innovation of every channel).

    Each chunk goes through :meth:`DedicatedObserverResidual.residuals` (the batch arithmetic: the
    compiled CESCKF kernel where the batch used it) from the carried state, a
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

    plant: dict
    noise: dict
    filter: dict
    monitored: tuple
    x0: np.ndarray
    sqrt_p0: np.ndarray
    outputs_of_plant: tuple = ()
    inputs_of_plant: tuple = ()

    def __post_init__(self):
        self.plant, self.noise, self.filter = dict(self.plant), dict(self.noise), dict(self.filter)
        self.monitored = tuple(int(m) for m in self.monitored)
        self.x0, self.sqrt_p0 = np.asarray(self.x0, float), np.asarray(self.sqrt_p0, float)
        self.outputs_of_plant, self.inputs_of_plant = tuple(self.outputs_of_plant), tuple(self.inputs_of_plant)

    def _built(self):
        """(the model, the residual generator), rebuilt once from their descriptions."""
        cached = self.__dict__.get("_generator")
        if cached is None:
            cached = self.__dict__["_generator"] = (
                DedicatedObserverResidual(filter=build(self.filter), monitored=self.monitored) if self.monitored
                else InnovationResidual(filter=build(self.filter)))  # no channel left out: the innovation (eq. 7)
        return self._model(), cached

    @property
    def _n_x(self) -> int:
        return len(self.x0)

    def _root_names(self):
        cached = self.__dict__.get("_roots")  # four times per served row: made once
        if cached is None:
            cached = self.__dict__["_roots"] = [(i, j, f"sqrt_cov_filt_{i}_{j}") for i in range(self._n_x)
                                                for j in range(i + 1)]
        return cached


    def state_vars(self) -> dict[str, StateVar]:
        out = {"filter_step": StateVar("Rows the filter has seen (0: start from x̂_0, P_0).", COUNT)}
        out.update({f"x_filt_{i}": StateVar(f"x̂_k|k of state {i} (eq. 12).", FINITE) for i in range(self._n_x)})
        for i, j, name in self._root_names():
            out[name] = StateVar(f"Entry ({i}, {j}) of the lower root S_k|k of P_k|k (eq. 18).",
                                 _ROOT_DIAGONAL if i == j else FINITE)
        out.update({f"u_last_{n}": StateVar(f"The last row's input {n} (drives the next prediction).", FINITE)
                    for n in self.inputs_of_plant})
        return out

    def initial_state(self) -> dict:
        state = {"filter_step": 0}
        state.update({f"x_filt_{i}": float(v) for i, v in enumerate(self.x0)})
        state.update({name: float(self.sqrt_p0[i, j]) for i, j, name in self._root_names()})
        state.update({f"u_last_{n}": 0.0 for n in self.inputs_of_plant})
        return state

    def example_row(self) -> np.ndarray:
        model, _ = self._built()
        return np.concatenate([np.asarray(model.h(self.x0[None]))[0], np.zeros(len(self.inputs_of_plant))])

    def update(self, columns, state) -> dict[str, np.ndarray]:
        model, generator = self._built()
        y = np.column_stack([np.asarray(columns[f"y_{n}"], float) for n in self.outputs_of_plant])
        u = (np.column_stack([np.asarray(columns[f"u_{n}"], float) for n in self.inputs_of_plant])
             if self.inputs_of_plant else np.zeros((len(y), 0)))
        bad = ~np.isfinite(u)
        if bad.any():
            row, col = np.argwhere(bad)[0]
            raise ConfigError(f"input column 'u_{self.inputs_of_plant[col]}' row {row} is {float(u[row, col])!r}, not a "
                              f"finite number; allowed: numbers (the filter's prediction needs every input)")
        rows, n_x = len(y), self._n_x
        step = int(state["filter_step"])
        start = None
        if step > 0:
            root = np.zeros((n_x, n_x))
            for i, j, name in self._root_names():
                root[i, j] = float(state[name])
            start = FilterStart(np.array([float(state[f"x_filt_{i}"]) for i in range(n_x)]), root,
                                np.array([float(state[f"u_last_{n}"]) for n in self.inputs_of_plant]))
        if rows == 0:
            r, x_filt, sqrt_cov = np.empty((0, len(self.outputs_of_plant))), np.empty((0, n_x)), np.empty((0, n_x, n_x))
        else:
            r, _, res, _ = generator.residuals(model, y[None], u[None], start)
            r, x_filt, sqrt_cov = r[0], res.x_filt[0], res.sqrt_cov_filt[0]
        out = {f"residual_{n}": r[:, c] for c, n in enumerate(self.outputs_of_plant)}
        out["filter_step"] = step + 1 + np.arange(rows, dtype=np.int64)
        out.update({f"x_filt_{i}": x_filt[:, i] for i in range(n_x)})
        out.update({name: sqrt_cov[:, i, j] for i, j, name in self._root_names()})
        out.update({f"u_last_{n}": u[:, c] for c, n in enumerate(self.inputs_of_plant)})
        return out


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
