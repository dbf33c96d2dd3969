"""Sensor faults g_k added to one output channel from an onset time.

Magnitudes are in units of σ, the in-control residual standard deviation of the
faulty channel from Phase-I calibration, so that the residual follows
N(μ + aσ, b²σ²) after the onset as in paper 000 (§2.1). The variance fault adds
independent noise of standard deviation σ√(b² − 1) to the sensor: for a residual
that does not feed the faulty sensor back into its own prediction (the dedicated
observer of :mod:`mosd.estimators.residuals`) the residual's standard deviation becomes bσ.
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from ..validation import ConfigError, Interval, Param
from .base import Fault

FAULT_KINDS = ("offset", "variance", "offset_var", "drift")


def unit_of(fault, scale: float | None) -> float:
    """``scale`` for a relative fault (required: no default unit can be right), 1 for an absolute one or None."""
    if fault is None or not fault.relative:
        return 1.0
    if scale is None:
        raise ValueError(f"{fault!r} is relative (in σ of the fault-free residual) but no fault_scale was given; "
                         "simulate it through mosd.experiment.Experiment, which computes it (fault_scale)")
    return float(scale)


def sensor_fault_signals(fault, t: np.ndarray, rngs: Sequence[np.random.Generator], n_outputs: int,
                         scale: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The additive sensor-fault signal g of every replication, and where the fault is active.

    The one injection of a sensor fault (a :class:`SensorFault`, a
    :class:`~mosd.faults.ramp.RampFault`: anything with ``channel``,
    ``signal(t, scale, rng)`` and ``active(t)``): the plants add ``g`` to their
    outputs, and a study that adds a fault to a fault-free log after the fact
    gets the same numbers as the plant.

    Parameters
    ----------
    fault : fault or None
        None: no fault (g = 0, the mask all False).
    t : ndarray, shape (N,)
        Sample times (s).
    rngs : sequence of numpy.random.Generator
        One per replication, in order (replication r's ``signal`` draws from ``rngs[r]``).
    n_outputs : int
        Number of output channels n_y.
    scale : float or None
        σ of the faulty channel's fault-free residual, the unit of a relative fault's magnitudes
        (:meth:`mosd.experiment.Experiment.fault_scale` computes it); None refuses a relative
        fault, an absolute one ignores it.

    Returns
    -------
    g : ndarray, shape (R, N, n_y)
        Zero except on the fault's channel.
    mask : ndarray of bool, shape (R, N)
        True where the fault is active.
    """
    t = np.asarray(t, float)
    scale = unit_of(fault, scale)
    g = np.zeros((len(rngs), t.shape[0], int(n_outputs)))
    mask = np.zeros((len(rngs), t.shape[0]), dtype=bool)
    if fault is not None:
        for r, rng in enumerate(rngs):
            g[r, :, fault.channel] = fault.signal(t, scale, rng)
        mask[:] = fault.active(t)
    return g, mask


class SensorFault(Fault):
    """An additive sensor fault on one output channel."""

    params = {
        "kind": Param(FAULT_KINDS, "offset: g = aσ; variance: extra noise so the std becomes bσ; offset_var: both; "
                      "drift: g = aσ (t − t_onset) per second (a ramp)."),
        "channel": Param(Interval(0, math.inf, integer=True), "Index of the faulty output channel (paper 000: 0, "
                         "the displacement x_p)."),
        "a": Param(Interval(-1e6, 1e6), "Offset in σ (drift: σ per second)."),
        "b": Param(Interval(1.0, 1e6), "Standard-deviation factor."),
    }
    relative = True  # magnitudes in units of the channel's in-control residual σ
    acts_on = "sensor"  # g added to output `channel` (sensor_fault_signals)

    def __init__(self, kind: str = "offset", channel: int = 0, onset: float = 2.7, a: float = 2.0, b: float = 1.0,
                 role: str = "target"):
        super().__init__(onset=onset, role=role)
        self._assign(locals())
        if self.kind in ("offset", "offset_var", "drift") and self.a == 0.0:
            raise ConfigError(f"fault.a=0 makes the {kind} fault empty; allowed: a != 0")
        if self.kind in ("variance", "offset_var") and self.b == 1.0:
            raise ConfigError(f"fault.b=1 makes the {kind} fault empty; allowed: b > 1")

    def __repr__(self) -> str:
        return f"SensorFault(kind={self.kind!r}, channel={self.channel}, onset={self.onset}, a={self.a}, b={self.b})"

    def signal(self, t: np.ndarray, scale: float, rng: np.random.Generator) -> np.ndarray:
        """g_k for one replication, shape (N,), in the channel's units.

        ``scale`` is σ of the channel's residual; ``rng`` draws the extra noise
        of the variance faults (one draw per sample, made whatever the kind so
        that the fault-free part of a run does not depend on it).
        """
        t = np.asarray(t, float)
        on = self.active(t)
        noise = rng.standard_normal(t.shape[0])
        g = np.zeros_like(t)
        if self.kind in ("offset", "offset_var"):
            g += self.a * scale
        elif self.kind == "drift":
            g += self.a * scale * np.clip(t - self.onset, 0.0, None)
        if self.kind in ("variance", "offset_var"):
            g += math.sqrt(self.b**2 - 1.0) * scale * noise
        return np.where(on, g, 0.0)
