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

from ..detectors.pca import PCAModel
from ..types import Residuals, Trace
from ..validation import ConfigError, Interval, Param
from .base import Estimator


class PCAResidual(Estimator):
    """T², SPE and scores of a PCA fitted on fault-free runs (module docstring)."""

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
        fitted = getattr(self, "model_", None)
        if fitted is None:
            raise ConfigError("estimator PCAResidual is not fitted; allowed: fit on fault-free runs first "
                              "(the experiment does this)")
        a = self.n_components
        z = fitted.standardise(trace.y)
        scores = fitted.scores(z, standardised=True)[..., :a]
        residual = z - scores @ fitted.loadings[:, :a].T
        extra = {"t2": np.sum(scores**2 / fitted.eigenvalues[:a], axis=-1), "spe": np.sum(residual**2, axis=-1),
                 "scores": scores}
        return Residuals.of(trace, r=residual, channels=fitted.names, extra=extra)
