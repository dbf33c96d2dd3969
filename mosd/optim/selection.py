"""Choosing one detector design from the optimiser's archive.

Paper 000, step 7 (after eq. 39) picks "the member that makes MDR and FAR smallest
together" without saying how; docs/DECISIONS.md §6 makes that the maximum detection
accuracy 1 − FAR − MDR and offers two alternatives. The rules below take the
archive's objective matrix F with F[:, 0] = FAR and F[:, 1] = MDR (both minimised,
eq. 36) and return a row index; :func:`choose` maps any objective set onto them
(``objectives`` names the columns of F): the FAR/MDR rules use the ``far`` and
``mdr`` columns, and ``knee`` on three or more objectives is the design closest to
the ideal point after scaling every objective to [0, 1] over the archive.
"""
from __future__ import annotations

from dataclasses import dataclass
import warnings

import numpy as np

from ..metrics.summary import accuracy
from ..validation import ConfigError, Interval, check_in

#: Differences in FAR, MDR or accuracy below this count as ties (floating-point noise of
#: rates computed as counts / samples).
TIE_TOLERANCE = 1e-12
RULES = ("max_accuracy", "knee", "min_mdr_far_le")


class SelectionWarning(UserWarning):
    """The chosen design does not meet the rule's constraint (see :func:`min_mdr_far_le`)."""


@dataclass(frozen=True)
class Selection:
    """The outcome of a selection rule.

    Attributes
    ----------
    index : int
        Row of the chosen design in X / F.
    rule : str
        The rule that chose it.
    constraint_met : bool
        False only when ``min_mdr_far_le`` found no design with FAR <= alpha and fell
        back to the lowest-FAR design.
    """

    index: int
    rule: str
    constraint_met: bool = True


def max_accuracy(F) -> int:
    """Index of the design with the largest detection accuracy 1 − FAR − MDR.

    Accuracies within 1e-12 of the best are ties, broken by the lower FAR (then the
    lower MDR, then the first row).
    """
    F = _check_front(F)
    values = accuracy(F[:, 0], F[:, 1])
    candidates = np.flatnonzero(values >= values.max() - TIE_TOLERANCE)
    return _lowest_far(F, candidates)


def knee(F) -> int:
    """Index of the knee: the design farthest from the line through the two extremes.

    Both objectives are first scaled to [0, 1] by the set's own minimum and maximum
    (an objective with no spread is left unscaled). Because the extremes span those
    ranges, the ranking of distances is the same as in raw units (an affine map keeps
    ratios of distances to a line); the scaling only keeps the arithmetic well
    conditioned when FAR and MDR differ by orders of magnitude. The extremes are the lowest-FAR and
    the lowest-MDR designs (ties broken by the other objective). Distances are signed,
    positive on the side of the ideal point (0, 0), so for a convex front the knee is the
    bulge towards the ideal; on a straight or concave front no point lies on that side and
    the rule returns the point closest to the line from the far side, i.e. an extreme.
    Ties (within 1e-12) go to the lower FAR. With a single design, or when one design is
    best in both objectives, that design is returned.
    """
    F = _check_front(F)
    spread = F.max(axis=0) - F.min(axis=0)
    scaled = (F - F.min(axis=0)) / np.where(spread > 0, spread, 1.0)
    every = np.arange(len(F))
    low_far = _lowest_far(scaled, every)
    low_mdr = _lowest_far(scaled[:, ::-1], every)
    direction = scaled[low_mdr] - scaled[low_far]
    length = np.hypot(*direction)
    if length == 0.0:
        return low_far
    # minus the 2-D cross product (direction × relative): with the extremes at (0, a) and
    # (b, 0) it is positive exactly on the ideal point's side of the line
    relative = scaled - scaled[low_far]
    distance = (direction[1] * relative[:, 0] - direction[0] * relative[:, 1]) / length
    candidates = np.flatnonzero(distance >= distance.max() - TIE_TOLERANCE)
    return _lowest_far(F, candidates)


def min_mdr_far_le(F, alpha: float = 0.05) -> Selection:
    """The lowest-MDR design among those with FAR <= alpha.

    Ties in MDR (within 1e-12) go to the lower FAR; FAR is compared with alpha with the
    same tolerance. If no design meets FAR <= alpha, the rule does not fail: it returns
    the lowest-FAR design (ties → lower MDR) with ``constraint_met=False`` and issues a
    :class:`SelectionWarning`, so a pipeline run still finishes and records that the
    false-alarm budget was not met.
    """
    F = _check_front(F)
    alpha = check_in("selection.alpha", alpha, Interval(0.0, 1.0))
    feasible = np.flatnonzero(F[:, 0] <= alpha + TIE_TOLERANCE)
    if feasible.size == 0:
        index = _lowest_far(F, np.arange(len(F)))
        warnings.warn(f"no design has FAR <= {alpha:g} (lowest FAR {F[index, 0]:.4g}); "
                      "chose the lowest-FAR design", SelectionWarning, stacklevel=2)
        return Selection(index, "min_mdr_far_le", constraint_met=False)
    mdr = F[feasible, 1]
    candidates = feasible[mdr <= mdr.min() + TIE_TOLERANCE]
    return Selection(_lowest_far(F, candidates), "min_mdr_far_le")


