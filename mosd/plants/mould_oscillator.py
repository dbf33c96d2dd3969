"""Paper 000's plant: the servo-driven mould oscillator in closed loop with a PI speed controller.

It provides f, h and a controller; :class:`~mosd.plants.base.ClosedLoopPlant`
runs the loop and injects noise and the sensor fault.
"""
from __future__ import annotations

import math

import numpy as np

from ..model import PointwiseModel, StateSpaceModel
from ..validation import Interval, Param
from .base import ClosedLoopPlant

_RPM_PER_RAD_S = 60.0 / (2.0 * math.pi)
_POSITIVE = Interval(0.0, math.inf, open_low=True)
_NONNEGATIVE = Interval(0.0, math.inf)


class SpeedPI:
    """Discrete PI speed controller with a feed-forward of the nominal load.

    i_q = i_ff + K_p e_k + K_i T Σ e_j,  e = n_ref − n_measured, clamped to
    ±i_max with conditional integration (no wind-up while saturated).
    """

    def __init__(self, n_ref, kp, ki, i_ff, i_max, dt, speed_channel=2):
        self.n_ref, self.kp, self.ki, self.i_ff = n_ref, kp, ki, i_ff
        self.i_max, self.dt, self.speed_channel = i_max, dt, speed_channel
        self._integral = None

    def reset(self, n_reps: int) -> None:
        self._integral = np.zeros(n_reps)

    def __call__(self, y: np.ndarray) -> np.ndarray:
        e = self.n_ref - y[:, self.speed_channel]
        e = np.where(np.isnan(e), 0.0, e)  # a lost speed sample holds the integral
        unsat = self.i_ff + self.kp * e + self.ki * (self._integral + self.dt * e)
        ok = np.abs(unsat) < self.i_max
        self._integral = np.where(ok, self._integral + self.dt * e, self._integral)
        i_q = np.clip(self.i_ff + self.kp * e + self.ki * self._integral, -self.i_max, self.i_max)
        return i_q[:, None]


