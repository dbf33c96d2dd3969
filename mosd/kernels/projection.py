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
def scores(X, mean, scale, loadings, eigenvalues, a, k):
    """T²(a), SPE(a), completeness and the k largest contributions to each, per row of X (n, m): one pass per row.

    T² and SPE are the same numbers, bit for bit, as standardising, :func:`project` and the component-major
    sums of ``mosd.detectors.pca._Projected.of(..., components=a)``: T² = Σ_{j<a} t_j²/λ_j from the first
    component up, SPE = Σ_{j≥a} t_j² from the last component down (loadings with a column per variable,
    so nothing lies outside their span); NaN where a value is missing. The deployed PCA scores a stream
    with it without the (n, m) and (n, r) intermediates of the array form.

    ``top_t2``/``top_spe`` (n, k) hold the variables with the k largest contributions, largest first (the
    first variable wins a tie): T² c_i = z_i Σ_{j<a} P_ij t_j/λ_j, SPE c_i = (z_i − Σ_{j<a} P_ij t_j)²
    (``PCAModel.contributions``), each from the row's own numbers in a fixed order, so a chunk of any size
    ranks alike. Rows with a missing value get 0, 1, …, k−1 (they are not scored). k = 0 ranks nothing.
    """
    n, m = X.shape
    r = loadings.shape[1]
    t2 = np.empty(n)
    spe = np.empty(n)
    complete_rows = np.empty(n, np.bool_)
    top_t2 = np.empty((n, k), np.int64)
    top_spe = np.empty((n, k), np.int64)
    z = np.empty(m)
    t = np.empty(r)
    scaled = np.empty(max(a, 1))
    back = np.empty(m)
    c_t2 = np.empty(m)
    c_spe = np.empty(m)
    fitted = np.empty(m)
    leading = np.ascontiguousarray(loadings[:, :a].T) if k > 0 else np.empty((0, m))
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
            for j in range(k):
                top_t2[row, j] = j
                top_spe[row, j] = j
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
        if k == 0:
            continue
        for j in range(a):
            scaled[j] = t[j] / eigenvalues[j]
        # back = Pₐ (t/λ)ₐ and fitted = Pₐ tₐ, summed over j in order from 0, vectorised along the variables
        for i in range(m):
            back[i] = 0.0
            fitted[i] = 0.0
        for j in range(a):
            weights = leading[j]
            sj = scaled[j]
            tj = t[j]
            for i in range(m):
                back[i] += weights[i] * sj
                fitted[i] += weights[i] * tj
        for i in range(m):
            residual = z[i] - fitted[i]
            c_t2[i] = z[i] * back[i]
            c_spe[i] = residual * residual
        # k passes of argmax: only a strictly larger value takes the lead, so the lower index wins a tie,
        # as repeated np.argmax ranks
        for j in range(k):
            lead_t2, lead_spe = 0, 0
            best_t2, best_spe = c_t2[0], c_spe[0]
            for i in range(1, m):
                if c_t2[i] > best_t2:
                    best_t2, lead_t2 = c_t2[i], i
                if c_spe[i] > best_spe:
                    best_spe, lead_spe = c_spe[i], i
            top_t2[row, j], top_spe[row, j] = lead_t2, lead_spe
            c_t2[lead_t2], c_spe[lead_spe] = -np.inf, -np.inf
    return t2, spe, complete_rows, top_t2, top_spe


def warm_up() -> None:
    """Load (or compile) the kernels."""
    project(np.zeros((2, 3)), np.zeros((3, 2)))
    scores(np.zeros((2, 3)), np.zeros(3), np.ones(3), np.eye(3), np.ones(3), 1, 2)
