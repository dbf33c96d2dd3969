"""PCA monitoring: Hotelling's T² and the squared prediction error (SPE, Q) with their limits.

The residual generator is :class:`PCAModel`: the calibration rows are
standardised (mean and standard deviation with ddof = 1) and decomposed by
SciPy's SVD, Z = U S Vᵀ, so that the loadings are P = V and the eigenvalues of
the correlation matrix λ_j = s_j² / (n − 1). For a standardised row z and a
components, with scores t = Pₐᵀ z:

    T² = tᵀ Λₐ⁻¹ t = Σ_{j≤a} t_j² / λ_j                   (Hotelling)
    SPE = ‖(I − Pₐ Pₐᵀ) z‖² = Σ_{j>a} t_j² (+ the part outside the rows' span)

Limits at level α (as in Yin et al. 2012, J. Process Control 22; Jackson & Mudholkar 1979 for SPE):

    T²_α = a (n² − 1) / (n (n − a)) · F_α(a, n − a)
    SPE_α = θ₁ [c_α √(2 θ₂ h₀²) / θ₁ + 1 + θ₂ h₀ (h₀ − 1) / θ₁²]^(1/h₀)     (Jackson–Mudholkar)

with θ_i = Σ_{j>a} λ_jⁱ, h₀ = 1 − 2 θ₁ θ₃ / (3 θ₂²) and c_α the standard normal
(1 − α) quantile; or the empirical (1 − α) quantile of the statistic on
held-back fault-free data. The combined rule alarms when T² or SPE is above
its limit.

:class:`PCADetector` makes this a tunable detector for any monitor whose points
z (R, K, m) are the variables to monitor (recorded signals, or any estimator's
residual channels): n_components (integer), α, an EWMA λ on both statistics
(λ < 1 breaks the theoretical limits, so they are then recalibrated on the
held-back calibration runs) and a persistence (integer).
"""
from __future__ import annotations

import copy
import math
from dataclasses import dataclass

import numpy as np
from scipy import linalg, special

from ..streaming import LEGACY_STAGES
from ..validation import ConfigError, Interval, Param
from .latent import LIMITS, LatentDetector, empirical_limit, ewma_from, latent_params, point_names  # noqa: F401 (re-exported)
from .latent import flat_statistic
from .pca_rows import TOP, top_indices, top_labels

#: rows scored per block by the NumPy path of :func:`stream_scores` (the (block, m) intermediates stay in cache)
BLOCK = 2048

STATISTICS = ("combined", "t2", "spe")


