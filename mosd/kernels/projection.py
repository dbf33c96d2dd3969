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


def warm_up() -> None:
    """Load (or compile) the kernel."""
    project(np.zeros((2, 3)), np.zeros((3, 2)))
