"""Charts for the process mean and variance together: SS-DEWMA, SS-EWMA, M-DEWMA, Max-EWMA (paper 000, eqs. 19–27, 35)."""
from __future__ import annotations

import functools
import math
from typing import ClassVar

import numpy as np
from scipy import special

from ..validation import Interval, Param
from .chart import Chart
from .statistics import dewma_variance, ewma_variance, subgroup_mean_statistic, subgroup_variance_statistic



@functools.cache  # computed when a theoretical max-chart limit first needs it: scipy.integrate stays unloaded until then
def max_abs_normal_moments() -> tuple[float, float]:
    """Mean and standard deviation of max(|X₁|, |X₂|), X₁, X₂ i.i.d. N(0, 1).

    P(M <= m) = (2Φ(m) − 1)², so E M = ∫(1 − (2Φ(m) − 1)²) dm and
    E M² = ∫ 2m (1 − (2Φ(m) − 1)²) dm, evaluated by quadrature (E M = 2/√π ≈ 1.128379,
    sd M ≈ 0.602810, the constants of Chen, Cheng & Xie 2001).
    """
    from scipy import integrate

    tail = lambda m: 1.0 - (2.0 * special.ndtr(m) - 1.0) ** 2  # noqa: E731
    mean = integrate.quad(tail, 0.0, np.inf, epsabs=1e-13)[0]
    second = integrate.quad(lambda m: 2.0 * m * tail(m), 0.0, np.inf, epsabs=1e-13)[0]
    return mean, math.sqrt(second - mean**2)


class _MeanVarianceChart(Chart):
    """One chart for the process mean and variance together (U_k and V_k of eqs. 19–20).

    Both statistics are smoothed ``order`` times with the same λ (1: EWMA, eqs.
    21–22; 2: double EWMA, eqs. 23–24) and combined as a sum of squares
    (``combine="ss"``, eq. 25) or as the larger absolute value (``"max"``): the chart's step
    (:meth:`~mosd.detectors.chart.Chart.scan`, :func:`mosd.kernels.ewma.combine_step`).

    Limits: ``"phase1"`` (eq. 27), ``"theoretical"`` and ``"normalised"`` (module
    docstring). The theoretical limit uses the exact in-control law at each k:
    SS/σ²_k ~ χ²₂ gives UCL_k = 2σ²_k(1 + K) (eq. 35); max/σ_k ~ max(|X₁|, |X₂|)
    gives UCL_k = σ_k(E M + K sd M). That law is the raw statistic's, so
    ``"theoretical"`` with a denoiser is refused (:class:`~mosd.detectors.chart.Chart`).
    """

    order: ClassVar[int] = 2
    combine: ClassVar[str] = "ss"
    parts = ("u", "v")
    params = {
        "lam": Param(Interval(0.0, 1.0, open_low=True, open_high=True), "Smoothing parameter λ.", tunable=True),
        "K": Param(Interval(0.0, 10.0), "Control width K_SD (eq. 27 or 35).", tunable=True),
    }
    limits = ("phase1", "theoretical", "normalised")
    model_limits = ("theoretical",)

    def __init__(self, lam: float = 0.3, K: float = 3.0, limit: str = "phase1", denoiser=None):
        super().__init__(limit=limit, denoiser=denoiser)
        self._assign(locals())

    def smoothed_variance(self, n_points: int, lam=None) -> np.ndarray:
        """In-control variance of the smoothed statistics at k = 1..n_points (eq. 29 or 31), for this chart's λ
        or for ``lam`` (P, 1): (P, n_points)."""
        lam = self.lam if lam is None else lam
        if self.order == 1:
            return ewma_variance(lam, n_points)
        return dewma_variance(lam, n_points)

    def features(self, z: np.ndarray) -> np.ndarray:
        return np.stack([subgroup_mean_statistic(z), subgroup_variance_statistic(z)], axis=-2)

    def _scale(self, n_points: int, lam=None) -> np.ndarray:
        var = self.smoothed_variance(n_points, lam)
        return var if self.combine == "ss" else np.sqrt(var)

    def control_limit(self, n_points: int) -> np.ndarray:
        if self.limit != "theoretical":
            return self._phase1_limit(self.K, n_points)
        if self.combine == "ss":
            return 2.0 * self.smoothed_variance(n_points) * (1.0 + self.K)
        mean, sd = max_abs_normal_moments()
        return self._scale(n_points) * (mean + self.K * sd)


class SSDEWMA(_MeanVarianceChart):
    """Sum-of-squares double EWMA chart (Teh, Khoo & Wu 2011; paper 000 eqs. 19–27, 35).

    L_k = W_k² + Q_k² (eq. 25), W and Q the double EWMAs of U_k and V_k; the
    plotted l_k is L_k after denoising (§3.2), or L_k/σ²_{W_k} before denoising
    for ``limit="normalised"``.
    """

    order, combine = 2, "ss"


class SSEWMA(_MeanVarianceChart):
    """Sum-of-squares EWMA chart: Y_k² + Z_k² (eqs. 21–22; Xie 1999)."""

    order, combine = 1, "ss"


class MDEWMA(_MeanVarianceChart):
    """Maximum double EWMA chart: max(|W_k|, |Q_k|) (Khoo, Teh & Wu 2010)."""

    order, combine = 2, "max"


class MaxEWMA(_MeanVarianceChart):
    """Max-EWMA chart: max(|Y_k|, |Z_k|) (Chen, Cheng & Xie 2001)."""

    order, combine = 1, "max"
