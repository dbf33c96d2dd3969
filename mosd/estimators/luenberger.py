"""A fixed-gain (Luenberger) observer residual: the worked example of docs/ADD_A_SYSTEM.md.

The observer runs the plant's own nonlinear model and corrects it with a
constant gain L placed on the model's linearisation at its initial state
(Luenberger 1971): x̂_{k+1} = f(x̂_k, u_k) + L (y_k − h(x̂_k)), residual
r_k = y_k − h(x̂_k). Slow observer poles keep a sensor fault in the residual
longer (the gain absorbs less of it); fast ones track model error better.
"""
from __future__ import annotations

import numpy as np
from scipy.signal import place_poles

from ..model import StateSpaceModel
from ..streaming import FINITE, StateVar
from ..types import Residuals, Trace
from ..validation import ConfigError, Interval, Param
from .base import plant_columns
from .step import StepEstimator


def observer_step(model: StateSpaceModel, x_hat: np.ndarray, y: np.ndarray, u: np.ndarray, gain: np.ndarray):
    """(r_k, x̂_{k+1}) from x̂_k (R, n_x), y_k (R, n_y), u_k (R, n_u): the one arithmetic of the batch
    estimate and the causal form. The correction L r is summed over the outputs in order (no BLAS: its
    rounding would depend on how many replications share the product)."""
    r = y - model.h(x_hat)
    known = np.where(np.isnan(r), 0.0, r)
    correction = np.zeros_like(x_hat)
    for j in range(gain.shape[1]):
        correction += known[:, j:j + 1] * gain[:, j]
    return r, model.f(x_hat, u) + correction


def jacobian(function, point: np.ndarray, step: float = 1e-7) -> np.ndarray:
    """The Jacobian of ``function`` at ``point`` by central differences, shape (n_out, n_in)."""
    point = np.asarray(point, float)
    columns = []
    for i in range(point.size):
        delta = np.zeros_like(point)
        delta[i] = step * max(1.0, abs(point[i]))
        columns.append((function(point + delta) - function(point - delta)) / (2.0 * delta[i]))
    return np.stack(columns, axis=-1)


