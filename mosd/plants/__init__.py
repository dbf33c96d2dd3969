"""Plants (the contract in :mod:`.base`); one module per plant."""
from .base import ClosedLoopPlant, Plant
from .mould_oscillator import MouldOscillator, SpeedPI

__all__ = ["ClosedLoopPlant", "MouldOscillator", "Plant", "SpeedPI"]
