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

from dataclasses import dataclass

import numpy as np
from scipy import stats

from ..streaming import COUNT, FINITE, PointDecision, StateVar, points_of, spread
from ..validation import ConfigError, Interval, Param
from .base import Decisions, Detector, persistent, run_lengths


class AdaptiveChi2Detector(Detector):
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

    def online(self, calibration_z=None, inputs=None) -> "OnlineAdaptiveChi2":
        """This design's causal form (the threshold comes from α alone: calibration data are not used)."""
        return OnlineAdaptiveChi2(chi2_threshold=float(self.a * self.chi2_threshold(self.alpha)), b=float(self.b),
                                  lag=int(self.lag), persistence=int(self.persistence))

    def population(self, calibration_features: np.ndarray, features: np.ndarray, X: np.ndarray) -> Decisions:
        """Decisions of every design (α, a, b) in X (P, 3) on z (R, K, 2) = [λ_k, E_k/σ_N].

        NaN points (no prediction yet, a missing sample) never alarm, nor do the
        first ``lag`` points (no E_{k−d} yet) unless b = 0; with b = 0 a NaN E is ignored.
        """
        X = np.atleast_2d(np.asarray(X, float))
        z = np.asarray(features, float)
        if z.ndim != 3 or z.shape[-1] != 2:
            raise ConfigError(f"detector adaptive_chi2 needs points z of shape (R, K, 2) = [chi2, observer_residual_scaled], "
                              f"got {z.shape}; allowed: monitor.outputs with two outputs")
        alpha, a, b = X[:, 0], X[:, 1], X[:, 2]
        statistic = np.broadcast_to(z[..., 0], (X.shape[0],) + z.shape[:2])
        weight = b[:, None, None]
        lagged = np.full(z.shape[:2], np.nan)  # E_{k−d}/σ_N: NaN before the first d points
        lagged[:, self.lag:] = z[:, : z.shape[1] - self.lag, 1]
        # a design that ignores E (b = 0) must not inherit its NaNs (no prediction yet)
        observer_term = np.where(weight > 0, weight * lagged[None] ** 2, 0.0)
        threshold = (a * self.chi2_threshold(alpha))[:, None, None] + observer_term
        exceed = statistic > threshold  # False wherever a NaN is involved
        decision = persistent(exceed, self.persistence).astype(np.int8)
        return Decisions(statistic=statistic, threshold=threshold, decision=decision)


@dataclass
class OnlineAdaptiveChi2(PointDecision):
    """:class:`AdaptiveChi2Detector`'s causal form: points in (``point``, ``z_1`` = λ_k, ``z_2`` = E_k/σ_N);
    ``statistic`` (λ_k), ``limit`` (a·T_D + b·(E_{k−d}/σ_N)²), ``decision`` and ``alarm`` out.

    State: the last d scaled observer residuals (``observer_1`` = E_{k−1}/σ_N, ...; null before the first
    points, as the population's NaN) and ``run_length`` (consecutive exceedances).
    """

    chi2_threshold: float   # a·T_D
    b: float
    lag: int
    persistence: int

    n = 2  # [λ_k, E_k/σ_N]

    def state_vars(self) -> dict[str, StateVar]:
        out = {f"observer_{i}": StateVar(f"E/σ_N of the point {i} back (null: none yet).", FINITE, missing=True)
               for i in range(1, self.lag + 1)}
        out["run_length"] = StateVar("Consecutive points above the threshold.", COUNT)
        return out

    def initial_state(self) -> dict:
        return {**{f"observer_{i}": np.nan for i in range(1, self.lag + 1)}, "run_length": 0}

    def update(self, columns, state) -> dict[str, np.ndarray]:
        rows, at, z = points_of(columns, 2)
        d = self.lag
        carried = np.array([float(state[f"observer_{i}"]) for i in range(d, 0, -1)])   # oldest first
        history = np.concatenate([carried, z[:, 1]])
        lagged = history[:len(at)]                       # E_{k−d}/σ_N of each point
        observer_term = self.b * lagged**2 if self.b > 0 else np.zeros(len(at))
        threshold = self.chi2_threshold + observer_term
        with np.errstate(invalid="ignore"):
            exceed = z[:, 0] > threshold
        run = run_lengths(exceed, int(state["run_length"]))
        alarm = run >= self.persistence
        per_point = {"statistic": z[:, 0], "limit": threshold, "decision": alarm.astype(np.int64),
                     "alarm": alarm, "run_length": run}
        for i in range(1, d + 1):                        # E of the point i back, after each point
            per_point[f"observer_{i}"] = history[d - i + 1: d - i + 1 + len(at)]
        return spread(rows, at, per_point, state)
