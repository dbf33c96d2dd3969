"""The fault contract: what goes wrong, when, and whether it is to be detected.

A fault has an ``onset`` (s) and ``active(t)``; its ``role`` says whether a
detector should find it (``"target"``) or ignore it (``"nuisance"``: an alarm
while only a nuisance fault is active counts as a false alarm, paper 002's
isolation problem). ``relative = True`` means its magnitudes are in units of the
monitored residual's in-control σ from calibration (paper 000): the experiment
computes it (:meth:`mosd.experiment.Experiment.fault_scale`) and passes it to the
plant as ``fault_scale``, and a relative fault simulated without it is refused;
absolute faults ignore it.
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
from ..validation import Component, ConfigError, Interval, Param


class Fault(Component):
    """Base class of every fault (module docstring)."""

    config_group = "fault"
    params = {
        "onset": Param(Interval(0.0, math.inf), "Time (s) from which the fault is active."),
        "role": Param(ROLES, "target: to be detected; nuisance: an alarm on it is a false alarm."),
    }
    relative: bool = False

    def __init__(self, onset: float = 0.0, role: str = "target"):
        self._assign(locals())

    def active(self, t: np.ndarray) -> np.ndarray:
        """Boolean mask of the samples at which the fault is present."""
        return np.asarray(t) >= self.onset - 1e-12

    @property
    def members(self) -> tuple["Fault", ...]:
        """The faults a scenario runs side by side (one here)."""
        return (self,)


def _faults(key: str, value, owner) -> tuple:
    faults = tuple(value) if hasattr(value, "__iter__") and not isinstance(value, (str, bytes)) else (value,)
    if not faults or not all(isinstance(f, Fault) for f in faults):
        raise ConfigError(f"{key}={list(faults)!r} is not allowed; allowed: a non-empty list of faults")
    if all(f.role != "target" for f in faults):
        raise ConfigError(f"{key} has no fault with role=target; allowed: at least one target fault")
    return faults


class FaultSet(Fault):
    """Several faults, one per replication in turn (module docstring); onset and role are the members'."""

    params = {"onset": None, "role": None,
              "faults": Param(_faults, "The faults, at least one of them with the role target.",
                              kind="sequence of Fault")}

    def __init__(self, faults: Sequence[Fault]):
        self._assign(locals())
        faults = self.faults
        self.onset = min(f.onset for f in faults)
        self.role = "target"
        self.relative = any(f.relative for f in faults)

    @property
    def members(self) -> tuple[Fault, ...]:
        return self.faults

    def __repr__(self) -> str:
        return f"FaultSet({list(self.faults)!r})"