class MouldOscillator(ClosedLoopPlant):
    """Servo-motor-driven continuous-casting mould oscillator (paper 000, eqs. 40–41, Table 1).

    States x = [x_p (mm), θ (rad), n (r/min)], input u = i_q (A), outputs y = x.
    Continuous-time model, Euler-discretised with step ``dt``::

        ω   = 2π n / (60 i_r)                                   eccentric shaft speed
        ẋ_p = A ω cos θ                                         A = 3 mm eccentricity
        θ̇  = ω
        ṅ  = (1.5 p ψ_f / J)(60/2π) i_q − (B/J) n − (60/2π) T_L / J

    (eq. 41 prints "1.5pnψ_f"; the n is a typo.) The load torque on the motor shaft
    is the mould's weight lifted by the eccentric plus a constant friction::

        T_L = T_c + m g (A/1000) cos θ / i_r

    The paper's controller (adaptive sliding mode with an extended state
    observer, its ref. 17) is not given; here a PI speed loop with a
    feed-forward of the mean load holds n_ref = 60 i_r f, which gives the
    oscillation frequency f; the amplitude is A by the eccentric's geometry.
    The loop bandwidth ``speed_bandwidth`` sets K_p = ω_c / k_t and
    K_i = K_p ω_c / 5 with k_t = (1.5 p ψ_f / J)(60/2π).
    """

    params = {
        "dt": Param(Interval(0.0, 0.1, open_low=True), "Sampling period T in s (Table 1: 0.001)."),
        "frequency": Param(Interval(0.0, 20.0, open_low=True), "Oscillation frequency in Hz (Table 1: 120 /min "
                           "= 2 Hz)."),
        "amplitude": Param(_POSITIVE, "Eccentricity A in mm (paper: 3)."),
        "pole_pairs": Param(_POSITIVE, "Pole pairs p (Table 1)."),
        "flux": Param(_POSITIVE, "Permanent-magnet flux ψ_f in Wb (Table 1)."),
        "inertia": Param(_POSITIVE, "Inertia J in kg·m² (Table 1)."),
        "friction": Param(_NONNEGATIVE, "Viscous friction B (Table 1)."),
        "gear_ratio": Param(_POSITIVE, "Reduction ratio i_r (Table 1)."),
        "rated_current": Param(_POSITIVE, "Rated current I_N in A (Table 1)."),
        "mould_mass": Param(_NONNEGATIVE, "Oscillating mass m in kg (not in the paper; 5 t is typical)."),
        "coulomb_torque": Param(_NONNEGATIVE, "Constant load torque T_c in N·m (not in the paper)."),
        "speed_bandwidth": Param(_POSITIVE, "Speed-loop crossover ω_c in rad/s."),
    }

    state_names = ("x_p", "theta", "n")
    output_names = ("x_p", "theta", "n")
    input_names = ("i_q",)

    def __init__(
        self,
        dt: float = 0.001,
        frequency: float = 2.0,
        amplitude: float = 3.0,
        pole_pairs: float = 3.0,
        flux: float = 0.96,
        inertia: float = 0.0547,
        friction: float = 0.004,
        gear_ratio: float = 5.1,
        rated_current: float = 45.0,
        mould_mass: float = 5000.0,
        coulomb_torque: float = 5.0,
        speed_bandwidth: float = 150.0,
    ):
        self._assign(locals())

    # -- physics --------------------------------------------------------------------
    @property
    def torque_constant(self) -> float:
        """Electromagnetic torque per ampere of i_q, 1.5 p ψ_f (N·m/A)."""
        return 1.5 * self.pole_pairs * self.flux

    @property
    def n_ref(self) -> float:
        """Motor speed (r/min) that turns the eccentric at ``frequency``."""
        return 60.0 * self.gear_ratio * self.frequency

    @property
    def gravity_torque(self) -> float:
        """Amplitude of the mould-weight torque on the motor shaft (N·m)."""
        return self.mould_mass * 9.81 * (self.amplitude / 1000.0) / self.gear_ratio

    def derivative(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Right-hand side of eq. 40 (broadcasts over leading axes)."""
        x_p, theta, n = x[..., 0], x[..., 1], x[..., 2]
        i_q = u[..., 0]
        omega = 2.0 * math.pi * n / (60.0 * self.gear_ratio)
        load = self.coulomb_torque + self.gravity_torque * np.cos(theta)
        n_dot = (
            self.torque_constant / self.inertia * _RPM_PER_RAD_S * i_q
            - self.friction / self.inertia * n
            - _RPM_PER_RAD_S * load / self.inertia
        )
        return np.stack([self.amplitude * omega * np.cos(theta), omega, n_dot], axis=-1)

    def f(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Euler step x_{k+1} = x_k + T ẋ(x_k, u_k) (eq. 41)."""
        return x + self.dt * self.derivative(x, u)

    @staticmethod
    def h(x: np.ndarray) -> np.ndarray:
        """All three states are measured."""
        return x

    def initial_state(self) -> np.ndarray:
        """At the operating speed, mould at mid-stroke (x_p = 0, θ = 0).

        The paper starts from x_0 = 0, which adds a motor run-up irrelevant to
        monitoring; starting at speed keeps every sample usable.
        """
        return np.array([0.0, 0.0, self.n_ref])

    def model(self, noise) -> StateSpaceModel:
        """The discrete model the estimators use (x̂_0 = x_0, P_0 = I as in the paper).

        Q and R are the Gaussian noise model's covariances (``noise.process_cov``,
        ``noise.measurement_cov``).
        """
        return StateSpaceModel(
            f=self.f,
            h=self.h,
            Q=np.asarray(noise.process_cov, float),
            R=np.asarray(noise.measurement_cov, float),
            x0=self.initial_state(),
            P0=np.eye(3),
            dt=self.dt,
            state_names=self.state_names,
            output_names=self.output_names,
            pointwise=self._pointwise(),
        )

    def _compiled_loop(self, controller):
        """:func:`mosd.kernels.plants.simulate_mould_oscillator` when kernels are on and nothing was overridden."""
        from .. import kernels

        pointwise = self._pointwise()
        if pointwise is None or type(controller) is not SpeedPI or not kernels.enabled():
            return None
        from ..kernels.plants import simulate_mould_oscillator

        params = np.asarray(pointwise.params, float)
        gains = np.array([controller.n_ref, controller.kp, controller.ki, controller.i_ff, controller.i_max,
                          controller.dt, controller.speed_channel], float)

        def loop(x0, v, g, w):
            return simulate_mould_oscillator(params, gains, x0, np.ascontiguousarray(v), np.ascontiguousarray(g),
                                             np.ascontiguousarray(w))

        return loop

    def _pointwise(self) -> PointwiseModel | None:
        """f and h for the compiled CESCKF (the parameter order of mosd.kernels.cubature._mould_oscillator).

        None for a subclass that changes the physics: the kernel knows only this class's.
        """
        cls = type(self)
        if any(getattr(cls, name) is not getattr(MouldOscillator, name)
               for name in ("f", "h", "derivative", "initial_state")):
            return None
        return PointwiseModel("mould_oscillator", (
            self.dt, self.amplitude, self.gear_ratio, self.coulomb_torque, self.gravity_torque,
            self.torque_constant, self.inertia, self.friction), (0, 1, 2))

    def controller(self) -> SpeedPI:
        """A fresh closed-loop speed controller (see class docstring)."""
        k_t = self.torque_constant / self.inertia * _RPM_PER_RAD_S
        kp = self.speed_bandwidth / k_t
        ki = kp * self.speed_bandwidth / 5.0
        mean_load = self.coulomb_torque + self.friction * self.n_ref / _RPM_PER_RAD_S
        return SpeedPI(
            n_ref=self.n_ref,
            kp=kp,
            ki=ki,
            i_ff=mean_load / self.torque_constant,
            i_max=3.0 * self.rated_current,
            dt=self.dt,
            speed_channel=2,
        )
