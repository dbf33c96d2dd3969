"""Detectors: the decision from the monitor's points (the contract in :mod:`.base`).

SPC charts (paper 000) derive from :class:`~mosd.detectors.chart.Chart`; one
module per detector family, exported by existing (:mod:`mosd.exports`).
"""
from ..exports import lazy
from .base import Decisions, Detector, persistent
from .chart import Chart
from .ewma_chart import EWMA, MSOEWMA
from .mean_variance import MDEWMA, SSDEWMA, SSEWMA, MaxEWMA, max_abs_normal_moments
from .statistics import (dewma_variance, ewma, ewma_time_major, ewma_variance, subgroup_mean_statistic,
                         subgroup_variance_statistic)

#: every module's components, found by a scan of the sources and imported on first use (mosd.exports)
__getattr__, __dir__ = lazy(__name__, globals())