class LuenbergerObserver(StepEstimator):
    """Residual r_k = y_k − h(x̂_k) of a constant-gain observer of the plant's model (module docstring).

    The gain places the eigenvalues of A − L C (A = ∂f/∂x, C = ∂h/∂x at the model's
    x̂_0 and the first input) at ``poles``. A missing output (NaN) gives no correction
    and a NaN residual.

    Its step (:mod:`mosd.estimators.step`): :func:`observer_step` from the carried x̂ (``x_hat_<i>``,
    started at the model's x̂_0); the batch estimate is that scan over every run from the start.
    """

    params = {"poles": Param(Interval(0.0, 1.0, open_high=True), "Eigenvalues of the observer's error dynamics "
                             "A − LC, one per state (discrete time: 0 is deadbeat, near 1 slow).", sequence=True)}

    def __init__(self, poles=(0.98, 0.98)):
        self._assign(locals())

    def gain(self, model: StateSpaceModel, u0: np.ndarray) -> np.ndarray:
        """L (n_x, n_y) placing the poles on the linearisation at (x̂_0, u0)."""
        if len(self.poles) != model.n_x:
            raise ConfigError(f"estimator.poles has {len(self.poles)} values; allowed: {model.n_x}, one per state "
                              f"({', '.join(model.state_names)})")
        x0 = np.asarray(model.x0, float)
        a = jacobian(lambda x: model.f(x, u0), x0)
        c = jacobian(model.h, x0)
        try:
            return place_poles(a.T, c.T, np.asarray(self.poles, float)).gain_matrix.T
        except ValueError as exc:  # unobservable pair, or a pole repeated more often than there are outputs
            raise ConfigError(f"estimator.poles={list(self.poles)!r} cannot be placed: {exc}") from None

    def estimate(self, trace: Trace, model: StateSpaceModel) -> Residuals:
        """The residuals of every replication, all output channels: :meth:`scan` from x̂_0."""
        y, u = np.asarray(trace.y, float), np.asarray(trace.u, float)
        params = self.step_params(model, trace)
        columns = {f"y_{j}": y[..., j] for j in range(y.shape[-1])}
        columns.update({f"u_{j}": u[..., j] for j in range(u.shape[-1])})
        out = self.scan(model, params, self.start(params), columns)
        r = np.stack([out[f"residual_{j}"] for j in range(y.shape[-1])], axis=-1)
        return Residuals.of(trace, r=r, channels=model.output_names)

    @staticmethod
    def _u0(u: np.ndarray) -> np.ndarray:
        """The input the gain is placed at: zero, so that the gain is the model's alone (the same for the
        calibration, training and test runs and for a stream; a mean over a batch's first inputs made it
        depend on the batch). For the two-tank cascade ∂f/∂x does not depend on the inflow at all."""
        return np.zeros(np.shape(u)[-1])

    # -- the step (mosd.estimators.step) ---------------------------------------------------
    def step_params(self, model: StateSpaceModel, trace: Trace | None = None) -> dict[str, np.ndarray]:
        """The gain L placed at the model's x̂_0 (:meth:`gain`; ``trace``'s inputs say how many) and x̂_0."""
        u = np.zeros((0, 0)) if trace is None else np.asarray(trace.u, float)
        return {"gain": self.gain(model, self._u0(u)), "x0": np.asarray(model.x0, float)}

    def step_state(self, params: dict, reads: tuple = ()) -> dict:
        return {f"x_hat_{i}": (StateVar(f"The observer's estimate of state {i}.", FINITE), float(v))
                for i, v in enumerate(params["x0"])}

    def scan(self, model, params: dict, state: dict, columns: dict, trajectory: bool = False) -> dict:
        """r_k and x̂_{k+1} of every run by :func:`observer_step` (:meth:`StepEstimator.scan`): the columns are the
        outputs ``y_*`` then the inputs ``u_*``, in the model's order; out ``residual_<j>`` per output, by
        position j when the columns are not the model's names (the batch), else by name."""
        gain = np.asarray(params["gain"], float)
        names = list(columns)
        ys, us = names[:model.n_y], names[model.n_y:]
        y = np.stack([columns[n] for n in ys], axis=-1)
        u = np.stack([columns[n] for n in us], axis=-1) if us else np.zeros(y.shape[:2] + (0,))
        runs, rows = y.shape[:2]
        x_hat = np.stack([np.broadcast_to(np.asarray(state[f"x_hat_{i}"], float), (runs,))
                          for i in range(model.n_x)], axis=-1).copy()
        r = np.empty_like(y)
        states = np.empty((runs, rows, model.n_x)) if trajectory else None
        for k in range(rows):
            r[:, k], x_hat = observer_step(model, x_hat, y[:, k], u[:, k], gain)
            if trajectory:
                states[:, k] = x_hat
        out = {f"residual_{n[2:]}": r[..., j] for j, n in enumerate(ys)}
        if trajectory:
            out.update({f"x_hat_{i}": states[..., i] for i in range(model.n_x)})
        return out

    def example_row(self, model, params: dict, reads: tuple) -> np.ndarray:
        """h(x̂_0) and zero inputs."""
        outputs = np.asarray(model.h(np.asarray(params["x0"], float)[None]))[0]
        return np.concatenate([outputs, np.zeros(len(reads) - len(outputs))])

    # -- the causal form ----------------------------------------------------------------
    def online(self, model: StateSpaceModel = None, source=None, trace: Trace | None = None):
        """The observer as a stream of raw measurements and inputs (``y_<output>``, ``u_<input>`` per row in,
        ``residual_<output>`` out): :class:`~mosd.estimators.step.EstimatorStage` of :meth:`scan`.

        ``source`` describes the plant and noise (:func:`mosd.streaming.describe`) the model is rebuilt
        from; ``trace`` the runs (their number of inputs when the plant names none).
        """
        if source is None or trace is None:
            return super().online(model)
        inputs = tuple(source.get("input_names") or (f"u{i}" for i in range(np.shape(trace.u)[-1])))
        return self.stage(model, source, (*(f"y_{n}" for n in model.output_names), *(f"u_{n}" for n in inputs)),
                          tuple(f"residual_{n}" for n in model.output_names), trace)

    def raw_stream(self, trace: Trace, model: StateSpaceModel, input_names) -> dict[str, np.ndarray]:
        """The first replication's measurements and inputs as the causal form's columns."""
        return plant_columns(trace, model, input_names)
