"""Detection metrics by name: what runs report and what optimisers minimise.

Each :class:`Metric` maps decisions (..., R, K) and the truth (a
:class:`~mosd.types.Subgroups`) to one value per run (..., R); an objective is the
mean over runs (NaN runs — e.g. the delay of an undetected run — left out).
``minimise`` says whether smaller is better: only those can be objectives
(``optimizer.objectives`` in the config). Register a new metric with
:func:`register`; nothing else needs to change.
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import Callable

import numpy as np

from ..validation import ConfigError
from . import detection


@dataclass(frozen=True)
class Metric:
    """A named per-run detection metric."""

    name: str
    compute: Callable[[np.ndarray, object], np.ndarray]
    minimise: bool
    description: str
    unit: str = ""


METRICS: dict[str, Metric] = {}


def register(name: str, minimise: bool, description: str, unit: str = ""):
    """Decorator: add ``compute(decisions, truth) -> per-run values`` to :data:`METRICS`."""
    def wrap(compute):
        METRICS[name] = Metric(name, compute, minimise, description, unit)
        return compute
    return wrap


register("far", True, "false-alarm rate: share of points without the target fault that alarm (eq. 32)")(
    lambda d, truth: detection.false_alarm_rate(d, truth.fault_mask))
register("mdr", True, "missed-detection rate: share of target-fault points without an alarm (eq. 33)")(
    lambda d, truth: detection.missed_detection_rate(d, truth.fault_mask))
register("accuracy", False, "detection accuracy 1 - FAR - MDR (paper 000)")(
    lambda d, truth: detection.detection_accuracy(d, truth.fault_mask))
register("detection_rate", False, "share of target-fault runs detected at or after the onset")(
    lambda d, truth: detection.detection_rate(d, truth.fault_mask))
register("missed_run_rate", True, "share of target-fault runs never detected (1 - detection_rate)")(
    lambda d, truth: 1.0 - detection.detection_rate(d, truth.fault_mask))
register("delay", True, "points from onset to the first alarm, over detected runs only", "points")(
    lambda d, truth: detection.detection_delay(d, truth.fault_mask))
register("delay_censored", True, "delay with an undetected run counted as the whole faulty horizon", "points")(
    lambda d, truth: detection.censored_delay(d, truth.fault_mask))
register("isolation_rate", False, "share of target-fault runs whose first alarm names the true fault")(
    lambda d, truth: detection.isolation_rate(d, truth.fault_mask, truth.fault_label))
register("false_alarm_run_rate", True, "share of runs with any alarm on a point without the target fault")(
    lambda d, truth: detection.false_alarm_run_rate(d, truth.fault_mask))
register("nuisance_alarm_rate", True, "false isolation: share of points with only a nuisance fault active that "
         "alarm (paper 002)")(
    lambda d, truth: detection.role_alarm_rate(d, truth.fault_label, truth.fault_roles, "nuisance"))


def objective_names() -> list[str]:
    """Names a config may list as objectives (metrics to minimise)."""
    return sorted(name for name, metric in METRICS.items() if metric.minimise)


def check_objectives(names) -> tuple[str, ...]:
    """Validate ``optimizer.objectives``: at least two distinct minimised metrics."""
    if isinstance(names, str):
        names = [names]
    names = tuple(str(n) for n in names)
    allowed = ", ".join(objective_names())
    for name in names:
        if name not in METRICS or not METRICS[name].minimise:
            raise ConfigError(f"optimizer.objectives: {name!r} is not an objective; allowed: {allowed}")
    if len(names) < 2 or len(set(names)) != len(names):
        raise ConfigError(f"optimizer.objectives={list(names)} needs two or more distinct names; allowed: {allowed}")
    return names


def as_truth(truth):
    """``truth`` as something with ``fault_mask`` and ``fault_label``: a Subgroups, or a plain target mask."""
    if hasattr(truth, "fault_mask"):
        return truth
    from ..types import Subgroups

    mask = np.asarray(truth, bool)
    return Subgroups(z=np.empty((0,)), fault_mask=mask)


def per_run(name: str, decisions: np.ndarray, truth) -> np.ndarray:
    """Per-run values of metric ``name`` (``truth``: a Subgroups or the target-fault mask)."""
    return METRICS[name].compute(decisions, as_truth(truth))


def objective_values(names, decisions: np.ndarray, truth) -> np.ndarray:
    """Mean over runs of each named metric: (..., len(names)) for decisions (..., R, K)."""
    columns = []
    truth = as_truth(truth)
    for name in names:
        values = per_run(name, decisions, truth)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # "mean of empty slice": handled just below
            mean = np.nanmean(values, axis=-1)
        # a metric undefined on every run (no detection at all) is the worst case, not a hole
        columns.append(np.where(np.isfinite(mean), mean, np.inf))
    return np.stack(columns, axis=-1)

