"""Grid scans of a chart's two parameters (smoothing λ, limit width) on training data.

Two uses in paper 000:

* Fig. 1 — the FAR and MDR surfaces of the SS-DEWMA chart over a 20×20 grid of
  (λ, K_SD), which motivates the multi-objective search (§2.2.1);
* the tuning rule of the MS-OEWMA comparison chart (:class:`mosd.detectors.MSOEWMA`):
  for each λ the smallest width that keeps FAR <= α on the training data, then the λ
  whose design has the lowest MDR (:func:`constrained_grid_search`).

Both evaluate the whole grid as one population through
:class:`mosd.optim.problem.CandidateEvaluator`, in chunks that bound memory.
"""
from __future__ import annotations

import warnings

import numpy as np

from ..validation import ConfigError, Interval, check_in, check_int
from .selection import TIE_TOLERANCE, SelectionWarning

#: Candidates per evaluator call: the SS/M-DEWMA population recursion holds
#: (K, P, 2R) floats, ~32 MB for P = 100 at K = 1000 subgroups and R = 20 runs.
DEFAULT_CHUNK = 100


def _grid_values(name: str, values) -> np.ndarray:
    array = np.asarray(values, dtype=float).ravel()
    if array.size == 0:
        raise ConfigError(f"{name} is empty; allowed: at least one value")
    if not np.all(np.isfinite(array)):
        raise ConfigError(f"{name} has non-finite values; allowed: finite numbers")
    if np.any(np.diff(array) <= 0):
        raise ConfigError(f"{name} is not strictly increasing; allowed: sorted distinct values")
    return array


def _parameter_names(evaluator) -> tuple[str, str]:
    names = list(evaluator.detector.tunable)
    if len(names) != 2:
        raise ConfigError(f"chart {type(evaluator.detector).__name__} tunes {names}; allowed: exactly two "
                          "parameters (smoothing, width)")
    return names[0], names[1]


def grid_objectives(evaluator, lam_values, width_values, chunk: int = DEFAULT_CHUNK) -> tuple[np.ndarray, np.ndarray]:
    """FAR and MDR of every (λ, width) pair of a rectangular grid.

    Parameters
    ----------
    evaluator : CandidateEvaluator
        Maps parameter rows X (P, 2) — in the order of ``evaluator.detector.tunable``,
        smoothing first, width second — to (FAR, MDR) means over the training runs
        (eqs. 32–33).
    lam_values, width_values : array_like, strictly increasing
        Grid axes; every value must be allowed by the chart's declared bounds.
    chunk : int
        Candidates per evaluator call (memory bound only; results do not depend on it).

    Returns
    -------
    far, mdr : ndarray, shape (len(lam_values), len(width_values))
        ``far[i, j]`` is the false-alarm rate of (lam_values[i], width_values[j]).
    """
    lam_name, width_name = _parameter_names(evaluator)
    lam = _grid_values("lam_values", lam_values)
    width = _grid_values("width_values", width_values)
    tunable = evaluator.detector.tunable
    for name, values in ((lam_name, lam), (width_name, width)):
        # both ends are checked: the grid is sorted, so every value is inside
        check_in(f"chart.{name}", float(values[0]), tunable[name])
        check_in(f"chart.{name}", float(values[-1]), tunable[name])
    chunk = check_int("chunk", chunk, 1)
    lam_mesh, width_mesh = np.meshgrid(lam, width, indexing="ij")
    X = np.column_stack([lam_mesh.ravel(), width_mesh.ravel()])
    F = np.concatenate([evaluator(X[start:start + chunk]) for start in range(0, len(X), chunk)], axis=0)
    shape = (lam.size, width.size)
    return F[:, 0].reshape(shape), F[:, 1].reshape(shape)


def constrained_grid_search(evaluator, lam_grid, width_grid, alpha: float = 0.05,
                            chunk: int = DEFAULT_CHUNK) -> tuple[dict[str, float], tuple[float, float]]:
    """MS-OEWMA tuning: for each λ the smallest width with FAR <= α, then the λ with the lowest MDR.

    Widening the limit can only remove alarms (the statistic does not depend on the
    width), so FAR falls and MDR rises along the width axis: the smallest feasible
    width is, for its λ, the design with the lowest MDR under the false-alarm budget.
    Among those per-λ designs the one with the lowest training MDR wins; ties
    (within 1e-12) go to the lower FAR, then the smaller λ.

    Parameters
    ----------
    evaluator : CandidateEvaluator
        See :func:`grid_objectives`.
    lam_grid, width_grid : array_like, strictly increasing
        Candidate smoothing parameters and limit widths.
    alpha : float in [0, 1]
        False-alarm budget on the training runs.
    chunk : int
        Candidates per evaluator call.

    Returns
    -------
    params : dict
        ``{smoothing name: λ, width name: width}`` in the chart's parameter names.
    objectives : (float, float)
        Training (FAR, MDR) of the chosen design.

    Warns
    -----
    SelectionWarning
        When no grid point meets FAR <= α; the lowest-FAR point (ties → lower MDR,
        then smaller λ, then smaller width) is returned instead, so a pipeline still
        finishes and the warning records that the budget was not met.
    """
    alpha = check_in("alpha", alpha, Interval(0.0, 1.0))
    lam_name, width_name = _parameter_names(evaluator)
    lam = _grid_values("lam_grid", lam_grid)
    width = _grid_values("width_grid", width_grid)
    far, mdr = grid_objectives(evaluator, lam, width, chunk=chunk)
    feasible = far <= alpha + TIE_TOLERANCE
    rows = np.flatnonzero(feasible.any(axis=1))
    if rows.size == 0:
        i, j = _lexicographic_min(far.ravel(), mdr.ravel(), far.shape)
        warnings.warn(f"no grid point has FAR <= {alpha:g} (lowest FAR {far[i, j]:.4g}); "
                      "chose the lowest-FAR point", SelectionWarning, stacklevel=2)
    else:
        first = np.argmax(feasible[rows], axis=1)  # smallest feasible width per λ
        row_far, row_mdr = far[rows, first], mdr[rows, first]
        best = np.flatnonzero(row_mdr <= row_mdr.min() + TIE_TOLERANCE)
        best = best[row_far[best] <= row_far[best].min() + TIE_TOLERANCE]
        k = best[0]  # rows are in increasing λ
        i, j = rows[k], first[k]
    params = {lam_name: float(lam[i]), width_name: float(width[j])}
    return params, (float(far[i, j]), float(mdr[i, j]))


def _lexicographic_min(primary: np.ndarray, secondary: np.ndarray, shape) -> tuple[int, int]:
    """Grid index of the lowest ``primary`` (ties → lowest ``secondary``, then first in C order)."""
    near = np.flatnonzero(primary <= primary.min() + TIE_TOLERANCE)
    near = near[secondary[near] <= secondary[near].min() + TIE_TOLERANCE]
    i, j = np.unravel_index(near[0], shape)
    return int(i), int(j)


__all__ = ["DEFAULT_CHUNK", "constrained_grid_search", "grid_objectives"]
