"""The PCA projection t = z P, compiled, with an order of operations that does not depend on the row count.

A BLAS product picks its kernel by the matrix sizes (a one-row product is a different routine from a
block of rows), so the last bits of a score can depend on how many rows were scored together. Here every
score is t_j = Σ_i z_i P_ij summed over i in order, whatever the rows: a series scored in one call, in
chunks or row by row gives the same bits (the deployed model's promise), and the tuning scores its
population with the same numbers.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from . import configure_compiler

configure_compiler()  # before this module's first compile


@njit(cache=True, nogil=True)
def project(Z, loadings):
    """t (n, r) = Z (n, m) @ loadings (m, r), each element summed over m in order from 0."""
    n, m = Z.shape
    r = loadings.shape[1]
    out = np.zeros((n, r))
    for row in range(n):
        acc = out[row]
        z = Z[row]
        for i in range(m):
            zi = z[i]
            weights = loadings[i]
            for j in range(r):
                acc[j] += zi * weights[j]
    return out


@njit(cache=True, nogil=True)
def t2_spe(X, mean, scale, loadings, eigenvalues, a):
    """T²(a), SPE(a) and completeness of each row of X (n, m), NaN where a value is missing: one pass per row.

    The same numbers, bit for bit, as standardising, :func:`project` and the component-major sums of
    ``mosd.detectors.pca._Projected.of(..., components=a)``: T² = Σ_{j<a} t_j²/λ_j from the first
    component up, SPE = Σ_{j≥a} t_j² from the last component down (loadings with a column per variable,
    so nothing lies outside their span). The deployed PCA scores a stream with it without the (n, m)
    and (n, r) intermediates of the array form.
    """
    n, m = X.shape
    r = loadings.shape[1]
    t2 = np.empty(n)
    spe = np.empty(n)
    complete_rows = np.empty(n, np.bool_)
    z = np.empty(m)
    t = np.empty(r)
    for row in range(n):
        x = X[row]
        complete = True
        for i in range(m):
            if not np.isfinite(x[i]):
                complete = False
        complete_rows[row] = complete
        if not complete:
            t2[row] = np.nan
            spe[row] = np.nan
            continue
        for i in range(m):
            z[i] = (x[i] - mean[i]) / scale[i]
        for j in range(r):
            t[j] = 0.0
        for i in range(m):
            zi = z[i]
            weights = loadings[i]
            for j in range(r):
                t[j] += zi * weights[j]
        total = (t[0] * t[0]) / eigenvalues[0]
        for j in range(1, a):
            total += (t[j] * t[j]) / eigenvalues[j]
        t2[row] = total
        tail = 0.0
        if a < r:
            tail = t[r - 1] * t[r - 1]
            for j in range(r - 2, a - 1, -1):
                tail += t[j] * t[j]
        spe[row] = tail + 0.0
    return t2, spe, complete_rows


def warm_up() -> None:
    """Load (or compile) the kernels."""
    project(np.zeros((2, 3)), np.zeros((3, 2)))
    t2_spe(np.zeros((2, 3)), np.zeros(3), np.ones(3), np.eye(3), np.ones(3), 1)
