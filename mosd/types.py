"""The data contracts that flow through the pipeline (DESIGN.md, "The pipeline").

``Trace`` is what a scenario simulates, ``Residuals`` what an estimator makes of it.
Both carry a batch of independent replications along axis 0 so that every stage
works on all replications in one call.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np


@dataclass(frozen=True)
class Trace:
    """A simulated (or recorded) batch of plant runs.

    Attributes
    ----------
    t : ndarray, shape (N,)
        Sample times in seconds.
    u : ndarray, shape (R, N, n_u)
        Control input applied after sample k (u_k drives x_k -> x_{k+1}).
    x : ndarray, shape (R, N, n_x)
        True states.
    y : ndarray, shape (R, N, n_y)
        Measurements as the estimator sees them, faults included; NaN where a
        sample is missing or a packet was lost.
    fault_mask : ndarray of bool, shape (R, N)
        True where the fault is active.
    meta : dict
        Free-form provenance (seeds, channel names, fault description, ...).
    """

    t: np.ndarray
    u: np.ndarray
    x: np.ndarray
    y: np.ndarray
    fault_mask: np.ndarray
    meta: dict[str, Any] = field(default_factory=dict)

    @property
    def n_reps(self) -> int:
        return self.y.shape[0]

    @property
    def n_samples(self) -> int:
        return self.y.shape[1]


@dataclass(frozen=True)
class Residuals:
    """Residual sequences generated from a :class:`Trace`.

    Attributes
    ----------
    r : ndarray, shape (R, N, m)
        Residual vectors (NaN where the measurement was missing).
    fault_mask : ndarray of bool, shape (R, N)
        Carried over from the trace.
    channels : tuple of str
        Name of each residual channel (length m).
    cov : ndarray, shape (R, N, m, m), optional
        Predicted residual covariance where the generator provides one.
    extra : dict
        Generator-specific outputs (e.g. state estimates, mode probabilities).
    """

    r: np.ndarray
    fault_mask: np.ndarray
    channels: tuple[str, ...]
    cov: np.ndarray | None = None
    extra: dict[str, Any] = field(default_factory=dict)

    def channel(self, name_or_index: str | int) -> np.ndarray:
        """The residual of one channel, shape (R, N)."""
        idx = self.channels.index(name_or_index) if isinstance(name_or_index, str) else int(name_or_index)
        return self.r[..., idx]


@dataclass(frozen=True)
class Subgroups:
    """Standardised residual subgroups, the charts' input.

    Attributes
    ----------
    z : ndarray, shape (R, K, n)
        K subgroups of size n per replication, each value standardised by the
        Phase-I mean and standard deviation of its channel (in control: i.i.d. N(0, 1)).
    fault_mask : ndarray of bool, shape (R, K)
        True where the fault is active at the subgroup's last sample.
    """

    z: np.ndarray
    fault_mask: np.ndarray
