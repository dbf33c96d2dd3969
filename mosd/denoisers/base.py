"""The denoiser contract and the identity denoiser.

A denoiser maps a batch of sequences (..., K) to denoised sequences of the same
shape along the last axis (``denoise``), says whether l_k depends on points
1..k only (``is_causal``; a whole-series wavelet threshold does not) and
describes itself for logs (``describe``).
"""
from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np

from ..validation import Component


@runtime_checkable
class Denoiser(Protocol):
    """What a chart needs of a denoiser."""

    @property
    def is_causal(self) -> bool: ...

    def describe(self) -> dict: ...

    def denoise(self, x) -> np.ndarray: ...


class NoDenoiser(Component):
    """Identity "denoiser": lets a chart run on the raw statistic {L_k} (no parameters)."""

    config_group = "denoise"
    window = None

    @property
    def is_causal(self) -> bool:
        """Always True: l_k = L_k uses nothing from the future."""
        return True

    def describe(self) -> dict:
        """Flat description for logs and results."""
        return {"denoiser": "none", "causal": True, "causality": "identity (causal)"}

    def __repr__(self) -> str:
        return "NoDenoiser()  # identity (causal)"

    def denoise(self, x) -> np.ndarray:
        """Return ``x`` as a float array (a copy, so callers may modify it)."""
        values = np.array(x, dtype=float)
        if values.ndim == 0:
            raise ValueError("denoise needs sequences along the last axis, got a scalar")
        return values
