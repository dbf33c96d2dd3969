"""Parameter-free subgroup statistics and the EWMA recursions of the SPC charts (paper 000, eqs. 19–31)."""
from __future__ import annotations

import math

import numpy as np
from scipy import signal, special


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
    eqs. 23/24, i.e. the filter λ²/(1 − (1−λ)z⁻¹)², computed in one IIR pass.
    """
    pole = 1.0 - lam
    a = np.poly(np.full(order, pole))
    return signal.lfilter([lam**order], a, x, axis=-1)


def ewma_time_major(x: np.ndarray, lams: np.ndarray, order: int = 1) -> np.ndarray:
    """:func:`ewma` of x (..., K) for many smoothing parameters, time-major: (K, P, M).

    M indexes the flattened leading axes of x. The ``order``-fold EWMA is the IIR filter λ^order / (1 − (1−λ)z⁻¹)^order; its
    difference equation runs in one Python loop over time on all (candidate,
    sequence) columns together, which for a population of candidates beats one
    filter call per candidate (see ``python -m mosd.bench``). Columns never mix, so
    a candidate's result does not depend on which other candidates share the call.
    """
    lams = np.asarray(lams, float).ravel()
    n_points = x.shape[-1]
    columns = np.ascontiguousarray(x.reshape(-1, n_points).T)  # time-major (K, M)
    shape = (lams.size, columns.shape[1])
    # denominator 1 + a_1 z⁻¹ + ... + a_order z⁻order, per candidate
    denominator = np.array([np.poly(np.full(order, 1.0 - lam)) for lam in lams])
    feedback = [np.ascontiguousarray(np.broadcast_to(-denominator[:, i, None], shape)) for i in range(1, order + 1)]
    gain = np.ascontiguousarray(np.broadcast_to((lams**order)[:, None], shape))
    out = np.zeros((n_points,) + shape)
    scratch = np.empty(shape)
    for k in range(n_points):
        current = out[k]
        np.multiply(gain, columns[k], out=current)
        for lag, coefficient in enumerate(feedback, start=1):
            if k >= lag:
                np.multiply(out[k - lag], coefficient, out=scratch)
                current += scratch
    return out


def dewma_variance(lam: float, n_points: int) -> np.ndarray:
    """σ²_{W_k} = λ⁴ Σ_{j=1..k} j²(1−λ)^{2(j−1)} for k = 1..n_points (eq. 31)."""
    j = np.arange(1, n_points + 1)
    return lam**4 * np.cumsum(j**2 * (1.0 - lam) ** (2 * (j - 1)))


def ewma_variance(lam: float, n_points: int) -> np.ndarray:
    """σ²_{Y_k} = λ(1 − (1−λ)^{2k})/(2 − λ) for k = 1..n_points (eq. 29)."""
    k = np.arange(1, n_points + 1)
    return lam * (1.0 - (1.0 - lam) ** (2 * k)) / (2.0 - lam)
