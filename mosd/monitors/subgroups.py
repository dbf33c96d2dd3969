"""Paper 000's monitor: residuals into standardised subgroups (docs/DECISIONS.md §2).

Two subgrouping modes feed the n-sample statistics of eqs. 19–20:

* ``"window"`` (default): n consecutive residuals of one monitored channel form a
  subgroup. A sensor fault sits on one channel; averaging n samples of that
  channel multiplies a mean shift aσ by √n in U_k (eq. 19), and S_k² sees the
  variance change of that channel alone.
* ``"channels"``: the paper's literal reading (§2.1): the n_y entries of one
  residual vector r_k, each standardised by its own Phase-I μ and σ. A fault on
  one of three channels then moves U_k by only a/√3 and dilutes V_k with two
  healthy channels, which is why it is not the default.
"""
from __future__ import annotations

import math

import numpy as np

from ..types import Residuals, Subgroups
from ..validation import ConfigError, Interval, Param
from .base import Monitor, _grid


class SubgroupMonitor(Monitor):
    """Standardise residuals with Phase-I statistics and cut them into subgroups."""

    params = {
        "subgroup": Param(("window", "channels"), "Subgrouping mode (module docstring)."),
        "n": Param(Interval(2, math.inf, integer=True), "Subgroup size for window (n >= 2 for S_k² in eq. 20)."),
        "channels": Param(Interval(0, math.inf, integer=True), "Monitored residual channels: exactly one for "
                          "window, at least two for channels.", sequence=True),
        "burn_in": Param(Interval(0, math.inf, integer=True), "Samples dropped at the start of every run (filter "
                         "start-up transient)."),
    }

    def __init__(self, subgroup: str = "window", n: int = 5, channels=(0,), burn_in: int = 200):
        self._assign(locals())
        if self.subgroup == "window" and len(self.channels) != 1:
            raise ConfigError(f"monitor.channels={list(self.channels)} must name one channel; allowed: one index with subgroup=window")
        if self.subgroup == "channels" and len(self.channels) < 2:
            raise ConfigError(f"monitor.channels={list(self.channels)} is too short; allowed: >= 2 indices with subgroup=channels")

    @property
    def subgroup_size(self) -> int:
        return self.n if self.subgroup == "window" else len(self.channels)

    def fit(self, residuals: Residuals) -> "Monitor":
        """Estimate μ and σ of each monitored channel from fault-free Phase-I residuals."""
        r = self._monitored(residuals)
        if residuals.fault_mask[:, self.burn_in :].any():
            raise ConfigError("monitor.fit got residuals with an active fault; allowed: fault-free Phase-I data")
        flat = r.reshape(-1, r.shape[-1])
        self.mean_ = np.nanmean(flat, axis=0)
        self.std_ = np.nanstd(flat, axis=0, ddof=1)
        if not np.all(self.std_ > 0):
            raise ConfigError("monitor: a monitored residual channel has zero variance in Phase I")
        return self

    def channel_std(self, channel: int) -> float:
        """σ of one monitored channel (the fault scale of :mod:`mosd.faults.sensor`)."""
        self._check_fitted()
        return float(self.std_[self.channels.index(channel)])

    def fault_scale(self, calibration: Residuals, channel: int) -> float:
        """The Phase-I σ of ``channel``: the fitted one when monitored, else computed alike."""
        if channel in self.channels and hasattr(self, "std_"):
            return self.channel_std(channel)
        return super().fault_scale(calibration, channel)

    def transform(self, residuals: Residuals) -> Subgroups:
        """Standardised subgroups z of shape (R, K, n) and their fault mask (R, K)."""
        self._check_fitted()
        z = (self._monitored(residuals) - self.mean_) / self.std_
        mask = residuals.fault_mask[:, self.burn_in :]
        label = residuals.fault_label[:, self.burn_in :]
        t = _grid(residuals)[self.burn_in :]
        if self.subgroup == "channels":
            return Subgroups(z=z, fault_mask=mask, fault_label=label, fault_roles=residuals.fault_roles, t=t)
        n = self.n
        n_sub = z.shape[1] // n
        if n_sub == 0:
            raise ConfigError(f"monitor.burn_in={self.burn_in} leaves fewer than n={n} samples of a "
                              f"{residuals.r.shape[1]}-sample run; allowed: burn_in <= {residuals.r.shape[1] - n}")
        z = z[:, : n_sub * n, 0].reshape(z.shape[0], n_sub, n)
        last = slice(n - 1, n_sub * n, n)  # a subgroup's fault state is that of its last sample
        return Subgroups(z=z, fault_mask=mask[:, last], fault_label=label[:, last],
                         fault_roles=residuals.fault_roles, t=t[last])

    def _monitored(self, residuals: Residuals) -> np.ndarray:
        m = residuals.r.shape[-1]
        if max(self.channels) >= m:
            raise ConfigError(f"monitor.channels={list(self.channels)} is out of range; allowed: 0..{m - 1}")
        return residuals.r[:, self.burn_in :, list(self.channels)]

    def _check_fitted(self) -> None:
        if not hasattr(self, "std_"):
            raise RuntimeError("Monitor is not fitted: call fit(phase1_residuals) first")
