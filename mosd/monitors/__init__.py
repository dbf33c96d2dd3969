"""Monitors: estimator outputs -> the detector's points (the contract in :mod:`.base`); one module per monitor,
exported by existing (:mod:`mosd.exports`)."""
from ..exports import lazy
from .base import Monitor
from .outputs import OutputMonitor
from .subgroups import SubgroupMonitor

#: every module's components, found by a scan of the sources and imported on first use (mosd.exports)
__getattr__, __dir__ = lazy(__name__, globals())
