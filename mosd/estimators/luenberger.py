"""A fixed-gain (Luenberger) observer residual: the worked example of docs/ADD_A_SYSTEM.md.

The observer runs the plant's own nonlinear model and corrects it with a
constant gain L placed on the model's linearisation at its initial state
(Luenberger 1971): x̂_{k+1} = f(x̂_k, u_k) + L (y_k − h(x̂_k)), residual
r_k = y_k − h(x̂_k). Slow observer poles keep a sensor fault in the residual
longer (the gain absorbs less of it); fast ones track model error better.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.signal import place_poles

from ..model import StateSpaceModel
from ..streaming import FINITE, StateVar
from ..types import Residuals, Trace
from ..validation import ConfigError, Interval, Param
from .base import Estimator, PlantStage, plant_columns


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


class LuenbergerObserver(Estimator):
    """Residual r_k = y_k − h(x̂_k) of a constant-gain observer of the plant's model (module docstring).

    The gain places the eigenvalues of A − L C (A = ∂f/∂x, C = ∂h/∂x at the model's
    x̂_0 and the first input) at ``poles``. A missing output (NaN) gives no correction
    and a NaN residual.
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
        """The residuals of every replication, all output channels."""
        y, u = np.asarray(trace.y, float), np.asarray(trace.u, float)
        n_reps, n_samples, _ = y.shape
        gain = self.gain(model, self._u0(u))
        x_hat = np.broadcast_to(np.asarray(model.x0, float), (n_reps, model.n_x)).copy()
        r = np.empty_like(y)
        for k in range(n_samples):
            r[:, k], x_hat = observer_step(model, x_hat, y[:, k], u[:, k], gain)
        return Residuals.of(trace, r=r, channels=model.output_names)

    @staticmethod
    def _u0(u: np.ndarray) -> np.ndarray:
        """The input the gain is placed at: zero, so that the gain is the model's alone (the same for the
        calibration, training and test runs and for a stream; a mean over a batch's first inputs made it
        depend on the batch). For the two-tank cascade ∂f/∂x does not depend on the inflow at all."""
        return np.zeros(np.shape(u)[-1])

    # -- the causal form ----------------------------------------------------------------
    def online(self, model: StateSpaceModel = None, source=None, trace: Trace | None = None) -> "OnlineLuenberger":
        """The observer as a stream of raw measurements and inputs (``y_<output>``, ``u_<input>`` per row).

        ``source`` describes the plant and noise (:func:`mosd.streaming.describe`) the model is rebuilt
        from; ``trace`` the runs whose first input the batch estimate placed the gain at.
        """
        if source is None or trace is None:
            return super().online(model)
        gain = self.gain(model, self._u0(np.asarray(trace.u, float)))
        inputs = tuple(source.get("input_names") or (f"u{i}" for i in range(np.shape(trace.u)[-1])))
        return OnlineLuenberger(plant=source["plant"], noise=source["noise"], gain=gain,
                                x0=np.asarray(model.x0, float), outputs=tuple(model.output_names), inputs=inputs)

    def raw_stream(self, trace: Trace, model: StateSpaceModel, input_names) -> dict[str, np.ndarray]:
        """The first replication's measurements and inputs as the causal form's columns."""
        return plant_columns(trace, model, input_names)


@dataclass
class OnlineLuenberger(PlantStage):
    """:class:`LuenbergerObserver`'s causal form: ``y_<output>`` and ``u_<input>`` in, ``residual_<output>`` out.

    The plant's model is rebuilt from its description (``plant``, ``noise``); the state is x̂ (``x_hat_<i>``),
    started at the model's x̂_0.
    """

    plant: dict
    noise: dict
    gain: np.ndarray
    x0: np.ndarray
    outputs_of_plant: tuple = ()
    inputs_of_plant: tuple = ()

    def __init__(self, plant, noise, gain, x0, outputs=(), inputs=(), outputs_of_plant=(), inputs_of_plant=()):
        self.plant, self.noise = dict(plant), dict(noise)
        self.gain, self.x0 = np.asarray(gain, float), np.asarray(x0, float)
        self.outputs_of_plant = tuple(outputs_of_plant or outputs)
        self.inputs_of_plant = tuple(inputs_of_plant or inputs)

    def state_vars(self) -> dict[str, StateVar]:
        return {f"x_hat_{i}": StateVar(f"The observer's estimate of state {i}.", FINITE) for i in range(len(self.x0))}

    def initial_state(self) -> dict:
        return {f"x_hat_{i}": float(v) for i, v in enumerate(self.x0)}

    def example_row(self) -> np.ndarray:
        model = self._model()
        return np.concatenate([np.asarray(model.h(self.x0[None]))[0], np.zeros(len(self.inputs_of_plant))])

    def update(self, columns, state) -> dict[str, np.ndarray]:
        model = self._model()
        y = np.column_stack([np.asarray(columns[f"y_{n}"], float) for n in self.outputs_of_plant])
        u = np.column_stack([np.asarray(columns[f"u_{n}"], float) for n in self.inputs_of_plant])
        x_hat = np.array([[float(state[f"x_hat_{i}"]) for i in range(len(self.x0))]])
        r, states = np.empty_like(y), np.empty((len(y), len(self.x0)))
        for k in range(len(y)):
            residual, x_hat = observer_step(model, x_hat, y[k:k + 1], u[k:k + 1], self.gain)
            r[k], states[k] = residual[0], x_hat[0]
        out = {f"residual_{n}": r[:, j] for j, n in enumerate(self.outputs_of_plant)}
        out.update({f"x_hat_{i}": states[:, i] for i in range(len(self.x0))})
        return out
