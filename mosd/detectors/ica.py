"""ICA monitoring (Lee, Yoo & Lee 2004, J. Process Control 14, 467–485): I², I²ₑ and SPE with their limits.

The residual generator is :class:`ICAModel`: the calibration rows are
standardised (mean and standard deviation, ddof = 1, as PCA) and unmixed by
scikit-learn's ``FastICA`` (whitening to unit variance, as many independent
components r as variables, ``random_state`` the detector's seed). Its unmixing
matrix W (r, m) and mixing matrix A = W⁺ (m, r) are kept as arrays; the rows of
W are ordered by their Euclidean norm, largest first (Lee et al.'s ordering of
the components by how much of the data they carry), and the first a are the
dominant ones. For a standardised row z (centred by FastICA's mean):

    ŝ = W z,   ŝ_d = (ŝ_1 … ŝ_a),   ŝ_e = (ŝ_{a+1} … ŝ_r)
    I² = ŝ_dᵀ ŝ_d                  (dominant part)
    I²ₑ = ŝ_eᵀ ŝ_e                 (excluded part)
    SPE = ‖z − A_d ŝ_d‖²           (what the dominant components leave unexplained)

(with unit-variance sources A_d = Q⁻¹ B_d, the paper's reconstruction). The
sources are not Gaussian, so there is no theoretical limit: each limit is the
empirical (1 − α) quantile of its statistic on the held-back calibration runs
(Lee et al. use a kernel density estimate of the same quantile).
"""
from __future__ import annotations

import warnings

import numpy as np

from ._nonlinear import finite_rows, require, standardisation
from .pca import _one_blas_thread, project

STATISTICS = ("combined", "i2", "i2e", "spe")


class ICAModel:
    """Standardisation and FastICA unmixing of fault-free rows, components ordered by ‖W_i‖ (module docstring).

    Parameters
    ----------
    X : ndarray, shape (..., m)
        Calibration rows; rows with a non-finite value are left out.
    seed : int
        FastICA's ``random_state`` (its initial unmixing matrix).
    max_iter, tol : int, float
        FastICA's iteration budget and tolerance.
    names : sequence of str, optional
        Variable names (for messages).

    Attributes
    ----------
    center, scale : ndarray (m,)
        z = (x − center) / scale: the standardisation with FastICA's (near-zero) mean folded in.
    unmixing : ndarray (r, m)
        W, rows ordered by Euclidean norm, largest first.
    mixing : ndarray (m, r)
        A, the columns in the same order.
    converged : bool
        False when FastICA stopped at ``max_iter`` (scikit-learn's ConvergenceWarning).
    """

    def __init__(self, X: np.ndarray, seed: int = 0, max_iter: int = 1000, tol: float = 1e-4, names=None):
        require("sklearn", "ica")
        from sklearn.decomposition import FastICA
        from sklearn.exceptions import ConvergenceWarning

        mean, scale, Z = standardisation(X, names, 3, "ICA")
        self.n, self.m = Z.shape
        ica = FastICA(n_components=min(self.n - 1, self.m), whiten="unit-variance", random_state=int(seed),
                      max_iter=int(max_iter), tol=float(tol))
        with warnings.catch_warnings(record=True) as caught, _one_blas_thread():
            warnings.simplefilter("always", ConvergenceWarning)
            ica.fit(Z)
        self.converged = not any(issubclass(w.category, ConvergenceWarning) for w in caught)
        W, A = np.asarray(ica.components_, float), np.asarray(ica.mixing_, float)
        order = np.argsort(-np.linalg.norm(W, axis=1), kind="stable")
        # a deterministic sign (largest weight positive): I², I²ₑ and SPE do not depend on it
        signs = np.sign(W[order, np.argmax(np.abs(W[order]), axis=1)])
        self.unmixing = W[order] * signs[:, None]
        self.mixing = A[:, order] * signs
        self.center = mean + scale * np.asarray(ica.mean_, float)
        self.scale = scale

    @property
    def r(self) -> int:
        return self.unmixing.shape[0]

    def sources(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(z, ŝ, finite): the centred standardised rows (..., m), their sources ŝ = W z (..., r) (0 in a row
        with a missing value) and which rows are complete."""
        Z, finite = finite_rows(X, self.center, self.scale)
        return Z, project(Z, self.unmixing.T), finite

    def statistics(self, X: np.ndarray, components: int | None = None) -> dict[str, np.ndarray]:
        """I², I²ₑ and SPE of the rows X (..., m) with a = 1..r dominant components at index a − 1 (..., r), or
        with ``components`` only (..., 1); NaN in a row with a missing value.

        I² and I²ₑ are cumulative sums of ŝ_j² (from the first component and from the last); SPE subtracts
        one dominant component's share A_j ŝ_j at a time, so every a is the same arithmetic.
        """
        Z, s, finite = self.sources(X)
        squares = s**2
        i2 = np.cumsum(squares, axis=-1)
        tail = np.cumsum(squares[..., ::-1], axis=-1)[..., ::-1]
        i2e = np.concatenate([tail[..., 1:], np.zeros(s.shape[:-1] + (1,))], axis=-1)
        top = self.r if components is None else int(components)
        residual = Z.copy()
        spe = np.empty(s.shape[:-1] + (top,))
        for j in range(top):
            residual -= s[..., j:j + 1] * self.mixing[:, j]
            spe[..., j] = np.sum(residual**2, axis=-1)
        if components is not None:
            a = int(components)
            i2, i2e, spe = i2[..., a - 1:a], i2e[..., a - 1:a], spe[..., a - 1:a]
        nan = ~finite[..., None]
        return {name: np.where(nan, np.nan, value) for name, value in (("i2", i2), ("i2e", i2e), ("spe", spe))}
