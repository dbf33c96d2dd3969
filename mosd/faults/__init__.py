"""Faults (the contract in :mod:`.base`); one module per fault family, exported by existing (:mod:`mosd.exports`)."""
from ..exports import lazy
from .base import Fault, FaultSet
from .sensor import FAULT_KINDS, SensorFault, sensor_fault_signals

#: every module's components, found by a scan of the sources and imported on first use (mosd.exports)
__getattr__, __dir__ = lazy(__name__, globals())
