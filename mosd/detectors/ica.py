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
from typing import Mapping

import numpy as np

from ..validation import ConfigError, Interval, Param
from ._nonlinear import finite_rows, require, standardisation
from .latent import LatentDetector, latent_params
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
    mean, scale, ica_mean : ndarray (m,)
        z = (x − mean) / scale − ica_mean: the standardisation, then FastICA's (near-zero) centring.
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
        self.max_iter, self.tol = int(max_iter), float(tol)
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
        self.mean, self.scale, self.ica_mean = mean, scale, np.asarray(ica.mean_, float)

    def fitted(self) -> dict:
        """The arrays the statistics need (:func:`ica_statistics`): what the served model saves."""
        return {"mean": self.mean, "scale": self.scale, "ica_mean": self.ica_mean, "unmixing": self.unmixing,
                "mixing": self.mixing, "converged": int(self.converged)}

    @property
    def r(self) -> int:
        return self.unmixing.shape[0]

    def sources(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(z, ŝ, finite): the centred standardised rows (..., m), their sources ŝ = W z (..., r) (0 in a row
        with a missing value) and which rows are complete."""
        Z, finite = finite_rows(X, self.mean, self.scale)
        Z = np.where(finite[..., None], Z - self.ica_mean, 0.0)
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


def ica_statistics(fitted: Mapping, X: np.ndarray, a: int) -> dict[str, np.ndarray]:
    """I², I²ₑ and SPE with a dominant components of the rows X (..., m), each (...), from the saved arrays of
    :meth:`ICAModel.fitted` (NumPy only: what the served model runs)."""
    model = ICAModel.__new__(ICAModel)
    model.mean, model.scale, model.ica_mean = (np.asarray(fitted[k], float) for k in ("mean", "scale", "ica_mean"))
    model.unmixing, mixing = np.asarray(fitted["unmixing"], float), np.asarray(fitted["mixing"], float)
    Z, s, finite = model.sources(X)
    squares = s**2
    residual = Z.copy()
    for j in range(a):  # one dominant component's share A_j ŝ_j at a time (the order of ICAModel.statistics)
        residual -= s[..., j:j + 1] * mixing[:, j]
    values = {"i2": np.sum(squares[..., :a], axis=-1), "i2e": np.sum(squares[..., a:], axis=-1),
              "spe": np.sum(residual**2, axis=-1)}
    return {name: np.where(finite, value, np.nan) for name, value in values.items()}


class ICADetector(LatentDetector):
    """ICA I², I²ₑ and SPE monitoring with tunable dominant components, α, EWMA λ and persistence (module docstring).

    The FastICA fit does not depend on the tuned component count: one fit serves every design. Every limit is
    empirical (the family has no theoretical one), whatever ``limits`` says.
    """

    STATISTICS = ("i2", "i2e", "spe")
    fit_keys = ("seed", "max_iter", "tol")
    params = latent_params({
        "max_components": Param(Interval(1, 10_000, integer=True), "Upper end of n_components' range (below the "
                                "number of variables)."),
        "n_components": Param(Interval(1, "max_components", integer=True), "Dominant independent components a "
                              "(ordered by the norm of their unmixing row).", tunable=True),
        "seed": Param(Interval(0, 2**32 - 1, integer=True), "FastICA's random_state (its initial unmixing "
                      "matrix): the run's root seed in conf/detector/ica.yaml."),
        "max_iter": Param(Interval(1, 1_000_000, integer=True), "FastICA's iteration budget."),
        "tol": Param(Interval(0.0, 1.0, open_low=True), "FastICA's convergence tolerance."),
    }, STATISTICS)

    def __init__(self, n_components: int = 9, alpha: float = 0.01, lam: float = 1.0, persistence: int = 1,
                 statistic: str = "combined", limits: str = "empirical", fit_runs: int | None = None,
                 max_components: int = 20,
                 persistence_max: int = 10, lam_min: float = 0.0,
                 flatline: float | None = None, seed: int = 0, max_iter: int = 1000,
                 tol: float = 1e-4):
        self._assign(locals())
        self._cache = {}

    def data_bounds(self, calibration_z: np.ndarray) -> dict[str, tuple[float, float]]:
        """λ's floor and a ≤ min(m, N) − 1 dominant components: FastICA whitens N complete fit rows of m variables
        into min(m, N) components, and I²ₑ keeps at least one."""
        fit = np.asarray(self.fit_rows(calibration_z), float)
        return {**super().data_bounds(calibration_z),
                "n_components": (1, min(fit.shape[-1], self.complete_count(fit)) - 1)}

    def fit(self, X: np.ndarray, design: Mapping) -> dict:
        model = ICAModel(X, seed=int(design["seed"]), max_iter=int(design["max_iter"]), tol=float(design["tol"]))
        if not model.converged:
            # seen on TE's 33 variables (nearly Gaussian directions): the last iterate is still an unmixing
            # whose I², I²ₑ and SPE are scored and limited empirically, so this is a warning, not an error
            warnings.warn(f"detector=ica: FastICA did not converge in detector.max_iter={model.max_iter} iterations "
                          f"(detector.tol={model.tol:g}); the statistics use its last unmixing matrix", stacklevel=2)
        return model.fitted()

    def score(self, fitted: Mapping, X: np.ndarray, design: Mapping, carried: Mapping | None = None):
        r = np.shape(fitted["unmixing"])[0]
        a = int(design["n_components"])
        if not 1 <= a <= r - 1:
            raise ConfigError(f"detector.n_components={a} is out of range for {r} independent components; "
                              f"allowed: integers in [1, {r - 1}]")
        return ica_statistics(fitted, X, a), {}
