"""Detection metrics (paper 000, eqs. 32–34) and their confidence intervals.

All functions take alarms and the fault mask with time on the last axis and
return one value per leading index (per replication, per candidate, ...).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import special


def false_alarm_rate(alarms: np.ndarray, fault_mask: np.ndarray) -> np.ndarray:
    """FAR = share of fault-free points with an alarm (eq. 32)."""
    healthy = ~np.broadcast_to(fault_mask, alarms.shape)
    return _share(alarms & healthy, healthy)


def missed_detection_rate(alarms: np.ndarray, fault_mask: np.ndarray) -> np.ndarray:
    """MDR = share of faulty points without an alarm = 1 − FDR (eq. 33)."""
    faulty = np.broadcast_to(fault_mask, alarms.shape)
    return _share(~alarms & faulty, faulty)


def fault_detection_rate(alarms: np.ndarray, fault_mask: np.ndarray) -> np.ndarray:
    """FDR = share of faulty points with an alarm (eq. 34)."""
    return 1.0 - missed_detection_rate(alarms, fault_mask)


def detection_accuracy(alarms: np.ndarray, fault_mask: np.ndarray) -> np.ndarray:
    """The paper's "detection accuracy" 1 − FAR − MDR."""
    return 1.0 - false_alarm_rate(alarms, fault_mask) - missed_detection_rate(alarms, fault_mask)


def detection_delay(alarms: np.ndarray, fault_mask: np.ndarray) -> np.ndarray:
    """Points from the fault onset to the first alarm at or after it (0 = at onset).

    NaN where the fault is never detected or never present.
    """
    faulty = np.broadcast_to(fault_mask, alarms.shape)
    has_fault = faulty.any(axis=-1)
    onset = np.argmax(faulty, axis=-1)
    hit = alarms & faulty
    detected = hit.any(axis=-1)
    first = np.argmax(hit, axis=-1)
    return np.where(has_fault & detected, (first - onset).astype(float), np.nan)


def _share(numerator: np.ndarray, denominator: np.ndarray) -> np.ndarray:
    count = denominator.sum(axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(count > 0, numerator.sum(axis=-1) / np.maximum(count, 1), np.nan)


@dataclass(frozen=True)
class Estimate:
    """A mean over replications with its 95 % confidence half-width (Student t)."""

    mean: float
    half_width: float
    n: int

    @classmethod
    def of(cls, values: np.ndarray, level: float = 0.95) -> "Estimate":
        v = np.asarray(values, float)
        v = v[np.isfinite(v)]
        if v.size == 0:
            return cls(float("nan"), float("nan"), 0)
        if v.size == 1:
            return cls(float(v[0]), float("nan"), 1)
        sem = v.std(ddof=1) / np.sqrt(v.size)
        return cls(float(v.mean()), float(special.stdtrit(v.size - 1, 0.5 + level / 2) * sem), int(v.size))

    def __str__(self) -> str:
        return f"{self.mean:.4g} ± {self.half_width:.2g}"


@dataclass(frozen=True)
class DetectionReport:
    """Per-replication metrics of one design on one set of runs."""

    false_alarm_rate: np.ndarray
    missed_detection_rate: np.ndarray
    detection_delay: np.ndarray

    @classmethod
    def of(cls, alarms: np.ndarray, fault_mask: np.ndarray) -> "DetectionReport":
        return cls(
            false_alarm_rate(alarms, fault_mask),
            missed_detection_rate(alarms, fault_mask),
            detection_delay(alarms, fault_mask),
        )

    @property
    def accuracy(self) -> np.ndarray:
        return 1.0 - self.false_alarm_rate - self.missed_detection_rate

    def summary(self) -> dict[str, Estimate]:
        """Mean and 95 % CI of FAR, MDR, accuracy and delay over replications."""
        return {
            "far": Estimate.of(self.false_alarm_rate),
            "mdr": Estimate.of(self.missed_detection_rate),
            "accuracy": Estimate.of(self.accuracy),
            "delay": Estimate.of(self.detection_delay),
        }
