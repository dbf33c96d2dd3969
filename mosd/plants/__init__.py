"""Plants (the contract in :mod:`.base`); one module per plant."""
from ..exports import lazy
from .base import ClosedLoopPlant, Plant
from .mould_oscillator import MouldOscillator, SpeedPI

#: the other components of the kind, imported on first use (mosd.exports)
_LAZY = {
    "FlappingWingMAV": "flapping_wing",
    "NetworkedTarget": "networked_target",
    "ScalarNonlinearPlant": "scalar_nonlinear",
}
__getattr__, __dir__, __all__ = lazy(__name__, _LAZY, [
    "ClosedLoopPlant", "MouldOscillator", "Plant", "SpeedPI",
])
