"""Paper 003's χ² test signal: a Kalman filter of the GPS altitude driven by the measured down velocity.

Paper 003 (Wang et al. 2020, §1.2) runs an extended Kalman filter on the
vehicle's linearised state space and tests its residual with
λ_k = r_kᵀ S_k⁻¹ r_k ~ χ²(n). Its equations are lost and its vehicle model is
not given. This module is a **reconstruction** that needs no aerodynamic
model: the logged down velocity v_d drives a kinematic model of the GPS
altitude z = h + b (altitude plus GPS bias)::

    z_{k+1} = z_k − dt (v_d,k + v_d,k+1) / 2 + ε_k            (trapezoidal integration)
    y_k     = z_k + ν_k,   ν_k ~ N(0, σ_gps²)
    Var ε_k = dt² σ_vd² / 2 + σ_b² (1 − e^{−2 k_b dt}) + σ_m²

(ε collects the integrated velocity noise, the bias's Gauss–Markov step and
an integration/model error σ_m). The model is linear, so the EKF's Jacobians
are constant and the EKF *is* this Kalman filter. Why kinematic: the
detector of a flight log knows the sensors' noise but not the airframe's
aerodynamic coefficients; the kinematic relation ḣ = −v_d is exact; and the
residual has one channel, so λ_k ~ χ²(1) (the paper's "n = number of states"
is read as the dimension of the residual, which is what the χ² law needs).
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..types import Residuals, Trace
from ..validation import Interval, Param
from .base import Estimator


def kalman_start(y0: np.ndarray, r_var: float):
    """(z, P) at k = 0: the first sample with its own noise, or a wide prior where it is missing."""
    return np.where(np.isfinite(y0), y0, 0.0), np.where(np.isfinite(y0), r_var, 1e6)


def kalman_step(z, P, y, v_previous, v, dt: float, q: float, r_var: float):
    """(r_k, S_k, z_k, P_k) from (z_{k−1}, P_{k−1}), y_k and v_d at k − 1 and k (module docstring): the one
    arithmetic of the batch filter and the causal form (:class:`~mosd.estimators.neural_observer.ObserverStep`).
    A missing y_k skips the update (r_k, S_k NaN); a missing velocity skips the climb."""
    climb = -0.5 * dt * (v_previous + v)
    z_pred = z + np.where(np.isfinite(climb), climb, 0.0)
    P_pred = P + q
    innovation = y - z_pred
    S_k = P_pred + r_var
    seen = np.isfinite(innovation)
    gain = P_pred / S_k
    z = np.where(seen, z_pred + gain * np.where(seen, innovation, 0.0), z_pred)
    P = np.where(seen, (1.0 - gain) * P_pred, P_pred)
    return innovation, np.where(seen, S_k, np.nan), z, P


class AltitudeKalmanFilter(Estimator):
    """Kalman filter of GPS altitude with down-velocity input (module docstring; reconstruction)."""

    params = {
        "model_error": Param(Interval(0.0, math.inf), "σ_m (m per step) of what the trapezoidal integration of the "
                             "sampled down velocity misses (the flapping oscillation between samples)."),
        "altitude_channel": Param(Interval(0, math.inf, integer=True), "Output channel of the GPS altitude (m)."),
        "velocity_channel": Param(Interval(0, math.inf, integer=True), "Output channel of the down velocity (m/s)."),
    }

    def __init__(self, model_error: float = 0.04, altitude_channel: int = 0, velocity_channel: int = 1):
        self._assign(locals())

    def process_variance(self, model: Any) -> float:
        """Var ε_k of the module docstring."""
        dt = model.dt
        bias_step = model.gps_bias_sigma**2 * (1.0 - math.exp(-2.0 * model.gps_bias_rate * dt))
        return dt**2 * model.down_velocity_variance / 2.0 + bias_step + self.model_error**2

    def filter(self, trace: Trace, model: Any) -> dict[str, np.ndarray]:
        """Innovations r, their variance S, λ = r²/S and the filtered altitude, each (R, N).

        r, S and λ are NaN at k = 0 (no prediction yet) and where the GPS
        sample is missing; a missing sample skips the update.
        """
        y = trace.y[..., self.altitude_channel]
        v_d = trace.y[..., self.velocity_channel]
        q = self.process_variance(model)
        r_var = model.gps_variance
        n_reps, N = y.shape
        r = np.full((n_reps, N), np.nan)
        S = np.full((n_reps, N), np.nan)
        z_filt = np.full((n_reps, N), np.nan)
        z, P = kalman_start(y[:, 0], r_var)
        z_filt[:, 0] = z
        for k in range(1, N):
            r[:, k], S[:, k], z, P = kalman_step(z, P, y[:, k], v_d[:, k - 1], v_d[:, k], model.dt, q, r_var)
            z_filt[:, k] = z
        return {"r": r, "S": S, "chi2": r * r / S, "z_filtered": z_filt}

    def estimate(self, trace: Trace, model: Any) -> Residuals:
        """Residuals r (R, N, 1) with cov S (R, N, 1, 1); extra ``chi2`` λ_k and ``h_filtered``."""
        out = self.filter(trace, model)
        return Residuals.of(trace, r=out["r"][..., None], channels=(model.output_names[self.altitude_channel],),
                            cov=out["S"][..., None, None], extra={"chi2": out["chi2"], "h_filtered": out["z_filtered"]})
