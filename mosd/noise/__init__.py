"""Noise models (the contract in :mod:`.base`); one module per model."""
from .base import NoiseModel
from .gaussian import GaussianNoise

__all__ = ["GaussianNoise", "NoiseModel"]
