"""Kernel PCA monitoring (Lee, Yoo, Choi, Vanrolleghem & Lee 2004, Chem. Eng. Sci. 59, 223–234): T² and SPE
in the feature space of a Gaussian (RBF) kernel.

The residual generator is :class:`KPCAModel`: the n calibration rows are
standardised (ddof = 1, as PCA) and decomposed by scikit-learn's ``KernelPCA``
with k(x, y) = exp(−‖x − y‖² / c), c = w·m (Lee et al.'s c = r m σ² with σ² = 1
after standardisation; the width w is tunable). The centred kernel matrix
K̃ = K − 1ₙK − K1ₙ + 1ₙK1ₙ has eigenvalues nλ_j and unit eigenvectors v_j;
α_j = v_j / √(nλ_j) are the normalised coefficients. For a row x, with
k_i = k(x_i, x) and the centring terms of the fit rows (column means k̄_i of K and
its grand mean k̄):

    k̃_i = k_i − mean(k) − k̄_i + k̄,   t_j = Σ_i α_ij k̃_i        (scores)
    T² = Σ_{j≤a} t_j² / λ_j                                      (Hotelling in feature space)
    SPE = ‖Φ̃(x)‖² − Σ_{j≤a} t_j²,   ‖Φ̃(x)‖² = k(x, x) − 2 mean(k) + k̄

The SPE is the squared distance of the centred feature vector from the span of
the first a components. Lee et al. write it as Σ_{j≤N} t_j² − Σ_{j≤a} t_j² over
all N non-zero components: the same number on the fit rows, but for a new row
their sum leaves out the part of Φ̃(x) outside the fit rows' span, which grows as
x moves away from them (a row far from every fit row has k ≈ 0, hence scores
near those of the mean and their SPE near zero, while ‖Φ̃(x)‖² → 1 + k̄).

Limits at level α: T²_α of the F distribution (:func:`mosd.detectors.pca.t2_limit`)
and SPE_α = g χ²_h(α) with g = b / (2a), h = 2a² / b, a and b the mean and
variance of the SPE on the fit rows (Lee et al.; Nomikos & MacGregor 1995); or the
empirical (1 − α) quantiles on held-back calibration runs.

The served model keeps the arrays (fit rows, α, λ, k̄_i, k̄, c) and scores with
NumPy: no scikit-learn object is saved.
"""
from __future__ import annotations

import numpy as np
from scipy import special

from ._nonlinear import finite_rows, require, standardisation
from .pca import _one_blas_thread, project

STATISTICS = ("combined", "t2", "spe")


def rbf(X: np.ndarray, rows: np.ndarray, width: float) -> np.ndarray:
    """k(x, x_i) = exp(−‖x − x_i‖² / width) of every row of X (p, m) against ``rows`` (n, m), shape (p, n).

    SciPy's ``cdist`` computes each distance from its two rows alone, so a row's kernel is the same
    whatever else is scored with it (the deployed model scores in blocks).
    """
    from scipy.spatial.distance import cdist

    return np.exp(-cdist(np.asarray(X, float), rows, "sqeuclidean") / width)


def spe_moment_limit(values: np.ndarray, alpha: float) -> float:
    """g χ²_h(α) with g = b / (2a), h = 2a² / b from the mean a and variance b (ddof = 1) of ``values``."""
    values = np.asarray(values, float)
    values = values[np.isfinite(values)]
    a, b = float(np.mean(values)), float(np.var(values, ddof=1))
    if not b > 0.0:
        return a
    return b / (2.0 * a) * float(special.chdtri(2.0 * a * a / b, alpha))


class KPCAModel:
    """Standardisation and RBF kernel PCA of fault-free rows (module docstring).

    Parameters
    ----------
    X : ndarray, shape (..., m)
        Calibration rows; rows with a non-finite value are left out.
    width : float
        w > 0: the kernel's c = w·m.
    max_components : int
        Components kept (at most n − 1); T² and SPE with a ≤ this many.
    names : sequence of str, optional
        Variable names (for messages).
    """

    def __init__(self, X: np.ndarray, width: float = 10.0, max_components: int = 20, names=None):
        require("sklearn", "kpca")
        from sklearn.decomposition import KernelPCA

        self.mean, self.scale, Z = standardisation(X, names, 3, "kernel PCA")
        self.n, self.m = Z.shape
        self.c = float(width) * self.m
        # dense: a deterministic eigendecomposition (arpack starts from a random vector)
        kpca = KernelPCA(n_components=min(int(max_components), self.n - 1), kernel="rbf", gamma=1.0 / self.c,
                         eigen_solver="dense")
        with _one_blas_thread():
            kpca.fit(Z)
        eig = np.asarray(kpca.eigenvalues_, float)
        keep = eig > eig[0] * 1e-12 if eig.size else eig.astype(bool)  # components with variance
        self.rows = Z
        self.alphas = np.asarray(kpca.eigenvectors_, float)[:, keep] / np.sqrt(eig[keep])
        self.eigenvalues = eig[keep] / self.n  # λ_j: the variance of t_j over the fit rows
        K = rbf(Z, Z, self.c)
        self.column_means = K.mean(axis=0)
        self.grand_mean = float(self.column_means.mean())

    @property
    def r(self) -> int:
        return self.alphas.shape[1]

    def scores(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(t, ‖Φ̃(x)‖², finite) of the rows X (..., m): scores (..., r), the centred feature vector's squared
        norm (...) and which rows are complete (0 in a row with a missing value)."""
        Z, finite = finite_rows(X, self.mean, self.scale)
        flat = Z.reshape(-1, self.m)
        k = rbf(flat, self.rows, self.c)
        k_mean = k.mean(axis=1)
        centred = k - k_mean[:, None] - self.column_means + self.grand_mean
        t = project(centred, self.alphas)
        norm = 1.0 - 2.0 * k_mean + self.grand_mean
        shape = Z.shape[:-1]
        return t.reshape(shape + (self.r,)), norm.reshape(shape), finite

    def statistics(self, X: np.ndarray, components: int | None = None) -> dict[str, np.ndarray]:
        """T² and SPE of the rows X (..., m) with a = 1..r components at index a − 1 (..., r), or with
        ``components`` only (..., 1); NaN in a row with a missing value."""
        t, norm, finite = self.scores(X)
        squares = t**2
        explained = np.cumsum(squares, axis=-1)
        t2 = np.cumsum(squares / self.eigenvalues, axis=-1)
        spe = np.maximum(norm[..., None] - explained, 0.0)
        if components is not None:
            a = int(components)
            t2, spe = t2[..., a - 1:a], spe[..., a - 1:a]
        nan = ~finite[..., None]
        return {"t2": np.where(nan, np.nan, t2), "spe": np.where(nan, np.nan, spe)}
