"""Detection metrics (paper 000, eqs. 32–34, and run-level rates).

Every function takes decisions (0 = no alarm, i >= 1 = fault i declared; a
boolean alarm array works too) and the target-fault mask with time on the last
axis, and returns one value per leading index (per replication, per candidate,
...). Points where no target fault is active — fault-free or nuisance-only —
are the "healthy" points of the false-alarm rate.
"""
from __future__ import annotations

import numpy as np

from .summary import accuracy


def _alarms(decisions: np.ndarray) -> np.ndarray:
    decisions = np.asarray(decisions)
    return decisions if decisions.dtype == bool else decisions != 0


def false_alarm_rate(alarms: np.ndarray, fault_mask: np.ndarray) -> np.ndarray:
    """FAR = share of points without the target fault that raise an alarm (eq. 32)."""
    alarms = _alarms(alarms)
    healthy = ~np.asarray(fault_mask, bool)
    return _share(alarms & healthy, healthy)


def missed_detection_rate(alarms: np.ndarray, fault_mask: np.ndarray) -> np.ndarray:
    """MDR = share of target-fault points without an alarm = 1 − FDR (eq. 33)."""
    alarms = _alarms(alarms)
    faulty = np.asarray(fault_mask, bool)
    return _share(~alarms & faulty, faulty)


def fault_detection_rate(alarms: np.ndarray, fault_mask: np.ndarray) -> np.ndarray:
    """FDR = share of target-fault points with an alarm (eq. 34)."""
    return 1.0 - missed_detection_rate(alarms, fault_mask)


def detection_accuracy(alarms: np.ndarray, fault_mask: np.ndarray) -> np.ndarray:
    """The paper's "detection accuracy" 1 − FAR − MDR."""
    return accuracy(false_alarm_rate(alarms, fault_mask), missed_detection_rate(alarms, fault_mask))


def _first_hit(alarms: np.ndarray, fault_mask: np.ndarray):
    """Onset index, first alarmed faulty index, whether any, whether a fault exists."""
    faulty = np.broadcast_to(fault_mask, alarms.shape)
    hit = alarms & faulty
    return np.argmax(faulty, axis=-1), np.argmax(hit, axis=-1), hit.any(axis=-1), faulty.any(axis=-1)


def detection_delay(alarms: np.ndarray, fault_mask: np.ndarray) -> np.ndarray:
    """Points from the fault onset to the first alarm at or after it (0 = at onset).

    NaN where the fault is never detected or never present: a mean of this is
    over the detected runs only — report it beside :func:`detection_rate`, or
    use :func:`censored_delay`.
    """
    onset, first, detected, has_fault = _first_hit(_alarms(alarms), fault_mask)
    return np.where(has_fault & detected, (first - onset).astype(float), np.nan)


def censored_delay(alarms: np.ndarray, fault_mask: np.ndarray) -> np.ndarray:
    """:func:`detection_delay` with an undetected run counted as the whole faulty horizon.

    An undetected run gets the number of faulty points (the delay is "beyond the
    horizon"), so a detector that misses runs cannot show a short delay. NaN only
    where the run has no target fault.
    """
    alarms = _alarms(alarms)
    onset, first, detected, has_fault = _first_hit(alarms, fault_mask)
    horizon = np.broadcast_to(fault_mask, alarms.shape).sum(axis=-1)
    delay = np.where(detected, first - onset, horizon).astype(float)
    return np.where(has_fault, delay, np.nan)


def detection_rate(alarms: np.ndarray, fault_mask: np.ndarray) -> np.ndarray:
    """1 where the target fault is detected at or after its onset, 0 where not, NaN without a target fault."""
    _, _, detected, has_fault = _first_hit(_alarms(alarms), fault_mask)
    return np.where(has_fault, detected.astype(float), np.nan)


def isolation_rate(decisions: np.ndarray, fault_mask: np.ndarray, fault_label: np.ndarray) -> np.ndarray:
    """1 where the first decision at or after the target onset names the true fault, else 0.

    NaN for runs without a target fault. For a binary detector on a single fault
    this equals :func:`detection_rate`.
    """
    decisions = np.asarray(decisions)
    alarms = _alarms(decisions)
    onset, first, detected, has_fault = _first_hit(alarms, fault_mask)
    label = np.broadcast_to(fault_label, alarms.shape)
    named = np.take_along_axis(decisions.astype(int), first[..., None], axis=-1)[..., 0]
    truth = np.take_along_axis(label.astype(int), first[..., None], axis=-1)[..., 0]
    return np.where(has_fault, (detected & (named == truth)).astype(float), np.nan)


def false_alarm_run_rate(alarms: np.ndarray, fault_mask: np.ndarray) -> np.ndarray:
    """1 where a run raises any alarm on a point without the target fault, else 0."""
    alarms = _alarms(alarms)
    healthy = ~np.broadcast_to(fault_mask, alarms.shape)
    return np.where(healthy.any(axis=-1), (alarms & healthy).any(axis=-1).astype(float), np.nan)


def role_alarm_rate(alarms: np.ndarray, fault_label: np.ndarray, fault_roles, role: str = "nuisance") -> np.ndarray:
    """Share of the points where a fault of ``role`` is active that raise an alarm (per run).

    Paper 002's false isolation: an alarm while only the nuisance fault acts names the
    wrong fault. ``fault_label`` is 0 (no fault) or i >= 1 (fault ``fault_roles[i - 1]``
    active). NaN for runs without such points.
    """
    alarms = _alarms(alarms)
    codes = [i + 1 for i, r in enumerate(fault_roles) if r == role]
    # the role's points of each run, then broadcast over the designs: np.isin over the (P, R, K) broadcast was
    # 43 % of paper 002's candidate evaluation
    points = np.isin(np.asarray(fault_label), codes)
    return _share(alarms & points, points)


def _share(numerator: np.ndarray, points: np.ndarray) -> np.ndarray:
    """numerator's True points over ``points``' per row, NaN where a row has no point; ``points`` broadcasts
    against ``numerator`` (a run's mask, not repeated per design: its count is taken once and broadcast)."""
    count = np.broadcast_to(np.asarray(points).sum(axis=-1), numerator.shape[:-1])
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(count > 0, numerator.sum(axis=-1) / np.maximum(count, 1), np.nan)
