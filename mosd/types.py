"""The data contracts that flow through the pipeline (docs/ARCHITECTURE.md).

``Trace`` is what a scenario simulates, ``Residuals`` what an estimator makes of
it, ``Subgroups`` what a monitor hands to a detector. All carry a batch of
independent replications along axis 0 so that every stage works on all
replications in one call.

Fault truth is carried twice: ``fault_mask`` (True where the *target* fault is
active — what FAR/MDR score against) and ``fault_label`` (0 where no fault is
active, i where fault i of the scenario is active, i = 1, 2, ...), with
``fault_roles[i - 1]`` saying whether fault i is a ``"target"`` (to be detected)
or a ``"nuisance"`` (to be ignored; an alarm on it is a false alarm).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

ROLES = ("target", "nuisance")


def _labels(fault_mask: np.ndarray, fault_label: np.ndarray | None) -> np.ndarray:
    if fault_label is None:
        return np.asarray(fault_mask, bool).astype(np.int8)
    label = np.asarray(fault_label)
    if label.shape != np.shape(fault_mask):
        raise ValueError(f"fault_label has shape {label.shape}, fault_mask {np.shape(fault_mask)}")
    return label


@dataclass(frozen=True)
class SensorSamples:
    """Asynchronous samples of one sensor over a batch of replications.

    Sensors of a networked system sample at their own instants (own first
    sample, own period, possibly random) and lose packets; each replication may
    have a different number of samples, so the arrays are padded with NaN.

    Attributes
    ----------
    t : ndarray, shape (R, S)
        Sample instants in seconds, NaN past the replication's last sample.
    y : ndarray, shape (R, S, m)
        Measurements as sent by the sensor (NaN in the padding).
    arrived : ndarray of bool, shape (R, S)
        True where the packet reached the fusion centre.
    """

    t: np.ndarray
    y: np.ndarray
    arrived: np.ndarray

    @property
    def received(self) -> np.ndarray:
        """True where a real sample exists and its packet arrived."""
        return self.arrived & np.isfinite(self.t)


@dataclass(frozen=True)
class Trace:
    """A simulated (or recorded) batch of plant runs.

    Attributes
    ----------
    t : ndarray, shape (N,)
        The base time grid in seconds (sample instants, or the fusion instants
        of an asynchronous system).
    u : ndarray, shape (R, N, n_u)
        Control input applied after sample k (u_k drives x_k -> x_{k+1}).
    x : ndarray, shape (R, N, n_x)
        True states on the base grid.
    y : ndarray, shape (R, N, n_y)
        Measurements on the base grid as the estimator sees them, faults
        included; NaN where a sample is missing or a packet was lost (an
        asynchronous system may leave this empty, n_y = 0, and use ``sensors``).
    fault_mask : ndarray of bool, shape (R, N)
        True where the target fault is active.
    meta : dict
        Free-form provenance (seeds, channel names, fault description, ...).
    fault_label : ndarray of int, shape (R, N), optional
        Which fault is active (module docstring); default ``fault_mask`` as 0/1.
    fault_roles : tuple of str
        Role of fault 1, 2, ... (``"target"`` or ``"nuisance"``).
    sensors : dict of str -> SensorSamples
        Per-sensor asynchronous samples (empty for a single-rate plant).
    """

    t: np.ndarray
    u: np.ndarray
    x: np.ndarray
    y: np.ndarray
    fault_mask: np.ndarray
    meta: dict[str, Any] = field(default_factory=dict)
    fault_label: np.ndarray | None = None
    fault_roles: tuple[str, ...] = ("target",)
    sensors: dict[str, SensorSamples] = field(default_factory=dict)

    def __post_init__(self):
        object.__setattr__(self, "fault_label", _labels(self.fault_mask, self.fault_label))

    @property
    def n_reps(self) -> int:
        return self.x.shape[0]

    @property
    def n_samples(self) -> int:
        return self.t.shape[0]


@dataclass(frozen=True)
class Residuals:
    """What an estimator makes of a :class:`Trace`: residuals and other outputs.

    Attributes
    ----------
    r : ndarray, shape (R, N, m)
        Residual vectors (NaN where the measurement was missing); m may be 0
        for an estimator whose detector reads ``extra`` only.
    fault_mask : ndarray of bool, shape (R, N)
        Carried over from the trace.
    channels : tuple of str
        Name of each residual channel (length m).
    cov : ndarray, shape (R, N, m, m), optional
        Predicted residual covariance where the generator provides one.
    extra : dict
        Further outputs on the same grid, each (R, N, ...): state estimates
        (``"x_filt"``), mode probabilities (``"mode_probabilities"``), test
        statistics (``"chi2"``), ...
    fault_label, fault_roles : see :class:`Trace`
    t : ndarray, shape (N,), optional
        Time of each output (the trace's base grid).
    """

    r: np.ndarray
    fault_mask: np.ndarray
    channels: tuple[str, ...]
    cov: np.ndarray | None = None
    extra: dict[str, Any] = field(default_factory=dict)
    fault_label: np.ndarray | None = None
    fault_roles: tuple[str, ...] = ("target",)
    t: np.ndarray | None = None

    def __post_init__(self):
        object.__setattr__(self, "fault_label", _labels(self.fault_mask, self.fault_label))

    @classmethod
    def of(cls, trace: Trace, r: np.ndarray, channels, **kwargs) -> "Residuals":
        """Residuals of ``trace`` with its fault truth and time grid carried over."""
        return cls(r=r, fault_mask=trace.fault_mask, channels=tuple(channels), fault_label=trace.fault_label,
                   fault_roles=trace.fault_roles, t=trace.t, **kwargs)

    def channel(self, name_or_index: str | int) -> np.ndarray:
        """The residual of one channel, shape (R, N)."""
        idx = self.channels.index(name_or_index) if isinstance(name_or_index, str) else int(name_or_index)
        return self.r[..., idx]


@dataclass(frozen=True)
class Subgroups:
    """A detector's input: points on the detection grid.

    Attributes
    ----------
    z : ndarray, shape (R, K, n)
        K points per replication with n values each: for an SPC chart, the
        standardised residual subgroups (in control i.i.d. N(0, 1)); for other
        detectors, selected estimator outputs (mode probabilities, χ² values, ...).
    fault_mask : ndarray of bool, shape (R, K)
        True where the target fault is active at the point's last sample.
    fault_label : ndarray of int, shape (R, K), optional
    fault_roles : tuple of str
    t : ndarray, shape (K,), optional
        Time of each point in seconds.
    """

    z: np.ndarray
    fault_mask: np.ndarray
    fault_label: np.ndarray | None = None
    fault_roles: tuple[str, ...] = ("target",)
    t: np.ndarray | None = None

    def __post_init__(self):
        object.__setattr__(self, "fault_label", _labels(self.fault_mask, self.fault_label))
