"""Discrete-time state-space models as the estimators see them."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Optional

import numpy as np


@dataclass(frozen=True)
class PointwiseModel:
    """The same f and h in the form a compiled filter runs (:mod:`mosd.kernels.cubature`).

    Attributes
    ----------
    transition : str
        Name of a compiled transition in :data:`mosd.kernels.cubature.TRANSITIONS`
        that computes this model's ``f`` at one point.
    params : tuple of float
        Its parameters, in the order the kernel documents.
    outputs : tuple of int
        The measurement model: output i is state ``outputs[i]``.
    """

    transition: str
    params: tuple[float, ...]
    outputs: tuple[int, ...]


@dataclass(frozen=True)
class StateSpaceModel:
    """x_{k+1} = f(x_k, u_k) + w_k,  y_k = h(x_k) + v_k,  w ~ (0, Q), v ~ (0, R).

    ``f`` and ``h`` broadcast over leading axes: ``f(x, u)`` takes x of shape
    (..., n_x) and u of shape (..., n_u) and returns (..., n_x); ``h(x)`` returns
    (..., n_y). ``x0`` and ``P0`` are the filter's initial mean and covariance.
    ``pointwise``, when a plant gives it, is the same f and h for a compiled
    filter (otherwise filters take their NumPy path).
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
    pointwise: Optional[PointwiseModel] = None

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
            pointwise=None if self.pointwise is None else PointwiseModel(
                self.pointwise.transition, self.pointwise.params, tuple(self.pointwise.outputs[i] for i in keep)),
        )
