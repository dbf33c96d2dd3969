"""Detectors: the decision from the monitor's points (the contract in :mod:`.base`).

SPC charts (paper 000) derive from :class:`~mosd.detectors.chart.Chart`; one
module per detector family.
"""
from ..exports import lazy
from .base import Decisions, Detector, persistent
from .chart import Chart
from .ewma_chart import EWMA, MSOEWMA
from .mean_variance import MDEWMA, SSDEWMA, SSEWMA, MaxEWMA, max_abs_normal_moments
from .statistics import (dewma_variance, ewma, ewma_time_major, ewma_variance, subgroup_mean_statistic,
                         subgroup_variance_statistic)

#: the other components of the kind, imported on first use (mosd.exports)
_LAZY = {
    "AdaptiveChi2Detector": "adaptive_chi2",
    "ModeProbabilityDetector": "mode_probability",
    "PCADetector": "pca",
    "ThresholdDetector": "threshold",
}
__getattr__, __dir__, __all__ = lazy(__name__, _LAZY, [
    "Chart", "Decisions", "Detector", "EWMA", "MDEWMA", "MSOEWMA", "MaxEWMA", "SSDEWMA", "SSEWMA", "dewma_variance",
    "ewma", "ewma_time_major", "ewma_variance", "max_abs_normal_moments", "persistent", "subgroup_mean_statistic",
    "subgroup_variance_statistic",
])
