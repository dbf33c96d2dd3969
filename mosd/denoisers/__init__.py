"""Denoisers of a chart statistic: one module per denoiser, the contract in :mod:`.base`."""
from .base import Denoiser, NoDenoiser
from .wavelet import WaveletDenoiser, select_threshold, threshold_coefficients

__all__ = ["Denoiser", "NoDenoiser", "WaveletDenoiser", "select_threshold", "threshold_coefficients"]
