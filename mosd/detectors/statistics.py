"""Parameter-free subgroup statistics and the EWMA recursions of the SPC charts (paper 000, eqs. 19–31)."""
from __future__ import annotations

import math

import numpy as np
from scipy import special


def subgroup_mean_statistic(z: np.ndarray) -> np.ndarray:
    """U_k = (r̄_k − μ)/(σ/√n) of eq. 19 for standardised subgroups z (..., K, n)."""
    n = z.shape[-1]
    return math.sqrt(n) * z.mean(axis=-1)


def subgroup_variance_statistic(z: np.ndarray) -> np.ndarray:
    """V_k = Φ⁻¹(H((n−1)S_k²/σ²; n−1)) of eq. 20 for standardised subgroups z (..., K, n).

    H is the χ²_{n−1} CDF. Both tails are computed in log space so that V_k stays
    finite for any S_k² > 0: the lower tail through log H, the upper through
    log(1 − H), with the leading asymptotic terms of the regularised incomplete
    gamma functions where the direct values underflow.
    """
    n = z.shape[-1]
    dof = n - 1
    x = dof * z.var(axis=-1, ddof=1)
    x = np.maximum(x, np.finfo(float).tiny)
    a, half = dof / 2.0, x / 2.0
    with np.errstate(divide="ignore"):
        log_cdf = np.log(special.chdtr(dof, x))
        log_sf = np.log(special.chdtrc(dof, x))
    # P(a, s) ~ s^a e^{-s} / Γ(a+1) as s -> 0 ;  Q(a, s) ~ s^{a-1} e^{-s} / Γ(a) as s -> ∞
    log_cdf = np.where(np.isfinite(log_cdf), log_cdf, a * np.log(half) - half - special.gammaln(a + 1.0))
    log_sf = np.where(np.isfinite(log_sf), log_sf, (a - 1.0) * np.log(half) - half - special.gammaln(a))
    lower = log_cdf < math.log(0.5)
    return np.where(lower, special.ndtri_exp(np.minimum(log_cdf, 0.0)), -special.ndtri_exp(np.minimum(log_sf, 0.0)))


def ewma(x: np.ndarray, lam: float, order: int = 1) -> np.ndarray:
    """EWMA applied ``order`` times along the last axis, started at 0.

    order=1 is eq. 21/22 (Y_k = (1−λ)Y_{k−1} + λU_k); order=2 is the double EWMA of
    eqs. 23/24, i.e. the filter λ²/(1 − (1−λ)z⁻¹)². The recursion is the charts' one
    (:func:`ewma_continue`), so a plotted statistic, a tuning's population and a deployed chart
    compute the same bits.
    """
    x = np.asarray(x, float)
    columns = np.ascontiguousarray(x.reshape(-1, x.shape[-1]).T)  # time-major (K, M)
    smoothed, _ = ewma_continue(columns, lam, order, np.zeros((order, columns.shape[1])))
    return smoothed.T.reshape(x.shape)


def ewma_continue(columns: np.ndarray, lam: float, order: int, past: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The ``order``-fold EWMA of time-major ``columns`` (K, C) continued from ``past`` (order, C).

    ``past`` holds y_{−1}, y_{−2}, ... of every column (zeros: a stream's start). Returns the
    smoothed columns (K, C) and the new ``past``: :func:`mosd.kernels.ewma.ewma_recursion`, the one
    recursion of every chart (compiled; plain Python where numba's JIT is disabled).
    """
    from ..kernels.ewma import ewma_recursion

    columns = np.ascontiguousarray(columns, dtype=float)
    gain, feedback = ewma_coefficients([lam], order)
    past = np.array(past, float, copy=True).reshape(order, columns.shape[1])
    out = np.empty_like(columns)
    ewma_recursion(columns, float(gain[0]), np.ascontiguousarray(feedback[0]), past, out)
    return out, past


def mean_and_sd(values: np.ndarray) -> tuple[float, float]:
    """Mean and standard deviation (ddof = 1) of every value: the Phase-I limit's E{l} and sd{l} (eq. 27).

    One summation for every path — the test evaluation, the fused candidate evaluation and the
    deployed chart: NumPy's pairwise algorithm written out (:func:`mosd.kernels.chart.mean_std`),
    because ``np.mean`` of the same numbers can round differently when the array is a view at
    another memory alignment (seen: 1 ulp between a limit fitted on a slice and on a copy).
    """
    flat = np.ascontiguousarray(values, dtype=float).ravel()
    from ..kernels.chart import mean_std

    # compiled whether or not the kernels replace the NumPy evaluation: it is one sum, not a strategy
    center, scale = mean_std(flat)
    return float(center), float(scale)


def ewma_coefficients(lams, order: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Gain λ^order (P,) and feedback −a_1..−a_order (P, order) of the ``order``-fold EWMA filter per λ.

    The denominator 1 + a_1 z⁻¹ + ... + a_order z⁻order is ``np.poly`` of the
    repeated pole 1 − λ; the compiled kernels take these very numbers, so both
    paths run the same arithmetic.
    """
    lams = np.asarray(lams, float).ravel()
    pole = 1.0 - lams
    # np.poly's products for orders 1 and 2 written out — the same bits, without a call per λ:
    # (1 − p z⁻¹) → a_1 = −p;  (1 − p z⁻¹)² → a_1 = (−p) + (−p), a_2 = (−p)(−p)
    if order == 1:
        return lams**order, -(-pole)[:, None]
    if order == 2:
        return lams**order, -np.column_stack([(-pole) + (-pole), (-pole) * (-pole)])
    denominator = np.array([np.poly(np.full(order, p)) for p in pole]).reshape(lams.size, order + 1)
    return lams**order, -denominator[:, 1:]


def ewma_time_major(x: np.ndarray, lams: np.ndarray, order: int = 1) -> np.ndarray:
    """:func:`ewma` of x (..., K) for many smoothing parameters, time-major: (K, P, M).

    M indexes the flattened leading axes of x. The ``order``-fold EWMA is the IIR filter
    λ^order / (1 − (1−λ)z⁻¹)^order; its difference equation runs over time on all (candidate,
    sequence) columns: :func:`mosd.kernels.ewma.ewma_population`, each candidate through the one
    recursion :func:`mosd.kernels.ewma.ewma_recursion`. Columns never mix, so a candidate's result
    does not depend on which other candidates share the call.
    """
    from ..kernels.ewma import ewma_population

    n_points = x.shape[-1]
    columns = np.ascontiguousarray(np.asarray(x, float).reshape(-1, n_points).T)  # time-major (K, M)
    gain, feedback = ewma_coefficients(lams, order)
    return ewma_population(columns, gain, np.ascontiguousarray(feedback))


def dewma_variance(lam: float, n_points: int) -> np.ndarray:
    """σ²_{W_k} = λ⁴ Σ_{j=1..k} j²(1−λ)^{2(j−1)} for k = 1..n_points (eq. 31); λ a number or (P, 1)."""
    j = np.arange(1, n_points + 1)
    # lam may be an array of shape (P, 1): each row is its λ's sequence (a cumulative sum runs in order either way)
    return lam**4 * np.cumsum(j**2 * (1.0 - lam) ** (2 * (j - 1)), axis=-1)


def ewma_variance(lam: float, n_points: int) -> np.ndarray:
    """σ²_{Y_k} = λ(1 − (1−λ)^{2k})/(2 − λ) for k = 1..n_points (eq. 29); λ a number or (P, 1)."""
    k = np.arange(1, n_points + 1)
    return lam * (1.0 - (1.0 - lam) ** (2 * k)) / (2.0 - lam)
