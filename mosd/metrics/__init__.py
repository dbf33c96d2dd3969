"""Metrics: detection rates and delays by name (:mod:`.registry`), estimation errors, reports."""
from .detection import (censored_delay, detection_accuracy, detection_delay, detection_rate, false_alarm_rate,
                        false_alarm_run_rate, fault_detection_rate, isolation_rate, missed_detection_rate, role_alarm_rate)
from .estimation import rmse, rmse_over_runs
from .registry import METRICS, Metric, check_objectives, objective_names, objective_values, per_run, register
from .report import DEFAULT_METRICS, DetectionReport
from .summary import REFERENCE_VALUE, Estimate, accuracy, confidence_interval, hypervolume, json_ready, reference_point

__all__ = [
    "DEFAULT_METRICS", "DetectionReport", "Estimate", "METRICS", "Metric", "REFERENCE_VALUE", "accuracy",
    "censored_delay", "check_objectives", "confidence_interval", "hypervolume", "reference_point",
    "detection_accuracy", "detection_delay", "detection_rate", "false_alarm_rate", "false_alarm_run_rate",
    "fault_detection_rate", "isolation_rate", "json_ready", "missed_detection_rate", "objective_names", "objective_values",
    "per_run", "register", "role_alarm_rate", "rmse", "rmse_over_runs",
]
