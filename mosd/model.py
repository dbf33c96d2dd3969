"""Discrete-time state-space models as the estimators see them."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np


@dataclass(frozen=True)
class StateSpaceModel:
    """x_{k+1} = f(x_k, u_k) + w_k,  y_k = h(x_k) + v_k,  w ~ (0, Q), v ~ (0, R).

    ``f`` and ``h`` broadcast over leading axes: ``f(x, u)`` takes x of shape
    (..., n_x) and u of shape (..., n_u) and returns (..., n_x); ``h(x)`` returns
    (..., n_y). ``x0`` and ``P0`` are the filter's initial mean and covariance.
    """

    f: Callable[[np.ndarray, np.ndarray], np.ndarray]
    h: Callable[[np.ndarray], np.ndarray]
    Q: np.ndarray
    R: np.ndarray
    x0: np.ndarray
    P0: np.ndarray
    dt: float
    state_names: tuple[str, ...]
    output_names: tuple[str, ...]

    @property
    def n_x(self) -> int:
        return len(self.state_names)

    @property
    def n_y(self) -> int:
        return len(self.output_names)

    def restrict_outputs(self, keep: list[int] | tuple[int, ...]) -> "StateSpaceModel":
        """The same model observed only through the output channels ``keep``."""
        keep = tuple(int(i) for i in keep)
        h = self.h
        return StateSpaceModel(
            f=self.f,
            h=lambda x: h(x)[..., keep],
            Q=self.Q,
            R=self.R[np.ix_(keep, keep)],
            x0=self.x0,
            P0=self.P0,
            dt=self.dt,
            state_names=self.state_names,
            output_names=tuple(self.output_names[i] for i in keep),
        )
