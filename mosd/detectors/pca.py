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

from ..streaming import COUNT, SQUARES, OnlineStage, StateVar, points_of, spread
from ..validation import ConfigError, Interval, Param
from .base import run_lengths
from .latent import LIMITS, LatentDetector, empirical_limit, ewma_from, latent_params, point_names  # noqa: F401 (re-exported)

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
    the test evaluation and the deployed :class:`OnlinePCA` all run :meth:`of`)."""

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

    # -- the causal form: the generic stage plus each row's top contributing tags ---------------
    def online(self, calibration_z: np.ndarray, inputs) -> "OnlinePCA":
        """This tuned design calibrated on ``calibration_z`` (R, K, m) as an :class:`OnlinePCA` on the columns ``inputs``.

        The generic :class:`~mosd.detectors.latent.OnlineLatent` scores the same T², SPE and alarms
        (``tests/test_families.py``); :class:`OnlinePCA` adds the tags contributing most per row.
        """
        calibration_z = np.asarray(calibration_z, float)
        generic = super().online(calibration_z, inputs)
        if self.flatline:  # OnlinePCA scores T² and SPE only: the base's flat statistic needs the generic stage
            return generic
        model = self._model(generic.fitted)
        limits, starts = dict(zip(generic.names, generic.limits)), dict(zip(generic.names, generic.starts))
        return OnlinePCA(tags=point_names(inputs, len(model.mean)), mean=model.mean, scale=model.scale,
                         loadings=model.loadings, eigenvalues=model.eigenvalues, n_fit=int(model.n),
                         n_components=int(self.n_components), alpha=float(self.alpha), lam=float(self.lam),
                         persistence=int(self.persistence), statistic=str(self.statistic),
                         t2_limit=float(limits["t2"]), spe_limit=float(limits["spe"]),
                         # the in-control mean the tuning starts its EWMA from
                         t2_start=float(starts["t2"]), spe_start=float(starts["spe"]))


#: variables named per row in ``top_t2`` / ``top_spe``
TOP = 3
#: rows scored per block by the deployed PCA (the (block, m) intermediates stay in cache)
BLOCK = 2048


@dataclass
class OnlinePCA(OnlineStage):
    """A tuned :class:`PCADetector`'s causal form: tag rows in; T², SPE, their limits, the alarm and the top tags out.

    The fitted pipeline of a recorded-data run: the standardisation (mean and standard deviation of the
    fit rows), the PCA (loadings, eigenvalues), the tuned design (components a, α, EWMA λ, persistence)
    and its calibrated limits. Scores are :meth:`_Projected.of` (the tuning's own arithmetic), the EWMA
    is :func:`ewma_from` and the persistence count :func:`~mosd.detectors.base.run_lengths`, each
    continued from the carried state: ``ewma_t2``, ``ewma_spe`` (the EWMAs; at a stream's start the mean
    T²/SPE of the fit rows, where the tuning starts them) and ``run_length`` (consecutive points above the
    limit). A row with a missing value has no scores and no alarm.

    Outputs per row: ``t2``, ``spe`` (raw), ``t2_smoothed``, ``spe_smoothed``, ``t2_limit``, ``spe_limit``,
    ``ratio`` (the alarmed statistic over its limit: the larger of the two for the combined rule),
    ``alarm`` and ``top_t2``/``top_spe``: the :data:`TOP` variables contributing most (``tag;tag;tag``).
    """

    tags: tuple
    mean: np.ndarray
    scale: np.ndarray
    loadings: np.ndarray      # (m, r): every component (the SPE tail sums over those left out)
    eigenvalues: np.ndarray   # (r,)
    n_fit: int
    n_components: int
    alpha: float
    lam: float
    persistence: int
    statistic: str
    t2_limit: float
    spe_limit: float
    t2_start: float
    spe_start: float

    @property
    def inputs(self) -> tuple[str, ...]:
        return ("point", *(f"z_{j}" for j in range(1, len(self.tags) + 1)))

    @property
    def outputs(self) -> tuple[str, ...]:
        return ("t2", "spe", "t2_smoothed", "spe_smoothed", "t2_limit", "spe_limit", "ratio", "alarm", "top_t2",
                "top_spe")

    def state_vars(self) -> dict[str, StateVar]:
        return {"ewma_t2": StateVar("EWMA of T² after the last row, a sum of squares.", SQUARES),
                "ewma_spe": StateVar("EWMA of SPE after the last row, a sum of squares.", SQUARES),
                "run_length": StateVar("Consecutive points above the limit.", COUNT)}

    def initial_state(self) -> dict:
        return {"ewma_t2": float(self.t2_start), "ewma_spe": float(self.spe_start), "run_length": 0}

    def example_row(self) -> np.ndarray:
        return np.asarray(self.mean, float)

    def model(self) -> PCAModel:
        """A :class:`PCAModel` with these arrays (no refit)."""
        model = PCAModel.__new__(PCAModel)
        model.names, model.n, model.m = tuple(self.tags), int(self.n_fit), len(self.tags)
        model.mean, model.scale = np.asarray(self.mean, float), np.asarray(self.scale, float)
        model.loadings, model.eigenvalues = np.asarray(self.loadings, float), np.asarray(self.eigenvalues, float)
        return model

    def update(self, columns, state, top: bool = True) -> dict[str, np.ndarray]:
        rows, at, X = points_of(columns, len(self.tags))
        return spread(rows, at, self.score(X, state, top), state)

    def score(self, X: np.ndarray, state, top: bool = True) -> dict[str, np.ndarray]:
        """Outputs and state after each row of X (rows, m: the tags in order), from ``state``."""
        n, a = len(X), int(self.n_components)
        model = self.__dict__.get("_model") or self.__dict__.setdefault("_model", self.model())
        raw = {"t2": np.empty(n), "spe": np.empty(n)}
        finite = np.empty(n, bool)
        from .. import kernels

        fused = kernels.enabled() and model.loadings.shape[1] >= model.m
        index = None
        if fused:  # one pass per row, the same bits as _Projected.of (kernels.projection.scores)
            from ..kernels.projection import scores

            k = min(TOP, model.m) if top else 0
            raw["t2"], raw["spe"], finite, top_t2, top_spe = scores(
                np.ascontiguousarray(X, dtype=float), model.mean, model.scale, np.ascontiguousarray(model.loadings),
                model.eigenvalues, a, k)
            index = {"t2": top_t2, "spe": top_spe}
        else:
            # blocks of BLOCK rows, so that the (block, m) intermediates stay in cache (buffers made once per
            # call); every step is row by row, so the blocks change no bit
            index = {"t2": np.empty((n, TOP), np.intp), "spe": np.empty((n, TOP), np.intp)} if top else None
            block = min(BLOCK, n)
            Z_buffer, c_buffer = np.empty((block, model.m)), np.empty((block, model.m))
            with _one_blas_thread():
                for lo in range(0, n, BLOCK):
                    hi = min(lo + BLOCK, n)
                    proj = _Projected.of(model, X[lo:hi], components=a)
                    raw["t2"][lo:hi], raw["spe"][lo:hi] = proj.t2[:, 0], proj.spe[:, 0]
                    finite[lo:hi] = proj.finite
                    if top:
                        Z = np.subtract(X[lo:hi], self.mean, out=Z_buffer[:hi - lo])
                        Z /= self.scale
                        ok = finite[lo:hi]
                        if not ok.all():
                            Z[~ok] = 0.0
                        for name in ("t2", "spe"):
                            index[name][lo:hi] = self._top(Z, name, c_buffer[:hi - lo])
        tops = {name: self._labels(index[name], finite) for name in ("t2", "spe")} if top else None
        out: dict[str, np.ndarray] = {}
        ratios = []
        for name, start, limit in (("t2", self.t2_start, self.t2_limit), ("spe", self.spe_start, self.spe_limit)):
            values = raw[name]
            smooth = ewma_from(values, self.lam, float(start), previous=float(state[f"ewma_{name}"]))
            value = np.where(finite, smooth, np.nan)
            out[name], out[f"{name}_smoothed"], out[f"{name}_limit"] = values, value, np.full(n, float(limit))
            out[f"ewma_{name}"] = smooth
            if self.statistic in ("combined", name):
                with np.errstate(invalid="ignore"):
                    ratios.append(value / limit)
        ratio = ratios[0] if len(ratios) == 1 else np.fmax(ratios[0], ratios[1])
        with np.errstate(invalid="ignore"):
            above = ratio > 1.0
        run = run_lengths(above, int(state["run_length"]))
        out["ratio"], out["alarm"], out["run_length"] = ratio, run >= self.persistence, run
        for name in ("t2", "spe"):
            out[f"top_{name}"] = tops[name] if top else np.full(n, "", dtype=object)
        return out

    def _top(self, Z: np.ndarray, name: str, out: np.ndarray) -> np.ndarray:
        """Indices of the :data:`TOP` largest contributions per standardised row of Z (0 where missing), largest
        first; ``out`` (rows, m) is scratch.

        T²: c_i = z_i (Pₐ Λₐ⁻¹ Pₐᵀ z)_i; SPE: c_i = e_i², e = (I − Pₐ Pₐᵀ) z (:meth:`PCAModel.contributions`),
        each one product with an (m, m) matrix made once.
        """
        maps = self.__dict__.get("_maps")
        if maps is None:
            a, P = int(self.n_components), np.asarray(self.loadings, float)
            maps = self.__dict__["_maps"] = {
                "t2": (P[:, :a] / np.asarray(self.eigenvalues)[:a]) @ P[:, :a].T,
                "spe": np.eye(len(P)) - P[:, :a] @ P[:, :a].T}
        c = np.matmul(Z, maps[name], out=out)
        if name == "t2":
            c *= Z
        else:
            c *= c
        return _largest(c, TOP)

    def _labels(self, index: np.ndarray, finite: np.ndarray) -> np.ndarray:
        """``tag;tag;tag`` per row of (n, TOP) indices, largest first ('' where the row is not scored): each
        combination joined once (a few hundred in a file), then looked up in a table of every combination."""
        out = self._joined(index)
        if not finite.all():
            out[~finite] = ""
        return out

    def _joined(self, index: np.ndarray) -> np.ndarray:
        m, k = len(self.tags), index.shape[1]
        code = np.zeros(len(index), np.int64)
        for j in range(k):
            code = code * m + index[:, j]
        if m**k > 1 << 20:  # too many combinations for a table: join each distinct one of this block
            unique, inverse = np.unique(code, return_inverse=True)
            joined = [";".join(self.tags[(c // m**(k - 1 - j)) % m] for j in range(k)) for c in unique.tolist()]
            return np.array(joined, dtype=object)[inverse.reshape(-1)]
        table = self.__dict__.get("_label_table")
        if table is None:
            table = self.__dict__["_label_table"] = (np.full(m**k, None, dtype=object), np.zeros(m**k, bool))
        labels, filled = table
        for c in np.unique(code[~filled[code]]).tolist():
            parts, rest = [], c
            for _ in range(k):
                rest, j = divmod(rest, m)
                parts.append(self.tags[j])
            labels[c], filled[c] = ";".join(reversed(parts)), True
        return labels[code]


def _largest(c: np.ndarray, k: int) -> np.ndarray:
    """Column indices of the k largest values of every row of c, largest first (c is overwritten)."""
    rows = np.arange(len(c))
    out = np.empty((len(c), min(k, c.shape[1])), np.intp)
    for j in range(out.shape[1]):
        out[:, j] = winner = np.argmax(c, axis=1)
        if j + 1 < out.shape[1]:
            c[rows, winner] = -np.inf
    return out
