"""A monitor that hands selected estimator outputs to the detector unchanged.

For detectors that read something other than standardised residual subgroups:
mode probabilities (paper 001), an estimation error (paper 002), a χ² value and
an observer residual (paper 003). Each named output is an entry of the
estimator's ``extra`` (or ``"residual"`` for r itself), of shape (R, N) or
(R, N, m); they are stacked along the last axis into z (R, K, n).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from ..streaming import COUNT, OnlineStage, StateVar
from ..types import Residuals, Subgroups
from ..validation import ConfigError, Interval, Param, check_names
from .base import Monitor, _grid


_ALLOWED = "names of estimator outputs, e.g. [residual]"


class OutputMonitor(Monitor):
    """Select outputs by name (module docstring)."""

    params = {
        "outputs": Param(lambda key, value, monitor: check_names(key, value, _ALLOWED),
                         "Names in the estimator's ``extra``, or ``\"residual\"``.", kind="sequence of str"),
        "burn_in": Param(Interval(0, math.inf, integer=True), "Points dropped at the start of every run."),
    }

    def __init__(self, outputs: Sequence[str] = ("residual",), burn_in: int = 0):
        self._assign(locals())

    def _select(self, outputs: Residuals) -> np.ndarray:
        parts = []
        for name in self.outputs:
            if name == "residual":
                value = outputs.r
            elif name in outputs.extra:
                value = np.asarray(outputs.extra[name], float)
            else:
                allowed = ", ".join(["residual", *(k for k, v in outputs.extra.items() if isinstance(v, np.ndarray))])
                raise ConfigError(f"monitor.outputs: {name!r} is not an output of the estimator; allowed: {allowed}")
            parts.append(value if value.ndim == 3 else value[..., None])
        return np.concatenate(parts, axis=-1)

    def stream(self, outputs: Residuals, residual_columns=()) -> dict[str, np.ndarray]:
        """The selected outputs of the first replication, one column each, in the order of z's last axis."""
        values = self._select(outputs)[0]
        return dict(zip(self.columns(outputs, residual_columns), values.T))

    def columns(self, outputs: Residuals, residual_columns=()) -> tuple[str, ...]:
        """The stream's column names of the selected outputs, in the order of z's last axis.

        ``residual`` → the estimator's name of each channel (``residual_columns``, else ``residual_<j>``);
        an output of shape (R, N) → its name; (R, N, m) → ``<name>_<j>``.
        """
        names = []
        for name in self.outputs:
            value = outputs.r if name == "residual" else np.asarray(outputs.extra[name])
            if value.ndim == 2:
                names.append(name)
                continue
            for j in range(value.shape[-1]):
                if name == "residual":
                    names.append(residual_columns[j] if j < len(residual_columns) else f"residual_{j}")
                else:
                    names.append(f"{name}_{j}")
        return tuple(names)

    def online(self, inputs) -> OnlineSelect:
        """The causal form on the stream's columns ``inputs`` (:meth:`columns`)."""
        return OnlineSelect(columns=tuple(inputs), burn_in=int(self.burn_in))

    def transform(self, outputs: Residuals) -> Subgroups:
        n_points = outputs.fault_mask.shape[-1]
        if self.burn_in >= n_points:
            raise ConfigError(f"monitor.burn_in={self.burn_in} leaves no point of a {n_points}-point run; "
                              f"allowed: 0..{n_points - 1}")
        z = self._select(outputs)[:, self.burn_in:]
        return Subgroups(z=z, fault_mask=outputs.fault_mask[:, self.burn_in:],
                         fault_label=outputs.fault_label[:, self.burn_in:], fault_roles=outputs.fault_roles,
                         t=_grid(outputs)[self.burn_in:])


@dataclass
class OnlineSelect(OnlineStage):
    """:class:`OutputMonitor`'s causal form: the selected output columns in, the detector's points out.

    Outputs per row: ``point``, the number k = 1, 2, ... of the point the row is (0 in the burn-in), and
    the row's values as ``z_1`` ... ``z_n`` (NaN in the burn-in; internal: they feed the detector).
    State: ``samples_seen`` (rows since the stream's start).
    """

    columns: tuple
    burn_in: int

    @property
    def inputs(self) -> tuple[str, ...]:
        return tuple(self.columns)

    @property
    def points(self) -> tuple[str, ...]:
        cached = self.__dict__.get("_points")  # asked for on every served request: made once
        if cached is None or len(cached) != len(self.columns):
            cached = self.__dict__["_points"] = tuple(f"z_{j}" for j in range(1, len(self.columns) + 1))
        return cached

    @property
    def outputs(self) -> tuple[str, ...]:
        return ("point", *self.points)

    @property
    def internal(self) -> tuple[str, ...]:
        return ("point", *self.points)   # the detector's outputs say what each point decided

    def state_vars(self) -> dict[str, StateVar]:
        return {"samples_seen": StateVar("Rows seen since the stream's start.", COUNT)}

    def initial_state(self) -> dict:
        return {"samples_seen": 0}

    def update(self, columns, state) -> dict[str, np.ndarray]:
        first = next(iter(columns.values())) if columns else np.empty(0)
        rows, seen = len(first), int(state["samples_seen"])
        index = seen + np.arange(rows) - self.burn_in            # point index past the burn-in (< 0: in it)
        live = index >= 0
        out = {"point": np.where(live, index + 1, 0).astype(np.int64)}
        every = bool(live.all())  # past the burn-in: the columns pass as they are
        for name, column in zip(self.points, self.columns):
            values = np.asarray(columns[column], float)
            out[name] = values if every else np.where(live, values, np.nan)
        out["samples_seen"] = seen + np.arange(1, rows + 1, dtype=np.int64)
        return out
