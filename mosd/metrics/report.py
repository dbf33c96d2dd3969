"""Per-run metrics of one design on one set of runs, and their confidence intervals."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .registry import METRICS, per_run
from .summary import Estimate

#: What every report holds (more can be asked for by name).
DEFAULT_METRICS = ("far", "mdr", "accuracy", "delay", "detection_rate", "delay_censored")


@dataclass(frozen=True)
class DetectionReport:
    """Per-replication values of named metrics (:mod:`mosd.metrics.registry`).

    ``values[name]`` has one entry per replication (NaN where the metric is
    undefined for that run, e.g. the delay of an undetected run).
    """

    values: dict[str, np.ndarray] = field(default_factory=dict)

    @classmethod
    def of(cls, decisions: np.ndarray, truth, names=DEFAULT_METRICS) -> "DetectionReport":
        """Score decisions (R, K) against ``truth`` (anything with fault_mask / fault_label)."""
        return cls({name: np.asarray(per_run(name, decisions, truth), float) for name in names})

    @property
    def false_alarm_rate(self) -> np.ndarray:
        return self.values["far"]

    @property
    def missed_detection_rate(self) -> np.ndarray:
        return self.values["mdr"]

    @property
    def detection_delay(self) -> np.ndarray:
        return self.values["delay"]

    @property
    def accuracy(self) -> np.ndarray:
        return self.values["accuracy"]

    @property
    def n_runs(self) -> int:
        return len(next(iter(self.values.values())))

    def summary(self) -> dict[str, Estimate]:
        """Mean and 95 % CI of every metric over replications (a delay over detected runs only)."""
        return {name: Estimate.of(v) for name, v in self.values.items()}

    def median_censored_delay(self) -> float:
        """Median delay with undetected runs counted beyond the horizon (inf when most runs are missed)."""
        delay = self.values.get("delay_censored")
        detected = self.values.get("detection_rate")
        if delay is None or detected is None:
            return float("nan")
        v = np.where(detected == 1.0, delay, np.inf)[np.isfinite(detected)]
        return float(np.median(v)) if v.size else float("nan")


__all__ = ["DEFAULT_METRICS", "DetectionReport", "Estimate", "METRICS"]
