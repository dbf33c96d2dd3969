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

    def transform(self, outputs: Residuals) -> Subgroups:
        n_points = outputs.fault_mask.shape[-1]
        if self.burn_in >= n_points:
            raise ConfigError(f"monitor.burn_in={self.burn_in} leaves no point of a {n_points}-point run; "
                              f"allowed: 0..{n_points - 1}")
        z = self._select(outputs)[:, self.burn_in:]
        return Subgroups(z=z, fault_mask=outputs.fault_mask[:, self.burn_in:],
                         fault_label=outputs.fault_label[:, self.burn_in:], fault_roles=outputs.fault_roles,
                         t=_grid(outputs)[self.burn_in:])
