"""Paper 002's information potential and entropy cost (:mod:`mosd.estimators.entropy_filter`), compiled.

The NumPy reference :func:`mosd.estimators.entropy_filter.information_potential`
forms (N, N) arrays of the pairwise differences z_ij = Δa_ij − U Δb_ij and of the
Gaussians G_σ(z_ij), then sums them. Here one pass over the pairs accumulates the
three sums and allocates nothing. It visits each unordered pair once: z and Δb
are antisymmetric in (i, j), so G, G·z·Δb and G·Δb²·(1 − z²/σ²) are symmetric;
the diagonal (z = Δb = 0) adds G_σ(0) to V and nothing to V′ and V″. Half the
exponentials of the reference, no memory traffic.

Not bit-identical: the reference sums N² terms with NumPy's pairwise summation,
this kernel sums each row i's terms j > i and then the row sums, and factors the
constant 1/(√(2π) σ) out of the sums. V agrees to ~1e-15 relative; V′ and V″ are
sums of terms of both signs, so their agreement is ~1e-15 of Σ|terms| (the
rounding of either order), which is relative to V′ itself unless V′ cancels to
near zero (``tests/test_kernel_entropy.py``).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

_SQRT_2PI = math.sqrt(2.0 * math.pi)


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
    total0 = 0.0  # Σ_{i<j} G/c, with c = 1/(√(2π) σ) factored out
    total1 = 0.0  # Σ_{i<j} G z Δb / c
    total2 = 0.0  # Σ_{i<j} G Δb² (1 − z²/σ²) / c
    for i in range(n):
        ai = a[i]
        bi = b[i]
        # one accumulator per row: the long outer sum adds N partial sums, not N²/2 terms
        row0 = 0.0
        row1 = 0.0
        row2 = 0.0
        for j in range(i + 1, n):
            db = bi - b[j]
            z = (ai - a[j]) - gain * db
            q = z / sigma
            q2 = q * q
            g = math.exp(-0.5 * q2)
            row0 += g
            row1 += g * z * db
            row2 += g * (db * db) * (1.0 - q2)
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
