"""Paper 003's χ² test with an adaptive threshold that grows with the neural observer's error.

Wang et al. 2020 (paper 003, §1.2). A residual r with covariance S gives
λ_k = r_kᵀ S_k⁻¹ r_k ~ χ²(n) while the sensor is healthy; the fixed threshold
T_D is the (1 − α) quantile of χ²(n) for a tolerated false-alarm rate α.
Because the neural observer is itself imperfect the paper raises the
threshold with the observer's residual E_k (**reconstruction**, equations lost)::

    T_k = a · T_D + b · (E_{k−d} / σ_N)²,     alarm at k  ⇔  λ_k > T_k

with a = b = 1 in the paper. The paper's T_D + E_k adds metres to a χ²
quantile; here the observer term is dimensionless, a χ²(1)-like value: the
monitor hands the residual in units of the observer's N-step prediction σ_N
(``observer_residual_scaled`` = E_k/σ_N) and the detector squares it. The lag
d ≥ 0 (``lag``, default 1: the threshold at k is set from what was known at
k − 1) is the paper's "the threshold follows the residual with a delay";
issue 20 and docs/systems/paper003.md. Which χ² statistic is tested is the
monitor's choice: points z (R, K, 2) = [λ_k, E_k/σ_N], e.g.
``[chi2, observer_residual_scaled]`` (the Kalman filter's innovation test, as
the paper's §1.2 reads) or ``[observer_chi2, observer_residual_scaled]`` (the
observer's own standardised residual, as its Fig. 7 plots).
The threshold comes from α alone, so calibration data are not used.
"""
from __future__ import annotations

import numpy as np
from scipy import stats

from ..streaming import COUNT, FINITE, StateVar
from ..validation import ConfigError, Interval, Param
from .base import persistent
from .step import StepDetector


class AdaptiveChi2Detector(StepDetector):
    """λ_k > a·T_D(α) + b·(E_{k−d}/σ_N)² (module docstring; reconstruction of paper 003 §1.2)."""

    params = {
        "alpha": Param(Interval(0.0, 0.5, open_low=True, open_high=True), "Tolerated false-alarm probability per "
                       "point of the χ² test.", tunable=True),
        "a": Param(Interval(0.0, 5.0), "Weight of the χ² threshold T_D (paper: 1).", tunable=True),
        "b": Param(Interval(0.0, 20.0), "Weight of the squared scaled observer residual (E_{k−d}/σ_N)² (paper: 1).",
                   tunable=True),
        "dof": Param(Interval(1, 100, integer=True), "Degrees of freedom of λ_k (the residual's dimension)."),
        "persistence": Param(Interval(1, 1000, integer=True), "Consecutive exceedances before an alarm (paper: 1)."),
        "lag": Param(Interval(0, 1000, integer=True), "d, the points by which the threshold follows the residual "
                     "(the paper gives no value; 1: the smallest delay that keeps λ_k out of its own threshold)."),
    }

    def __init__(self, alpha: float = 0.01, a: float = 1.0, b: float = 1.0, dof: int = 1, persistence: int = 1,
                 lag: int = 1):
        self._assign(locals())

    def chi2_threshold(self, alpha: np.ndarray | float) -> np.ndarray:
        """T_D = F⁻¹_{χ²(dof)}(1 − α)."""
        return stats.chi2.ppf(1.0 - np.asarray(alpha, float), self.dof)

    # -- the one step (mosd.detectors.step) -------------------------------------------------
    def step_params(self, X: np.ndarray, calibration_features=None) -> dict[str, np.ndarray]:
        """a·T_D(α) and b per design of X (P, 3) = (α, a, b), and the persistence; calibration data are not used."""
        X = np.atleast_2d(np.asarray(X, float))
        return {"chi2_threshold": X[:, 1] * self.chi2_threshold(X[:, 0]), "b": X[:, 2],
                "persistence": np.full(X.shape[0], float(self.persistence))}

    def step_state(self, n: int) -> dict:
        out = {f"observer_{i}": (StateVar(f"E/σ_N of the point {i} back (null: none yet).", FINITE, missing=True),
                                 np.nan) for i in range(1, self.lag + 1)}
        out["run_length"] = (StateVar("Consecutive points above the threshold.", COUNT), 0)
        return out

    def scan(self, params, state, features, trajectory=False) -> dict[str, np.ndarray]:
        """λ_k > a·T_D + b·(E_{k−d}/σ_N)² on z (R, K, 2) = [λ_k, E_k/σ_N], E_{k−d} carried from the points before.

        NaN points (no prediction yet, a missing sample) never alarm, nor do the first ``lag`` points of a
        stream's start (no E_{k−d} yet) unless b = 0; with b = 0 a NaN E is ignored.
        """
        z = np.asarray(features, float)
        if z.ndim != 3 or z.shape[-1] != 2:
            raise ConfigError(f"detector adaptive_chi2 needs points z of shape (R, K, 2) = [chi2, observer_residual_scaled], "
                              f"got {z.shape}; allowed: monitor.outputs with two outputs")
        d, n_points = self.lag, z.shape[1]
        weight = np.asarray(params["b"], float).reshape(-1, 1, 1)
        # E_{k−d}/σ_N of each point: the carried E of the d points before (oldest first), then this run's
        carried = [np.asarray(state[f"observer_{i}"], float) for i in range(d, 0, -1)]
        batch = np.broadcast_shapes((1, z.shape[0]), *(c.shape for c in carried))
        history = np.concatenate([*(np.broadcast_to(c, batch)[..., None] for c in carried),
                                  np.broadcast_to(z[None, :, :, 1], batch + (n_points,))], axis=-1)
        lagged = history[..., :n_points]
        statistic = np.broadcast_to(z[..., 0], (weight.shape[0],) + z.shape[:2])
        # a design that ignores E (b = 0) must not inherit its NaNs (no prediction yet)
        observer_term = np.where(weight > 0, weight * lagged**2, 0.0)
        threshold = np.asarray(params["chi2_threshold"], float).reshape(-1, 1, 1) + observer_term
        with np.errstate(invalid="ignore"):
            exceed = statistic > threshold  # False wherever a NaN is involved
        held = persistent(exceed, np.asarray(params["persistence"]).astype(int), state["run_length"], trajectory)
        decision, run = held if trajectory else (held, None)
        out = {"statistic": statistic, "limit": threshold, "decision": decision.astype(np.int8)}
        if trajectory:
            out["run_length"] = run
            for i in range(1, d + 1):  # E of the point i back, after each point
                out[f"observer_{i}"] = np.broadcast_to(history[..., d - i + 1: d - i + 1 + n_points],
                                                       statistic.shape)
        return out
