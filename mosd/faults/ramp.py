"""A ramp (slowly varying, "drift") sensor fault in absolute units (paper 003).

Paper 003 (Wang et al. 2020, §2.2, Table 1) injects into the GPS altitude log
ramps of 0.1 … 1.0 m/s from step 500 (100 s at 5 Hz): g(t) = rate · (t − onset)
for t >= onset, 0 before. Unlike :class:`~mosd.faults.sensor.SensorFault`
(magnitudes in units of the residual's σ) the rate is in the channel's own
units per second, so the fault does not depend on any calibration.
"""
from __future__ import annotations

import math

import numpy as np

from ..validation import Interval, Param
from .base import Fault


class RampFault(Fault):
    """g(t) = rate · (t − onset) on one output channel from ``onset`` on (paper 003: 100 s = step 500)."""

    params = {
        "rate": Param(Interval(-100.0, 100.0), "Slope in the channel's units per second (m/s for the GPS "
                      "altitude); paper 003: 0.1 … 1.0.", nonzero=True),
        "channel": Param(Interval(0, math.inf, integer=True), "Index of the faulty output channel "
                         "(flapping-wing plant: 0, the GPS altitude)."),
    }
    relative = False  # the rate is in absolute units
    acts_on = "sensor"  # g added to output `channel` (sensor_fault_signals)

    def __init__(self, rate: float = 0.5, channel: int = 0, onset: float = 100.0, role: str = "target"):
        super().__init__(onset=onset, role=role)
        self._assign(locals())

    def __repr__(self) -> str:
        return f"RampFault(rate={self.rate}, channel={self.channel}, onset={self.onset}, role={self.role!r})"

    def signal(self, t: np.ndarray, scale: float, rng: np.random.Generator) -> np.ndarray:
        """g_k for one replication, shape (N,); ``scale`` and ``rng`` are unused (absolute, deterministic)."""
        t = np.asarray(t, float)
        return np.where(self.active(t), self.rate * (t - self.onset), 0.0)
