"""Constant additive actuator faults (paper 001, §2).

Paper 001 writes a fault on actuator m as the extra input e_m f: e_m the m-th
column of the identity (the fault's direction), f a scalar amplitude that is
constant (or slowly varying) from the onset. The plant adds B e_m f to its
input; the estimator does not know f and estimates it as an augmented state.
"""
from __future__ import annotations

import math

import numpy as np

from ..validation import Interval, Param
from .base import Fault


class ActuatorFault(Fault):
    """A constant additive fault of amplitude f on one actuator from ``onset`` on (paper: 16.5 s)."""

    params = {
        "actuator": Param(Interval(1, math.inf, integer=True), "Which actuator fails, numbered from 1 as in the "
                          "paper (its example: 2); a detector that isolates declares fault i for actuator i."),
        "amplitude": Param(Interval(-1e6, 1e6), "f, in the units of the input (paper: 2).", nonzero=True),
    }
    relative = False  # amplitudes are in input units, not in residual σ
    acts_on = "actuator"  # f added to input `actuator` (1-based)

    def __init__(self, actuator: int = 2, amplitude: float = 2.0, onset: float = 16.5, role: str = "target"):
        super().__init__(onset=onset, role=role)
        self._assign(locals())

    def __repr__(self) -> str:
        return f"ActuatorFault(actuator={self.actuator}, amplitude={self.amplitude}, onset={self.onset})"

    def signal(self, t: np.ndarray) -> np.ndarray:
        """f(t): the amplitude where the fault is active, 0 before; shape of ``t``."""
        return np.where(self.active(t), self.amplitude, 0.0)

