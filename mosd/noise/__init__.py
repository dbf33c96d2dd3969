"""Noise models (the contract in :mod:`.base`); one module per model, exported by existing (:mod:`mosd.exports`)."""
from ..exports import lazy
from .base import NoiseModel
from .gaussian import GaussianNoise

#: every module's components, found by a scan of the sources and imported on first use (mosd.exports)
__getattr__, __dir__ = lazy(__name__, globals())
