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

Limits at level α: T²_α of the F distribution (:func:`mosd.detectors.pca.t2_limit`, PCA's
new-observation form a(n² − 1)/(n(n − a)) F; Lee et al. write a(n − 1)/(n − a) F, (n + 1)/n smaller)
and SPE_α = g χ²_h(α) with g = b / (2a), h = 2a² / b, a and b the mean and
variance of the SPE on the fit rows (Lee et al.; Nomikos & MacGregor 1995); or the
empirical (1 − α) quantiles on held-back calibration runs.

The served model keeps the arrays (fit rows, α, λ, k̄_i, k̄, c) and scores with
NumPy: no scikit-learn object is saved.
"""
from __future__ import annotations

from typing import Mapping

import numpy as np
from scipy import special

from ..validation import ConfigError, Interval, Param
from ._nonlinear import finite_rows, require, standardisation
from .latent import LatentDetector, latent_params
from .pca import _one_blas_thread, project, t2_limit

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
    return moment_limit(float(np.mean(values)), float(np.var(values, ddof=1)), alpha)


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

        # the SPE's mean and variance on the fit rows for every a: its g χ²_h limit (spe_moment_limit)
        fit_spe = self.statistics(Z * self.scale + self.mean)["spe"]
        self.spe_mean, self.spe_var = fit_spe.mean(axis=0), fit_spe.var(axis=0, ddof=1)

    @property
    def r(self) -> int:
        return self.alphas.shape[1]

    def fitted(self) -> dict:
        """The arrays the statistics and limits need: what the served model saves."""
        return {"mean": self.mean, "scale": self.scale, "rows": self.rows, "alphas": self.alphas,
                "eigenvalues": self.eigenvalues, "column_means": self.column_means, "grand_mean": self.grand_mean,
                "c": self.c, "n": self.n, "spe_mean": self.spe_mean, "spe_var": self.spe_var}

    @classmethod
    def from_fitted(cls, fitted: Mapping) -> "KPCAModel":
        """The model of saved arrays (no refit, no scikit-learn)."""
        model = cls.__new__(cls)
        for name, value in fitted.items():
            setattr(model, name, np.asarray(value, float) if np.ndim(value) else value)
        model.m = len(model.mean)
        return model

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


def moment_limit(mean: float, variance: float, alpha: float) -> float:
    """g χ²_h(α), g = b / (2a), h = 2a² / b, from a statistic's mean a and variance b (a when b is 0)."""
    if not variance > 0.0:
        return float(mean)
    return variance / (2.0 * mean) * float(special.chdtri(2.0 * mean * mean / variance, alpha))


class KernelPCADetector(LatentDetector):
    """Kernel PCA T² and SPE monitoring with tunable kernel width, components, α, EWMA λ and persistence
    (module docstring).

    One kernel PCA per width serves every component count; the kernel rows of a data set are computed once
    per width (the scores of every component are kept, a design takes its first a).
    """

    STATISTICS = ("t2", "spe")
    fit_keys = ("width", "max_components")
    params = latent_params({
        "max_components": Param(Interval(1, 10_000, integer=True), "Upper end of n_components' range (below the "
                                "number of fit rows)."),
        "width_max": Param(Interval(1, 1_000_000, integer=True), "Upper end of the width's range."),
        "n_components": Param(Interval(1, "max_components", integer=True), "Kernel principal components a.",
                              tunable=True),
        "width": Param(Interval(1, "width_max", integer=True), "Kernel width w: k(x, y) = exp(−‖x − y‖² / (w m)) "
                       "on the standardised rows (Lee et al. 2004's c = r m σ², r = w).", tunable=True),
    }, STATISTICS)

    def __init__(self, n_components: int = 9, width: int = 10, alpha: float = 0.01, lam: float = 1.0,
                 persistence: int = 1, statistic: str = "combined", limits: str = "theoretical",
                 fit_runs: int | None = None, max_components: int = 20, width_max: int = 1000,
                 persistence_max: int = 10, lam_min: float = 0.0, flatline: float | None = None):
        self._assign(locals())
        self._cache = {}

    def data_bounds(self, calibration_z: np.ndarray) -> dict[str, tuple[float, float]]:
        """λ's floor and a ≤ N − 1 kernel components of N complete fit rows (the centred kernel matrix's rank)."""
        fit = np.asarray(self.fit_rows(calibration_z), float)
        return {**super().data_bounds(calibration_z), "n_components": (1, self.complete_count(fit) - 1)}

    def fit(self, X: np.ndarray, design: Mapping) -> dict:
        return KPCAModel(X, width=float(design["width"]), max_components=int(design["max_components"])).fitted()

    def _all_components(self, fitted: Mapping, X: np.ndarray) -> dict:
        """T² and SPE of every a (…, r) of the rows X: the kernel rows once per fit and data set, while both live."""
        def make():
            with _one_blas_thread():
                return KPCAModel.from_fitted(fitted).statistics(X)

        kept = self.__dict__.setdefault("_kernel_scores", {})
        key = (id(fitted), id(X))
        hit = kept.get(key)
        if hit is None or hit[0] is not fitted or hit[1] is not X:
            if len(kept) >= 8:  # a tuning scores the fit, held-back and tuning rows of a few widths at a time
                kept.pop(next(iter(kept)))
            hit = kept[key] = (fitted, X, make())
        return hit[2]

    def __getstate__(self):
        state = super().__getstate__()
        state.pop("_kernel_scores", None)
        return state

    def population(self, calibration_features: np.ndarray, features: np.ndarray, X: np.ndarray):
        """The base's population with the designs taken width by width (each design's decisions are its own, so
        the order changes no bit): the kernel rows of one width are then computed once, not once per design."""
        X = np.atleast_2d(np.asarray(X, float))
        width = self.tunable["width"].round(X[:, list(self.tunable).index("width")], clip=True)
        order = np.argsort(width, kind="stable")
        decided = super().population(calibration_features, features, X[order])
        back = np.argsort(order)
        return decided[back]

    def score(self, fitted: Mapping, X: np.ndarray, design: Mapping, carried: Mapping | None = None):
        r = np.shape(fitted["alphas"])[1]
        a = int(design["n_components"])
        if not 1 <= a <= r:
            raise ConfigError(f"detector.n_components={a} is out of range for {r} kernel components "
                              f"(detector.max_components={design['max_components']}, {int(fitted['n'])} fit rows); "
                              f"allowed: integers in [1, {r}]")
        # the served model scores each block once: no cache there
        every = (self._all_components(fitted, X) if np.size(X) > 4096
                 else KPCAModel.from_fitted(fitted).statistics(X))
        return {name: value[..., a - 1] for name, value in every.items()}, {}

    def limit(self, fitted: Mapping, name: str, alpha: float, design: Mapping) -> float | None:
        a = int(design["n_components"])
        if name == "t2":
            return t2_limit(int(fitted["n"]), a, alpha)
        return moment_limit(float(fitted["spe_mean"][a - 1]), float(fitted["spe_var"][a - 1]), alpha)
