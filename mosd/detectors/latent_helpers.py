"""The row-wise helpers of the recorded-data families (:mod:`mosd.detectors.latent`): lag buffers, scaling, the
empirical limit, the EWMA of a statistic and the base's ``flat`` statistic.

Families import them from :mod:`mosd.detectors.latent` (re-exported there); they live apart so that each
module stays one job.
"""
from __future__ import annotations

import math
from typing import Mapping

import numpy as np

from .. import kernels
from ..streaming import FINITE, StateVar
from ..validation import ConfigError


# -- helpers for dynamic families ------------------------------------------------------------
def lag_state(m: int, lags: int, prefix: str = "lag") -> dict[str, tuple[StateVar, float]]:
    """The declared state of a buffer of the last ``lags`` rows of m variables: ``<prefix><j>_<i>`` is
    variable i of the row j steps back (NaN, JSON null, before a stream has that many rows)."""
    return {f"{prefix}{j}_{i}": (StateVar(f"Variable {i} of the row {j} step(s) back.", FINITE, missing=True), math.nan)
            for j in range(1, lags + 1) for i in range(1, m + 1)}


def lagged(X: np.ndarray, lags: int, carried: Mapping | None = None, prefix: str = "lag"):
    """The causal lagged rows [x_k, x_{k−1}, ..., x_{k−lags}] of X (R, K, m) and the buffer after each row.

    Rows before a run's start come from ``carried`` (:func:`lag_state`'s names, (R,) each) or are NaN.

    Returns
    -------
    rows : ndarray, shape (R, K, (lags + 1) m)
        Row k: x_k, then x_{k−1}, ... (blocks of m).
    after : dict
        ``<prefix><j>_<i>`` → (R, K): the buffer after each row (x_{k−j+1}).
    """
    X = np.asarray(X, float)
    R, K, m = X.shape
    history = np.full((R, lags, m), np.nan)
    if carried:
        for j in range(1, lags + 1):
            for i in range(1, m + 1):
                history[:, lags - j, i - 1] = np.asarray(carried[f"{prefix}{j}_{i}"], float).reshape(R)
    full = np.concatenate([history, X], axis=1)     # row lags + k is x_k
    rows = np.concatenate([full[:, lags - j: lags - j + K] for j in range(lags + 1)], axis=-1)
    after = {f"{prefix}{j}_{i}": full[:, lags - j + 1: lags - j + 1 + K, i - 1]
             for j in range(1, lags + 1) for i in range(1, m + 1)}
    return rows, after


def complete_rows(rows: np.ndarray) -> np.ndarray:
    """The rows (…, n) with every value finite, as (N, n): what a family fits on."""
    flat = np.asarray(rows, float).reshape(-1, np.shape(rows)[-1])
    return flat[np.all(np.isfinite(flat), axis=1)]