def select(F, rule: str = "max_accuracy", alpha: float = 0.05) -> Selection:
    """Apply a named rule and return a :class:`Selection` (index plus whether it is clean)."""
    if rule == "max_accuracy":
        return Selection(max_accuracy(F), rule)
    if rule == "knee":
        return Selection(knee(F), rule)
    if rule == "min_mdr_far_le":
        return min_mdr_far_le(F, alpha)
    raise ConfigError(f"selection.rule={rule!r} is not allowed; allowed: {', '.join(RULES)}")


def ideal_distance(F) -> int:
    """Index of the design closest to the ideal point, every objective scaled to [0, 1] over F.

    The knee rule for three or more objectives; ties go to the first row.
    """
    F = np.asarray(F, dtype=float)
    spread = F.max(axis=0) - F.min(axis=0)
    scaled = (F - F.min(axis=0)) / np.where(spread > 0, spread, 1.0)
    distance = np.sqrt((scaled**2).sum(axis=1))
    return int(np.argmax(distance <= distance.min() + TIE_TOLERANCE))


def choose(X, F, rule: str = "max_accuracy", alpha: float = 0.05, objectives=("far", "mdr")) -> int:
    """Row index of the chosen design in the archive (X, F).

    Parameters
    ----------
    X : array_like, shape (n, n_var)
        Archive designs (only checked to match F).
    F : array_like, shape (n, d)
        Objective values, columns named by ``objectives``.
    rule : {"max_accuracy", "knee", "min_mdr_far_le"}
        See the functions of the same names; the first and last need ``far`` and
        ``mdr`` among the objectives.
    alpha : float
        FAR budget of ``min_mdr_far_le``.
    objectives : sequence of str
        Names of F's columns (default: FAR, MDR).

    Returns
    -------
    int
    """
    objectives = tuple(objectives)
    F = np.asarray(F, dtype=float)
    if F.ndim != 2 or F.shape[1] != len(objectives) or len(F) == 0:
        raise ValueError(f"F must have shape (n >= 1, {len(objectives)}) with columns {', '.join(objectives)}; "
                         f"got {F.shape}")
    X = np.asarray(X)
    if len(X) != len(F):
        raise ValueError(f"X has {len(X)} rows but F has {len(F)}; they must match")
    if np.isnan(F).any():
        raise ValueError("F has NaN entries")
    # a design with an undefined (infinite) objective only wins when every design has one
    finite = np.flatnonzero(np.isfinite(F).all(axis=1))
    rows = finite if finite.size else np.arange(len(F))
    sub = np.where(np.isfinite(F[rows]), F[rows], np.finfo(float).max / 4)
    if rule == "knee" and objectives != ("far", "mdr"):
        if len(objectives) == 2:
            return int(rows[knee(sub)])
        return int(rows[ideal_distance(sub)])
    far = false_alarm_column(rule, objectives)
    if objectives != (far, "mdr"):
        sub = sub[:, [objectives.index(far), objectives.index("mdr")]]
    return int(rows[select(sub, rule, alpha).index])


#: objectives that play FAR in the FAR/MDR rules, in order of preference: the false-alarm rate, or
#: paper 002's false isolation (alarms while only the nuisance fault acts)
FALSE_ALARM_OBJECTIVES = ("far", "nuisance_alarm_rate")


def false_alarm_column(rule: str, objectives) -> str:
    """The objective that plays FAR in ``rule`` (``far``, else ``nuisance_alarm_rate``), or a one-line error."""
    objectives = tuple(objectives)
    far = next((name for name in FALSE_ALARM_OBJECTIVES if name in objectives), None)
    if rule != "knee" and (far is None or "mdr" not in objectives):
        raise ConfigError(f"selection.rule={rule} needs far and mdr (or nuisance_alarm_rate and mdr) among "
                          f"optimizer.objectives ({', '.join(objectives)}); allowed: knee")
    return far or "far"


def _check_front(F) -> np.ndarray:
    F = np.asarray(F, dtype=float)
    if F.ndim != 2 or F.shape[1] != 2 or len(F) == 0:
        raise ValueError(f"F must have shape (n >= 1, 2) with columns FAR, MDR; got {F.shape}")
    if not np.all(np.isfinite(F)):
        raise ValueError("F has non-finite entries")
    return F


def _lowest_far(F: np.ndarray, candidates: np.ndarray) -> int:
    """Among ``candidates``, the lowest F[:, 0], then lowest F[:, 1], then the first row."""
    far = F[candidates, 0]
    near_best = candidates[far <= far.min() + TIE_TOLERANCE]
    mdr = F[near_best, 1]
    return int(near_best[np.argmax(mdr <= mdr.min() + TIE_TOLERANCE)])

