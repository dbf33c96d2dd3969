"""The monitor contract: from an estimator's outputs to the points a detector decides on.

``fit(calibration)`` learns what it needs from fault-free calibration outputs
(e.g. the residual mean and σ of Phase I); ``transform(outputs)`` returns
:class:`~mosd.types.Subgroups` — points z (R, K, n) with the fault truth and the
time of every point. ``fault_scale(channel)`` is the in-control σ of a residual
channel, the unit of relative faults (:mod:`mosd.faults.base`).
"""
from __future__ import annotations

import numpy as np

from ..streaming import NoStreamingForm, OnlineStage
from ..types import Residuals, Subgroups
from ..validation import Component, ConfigError


class Monitor(Component):
    """Base class of every monitor (module docstring)."""

    config_group = "monitor"
    burn_in: int = 0

    def fit(self, calibration: Residuals) -> "Monitor":
        return self

    def transform(self, outputs: Residuals) -> Subgroups:
        raise NotImplementedError

    # -- the causal form (mosd.streaming) -------------------------------------------------
    def stream(self, outputs: Residuals, residual_columns=()) -> dict[str, np.ndarray]:
        """The columns this monitor reads over the first replication of ``outputs``, (N,) each, named
        (``residual_columns``: the estimator's name for each residual channel)."""
        raise NoStreamingForm(f"the monitor {type(self).__name__} has no streaming form")

    def online(self, columns) -> OnlineStage:
        """The fitted monitor's causal form on the stream's columns ``columns`` (:meth:`stream`'s names)."""
        raise NoStreamingForm(f"the monitor {type(self).__name__} has no streaming form")

    def fault_scale(self, calibration: Residuals, channel: int) -> float:
        """σ of residual ``channel`` over fault-free calibration outputs (after the burn-in)."""
        r = calibration.r[:, self.burn_in:, channel]
        sigma = float(np.nanstd(r, ddof=1))
        if not np.isfinite(sigma) or sigma <= 0:
            raise ConfigError(f"fault.channel={channel}: the residual has no in-control spread to scale the fault by")
        return sigma


def _grid(outputs: Residuals, dt: float | None = None) -> np.ndarray:
    """The outputs' time grid (their own, or k·dt)."""
    if outputs.t is not None:
        return np.asarray(outputs.t, float)
    return np.arange(outputs.fault_mask.shape[-1]) * (dt or 1.0)
