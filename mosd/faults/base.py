"""The fault contract: what goes wrong, when, and whether it is to be detected.

A fault has an ``onset`` (s) and ``active(t)``; its ``role`` says whether a
detector should find it (``"target"``) or ignore it (``"nuisance"``: an alarm
while only a nuisance fault is active counts as a false alarm, paper 002's
isolation problem). ``relative = True`` means its magnitudes are in units of the
monitored residual's in-control σ from calibration (paper 000), which the
experiment passes to the plant as ``fault_scale``; absolute faults ignore it.
How a fault acts (on a sensor, an actuator, the state) is the plant's business:
each plant documents the fault classes it accepts.

:class:`FaultSet` runs several faults side by side: replication r of a stream
gets fault ``r mod n`` — e.g. a target fault on even and a nuisance fault on odd
replications, so that an optimiser trades detection of the one against alarms on
the other.
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from ..types import ROLES
from ..validation import ConfigError, Interval, check_choice, check_in


class Fault:
    """Base class of every fault (module docstring).

    Parameters
    ----------
    onset : float
        Time (s) from which the fault is active, >= 0.
    role : {"target", "nuisance"}
    """

    relative: bool = False

    def __init__(self, onset: float = 0.0, role: str = "target"):
        self.onset = check_in("fault.onset", onset, Interval(0.0, math.inf))
        self.role = check_choice("fault.role", role, ROLES)

    def active(self, t: np.ndarray) -> np.ndarray:
        """Boolean mask of the samples at which the fault is present."""
        return np.asarray(t) >= self.onset - 1e-12

    @property
    def members(self) -> tuple["Fault", ...]:
        """The faults a scenario runs side by side (one here)."""
        return (self,)


class FaultSet(Fault):
    """Several faults, one per replication in turn (module docstring).

    Parameters
    ----------
    faults : sequence of Fault
        At least one; at least one of them must have the role ``"target"``.
    """

    def __init__(self, faults: Sequence[Fault]):
        faults = tuple(faults)
        if not faults or not all(isinstance(f, Fault) for f in faults):
            raise ConfigError(f"fault.faults={list(faults)!r} is not allowed; allowed: a non-empty list of faults")
        if all(f.role != "target" for f in faults):
            raise ConfigError("fault.faults has no fault with role=target; allowed: at least one target fault")
        self.faults = faults
        self.onset = min(f.onset for f in faults)
        self.role = "target"
        self.relative = any(f.relative for f in faults)

    @property
    def members(self) -> tuple[Fault, ...]:
        return self.faults

    def __repr__(self) -> str:
        return f"FaultSet({list(self.faults)!r})"
