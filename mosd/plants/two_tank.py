"""A two-tank level loop: the worked example of docs/ADD_A_SYSTEM.md (one module, one YAML).

Two gravity-drained tanks in cascade (the classic quadruple-tank laboratory
process reduced to one branch; Johansson 2000, eq. 1): a pump fills tank 1,
tank 1 drains into tank 2, tank 2 drains out. A PI controller holds the level of
tank 2 at its set point by the pump flow. Both levels are measured; a sensor
fault on a level sensor (``+fault=offset fault.channel=1``) is what the
detector looks for.
"""
from __future__ import annotations

import math

import numpy as np

from ..model import StateSpaceModel
from ..validation import ConfigError, Interval, Param
from .base import ClosedLoopPlant

GRAVITY = 9.81  # m/s²
_POSITIVE = Interval(0.0, math.inf, open_low=True)


class LevelPI:
    """Discrete PI controller of one level by the pump flow, clamped to [0, q_max] without wind-up.

    q_k = q_ff + K_p e_k + K_i T Σ e_j with e = h_ref − y[channel]. The
    interface :class:`~mosd.plants.base.ClosedLoopPlant` calls: ``reset(n_reps)``
    before a batch, then ``__call__(y)`` with the outputs y (R, n_y) of sample k,
    returning the inputs u (R, n_u) applied from k to k+1.
    """

    def __init__(self, set_point: float, kp: float, ki: float, feed_forward: float, q_max: float, dt: float,
                 channel: int = 1):
        self.set_point, self.kp, self.ki, self.feed_forward = set_point, kp, ki, feed_forward
        self.q_max, self.dt, self.channel = q_max, dt, channel
        self._integral = None

    def reset(self, n_reps: int) -> None:
        self._integral = np.zeros(n_reps)

    def __call__(self, y: np.ndarray) -> np.ndarray:
        error = self.set_point - y[:, self.channel]
        unclamped = self.feed_forward + self.kp * error + self.ki * (self._integral + self.dt * error)
        inside = (unclamped > 0.0) & (unclamped < self.q_max)
        self._integral = np.where(inside, self._integral + self.dt * error, self._integral)
        flow = np.clip(self.feed_forward + self.kp * error + self.ki * self._integral, 0.0, self.q_max)
        return flow[:, None]


class TwoTank(ClosedLoopPlant):
    """Two gravity-drained tanks in cascade, the lower level held by a PI pump controller.

    States x = [h_1, h_2] (m), input u = q (m³/s, the pump flow), outputs y = x
    (two level sensors). Torricelli outflows, Euler-discretised with step ``dt``::

        h_1' = (q − a_1 √(2 g h_1)) / A_1
        h_2' = (a_1 √(2 g h_1) − a_2 √(2 g h_2)) / A_2

    The run starts at the steady state of the set point (h_2 = ``set_point``,
    h_1 = (a_2/a_1)² h_2, q = a_2 √(2 g h_2)); levels are kept ≥ 0.
    """

    params = {
        "dt": Param(Interval(0.0, 10.0, open_low=True), "Sampling period (s)."),
        "area": Param(_POSITIVE, "Cross-section A_1 = A_2 of the tanks (m²)."),
        "outlet_upper": Param(_POSITIVE, "Outlet area a_1 of tank 1 (m²)."),
        "outlet_lower": Param(_POSITIVE, "Outlet area a_2 of tank 2 (m²)."),
        "set_point": Param(Interval(0.0, 10.0, open_low=True), "Level h_2 the controller holds (m)."),
        "bandwidth": Param(_POSITIVE, "Crossover of the level loop (rad/s): sets K_p and K_i."),
        "max_flow": Param(_POSITIVE, "The pump's largest flow q_max (m³/s)."),
    }
    state_names, input_names, output_names = ("h1", "h2"), ("q",), ("h1", "h2")

    def __init__(self, dt: float = 1.0, area: float = 0.0154, outlet_upper: float = 5.0e-5,
                 outlet_lower: float = 5.0e-5, set_point: float = 0.3, bandwidth: float = 0.05,
                 max_flow: float = 5.0e-4):
        self._assign(locals())
        if self.steady_flow() >= self.max_flow:
            raise ConfigError(f"plant.max_flow={max_flow!r} cannot hold plant.set_point={set_point!r}; allowed: "
                              f"> {self.steady_flow():.3g} (the steady outflow a_2 √(2 g h_2))")

    def steady_flow(self) -> float:
        return self.outlet_lower * math.sqrt(2.0 * GRAVITY * self.set_point)

    def initial_state(self) -> np.ndarray:
        upper = (self.outlet_lower / self.outlet_upper) ** 2 * self.set_point
        return np.array([upper, self.set_point])

    def f(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        h = np.maximum(x, 0.0)
        out_upper = self.outlet_upper * np.sqrt(2.0 * GRAVITY * h[..., 0])
        out_lower = self.outlet_lower * np.sqrt(2.0 * GRAVITY * h[..., 1])
        dh1 = (u[..., 0] - out_upper) / self.area
        dh2 = (out_upper - out_lower) / self.area
        return np.maximum(x + self.dt * np.stack([dh1, dh2], axis=-1), 0.0)

    def h(self, x: np.ndarray) -> np.ndarray:
        return x

    def controller(self) -> LevelPI:
        """A fresh PI controller: K_p = ω A (the lower tank as an integrator), K_i = K_p ω / 4."""
        kp = self.bandwidth * self.area
        return LevelPI(self.set_point, kp, kp * self.bandwidth / 4.0, self.steady_flow(), self.max_flow, self.dt)

    def model(self, noise) -> StateSpaceModel:
        """What an estimator assumes: f and h above, Q and R the noise model's, x̂_0 the steady state."""
        return StateSpaceModel(f=self.f, h=self.h, Q=np.asarray(noise.process_cov, float),
                               R=np.asarray(noise.measurement_cov, float), x0=self.initial_state(),
                               P0=np.eye(2) * 1e-4, dt=self.dt, state_names=self.state_names,
                               output_names=self.output_names)
