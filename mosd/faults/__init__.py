"""Faults (the contract in :mod:`.base`); one module per fault family."""
from .base import Fault, FaultSet
from .sensor import FAULT_KINDS, SensorFault, sensor_fault_signals

__all__ = ["FAULT_KINDS", "Fault", "FaultSet", "SensorFault", "sensor_fault_signals"]
