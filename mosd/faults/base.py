"""The fault contract: what goes wrong, when, and whether it is to be detected.

A fault has an ``onset`` (s) and ``active(t)``; its ``role`` says whether a
detector should find it (``"target"``) or ignore it (``"nuisance"``: an alarm
while only a nuisance fault is active counts as a false alarm, paper 002's
isolation problem). ``relative = True`` means its magnitudes are in units of the
monitored residual's in-control σ from calibration (paper 000): the experiment
computes it (:meth:`mosd.experiment.Experiment.fault_scale`) and passes it to the
plant as ``fault_scale``, and a relative fault simulated without it is refused;
absolute faults ignore it.
A fault declares where it acts, ``acts_on`` (one of :data:`ACTS_ON`), and with
it the interface the plants call:

* ``"sensor"``: an additive signal on one output channel: ``channel`` (0-based,
  into the plant's ``output_names``) and ``signal(t, scale, rng) -> (N,)``
  (:func:`mosd.faults.sensor.sensor_fault_signals` injects it);
* ``"actuator"``: an additive input on one actuator: ``actuator`` (1-based, into
  the plant's ``input_names``) and ``signal(t) -> (N,)``;
* ``"state"``: an additive input of the state equation: ``signal(t, scale, rng) -> (N,)``.

A plant declares where its ``simulate`` injects faults (``Plant.fault_targets``)
and :meth:`mosd.plants.base.Plant.check_fault` follows from the two
declarations: a fault acting where the plant takes none, or on a channel or
actuator the plant does not have, is refused in one line before any simulation.

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

#: where a fault can act (``Fault.acts_on``), in the words of the module docstring
ACTS_ON = ("state", "actuator", "sensor")


class Fault(Component):
    """Base class of every fault (module docstring)."""

    config_group = "fault"
    params = {
        "onset": Param(Interval(0.0, math.inf), "Time (s) from which the fault is active."),
        "role": Param(ROLES, "target: to be detected; nuisance: an alarm on it is a false alarm."),
    }
    relative: bool = False
    #: where the fault acts: one of ACTS_ON (every fault class declares it; "" refuses it on every plant)
    acts_on: str = ""

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
        # where the members act (a plant checks each member: Plant.check_fault)
        self.acts_on = ", ".join(dict.fromkeys(f.acts_on for f in faults))

    @property
    def members(self) -> tuple[Fault, ...]:
        return self.faults

    def __repr__(self) -> str:
        return f"FaultSet({list(self.faults)!r})"
