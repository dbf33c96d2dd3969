"""Paper 002's information potential and entropy cost (:mod:`mosd.estimators.entropy_filter`), compiled.

The NumPy reference :func:`mosd.estimators.entropy_filter.information_potential`
forms (N, N) arrays of the pairwise differences z_ij = Δa_ij − U Δb_ij and of the
Gaussians G_σ(z_ij), then sums them. Here one pass over the pairs accumulates the
three sums with O(N) scratch (one row of pairs at a time), no (N, N) array. It
visits each unordered pair once: z and Δb
are antisymmetric in (i, j), so G, G·z·Δb and G·Δb²·(1 − z²/σ²) are symmetric;
the diagonal (z = Δb = 0) adds G_σ(0) to V and nothing to V′ and V″. Half the
exponentials of the reference. Every operation is plain IEEE arithmetic (no
fast-math reassociation or contraction), so results do not depend on the
vector width the machine compiles for.

The exponentials are computed by a branch-free range reduction and polynomial
that the compiler vectorises (numba's ``math.exp`` is a scalar libm call and
took two thirds of the time); within ~1 ulp of libm, which still takes the
arguments below −708 (subnormal and zero results).

Not bit-identical: the reference sums N² terms with NumPy's pairwise summation,
this kernel sums each row i's terms j > i in 8 interleaved partial sums, then
the rows, and factors the constant 1/(√(2π) σ) out of the sums. V agrees to a
few 1e-15 relative; V′ and V″ are sums of terms of both signs, so their
agreement is ~1e-15 of Σ|terms| (the rounding of either order). Relative to V′
itself that is up to 2.4e-13 on the 400 calls of the paper002 preset, where
Σ|terms| is up to 8e4 × |V′| (the reference is off the exactly rounded sum by
2.7e-13 there, this kernel by 5.1e-13) (``tests/test_kernel_entropy.py``).
The designed gain schedule of
:meth:`~mosd.estimators.EntropyIsolationFilter.fit` agrees to ~1e-16 with one
Newton iteration per step; with several, the backtracking test ``J_trial <= J``
near convergence compares values equal to the last digit and may go either
way, moving a gain by up to ~1e-8.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from . import configure_compiler

configure_compiler()  # before this module's first compile

_SQRT_2PI = math.sqrt(2.0 * math.pi)

# exp(x) = 2^k exp(r), k = round(x / ln 2), r = x − k ln 2 (|r| <= ln2 / 2), by branch-free operations that
# LLVM vectorises (numba's exp is a scalar libm call, ~2/3 of the time of a pass). ln 2 is split as in
# fdlibm (k·_LN2_HI exact for |k| < 2^11); exp(r) by its Taylor series to r^13 (remainder < 1e-17 relative);
# 2^k by writing k + 1023 into a float's exponent bits. Within ~1 ulp of libm's exp (measured: 1.004 ulp
# over 2·10^5 arguments in [−708, 0]); exact arguments below −708 (subnormal or zero results) go to libm.
_LOG2E = 1.4426950408889634
_LN2_HI = 6.93147180369123816490e-01
_LN2_LO = 1.90821492927058770002e-10
_ROUND = 6755399441055744.0  # 1.5·2^52: x + _ROUND rounds x to an integer, held in the low mantissa bits
_ROUND_BITS = int(np.array([_ROUND]).view(np.int64)[0])
_EXP_FLOOR = -708.0  # 2^k stays normal above
_LANES = 8
_C = tuple(1.0 / math.factorial(n) for n in range(14))
_C2, _C3, _C4, _C5, _C6, _C7, _C8, _C9, _C10, _C11, _C12, _C13 = _C[2:]


@njit(cache=True, nogil=True, error_model="numpy")
def information_potential(a, b, gain, s):
    """V, V′, V″ of e = a − U b at U = ``gain``; the compiled reference (same arguments and results).

    Parameters
    ----------
    a, b : float64 (N,)
        The affine coefficients of each particle's next error.
    gain : float
        U.
    s : float
        Parzen bandwidth of e (the pairwise differences' kernel has σ = √2 s).

    Returns
    -------
    V, dV, d2V : float
    """
    n = a.shape[0]
    sigma = math.sqrt(2.0) * s
    # per row i, the pairs j > i: z, Δb, exp(r) and the rounded k of each Gaussian, then 2^k, then the sums
    zs = np.empty(n)
    dbs = np.empty(n)
    mantissa = np.empty(n)
    rounded = np.empty(n)
    rounded_bits = rounded.view(np.int64)
    scale_bits = np.empty(n, np.int64)
    scale = scale_bits.view(np.float64)
    acc0 = np.empty(_LANES)
    acc1 = np.empty(_LANES)
    acc2 = np.empty(_LANES)
    total0 = 0.0  # Σ_{i<j} G/c, with c = 1/(√(2π) σ) factored out
    total1 = 0.0  # Σ_{i<j} G z Δb / c
    total2 = 0.0  # Σ_{i<j} G Δb² (1 − z²/σ²) / c
    for i in range(n):
        ai = a[i]
        bi = b[i]
        m = n - i - 1
        for j in range(m):
            db = bi - b[i + 1 + j]
            z = (ai - a[i + 1 + j]) - gain * db
            zs[j] = z
            dbs[j] = db
            q = z / sigma
            x = max(-0.5 * (q * q), _EXP_FLOOR)
            t = x * _LOG2E + _ROUND
            k = t - _ROUND
            r = (x - k * _LN2_HI) - k * _LN2_LO
            mantissa[j] = 1.0 + r * (1.0 + r * (_C2 + r * (_C3 + r * (_C4 + r * (_C5 + r * (_C6 + r * (
                _C7 + r * (_C8 + r * (_C9 + r * (_C10 + r * (_C11 + r * (_C12 + r * _C13))))))))))))
            rounded[j] = t
        for j in range(m):
            scale_bits[j] = (rounded_bits[j] - _ROUND_BITS + 1023) << 52
        # per row, _LANES interleaved partial sums (j mod _LANES), then the row's sum added to the total: shorter
        # chains of additions, so less rounding where V′ or V″ cancels, and independent adds in flight
        for lane in range(_LANES):
            acc0[lane] = 0.0
            acc1[lane] = 0.0
            acc2[lane] = 0.0
        for j in range(m):
            z = zs[j]
            db = dbs[j]
            q = z / sigma
            q2 = q * q
            if q2 > -2.0 * _EXP_FLOOR:
                g = math.exp(-0.5 * q2)
            else:
                g = mantissa[j] * scale[j]
            lane = j % _LANES
            acc0[lane] += g
            acc1[lane] += g * z * db
            acc2[lane] += g * (db * db) * (1.0 - q2)
        row0 = 0.0
        row1 = 0.0
        row2 = 0.0
        for lane in range(_LANES):
            row0 += acc0[lane]
            row1 += acc1[lane]
            row2 += acc2[lane]
        total0 += row0
        total1 += row1
        total2 += row2
    c = 1.0 / (_SQRT_2PI * sigma)
    n2 = float(n) * float(n)
    V = (float(n) + 2.0 * total0) * c / n2
    dV = 2.0 * total1 * c / (n2 * sigma * sigma)
    d2V = -2.0 * total2 * c / (n2 * sigma * sigma)
    return V, dV, d2V


@njit(cache=True, nogil=True, error_model="numpy")
def renyi_quadratic(a, b, gain, s):
    """H₂ = −ln V and its first two derivatives in U; the compiled :func:`~mosd.estimators.entropy_filter.renyi_quadratic`."""
    V, dV, d2V = information_potential(a, b, gain, s)
    return -math.log(V), -dV / V, -(d2V * V - dV * dV) / (V * V)


@njit(cache=True, nogil=True, error_model="numpy")
def cost(a1, b1, a2, b2, gain, s1, s2, R1, R2):
    """J = R₂ H₂(e²) − R₁ H₂(e¹) and its first two derivatives in U; the compiled :meth:`EntropyIsolationFilter.cost`."""
    H1, dH1, d2H1 = renyi_quadratic(a1, b1, gain, s1)
    H2, dH2, d2H2 = renyi_quadratic(a2, b2, gain, s2)
    return R2 * H2 - R1 * H1, R2 * dH2 - R1 * dH1, R2 * d2H2 - R1 * d2H1


def warm_up() -> None:
    """Load (or compile) the kernels for float64 particles."""
    a = np.linspace(-1.0, 1.0, 4)
    information_potential(a, a, 0.5, 0.1)
    cost(a, a, a, a, 0.5, 0.1, 0.1, 1.0, 20.0)
