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
from dataclasses import dataclass

import numpy as np

from ..streaming import COUNT, FINITE, OnlineStage, StateVar
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

    def stream(self, outputs: Residuals, residual_columns=()) -> dict[str, np.ndarray]:
        """The monitored residual channels of the first replication, named as the estimator names them."""
        return {(residual_columns[c] if c < len(residual_columns) else f"residual_{c}"):
                np.asarray(outputs.r[0, :, c], float) for c in self.channels}

    def online(self, columns) -> "OnlineSubgroups":
        """The fitted monitor's causal form on the monitored channels' columns (:meth:`stream`)."""
        self._check_fitted()
        return OnlineSubgroups(columns=tuple(columns), mean=np.asarray(self.mean_, float),
                               std=np.asarray(self.std_, float), subgroup=str(self.subgroup), n=int(self.subgroup_size),
                               burn_in=int(self.burn_in))

    def _monitored(self, residuals: Residuals) -> np.ndarray:
        m = residuals.r.shape[-1]
        if max(self.channels) >= m:
            raise ConfigError(f"monitor.channels={list(self.channels)} is out of range; allowed: 0..{m - 1}")
        return residuals.r[:, self.burn_in :, list(self.channels)]

    def _check_fitted(self) -> None:
        if not hasattr(self, "std_"):
            raise RuntimeError("Monitor is not fitted: call fit(phase1_residuals) first")


@dataclass
class OnlineSubgroups(OnlineStage):
    """:class:`SubgroupMonitor`'s causal form: residual rows in, a standardised subgroup on each row that completes one.

    Inputs: the monitored residual channels, one column each (``columns``), from a stream's start (the
    first ``burn_in`` rows are skipped, as in training). Outputs per row: ``subgroup``, the number
    k = 1, 2, ... of the subgroup the row completes (0 on a row that completes none), and its
    standardised points ``z_1`` ... ``z_n`` (NaN elsewhere; internal: they feed the detector).

    State: ``samples_seen`` (rows since the stream's start) and, for ``window`` subgroups, the raw
    residuals of the unfinished subgroup (``pending_1`` ... ``pending_{n-1}``; only the first
    ``(samples_seen − burn_in) mod n`` count).
    """

    columns: tuple
    mean: np.ndarray
    std: np.ndarray
    subgroup: str
    n: int
    burn_in: int
    accepts_missing = False  # a residual stream has no gaps; a subgroup with one has no U_k, V_k

    @property
    def inputs(self) -> tuple[str, ...]:
        return tuple(self.columns)

    @property
    def points(self) -> tuple[str, ...]:
        return tuple(f"z_{j}" for j in range(1, self.n + 1))

    @property
    def outputs(self) -> tuple[str, ...]:
        return ("subgroup", "point", *self.points)

    @property
    def internal(self) -> tuple[str, ...]:
        return ("point", *self.points)   # point: the subgroup's number, as any monitor names its points

    def state_vars(self) -> dict[str, StateVar]:
        out = {"samples_seen": StateVar("Rows seen since the stream's start.", COUNT)}
        if self.subgroup == "window":
            out.update({f"pending_{j}": StateVar(f"Residual {j} of the unfinished subgroup.", FINITE)
                        for j in range(1, self.n)})
        return out

    def initial_state(self) -> dict:
        return {name: (0 if name == "samples_seen" else 0.0) for name in self.state_vars()}

    def example_row(self) -> np.ndarray:
        return np.asarray(self.mean, float)

    def update(self, columns, state) -> dict[str, np.ndarray]:
        X = np.column_stack([np.asarray(columns[c], float) for c in self.columns]) if self.columns else np.empty((0, 0))
        rows, n = len(X), int(self.n)
        seen = int(state["samples_seen"])
        after = seen + np.arange(rows) - self.burn_in           # sample index past the burn-in (< 0: in it)
        live = after >= 0
        done_before = max(seen - self.burn_in, 0)               # post-burn-in samples before this chunk
        if self.subgroup == "window":
            held = done_before % n                              # samples of the unfinished subgroup carried in
            pending = np.array([float(state[f"pending_{j}"]) for j in range(1, n)])[:held]
            raw = np.concatenate([pending, X[live, 0]])         # post-burn-in samples from the subgroup's start
            first = (done_before - held) // n                   # subgroups completed before this chunk
            complete = len(raw) // n
            z = ((raw[:complete * n, None] - self.mean) / self.std)[:, 0].reshape(complete, n)
            closes = live & ((after + 1) % n == 0)
        else:
            first, z = done_before, (X[live] - self.mean) / self.std
            complete = len(z)
            closes = live
        at = np.flatnonzero(closes)
        out = {"subgroup": np.zeros(rows, np.int64)}
        out["subgroup"][at] = first + np.arange(1, complete + 1)
        out["point"] = out["subgroup"]
        for j, name in enumerate(self.points):
            column = np.full(rows, np.nan)
            column[at] = z[:, j]
            out[name] = column
        out["samples_seen"] = seen + np.arange(1, rows + 1, dtype=np.int64)
        if self.subgroup == "window":
            position = np.where(live, after % n, -1)            # index of the row's sample in its subgroup
            base = done_before - held                           # post-burn-in index of raw[0]
            for j in range(1, n):
                source = after - position + (j - 1) - base      # raw index of the subgroup's j-th sample
                valid = live & (position < n - 1) & (j - 1 <= position)
                column = np.zeros(rows)
                column[valid] = raw[source[valid]]
                out[f"pending_{j}"] = column
        return out
