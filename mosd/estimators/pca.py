"""PCA as a residual generator: T², SPE and the scores of every sample, as estimator outputs.

:class:`PCAResidual` fits :class:`mosd.detectors.pca.PCAModel` on fault-free data
(the calibration split of recorded data, or the estimator stream of a simulated
plant: it is a trainable estimator) and hands on, for every sample, the
residual e = (I − Pₐ Pₐᵀ) z of the standardised measurements (``r``, one channel
per variable) and in ``extra``: ``"t2"`` (Hotelling's T²), ``"spe"`` (= ‖e‖²) and
``"scores"`` (the a scores). Any detector that reads a scalar output can then
decide on T² or SPE (e.g. ``monitor.outputs=[t2]`` with the threshold detector);
:class:`~mosd.detectors.pca.PCADetector` instead reads the measurements and
tunes the number of components itself.
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..detectors.pca import PCAModel, project
from ..types import Residuals, Trace
from ..validation import ConfigError, Interval, Param
from .step import StepEstimator


class PCAResidual(StepEstimator):
    """T², SPE and scores of a PCA fitted on fault-free runs (module docstring).

    Its step (:mod:`mosd.estimators.step`) is :func:`pca_residual` of each row on its own: no state. The
    batch estimate and the served stage (the tags in by name; ``residual_<tag>``, ``t2``, ``spe`` and
    ``scores_<j>`` out) run that one function with the fitted arrays of :meth:`step_params`.
    """

    params = {
        "n_components": Param(Interval(1, 10_000, integer=True), "Principal components a (and below the number of "
                              "variables and fit rows)."),
        "fit_runs": Param(Interval(1, math.inf, integer=True), "Fit on the first fit_runs runs of the training trace "
                          "only (recorded data: 1 is ``d00.dat`` of the TE calibration split); None: on every "
                          "complete row.", optional=True),
    }
    requires_fit = True
    fit_on_faults = False

    def __init__(self, n_components: int = 9, fit_runs: int | None = None):
        self._assign(locals())

    def fit(self, trace: Trace, model: Any = None, rng: np.random.Generator | None = None) -> "PCAResidual":
        y = trace.y if self.fit_runs is None else trace.y[: self.fit_runs]
        names = trace.meta.get("variables") or tuple(f"y{i + 1}" for i in range(trace.y.shape[-1]))
        fitted = PCAModel(y, names)
        fitted.check_components(self.n_components, "estimator.n_components")
        self.model_ = fitted
        return self

    def estimate(self, trace: Trace, model: Any = None) -> Residuals:
        fitted = self._fitted()
        residual, t2, spe, scores = pca_residual(trace.y, **self.step_params())
        extra = {"t2": t2, "spe": spe, "scores": scores}
        return Residuals.of(trace, r=residual, channels=fitted.names, extra=extra)

    def _fitted(self) -> PCAModel:
        fitted = getattr(self, "model_", None)
        if fitted is None:
            raise ConfigError("estimator PCAResidual is not fitted; allowed: fit on fault-free runs first "
                              "(the experiment does this)")
        return fitted

    # -- the step (mosd.estimators.step) ---------------------------------------------------
    def step_params(self, model: Any = None, trace: Trace | None = None) -> dict[str, np.ndarray]:
        """The fitted PCA's mean, scale, first a loadings and eigenvalues (:func:`pca_residual`'s arrays)."""
        fitted, a = self._fitted(), self.n_components
        return {"mean": np.asarray(fitted.mean, float), "scale": np.asarray(fitted.scale, float),
                "loadings": np.ascontiguousarray(fitted.loadings[:, :a], dtype=float),
                "eigenvalues": np.asarray(fitted.eigenvalues[:a], float)}

    def scan(self, model, params: dict, state: dict, columns: dict, trajectory: bool = False) -> dict:
        """:func:`pca_residual` of every row (:meth:`StepEstimator.scan`); the columns are the tags in the fitted
        order (their names: ``residual_<tag>`` out)."""
        tags = list(columns)
        residual, t2, spe, scores = pca_residual(np.stack([columns[t] for t in tags], axis=-1), **params)
        out = {f"residual_{tag}": residual[..., j] for j, tag in enumerate(tags)}
        out.update({"t2": t2, "spe": spe})
        out.update({f"scores_{j}": scores[..., j] for j in range(scores.shape[-1])})
        return out

    def example_row(self, model, params: dict, reads: tuple) -> np.ndarray:
        return np.asarray(params["mean"], float)

    # -- the causal form ----------------------------------------------------------------
    def online(self, model: Any = None, source=None, trace: Trace | None = None):
        """The fitted PCA as a stream of the measured tags (one column per variable, by its name): memoryless."""
        tags, a = tuple(self._fitted().names), self.n_components
        return self.stage(None, None, tags, (*(f"residual_{tag}" for tag in tags), "t2", "spe",
                                             *(f"scores_{j}" for j in range(a))))

    def raw_stream(self, trace: Trace, model: Any, input_names=()) -> dict[str, np.ndarray]:
        """The first replication's measurements, one column per variable (the causal form's inputs)."""
        y = np.asarray(trace.y, float)[0]
        return {name: y[:, j] for j, name in enumerate(self._fitted().names)}


def pca_residual(Y, mean, scale, loadings, eigenvalues):
    """(residual e (..., m), T² (...), SPE (...), scores t (..., a)) of every row of Y (..., m).

    z = (y − mean)/scale, t = Pₐᵀ z, e = z − Pₐ t = (I − Pₐ Pₐᵀ) z, T² = Σ_j t_j²/λ_j, SPE = Σ_i e_i², each sum
    taken in a fixed order over one row's own numbers (both products through
    :func:`mosd.detectors.pca.project`, not a BLAS product, whose kernel a BLAS picks by the row count):
    a series gives the same bits in one call, in chunks or row by row, so the batch estimate and
    :meth:`PCAResidual.scan` agree bit for bit. A row with a missing value gives NaN.
    """
    Z = (np.asarray(Y, float) - mean) / scale
    m, a = loadings.shape
    t = project(Z, loadings)
    residual = Z - project(t, loadings.T)
    t2 = np.zeros(Z.shape[:-1])
    for j in range(a):
        t2 += t[..., j] ** 2 / eigenvalues[j]
    spe = np.zeros(Z.shape[:-1])
    for i in range(m):
        spe += residual[..., i] ** 2
    return residual, t2, spe, t