class PCAModel:
    """Standardisation and principal components of fault-free rows (module docstring).

    Parameters
    ----------
    X : ndarray, shape (n, m)
        Calibration rows; rows with a non-finite value are left out.
    names : sequence of str, optional
        Variable names (for contributions and messages).
    """

    def __init__(self, X: np.ndarray, names=None):
        X = np.asarray(X, float).reshape(-1, np.shape(X)[-1])
        X = X[np.all(np.isfinite(X), axis=1)]
        n, m = X.shape
        self.names = tuple(names) if names is not None else tuple(f"x{i + 1}" for i in range(m))
        if n < 3:
            raise ConfigError(f"the PCA calibration has {n} complete rows; allowed: at least 3")
        self.n, self.m = n, m
        self.mean = X.mean(axis=0)
        self.scale = X.std(axis=0, ddof=1)
        flat = np.flatnonzero(~(self.scale > 1e-12 * np.maximum(1.0, np.abs(self.mean))))
        if flat.size:
            raise ConfigError(f"variable {self.names[flat[0]]} is constant over the PCA calibration rows; "
                              "allowed: variables that vary (drop constant columns)")
        Z = (X - self.mean) / self.scale
        with _one_blas_thread():
            _, s, vt = linalg.svd(Z, full_matrices=False, lapack_driver="gesdd")
        # a deterministic sign (largest loading positive): T² and SPE do not depend on it, the scores do
        signs = np.sign(vt[np.arange(vt.shape[0]), np.argmax(np.abs(vt), axis=1)])
        self.loadings = (vt * signs[:, None]).T          # (m, r), r = min(n, m)
        self.eigenvalues = s**2 / (n - 1)                # (r,)

    # -- one row at a time or many: every method takes (..., m) -------------------------------
    def standardise(self, X: np.ndarray) -> np.ndarray:
        return (np.asarray(X, float) - self.mean) / self.scale

    def scores(self, X: np.ndarray, standardised: bool = False) -> np.ndarray:
        """t = Pᵀ z on every component, shape (..., r)."""
        Z = np.asarray(X, float) if standardised else self.standardise(X)
        return Z @ self.loadings

    def check_components(self, a: int, key: str = "detector.n_components") -> int:
        a = int(a)
        top = min(self.m, self.n) - 1
        if not 1 <= a <= top:
            raise ConfigError(f"{key}={a} is out of range for {self.m} variables and {self.n} calibration rows; "
                              f"allowed: integers in [1, {top}]")
        return a

    def t2(self, X: np.ndarray, a: int, standardised: bool = False) -> np.ndarray:
        """Hotelling's T² with a components, shape (...)."""
        t = self.scores(X, standardised)[..., : self.check_components(a)]
        return np.sum(t**2 / self.eigenvalues[:a], axis=-1)

    def spe(self, X: np.ndarray, a: int, standardised: bool = False) -> np.ndarray:
        """SPE (Q) with a components: the squared norm of the residual (I − Pₐ Pₐᵀ) z, shape (...)."""
        Z = np.asarray(X, float) if standardised else self.standardise(X)
        P = self.loadings[:, : self.check_components(a)]
        residual = Z - (Z @ P) @ P.T
        return np.sum(residual**2, axis=-1)

    def contributions(self, X: np.ndarray, a: int, standardised: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """Per-variable contributions to T² and to SPE, each (..., m), summing to the statistics.

        T²: c_i = z_i (Pₐ Λₐ⁻¹ Pₐᵀ z)_i (a complete decomposition: the c_i sum to T²);
        SPE: c_i = e_i² with e = (I − Pₐ Pₐᵀ) z.
        """
        Z = np.asarray(X, float) if standardised else self.standardise(X)
        P = self.loadings[:, : self.check_components(a)]
        t = Z @ P
        c_t2 = Z * ((t / self.eigenvalues[:a]) @ P.T)
        c_spe = (Z - t @ P.T) ** 2
        return c_t2, c_spe

    def fitted(self) -> dict:
        """The arrays and scalars of this model (the family base saves them; :meth:`from_fitted` takes them back)."""
        return {"mean": self.mean, "scale": self.scale, "loadings": self.loadings, "eigenvalues": self.eigenvalues,
                "n": int(self.n)}

    @classmethod
    def from_fitted(cls, fitted, names=None) -> "PCAModel":
        """A model with the arrays of :meth:`fitted` (no refit)."""
        model = cls.__new__(cls)
        model.mean, model.scale = np.asarray(fitted["mean"], float), np.asarray(fitted["scale"], float)
        model.loadings = np.asarray(fitted["loadings"], float)
        model.eigenvalues = np.asarray(fitted["eigenvalues"], float)
        model.n, model.m = int(fitted["n"]), len(model.mean)
        model.names = tuple(names) if names is not None else tuple(f"x{i + 1}" for i in range(model.m))
        return model

    def t2_limit(self, a: int, alpha: float) -> float:
        return t2_limit(self.n, self.check_components(a), alpha)

    def spe_limit(self, a: int, alpha: float) -> float:
        return spe_limit(self.eigenvalues[self.check_components(a):], alpha)


_BLAS: dict = {}


def _one_blas_thread():
    """One BLAS thread for a small SVD or product: a multi-threaded LAPACK call on a 500 x 33 matrix took
    0.5 s instead of 1 ms on a loaded 2-core machine (threads spinning for cores other processes hold).

    A cached threadpoolctl controller: 2 µs a call (a fresh ``threadpool_limits`` scans the loaded
    libraries, ~1 ms, more than the deployed model's whole block).
    """
    controller = _BLAS.get("controller")
    if controller is None:
        try:
            from threadpoolctl import ThreadpoolController
        except ImportError:  # pragma: no cover - threadpoolctl comes with scikit-learn; without it, BLAS decides
            import contextlib

            return contextlib.nullcontext()
        controller = _BLAS["controller"] = ThreadpoolController()
    return controller.limit(limits=1, user_api="blas")


def t2_limit(n: int, a: int, alpha: float) -> float:
    """T²_α = a (n² − 1) / (n (n − a)) · F_α(a, n − a) (module docstring)."""
    quantile = float(special.fdtri(a, n - a, 1.0 - alpha))
    return a * (n**2 - 1) / (n * (n - a)) * quantile


def spe_limit(residual_eigenvalues: np.ndarray, alpha: float) -> float:
    """Jackson–Mudholkar SPE_α from the eigenvalues left out of the model (module docstring).

    The approximation needs h₀ > 0; with very uneven residual eigenvalues h₀ ≤ 0 (seen on 20 tags and
    1,000 rows: h₀ = −0.21 gave a limit of 0.28 against θ₁ ≈ 3 and a test FAR of 0.99). There the
    limit is Box's (1954) scaled χ² with the same first two moments, SPE ~ g χ²_h with g = θ₂/θ₁,
    h = θ₁²/θ₂ (Nomikos & MacGregor 1995), which never falls below the mean θ₁ at α < 0.5.
    """
    lam = np.asarray(residual_eigenvalues, float)
    theta1, theta2, theta3 = (float(np.sum(lam**i)) for i in (1, 2, 3))
    if theta1 <= 0.0:
        return 0.0
    h0 = 1.0 - 2.0 * theta1 * theta3 / (3.0 * theta2**2)
    c_alpha = float(special.ndtri(1.0 - alpha))
    if h0 > 0.0:
        inner = c_alpha * math.sqrt(2.0 * theta2 * h0**2) / theta1 + 1.0 + theta2 * h0 * (h0 - 1.0) / theta1**2
        if inner > 0.0:
            return theta1 * inner ** (1.0 / h0)
    g, h = theta2 / theta1, theta1**2 / theta2
    return g * float(special.chdtri(h, alpha))


def project(Z: np.ndarray, loadings: np.ndarray) -> np.ndarray:
    """Scores t = Z P (..., r), each summed over the variables in order: the same bits whatever the rows
    (:mod:`mosd.kernels.projection`; the same sums in NumPy with the kernels off)."""
    Z = np.asarray(Z, float)
    flat = np.ascontiguousarray(Z.reshape(-1, Z.shape[-1]))
    loadings = np.ascontiguousarray(loadings, dtype=float)
    from .. import kernels

    if kernels.enabled():
        from ..kernels.projection import project as compiled

        t = compiled(flat, loadings)
    else:
        t = np.zeros((flat.shape[0], loadings.shape[1]))
        for i in range(flat.shape[1]):
            t += flat[:, i:i + 1] * loadings[i]
    return t.reshape(Z.shape[:-1] + (loadings.shape[1],))


@dataclass
class _Projected:
    """T²(a) and SPE(a) of every point, for every a or for one: the one PCA scoring (the tuning's population,
    the test evaluation and, with one component count, the served stage's rows all run :meth:`of`)."""

    t2: np.ndarray      # (R, K, r): T² with a = 1..r components at index a - 1 (one a: (R, K, 1))
    spe: np.ndarray     # (R, K, r): SPE with a = 1..r components at index a - 1 (one a: (R, K, 1))
    finite: np.ndarray  # (R, K): complete rows

    @classmethod
    def of(cls, model: PCAModel, z: np.ndarray, components: int | None = None) -> "_Projected":
        """Scores of the points z (..., m); ``components``: only T²(a) and SPE(a) for that a (same bits).

        Both sums run over the components one after the other (cumulative sums): T² from the first
        component up, SPE from the smallest down, so that a small SPE is not the difference of two
        large numbers; a prefix of those sums is the same number whether the others are computed or not.
        """
        finite = np.all(np.isfinite(z), axis=-1)
        Z = np.where(finite[..., None], model.standardise(z), 0.0)
        t = project(Z, model.loadings)
        squares = t**2
        # what lies outside the loadings' span: only when the fit had fewer rows than variables (with a
        # component per variable it is 0, and the difference of the two sums only rounding noise)
        outside = (np.maximum(np.sum(Z**2, axis=-1) - np.sum(squares, axis=-1), 0.0) if t.shape[-1] < Z.shape[-1]
                   else np.zeros(t.shape[:-1]))
        if components is None:
            t2 = np.cumsum(squares / model.eigenvalues, axis=-1)
            tail = np.cumsum(squares[..., ::-1], axis=-1)[..., ::-1]
            spe = np.concatenate([tail[..., 1:], np.zeros(t.shape[:-1] + (1,))], axis=-1) + outside[..., None]
        else:
            # the same sums, one component at a time over all rows at once (a cumulative sum's last
            # value, without the others): component-major, so each step is one contiguous pass
            a, r = int(components), squares.shape[-1]
            by_component = np.moveaxis(squares, -1, 0).reshape(r, -1)
            scaled = by_component[:a] / model.eigenvalues[:a, None]
            t2 = scaled[0].copy()
            for j in range(1, a):
                t2 += scaled[j]
            spe = np.zeros(by_component.shape[1])
            if a < r:
                spe = by_component[r - 1].copy()
                for j in range(r - 2, a - 1, -1):
                    spe += by_component[j]
            shape = t.shape[:-1] + (1,)
            t2, spe = t2.reshape(shape), spe.reshape(shape) + outside[..., None]
        nan = ~finite[..., None]
        return cls(np.where(nan, np.nan, t2), np.where(nan, np.nan, spe), finite)


def stream_scores(model, X: np.ndarray, a: int, top: bool, cache: dict):
    """T², SPE (rows,), the complete rows (rows,) and, with ``top``, the indices of each row's :data:`TOP`
    largest contributions to T² and to SPE ({"t2", "spe"} → (rows, TOP), largest first) of the rows X
    (rows, m) with ``a`` components; ``cache`` keeps the contribution maps of the NumPy path."""
    from .. import kernels

    n = len(X)
    if kernels.enabled() and model.loadings.shape[1] >= model.m:
        from ..kernels.projection import scores

        t2, spe, finite, top_t2, top_spe = scores(
            np.ascontiguousarray(X, dtype=float), model.mean, model.scale, np.ascontiguousarray(model.loadings),
            model.eigenvalues, a, min(TOP, model.m) if top else 0)
        return t2, spe, finite, ({"t2": top_t2, "spe": top_spe} if top else None)
    t2, spe, finite = np.empty(n), np.empty(n), np.empty(n, bool)
    # blocks of BLOCK rows, so that the (block, m) intermediates stay in cache (buffers made once per call);
    # every step is row by row, so the blocks change no bit
    index = {"t2": np.empty((n, min(TOP, model.m)), np.intp), "spe": np.empty((n, min(TOP, model.m)), np.intp)}
    block = max(min(BLOCK, n), 1)
    Z_buffer, c_buffer = np.empty((block, model.m)), np.empty((block, model.m))
    with _one_blas_thread():
        for lo in range(0, n, BLOCK):
            hi = min(lo + BLOCK, n)
            proj = _Projected.of(model, X[lo:hi], components=a)
            t2[lo:hi], spe[lo:hi], finite[lo:hi] = proj.t2[:, 0], proj.spe[:, 0], proj.finite
            if top:
                Z = np.subtract(X[lo:hi], model.mean, out=Z_buffer[:hi - lo])
                Z /= model.scale
                ok = finite[lo:hi]
                if not ok.all():
                    Z[~ok] = 0.0
                for name in ("t2", "spe"):
                    index[name][lo:hi] = top_indices(model, a, Z, name, c_buffer[:hi - lo], cache)
    return t2, spe, finite, (index if top else None)


class PCADetector(LatentDetector):
    """PCA T²/SPE monitoring with tunable components, α, EWMA λ and persistence (module docstring).

    The PCA family on :class:`~mosd.detectors.latent.LatentDetector`: the fitted model is the
    standardisation and every component of the fit rows (:meth:`PCAModel.fitted`), so that the component
    count is applied after the fit (one SVD per calibration set for the whole tuning); T² and SPE of every
    component count are projected once per data set (:class:`_Projected`) and sliced per design.
    """

    STATISTICS = ("t2", "spe")
    fit_keys = ()
    params = latent_params({
        "max_components": Param(Interval(1, 10_000, integer=True), "Upper end of n_components' range (below the "
                                "number of variables)."),
        "n_components": Param(Interval(1, "max_components", integer=True), "Principal components a.", tunable=True),
    }, STATISTICS)

    def __init__(self, n_components: int = 9, alpha: float = 0.01, lam: float = 1.0, persistence: int = 1,
                 statistic: str = "combined", limits: str = "theoretical", fit_runs: int | None = None,
                 max_components: int = 20, persistence_max: int = 10, lam_min: float = 0.0,
                 flatline: float | None = None):
        self._assign(locals())
        self._cache: dict = {}

    # -- the family ------------------------------------------------------------------------
    def data_bounds(self, calibration_z: np.ndarray) -> dict[str, tuple[float, float]]:
        """λ's floor (the base's) and a ≤ min(m, N) − 1: a PCA of N complete fit rows of m variables has that many
        components with a residual left for SPE."""
        fit = np.asarray(self.fit_rows(calibration_z), float)
        return {**super().data_bounds(calibration_z),
                "n_components": (1, min(fit.shape[-1], self.complete_count(fit)) - 1)}

    def fit(self, X: np.ndarray, design) -> dict:
        return PCAModel(X).fitted()

    def _model(self, fitted) -> "PCAModel":
        return self._remember(("pca", id(fitted)), (fitted,), lambda: PCAModel.from_fitted(fitted))

    def score(self, fitted, X, design, carried=None):
        model = self._model(fitted)
        a = model.check_components(design["n_components"])
        proj = self._remember(("projected", id(fitted), id(X)), (fitted, X),
                              lambda: _Projected.of(model, np.asarray(X, float)))
        return {"t2": proj.t2[..., a - 1], "spe": proj.spe[..., a - 1]}, {}

    def limit(self, fitted, name, alpha, design) -> float:
        model = self._model(fitted)
        a = model.check_components(design["n_components"])
        return t2_limit(model.n, a, alpha) if name == "t2" else spe_limit(model.eigenvalues[a:], alpha)

    def model(self, calibration_z: np.ndarray, names=None) -> PCAModel:
        """The PCA of the fit runs of ``calibration_z`` (R, K, m) (cached while the array lives)."""
        model = self._model(self.fitted(calibration_z))
        if names is not None:
            model = copy.copy(model)
            model.names = tuple(names)
        return model

    # -- the served stage's rows: one component count, and each row's top contributing tags ----------
    def score_rows(self, fitted, X, design, carried, explain=None):
        """T² and SPE of one stream's rows (:func:`~mosd.detectors.pca_rows.stream_scores`: the compiled one-pass
        scoring, the bits of the tuning's projection) and, with ``explain`` (the tags), each row's :data:`TOP`
        tags contributing most to each (``top_t2``, ``top_spe``: ``tag;tag;tag``, '' on a row not scored)."""
        model = self._model(fitted)
        a = model.check_components(design["n_components"])
        X = np.asarray(X, float)
        cache = self.__dict__.setdefault("_rows", {})
        t2, spe, finite, index = stream_scores(model, X.reshape(-1, X.shape[-1]), a, explain is not None, cache)
        shape = X.shape[:-1]
        statistics, after = {"t2": t2.reshape(shape), "spe": spe.reshape(shape)}, {}
        if design.get("flatline"):  # the base's flat statistic beside T² and SPE
            flat, after = flat_statistic(X, fitted["flat_scale"], float(design["flatline"]), carried)
            statistics[self.FLAT] = flat
        extra = {} if explain is None else {
            f"top_{name}": top_labels(index[name], finite, tuple(explain), cache).reshape(shape)
            for name in ("t2", "spe")}
        return statistics, after, extra

    def explained(self, design) -> tuple[str, ...]:
        return ("top_t2", "top_spe")


def _legacy_pca(fields):
    """The generic stage of an ``OnlinePCA`` an older model saved
    (:func:`~mosd.detectors.latent_stage.legacy_online_pca`)."""
    from .latent_stage import legacy_online_pca

    return legacy_online_pca(fields)


# the class models saved before the generic stage name: loading one imports this module, which finds its translation
LEGACY_STAGES["mosd.detectors.pca.OnlinePCA"] = _legacy_pca
