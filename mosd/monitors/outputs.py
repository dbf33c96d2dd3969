"""A monitor that hands selected estimator outputs to the detector unchanged.

For detectors that read something other than standardised residual subgroups:
mode probabilities (paper 001), an estimation error (paper 002), a χ² value and
an observer residual (paper 003). Each named output is an entry of the
estimator's ``extra`` (or ``"residual"`` for r itself), of shape (R, N) or
(R, N, m); they are stacked along the last axis into z (R, K, n).
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from ..streaming import COUNT, StateVar
from ..types import Residuals, Subgroups
from ..validation import ConfigError, Interval, Param, check_names
from .base import _grid
from .step import StepMonitor, after_rows


_ALLOWED = "names of estimator outputs, e.g. [residual]"


class OutputMonitor(StepMonitor):
    """Select outputs by name (module docstring).

    Its step (:mod:`mosd.monitors.step`): every row past the first ``burn_in`` is a point, its values the
    selected outputs as they are; the state is ``samples_seen``, the rows since the stream's start.
    """

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

    # -- the step (mosd.monitors.step) -------------------------------------------------------
    def step_state(self, params: dict, width: int) -> dict:
        return {"samples_seen": (StateVar("Rows seen since the stream's start.", COUNT), 0)}

    def scan(self, params: dict, state: dict, X: np.ndarray, trajectory: bool = False) -> dict[str, np.ndarray]:
        """Every row past the burn-in is a point; its values are the row's (:meth:`StepMonitor.scan`)."""
        rows = X.shape[1]
        seen, index = after_rows(state, rows, self.burn_in)
        at = np.flatnonzero(index >= 0)
        # the rows past the burn-in are a suffix of the chunk: z is a view of X
        out = {"at": at, "point": index[at] + 1, "z": X[:, rows - len(at):]}
        if trajectory:
            out["samples_seen"] = np.broadcast_to(seen + np.arange(1, rows + 1, dtype=np.int64), X.shape[:2])
        return out

    def transform(self, outputs: Residuals) -> Subgroups:
        n_points = outputs.fault_mask.shape[-1]
        if self.burn_in >= n_points:
            raise ConfigError(f"monitor.burn_in={self.burn_in} leaves no point of a {n_points}-point run; "
                              f"allowed: 0..{n_points - 1}")
        points = self.points(self._select(outputs))
        at = slice(n_points - len(points["at"]), None)   # the points: the rows past the burn-in
        return Subgroups(z=points["z"], fault_mask=outputs.fault_mask[:, at],
                         fault_label=outputs.fault_label[:, at], fault_roles=outputs.fault_roles, t=_grid(outputs)[at])
