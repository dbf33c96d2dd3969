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
from ..types import Residuals, Trace
from ..validation import ConfigError, Interval, Param
from .base import Estimator


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
        gain = self.gain(model, u[:, 0].mean(axis=0))
        x_hat = np.broadcast_to(np.asarray(model.x0, float), (n_reps, model.n_x)).copy()
        r = np.empty_like(y)
        for k in range(n_samples):
            r[:, k] = y[:, k] - model.h(x_hat)
            correction = np.where(np.isnan(r[:, k]), 0.0, r[:, k]) @ gain.T
            x_hat = model.f(x_hat, u[:, k]) + correction
        return Residuals.of(trace, r=r, channels=model.output_names)
