"""Faults (the contract in :mod:`.base`); one module per fault family."""
from ..exports import lazy
from .base import Fault, FaultSet
from .sensor import FAULT_KINDS, SensorFault, sensor_fault_signals

#: the other components of the kind, imported on first use (mosd.exports)
_LAZY = {
    "ActuatorFault": "actuator",
    "RampFault": "ramp",
    "RandomAmplitudeFault": "random_amplitude",
}
__getattr__, __dir__, __all__ = lazy(__name__, _LAZY, [
    "FAULT_KINDS", "Fault", "FaultSet", "SensorFault", "sensor_fault_signals",
])
