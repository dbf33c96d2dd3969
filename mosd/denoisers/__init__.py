"""Denoisers of a chart statistic: one module per denoiser, the contract in :mod:`.base`; exported by existing
(:mod:`mosd.exports`)."""
from ..exports import lazy
from .base import Denoiser, NoDenoiser
from .wavelet import WaveletDenoiser, select_threshold, threshold_coefficients

#: every module's components, found by a scan of the sources and imported on first use (mosd.exports)
__getattr__, __dir__ = lazy(__name__, globals())
