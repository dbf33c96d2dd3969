"""Dynamic PCA (Ku, Storer & Georgakis 1995, Chemometr. Intell. Lab. Syst. 30, 179-196): PCA of lagged rows.

Each row is augmented with the ``lags`` rows before it, x̃_k = [x_kᵀ, x_{k−1}ᵀ, ..., x_{k−l}ᵀ]ᵀ
(Ku et al., eq. 10: the lagged data matrix), and monitored with the PCA family's T² and SPE and
their F and Jackson–Mudholkar limits (:mod:`mosd.detectors.pca`) on those (l + 1) m columns (a
component count above (l + 1) m − 1 is lowered to it, so that any lags the tuning tries are valid). The
lags come from the stream's own past: the fit builds lagged rows within each calibration run,
and the deployed stage carries the last l rows as its state (``lag<j>_<i>``, null before a stream
has them), so a row with fewer than l predecessors is not scored.
"""
from __future__ import annotations

import numpy as np

from ..validation import Interval, Param
from .latent import LatentDetector, complete_rows, lag_state, lagged, latent_params
from .pca import PCADetector, PCAModel, _Projected


class DPCADetector(PCADetector):
    """Dynamic PCA T²/SPE with tunable lags, components, α, EWMA λ and persistence (module docstring)."""

    STATISTICS = ("t2", "spe")
    fit_keys = ("lags",)
    params = latent_params({
        "max_components": Param(Interval(1, 10_000, integer=True), "Upper end of n_components' range."),
        "max_lags": Param(Interval(1, 50, integer=True), "Upper end of the lags' range."),
        "n_components": Param(Interval(1, "max_components", integer=True), "Principal components a of the "
                              "lagged rows.", tunable=True),
        "lags": Param(Interval(0, "max_lags", integer=True), "Past rows l appended to each row (0: static PCA).",
                      tunable=True),
    }, STATISTICS)

    def __init__(self, n_components: int = 20, lags: int = 2, alpha: float = 0.01, lam: float = 1.0,
                 persistence: int = 1, statistic: str = "combined", limits: str = "theoretical",
                 fit_runs: int | None = None, max_components: int = 60, max_lags: int = 5,
                 persistence_max: int = 10, lam_min: float = 0.0, flatline: float | None = None):
        self._assign(locals())
        self._cache: dict = {}

    def data_bounds(self, calibration_z: np.ndarray) -> dict[str, tuple[float, float]]:
        """λ's floor, the lags l whose lagged fit rows number at least (l + 1) m + 1 (a PCA with a residual on
        every lagged column), and a ≤ (l + 1) m − 1 at the largest of them (a smaller l lowers a to its own)."""
        fit = np.asarray(self.fit_rows(calibration_z), float)
        m = fit.shape[-1]
        usable = [lags for lags in range(int(self.max_lags) + 1) if self.complete_count(fit, lags) > (lags + 1) * m]
        top = max(usable, default=0)
        return {**LatentDetector.data_bounds(self, calibration_z), "lags": (0, top),
                "n_components": (1, min((top + 1) * m, self.complete_count(fit, top)) - 1)}

    def fit(self, X: np.ndarray, design) -> dict:
        rows, _ = lagged(X, int(design["lags"]))
        return {**PCAModel(complete_rows(rows)).fitted(), "lags": int(design["lags"])}

    def _m(self, fitted) -> int:
        return len(fitted["mean"]) // (int(fitted["lags"]) + 1)

    def _components(self, model: PCAModel, design) -> int:
        """a, at most the lagged rows' (l + 1) m − 1: a tuning that lowers the lags keeps its component count valid."""
        return model.check_components(min(int(design["n_components"]), min(model.m, model.n) - 1))

    def limit(self, fitted, name, alpha, design) -> float:
        return super().limit(fitted, name, alpha, {**design, "n_components": self._components(self._model(fitted),
                                                                                                design)})

    def score(self, fitted, X, design, carried=None):
        model = self._model(fitted)
        a = self._components(model, design)
        lags = int(fitted["lags"])
        rows, after = lagged(X, lags, carried)
        if carried is None:  # the tuning: every component count projected once per data set
            proj = self._remember(("projected", id(fitted), id(X)), (fitted, X), lambda: _Projected.of(model, rows))
            return {"t2": proj.t2[..., a - 1], "spe": proj.spe[..., a - 1]}, after
        proj = _Projected.of(model, rows, components=a)
        return {"t2": proj.t2[..., 0], "spe": proj.spe[..., 0]}, after

    def state(self, fitted, design):
        return lag_state(self._m(fitted), int(fitted["lags"]))

    def score_rows(self, fitted, X, design, carried, explain=None):
        """The base's (:meth:`score` on the lagged rows, the lag buffer carried), not PCA's per-row top tags."""
        return LatentDetector.score_rows(self, fitted, X, design, carried, explain)

    def explained(self, design) -> tuple[str, ...]:
        return ()
