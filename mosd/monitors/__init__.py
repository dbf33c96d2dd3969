"""Monitors: estimator outputs -> the detector's points (the contract in :mod:`.base`)."""
from .base import Monitor
from .outputs import OutputMonitor
from .subgroups import SubgroupMonitor

__all__ = ["Monitor", "OutputMonitor", "SubgroupMonitor"]
