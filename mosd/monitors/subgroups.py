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

from ..streaming import COUNT, FINITE, StateVar
from ..types import Residuals, Subgroups
from ..validation import ConfigError, Interval, Param
from .base import Monitor, _grid
from .step import StepMonitor, after_rows


class SubgroupMonitor(StepMonitor):
    """Standardise residuals with Phase-I statistics and cut them into subgroups.

    Its step (:mod:`mosd.monitors.step`): the first ``burn_in`` rows are skipped; past them a ``window``
    subgroup closes on every n-th row (its n standardised residuals), a ``channels`` subgroup on every row
    (the row's standardised channels). State: ``samples_seen`` (rows since the stream's start) and, for
    ``window`` subgroups, the raw residuals of the unfinished subgroup (``pending_1`` ... ``pending_{n-1}``;
    only the first ``(samples_seen − burn_in) mod n`` count). The served stage shows the point's number
    as ``subgroup`` too, and refuses a missing residual (a subgroup with one has no U_k, V_k).
    """

    numbered = ("subgroup", "point")
    accepts_missing = False

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
        """Standardised subgroups z of shape (R, K, n) and their fault mask (R, K): :meth:`scan` from the start."""
        self._check_fitted()
        n_rows = residuals.r.shape[1]
        if self.subgroup == "window" and n_rows - self.burn_in < self.n:
            raise ConfigError(f"monitor.burn_in={self.burn_in} leaves fewer than n={self.n} samples of a "
                              f"{n_rows}-sample run; allowed: burn_in <= {n_rows - self.n}")
        points = self.points(self._monitored(residuals, burn_in=0))
        at = points["at"]   # a subgroup's fault state is that of its last sample
        return Subgroups(z=points["z"], fault_mask=residuals.fault_mask[:, at], fault_label=residuals.fault_label[:, at],
                         fault_roles=residuals.fault_roles, t=_grid(residuals)[at])

    def stream(self, outputs: Residuals, residual_columns=()) -> dict[str, np.ndarray]:
        """The monitored residual channels of the first replication, named as the estimator names them."""
        return {(residual_columns[c] if c < len(residual_columns) else f"residual_{c}"):
                np.asarray(outputs.r[0, :, c], float) for c in self.channels}

    # -- the step (mosd.monitors.step) -------------------------------------------------------
    def step_params(self) -> dict[str, np.ndarray]:
        """The Phase-I μ and σ of the monitored channels (:meth:`fit`)."""
        self._check_fitted()
        return {"mean": np.asarray(self.mean_, float), "std": np.asarray(self.std_, float)}

    def point_width(self, width: int) -> int:
        return self.subgroup_size

    def step_state(self, params: dict, width: int) -> dict:
        out = {"samples_seen": (StateVar("Rows seen since the stream's start.", COUNT), 0)}
        if self.subgroup == "window":
            out.update({f"pending_{j}": (StateVar(f"Residual {j} of the unfinished subgroup.", FINITE), 0.0)
                        for j in range(1, self.n)})
        return out

    def example_row(self, params: dict, width: int) -> np.ndarray:
        return np.asarray(params["mean"], float)

    def scan(self, params: dict, state: dict, X: np.ndarray, trajectory: bool = False) -> dict[str, np.ndarray]:
        """The subgroups the rows of ``X`` (R, N, c) close, standardised z = (r − μ)/σ (:meth:`StepMonitor.scan`)."""
        mean, std = params["mean"], params["std"]
        runs, rows = X.shape[:2]
        seen, after = after_rows(state, rows, self.burn_in)
        live = after >= 0
        done_before = max(seen - self.burn_in, 0)               # post-burn-in samples before this chunk
        if self.subgroup == "channels":
            at = np.flatnonzero(live)
            out = {"at": at, "point": done_before + np.arange(1, len(at) + 1), "z": (X[:, rows - len(at):] - mean) / std}
        else:
            # the rows past the burn-in are a suffix of the chunk: a view, not a copy
            out = self._scan_window(mean, std, state, X[:, rows - int(live.sum()):, 0], done_before, trajectory)
            out["at"] = np.flatnonzero(live & ((after + 1) % self.n == 0))
            if trajectory:
                out.update(self._pending(out.pop("raw"), after, live, done_before))
        if trajectory:
            out["samples_seen"] = np.broadcast_to(seen + np.arange(1, rows + 1, dtype=np.int64), (runs, rows))
        return out

    def _scan_window(self, mean, std, state, live_rows, done_before: int, trajectory: bool) -> dict:
        """The window subgroups of the carried unfinished one followed by ``live_rows`` (R, L)."""
        n = self.n
        held = done_before % n                                  # samples of the unfinished subgroup carried in
        runs = live_rows.shape[0]
        pending = np.stack([np.broadcast_to(np.asarray(state[f"pending_{j}"], float), (runs,))
                            for j in range(1, held + 1)], axis=-1) if held else np.empty((runs, 0))
        # post-burn-in samples from the subgroup's start (the rows themselves when no subgroup is unfinished)
        raw = np.concatenate([pending, live_rows], axis=1) if held else live_rows
        complete = raw.shape[1] // n
        z = ((raw[:, :complete * n] - mean[0]) / std[0]).reshape(runs, complete, n)
        out = {"point": (done_before - held) // n + np.arange(1, complete + 1), "z": z}
        if trajectory:
            out["raw"] = raw
        return out

    def _pending(self, raw: np.ndarray, after: np.ndarray, live: np.ndarray, done_before: int) -> dict:
        """``pending_j`` after every row (R, N): the j-th residual of the subgroup the row leaves unfinished."""
        n = self.n
        position = np.where(live, after % n, -1)                # index of the row's sample in its subgroup
        base = done_before - done_before % n                    # post-burn-in index of raw[:, 0]
        out = {}
        for j in range(1, n):
            source = after - position + (j - 1) - base          # raw index of the subgroup's j-th sample
            valid = live & (position < n - 1) & (j - 1 <= position)
            column = np.zeros((raw.shape[0], len(after)))
            column[:, valid] = raw[:, source[valid]]
            out[f"pending_{j}"] = column
        return out

    def _monitored(self, residuals: Residuals, burn_in: int | None = None) -> np.ndarray:
        """The monitored channels of every run from row ``burn_in`` (None: the monitor's burn-in)."""
        m = residuals.r.shape[-1]
        if max(self.channels) >= m:
            raise ConfigError(f"monitor.channels={list(self.channels)} is out of range; allowed: 0..{m - 1}")
        return residuals.r[:, self.burn_in if burn_in is None else burn_in:, list(self.channels)]

    def _check_fitted(self) -> None:
        if not hasattr(self, "std_"):
            raise RuntimeError("Monitor is not fitted: call fit(phase1_residuals) first")