def scaling(rows: np.ndarray, family: str, least: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """Mean and standard deviation (ddof = 1) of the complete rows (N, m); one line naming a constant variable."""
    if len(rows) < least:
        raise ConfigError(f"the {family} calibration has {len(rows)} complete rows; allowed: at least {least}")
    mean, scale = rows.mean(axis=0), rows.std(axis=0, ddof=1)
    flat = np.flatnonzero(~(scale > 1e-12 * np.maximum(1.0, np.abs(mean))))
    if flat.size:
        raise ConfigError(f"variable {flat[0] + 1} is constant over the {family} calibration rows; allowed: "
                          "variables that vary (drop constant columns)")
    return mean, scale


def empirical_limit(values: np.ndarray, alpha: float) -> float:
    """The (1 − α) quantile of the finite values (NumPy's linear interpolation)."""
    values = np.asarray(values, float)
    values = values[np.isfinite(values)]
    if values.size == 0:
        raise ConfigError("no finite held-back calibration point for an empirical limit; allowed: calibration "
                          "data with complete rows")
    return float(np.quantile(values, 1.0 - alpha))


def ewma_from(x: np.ndarray, lam: float, start: float, previous: float | None = None) -> np.ndarray:
    """E_k = λ x_k + (1 − λ) E_{k−1} along the last axis, from E_{−1} = ``previous`` (default ``start``).

    A missing point (NaN) enters as ``start``, the in-control mean: what a
    fault-free point adds on average. ``previous``: the carried E of a stream scored in parts
    (a float, or an array that broadcasts against x's rows).

    Compiled (:mod:`mosd.kernels.latent`) for a float ``previous``; SciPy's ``lfilter`` below is the
    reference, used with the kernels off: the same bits.
    """
    return _smoothed(x, lam, start, previous, masked=False)


def smoothed_values(x: np.ndarray, lam: float, start: float) -> np.ndarray:
    """A statistic's smoothed value: :func:`ewma_from` where x is finite, NaN where it is not (no alarm there)."""
    return _smoothed(x, lam, start, None, masked=True)


def _smoothed(x, lam: float, start: float, previous, masked: bool) -> np.ndarray:
    x = np.asarray(x, float)
    if np.ndim(previous) == 0 and x.ndim >= 1 and x.size and kernels.enabled():
        from ..kernels.latent import smooth_rows

        # a statistic is often a strided view (one of a family's stacked statistics): read in place, not copied
        rows = x if x.ndim == 2 else x.reshape(-1, x.shape[-1])
        out = smooth_rows(rows, float(lam), float(start), float(start if previous is None else previous),
                          masked, np.empty(rows.shape))
        return out.reshape(x.shape)
    filled = np.where(np.isfinite(x), x, start)
    if lam < 1.0 and x.shape[-1] != 0:
        # imported here: scipy.signal pulls in scipy.stats (ARCHITECTURE: not on every run's start)
        from scipy.signal import lfilter

        zi = np.full(filled.shape[:-1] + (1,), (1.0 - lam) * (start if previous is None else previous))
        filled = lfilter([lam], [1.0, -(1.0 - lam)], filled, axis=-1, zi=zi)[0]
    return np.where(np.isfinite(x), filled, np.nan) if masked else filled


def increment_scale(runs: np.ndarray) -> np.ndarray:
    """Mean squared increment of each tag (m,) within the runs (R, K, m): the in-control scale of ``flat``."""
    steps = np.diff(np.asarray(runs, float), axis=1).reshape(-1, np.shape(runs)[-1])
    steps = steps[np.all(np.isfinite(steps), axis=1)]
    if len(steps) < 2:
        raise ConfigError(f"the flatline statistic has {len(steps)} complete increments in the fit runs; allowed: "
                          "at least 2 (detector.flatline=null turns it off)")
    scale = np.mean(steps**2, axis=0)
    flat = np.flatnonzero(~(scale > 0.0))
    if flat.size:
        raise ConfigError(f"variable {flat[0] + 1} never changes over the fit runs, so its increments cannot "
                          "collapse; allowed: detector.flatline=null, or variables that vary")
    return scale


def flat_statistic(X: np.ndarray, scale: np.ndarray, smoothing: float, carried: Mapping | None = None):
    """The largest collapse of a tag's increments, per row: a stuck valve or a frozen transmitter.

    Each tag's squared increment over its in-control mean square, u_{k,i} = (x_{k,i} − x_{k−1,i})² / s_i
    (:func:`increment_scale`), is smoothed, v_{k,i} = λ_f u_{k,i} + (1 − λ_f) v_{k−1,i} from v = 1 (the
    exponentially weighted moving variance of MacGregor & Harris 1993, of the increments so that a slow drift
    does not move it), and the row's statistic is flat_k = max(0, max_i −ln v_{k,i}) (larger increments are the
    other statistics' business; at 0 it stays a square's domain): small in control, growing by
    −ln(1 − λ_f) per row while any tag stays exactly constant. Upper-tail statistics of a model (T², SPE) see
    no such tag: its values stay at their mean. A missing increment (a run's first row without a carried
    value, a missing value) enters as 1 (in control); an incomplete row is not scored.

    Returns (flat (R, K), after: ``flat_last_<i>``, ``flat_ewma_<i>`` (R, K) each).
    """
    X = np.asarray(X, float)
    R, K, m = X.shape
    last = np.full((R, 1, m), np.nan)
    start = np.ones((R, m))
    if carried:
        last[:, 0] = np.column_stack([np.asarray(carried[f"flat_last_{i}"], float).reshape(R)
                                      for i in range(1, m + 1)])
        start = np.column_stack([np.asarray(carried[f"flat_ewma_{i}"], float).reshape(R) for i in range(1, m + 1)])
    steps = np.moveaxis(np.diff(np.concatenate([last, X], axis=1), axis=1) ** 2 / scale, -1, 1)  # (R, m, K)
    # a missing increment enters as 1, the in-control value; each tag's EWMA continues from its carried value
    v = ewma_from(steps, float(smoothing), 1.0, previous=start[..., None])
    complete = np.all(np.isfinite(X), axis=-1)
    flat = np.where(complete, np.maximum(-np.log(np.maximum(v, np.finfo(float).tiny).min(axis=1)), 0.0), np.nan)
    after = {**{f"flat_last_{i}": X[..., i - 1] for i in range(1, m + 1)},
             **{f"flat_ewma_{i}": v[:, i - 1] for i in range(1, m + 1)}}
    return flat, after
