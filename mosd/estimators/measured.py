"""The measured signals themselves as residuals: for data-driven monitors of recorded data.

A PCA monitor (:class:`mosd.detectors.pca.PCADetector`) models the fault-free
correlation of the measurements directly: its residual generator is the PCA it
fits, not a physical model. This estimator hands the measured variables on
unchanged (``r = y``, one channel per variable, named after the variables), so
that the monitor and the detector can read them like any other residuals.
"""
from __future__ import annotations

from typing import Any

from ..types import Residuals, Trace
from .base import Estimator


class MeasuredSignals(Estimator):
    """r = y: every measured variable is a residual channel (module docstring)."""

    def residual_columns(self, outputs: Residuals) -> tuple[str, ...]:
        """The measured variables by their own names (a recorded table's tags)."""
        return tuple(outputs.channels)

    def online(self, model: Any = None, source=None, trace=None):
        """None: the outputs are the measurements themselves (a deployed pipeline starts at the monitor)."""
        return None

    def estimate(self, trace: Trace, model: Any = None) -> Residuals:
        names = tuple(trace.meta.get("variables") or (f"y{i + 1}" for i in range(trace.y.shape[-1])))
        return Residuals.of(trace, r=trace.y, channels=names)
