"""Noise models (the contract in :mod:`.base`); one module per model."""
from ..exports import lazy
from .base import NoiseModel
from .gaussian import GaussianNoise

#: the other components of the kind, imported on first use (mosd.exports)
_LAZY = {
    "BoundedNoise": "bounded",
    "ContinuousWhiteNoise": "continuous",
}
__getattr__, __dir__, __all__ = lazy(__name__, _LAZY, [
    "GaussianNoise", "NoiseModel",
])
