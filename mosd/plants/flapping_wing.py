"""Paper 003's plant: a flapping-wing MAV in longitudinal flight, logged as in the paper.

Wang, Du, Ye, Song, Zheng, "Slowly varying fault detection of flapping-wing
MAVs based on a multi-step neural network observer", Journal of Computer
Applications 40(8), 2020 (paper 003). The paper works on private flight logs
of its FWMAV and gives no vehicle model; this module is a **reconstruction**
that produces logs of the same kind: GPS altitude at 5 Hz with a slowly
wandering bias, down velocity, pitch, throttle and tail deflection of a
vehicle flying a wandering altitude and speed profile in closed loop
(docs/systems/paper003.md gives every equation and choice).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np
from scipy import linalg, optimize

from ..faults.sensor import sensor_fault_signals, unit_of
from ..types import Trace
from ..validation import ConfigError, Interval, Param
from .base import Plant

GRAVITY = 9.81
_POSITIVE = Interval(0.0, math.inf, open_low=True)
_NONNEGATIVE = Interval(0.0, math.inf)


@dataclass(frozen=True)
class Airframe:
    """Aerodynamic and inertial constants of the cycle-averaged vehicle.

    The defaults are the Zagi flying wing of Beard & McLain, *Small Unmanned
    Aircraft* (2012), Appendix E, **recalled from memory** (m, S, C_Lα, C_mα and
    C_mδe as given in the task; the others as we remember the table). The
    Zagi is the lightest airframe of that book (the other is the 13.5 kg
    Aerosonde) and, being tailless, is driven by one pitch surface, which
    plays the FWMAV's tail deflection. Drag uses the book's polar
    C_D = C_Dp + C_L(α)² / (π e AR) so that it stays positive at any δe.
    """

    mass: float = 1.56            # kg
    inertia_y: float = 0.1147     # J_y, kg m²
    wing_area: float = 0.2589     # S, m²
    span: float = 1.4224          # b, m
    chord: float = 0.3302         # c, m
    air_density: float = 1.2682   # ρ, kg/m³
    prop_area: float = 0.0314     # S_prop, m²
    prop_coefficient: float = 1.0 # C_prop
    motor_constant: float = 20.0  # k_motor, m/s per unit throttle
    oswald: float = 0.9           # e
    c_l0: float = 0.09167
    c_l_alpha: float = 3.5016
    c_l_q: float = 2.8932
    c_l_delta_e: float = 0.2724
    c_d_p: float = 0.0254
    c_m0: float = -0.02338
    c_m_alpha: float = -0.5675
    c_m_q: float = -1.3990
    c_m_delta_e: float = -0.3254

    @property
    def aspect_ratio(self) -> float:
        return self.span**2 / self.wing_area


@dataclass(frozen=True)
class FlappingWingModel:
    """What an estimator may assume about :class:`FlappingWingMAV` (its logged channels and sensor noise).

    Attributes
    ----------
    dt : float
        Logging period (s).
    output_names : tuple of str
    gps_variance, down_velocity_variance : float
        White-noise variances of the GPS altitude (m²) and the down velocity ((m/s)²).
    gps_bias_rate, gps_bias_sigma : float
        The GPS bias's Gauss–Markov rate k (1/s) and stationary σ (m).
    """

    dt: float
    output_names: tuple[str, ...]
    gps_variance: float
    down_velocity_variance: float
    gps_bias_rate: float
    gps_bias_sigma: float


class FlappingWingMAV(Plant):
    """Longitudinal, cycle-averaged flapping-wing MAV with its autopilot and logger (paper 003, §2; reconstruction).

    States x = [u, w, q, θ, h, b]: body-axis speeds (m/s), pitch rate (rad/s),
    pitch (rad), altitude (m) and the GPS altitude bias (m). Inputs
    [δt, δe]: throttle in [0, 1] and tail deflection (rad). Reconstructed
    dynamics (wing-level longitudinal flight, Beard & McLain ch. 3–4)::

        u̇ = −q w − g sin θ + (ρ V²S/2m)(C_L sin α − C_D cos α) + (ρ S_p C_p / 2m)((k δt)² − V²)
        ẇ =  q u + g cos θ − (ρ V²S/2m)(C_L cos α + C_D sin α)  + d_w
        q̇ = (ρ V²S c / 2J_y)(C_m0 + C_mα α + C_mq c q/2V + C_mδe δe)  + d_q
        θ̇ = q,   ḣ = u sin θ − w cos θ
        C_L = C_L0 + C_Lα α + C_Lq c q/2V + C_Lδe δe,   C_D = C_Dp + (C_L0 + C_Lα α)²/(π e AR)

    with V = √(u² + w²), α = atan2(w, u). The flapping is not resolved: its
    effect on the cycle-averaged motion is a narrow-band coloured disturbance
    d_w = A_w s(t), d_q = A_q s(t), with s a unit-variance second-order
    Gauss–Markov process (resonance ``flap_frequency``, damping ``flap_damping``).

    The autopilot is an LQR (with integral of the altitude error) on the model
    linearised about level trim at ``airspeed``; it tracks a wandering
    altitude and speed reference (smooth second-order random processes of σ
    ``altitude_wander`` and ``speed_wander``, time constant ``wander_time``)
    so that throttle and tail deflection keep moving. It runs at the
    integration rate and uses the true state: its own navigation is not what
    paper 003 monitors, and the paper injects its faults into logs after the
    flight, so a logged fault never enters the loop (neither does it here).

    Logged channels at ``dt`` (5 Hz, the paper's GPS rate), with white noise
    v_k from the noise model (n_y = 5) and the fault on its channel::

        y = [h + b + v₀ (+ fault), −ḣ + v₁, θ + v₂, δt + v₃, δe + v₄]

    The GPS bias b is a first-order Gauss–Markov process, ḃ = −k b + noise,
    exactly discretised (k = 1/1100 s⁻¹, σ 0.03–0.4 m); process noise w_k
    from the noise model (n_x = 6) is added to x after every logging step.
    Throttle is clipped to [0, 1] (see :attr:`airframe`).
    """

    params = {
        "dt": Param(Interval(0.0, 1.0, open_low=True), "Logging period (s); paper: 0.2 (5 Hz)."),
        "substeps": Param(Interval(1, 1000, integer=True), "RK4 steps per logging period (the autopilot and "
                          "disturbance update at this rate)."),
        "airspeed": Param(Interval(6.0, 30.0), "Trim airspeed (m/s)."),
        "altitude": Param(Interval(-1e4, 1e5), "Mean altitude (m)."),
        "altitude_wander": Param(_NONNEGATIVE, "σ of the altitude reference's wandering (m)."),
        "speed_wander": Param(Interval(0.0, 5.0), "σ of the speed reference's wandering (m/s)."),
        "wander_time": Param(_POSITIVE, "Time constant of the wandering (s)."),
        "flap_frequency": Param(Interval(0.0, "nyquist", open_low=True, open_high=True), "Centre frequency of the "
                                "flapping disturbance (Hz), below the integration's Nyquist 0.5 · substeps / dt."),
        "flap_damping": Param(Interval(0.0, 1.0, open_low=True), "Its damping ratio."),
        "flap_heave": Param(_NONNEGATIVE, "RMS of d_w (m/s²)."),
        "flap_pitch": Param(_NONNEGATIVE, "RMS of d_q (rad/s²)."),
        "gps_bias_sigma": Param(_NONNEGATIVE, "Stationary σ of the GPS bias (m) (paper 0.03–0.4)."),
        "gps_bias_rate": Param(_POSITIVE, "Its Gauss–Markov rate k (1/s) (paper 1/1100)."),
        "tail_limit": Param(Interval(0.0, 1.5, open_low=True), "Tail deflection is clipped to ±tail_limit (rad)."),
    }

    state_names = ("u", "w", "q", "theta", "h", "gps_bias")
    input_names = ("throttle", "tail_deflection")
    output_names = ("gps_altitude", "down_velocity", "pitch", "throttle", "tail_deflection")
    fault_targets = ("sensor",)  # a logged fault never enters the loop (class docstring)

    @property
    def nyquist(self) -> float:
        """Nyquist frequency of the integration grid, 0.5 · substeps / dt (Hz): flap_frequency's bound."""
        return 0.5 * self.substeps / self.dt

    def __init__(
        self,
        dt: float = 0.2,
        substeps: int = 10,
        airspeed: float = 12.0,
        altitude: float = 50.0,
        altitude_wander: float = 8.0,
        speed_wander: float = 1.0,
        wander_time: float = 25.0,
        flap_frequency: float = 2.0,
        flap_damping: float = 0.2,
        flap_heave: float = 0.5,
        flap_pitch: float = 0.5,
        gps_bias_sigma: float = 0.2,
        gps_bias_rate: float = 1.0 / 1100.0,
        tail_limit: float = 0.7,
    ):
        self._assign(locals())
        self.airframe = Airframe()
        self.trim_state, self.trim_input = self._trim(self.airspeed)
        if not 0.0 < self.trim_input[0] < 1.0 or abs(self.trim_input[1]) >= self.tail_limit:
            raise ConfigError(f"plant.airspeed={airspeed} cannot be trimmed within the throttle and tail limits; "
                              f"allowed: an airspeed the airframe can hold level (about 9..25 m/s)")
        self.gain = self._lqr_gain()

    # -- physics --------------------------------------------------------------------
    def derivative(self, x: np.ndarray, inputs: np.ndarray, disturbance: np.ndarray | float = 0.0) -> np.ndarray:
        """ẋ of the rigid-body states [u, w, q, θ, h] (class docstring); broadcasts over leading axes.

        ``disturbance`` is the flapping process s (unit variance), scaled here
        into d_w and d_q.
        """
        a = self.airframe
        u, w, q, theta = x[..., 0], x[..., 1], x[..., 2], x[..., 3]
        throttle, tail = inputs[..., 0], inputs[..., 1]
        speed = np.sqrt(u * u + w * w)
        alpha = np.arctan2(w, u)
        pressure_area = 0.5 * a.air_density * speed**2 * a.wing_area
        rate_term = a.chord * q / (2.0 * speed)
        lift_static = a.c_l0 + a.c_l_alpha * alpha
        c_l = lift_static + a.c_l_q * rate_term + a.c_l_delta_e * tail
        c_d = a.c_d_p + lift_static**2 / (math.pi * a.oswald * a.aspect_ratio)
        thrust = 0.5 * a.air_density * a.prop_area * a.prop_coefficient * ((a.motor_constant * throttle) ** 2 - speed**2)
        sin_a, cos_a = np.sin(alpha), np.cos(alpha)
        u_dot = -q * w - GRAVITY * np.sin(theta) + (pressure_area * (c_l * sin_a - c_d * cos_a) + thrust) / a.mass
        w_dot = (q * u + GRAVITY * np.cos(theta) - pressure_area * (c_l * cos_a + c_d * sin_a) / a.mass
                 + self.flap_heave * disturbance)
        c_m = a.c_m0 + a.c_m_alpha * alpha + a.c_m_q * rate_term + a.c_m_delta_e * tail
        q_dot = pressure_area * a.chord * c_m / a.inertia_y + self.flap_pitch * disturbance
        h_dot = u * np.sin(theta) - w * np.cos(theta)
        return np.stack([u_dot, w_dot, q_dot, q, h_dot], axis=-1)

    def _trim(self, airspeed: float) -> tuple[np.ndarray, np.ndarray]:
        """Level-flight trim at ``airspeed``: α, δt, δe with u̇ = ẇ = q̇ = 0, q = 0, θ = α."""

        def residual(z):
            alpha, throttle, tail = z
            x = np.array([airspeed * math.cos(alpha), airspeed * math.sin(alpha), 0.0, alpha, 0.0])
            return self.derivative(x, np.array([throttle, tail]))[:3]

        solution, info, ok, _ = optimize.fsolve(residual, [0.1, 0.6, -0.2], full_output=True, xtol=1e-12)
        alpha, throttle, tail = solution
        if ok != 1 or np.max(np.abs(info["fvec"])) > 1e-8:
            raise ConfigError(f"plant.airspeed={airspeed}: no level trim found; allowed: about 9..25 m/s")
        state = np.array([airspeed * math.cos(alpha), airspeed * math.sin(alpha), 0.0, alpha, self.altitude])
        return state, np.array([throttle, tail])

    def _lqr_gain(self) -> np.ndarray:
        """LQR gain K (2 × 6) on [δu, δw, δq, δθ, δh, ∫δh] about trim (finite-difference linearisation)."""
        n, eps = 5, 1e-6
        A = np.zeros((n + 1, n + 1))
        B = np.zeros((n + 1, 2))
        for j in range(n):
            step = np.zeros(n)
            step[j] = eps
            A[:n, j] = (self.derivative(self.trim_state + step, self.trim_input)
                        - self.derivative(self.trim_state - step, self.trim_input)) / (2 * eps)
        for j in range(2):
            step = np.zeros(2)
            step[j] = eps
            B[:n, j] = (self.derivative(self.trim_state, self.trim_input + step)
                        - self.derivative(self.trim_state, self.trim_input - step)) / (2 * eps)
        A[n, 4] = 1.0  # the integral of the altitude error
        # Bryson's rule: weight each error by the inverse square of what is tolerable
        Q = np.diag(1.0 / np.array([1.0, 1.0, 0.5, 0.2, 1.0, 10.0]) ** 2)
        R = np.diag(1.0 / np.array([0.2, 0.1]) ** 2)
        P = linalg.solve_continuous_are(A, B, Q, R)
        return np.linalg.solve(R, B.T @ P)

    # -- random processes ------------------------------------------------------------
    def _oscillator(self, step: float) -> tuple[np.ndarray, np.ndarray]:
        """Transition Φ and noise factor L (L Lᵀ = process covariance) of the unit-variance flapping process."""
        omega = 2.0 * math.pi * self.flap_frequency
        A = np.array([[0.0, 1.0], [-omega**2, -2.0 * self.flap_damping * omega]])
        stationary = linalg.solve_continuous_lyapunov(A, -np.array([[0.0, 0.0], [0.0, 1.0]]))
        stationary /= stationary[0, 0]  # unit variance of s
        phi = linalg.expm(A * step)
        cov = stationary - phi @ stationary @ phi.T
        vals, vecs = np.linalg.eigh(0.5 * (cov + cov.T))
        return phi, vecs * np.sqrt(np.clip(vals, 0.0, None)), stationary

    # -- the verbs ---------------------------------------------------------------------
    def simulate(self, n_samples: int, noise, fault, rngs: Sequence[np.random.Generator],
                 fault_scale: float | None = None) -> Trace:
        """``len(rngs)`` flights of ``n_samples`` logged samples (``fault`` None: fault-free).

        Draw order per replication (so that a flight never depends on the
        batch): noise model (w, v), then the plant's own draws (initial bias,
        bias, flapping, reference wander), then the fault's. The flights are flown by
        :func:`mosd.kernels.plants.simulate_flapping_wing` (each on its own, ~100× faster)
        or, with the kernels off, by :meth:`_flights` (all at once on NumPy arrays; their
        matrix products round differently in the last bits, ~1e-14).
        """
        n_reps, N, M = len(rngs), int(n_samples), self.substeps
        h_step = self.dt / M
        t = np.arange(N) * self.dt
        draws = [noise.draw(rng, N) for rng in rngs]
        w_proc = np.stack([d[0] for d in draws])
        v_meas = np.stack([d[1] for d in draws])
        if w_proc.shape[-1] != len(self.state_names) or v_meas.shape[-1] != len(self.output_names):
            raise ConfigError(f"noise: n_x={w_proc.shape[-1]}, n_y={v_meas.shape[-1]} do not fit plant flapping_wing; "
                              f"allowed: n_x={len(self.state_names)}, n_y={len(self.output_names)}")
        own = [(rng.standard_normal(), rng.standard_normal(N), rng.standard_normal((N * M, 2)),
                rng.standard_normal((2, 2)), rng.standard_normal((N * M, 2))) for rng in rngs]
        bias0 = np.array([o[0] for o in own])
        bias_noise = np.stack([o[1] for o in own])            # (R, N)
        flap_noise = np.stack([o[2] for o in own])            # (R, N M, 2)
        wander0 = np.stack([o[3] for o in own])               # (R, 2 processes, 2 stages)
        wander_noise = np.stack([o[4] for o in own])          # (R, N M, 2)
        channel = 0 if fault is None else fault.channel
        g, mask = sensor_fault_signals(fault, t, rngs, len(self.output_names), fault_scale)
        g = g[..., channel]

        # GPS bias: exact first-order Gauss-Markov discretisation on the logging grid
        decay = math.exp(-self.gps_bias_rate * self.dt)
        bias_step_sigma = self.gps_bias_sigma * math.sqrt(1.0 - decay**2)
        # flapping: exact discretisation of the unit-variance resonant process
        phi, flap_factor, flap_stationary = self._oscillator(h_step)
        flap_root = np.linalg.cholesky(flap_stationary + 1e-15 * np.eye(2))
        # wandering references: two cascaded first-order lags of white noise (smooth paths); the
        # first stage starts stationary, the second at zero so that every flight starts on its trim
        lag = math.exp(-h_step / self.wander_time)
        lag_sigma = math.sqrt(1.0 - lag**2)
        wander_first = wander0[:, 1, :]
        scale_ref = np.array([self.altitude_wander, self.speed_wander]) / math.sqrt(_cascade_variance(lag))

        bias = self.gps_bias_sigma * bias0
        from .. import kernels

        if kernels.enabled():
            from ..kernels.plants import simulate_flapping_wing

            arrays = [np.ascontiguousarray(a, dtype=float) for a in (
                self.trim_state, self.trim_input, self.gain, phi, flap_factor, wander0[:, 0, :], flap_root,
                wander_first, scale_ref, bias, bias_noise, flap_noise, wander_noise, w_proc)]
            trim_state, trim_input, gain, phi_c, factor, flap_draw, root, first, scale, level, *noises = arrays
            x, y, u_log, reference_log = simulate_flapping_wing(
                self._constants(), trim_state, trim_input, gain, float(self.altitude), float(self.tail_limit), M,
                h_step, phi_c, factor, flap_draw, root, lag, lag_sigma, first, scale, decay, bias_step_sigma, level,
                *noises)
        else:
            flap = wander0[:, 0, :] @ flap_root.T
            x, y, u_log, reference_log = self._flights(N, M, h_step, phi, flap_factor, flap, lag, lag_sigma,
                                                       wander_first, scale_ref, decay, bias_step_sigma, bias,
                                                       bias_noise, flap_noise, wander_noise, w_proc)
        y = y + v_meas
        y[..., channel] += g
        meta = {"fault": repr(fault), "fault_scale": unit_of(fault, fault_scale), "output_names": self.output_names,
                "dt": self.dt, "trim_input": self.trim_input.tolist(),
                # the autopilot's altitude (m) and forward-speed (m/s) references at the logging instants
                "reference": reference_log}
        return Trace(t=t, u=u_log, x=x, y=y, fault_mask=mask, meta=meta)

    def _constants(self) -> np.ndarray:
        """The airframe's and the flapping's constants in :data:`mosd.kernels.plants.FLIGHT_CONSTANTS`' order, each
        the float :meth:`derivative` computes from them (the same products in the same order)."""
        a = self.airframe
        return np.array([0.5 * a.air_density, a.wing_area, a.chord, a.c_l0, a.c_l_alpha, a.c_l_q, a.c_l_delta_e,
                         a.c_d_p, math.pi * a.oswald * a.aspect_ratio,
                         0.5 * a.air_density * a.prop_area * a.prop_coefficient, a.motor_constant, a.mass, a.c_m0,
                         a.c_m_alpha, a.c_m_q, a.c_m_delta_e, a.inertia_y, GRAVITY, self.flap_heave, self.flap_pitch])

    def _flights(self, N, M, h_step, phi, flap_factor, flap, lag, lag_sigma, wander_first, scale_ref, decay,
                 bias_step_sigma, bias, bias_noise, flap_noise, wander_noise, w_proc):
        """The flights on NumPy arrays, all replications at once (the reference of
        :func:`mosd.kernels.plants.simulate_flapping_wing`): x, y without noise, u and the references."""
        n_reps = len(bias)
        wander_second = np.zeros((n_reps, 2))
        x = np.empty((n_reps, N, len(self.state_names)))
        y = np.empty((n_reps, N, len(self.output_names)))
        u_log = np.empty((n_reps, N, len(self.input_names)))
        rigid = np.broadcast_to(self.trim_state, (n_reps, 5)).copy()
        integral = np.zeros(n_reps)
        reference_log = np.empty((n_reps, N, 2))
        for k in range(N):
            x[:, k, :5] = rigid
            x[:, k, 5] = bias
            h_dot = rigid[:, 0] * np.sin(rigid[:, 3]) - rigid[:, 1] * np.cos(rigid[:, 3])
            for m in range(M):
                i = k * M + m
                reference = wander_second * scale_ref  # (R, 2): altitude and speed offsets
                command, integral_rate = self._autopilot(rigid, integral, reference)
                if m == 0:
                    u_log[:, k] = command
                    reference_log[:, k] = reference + np.array([self.altitude, self.trim_state[0]])
                s0 = flap[:, 0]
                rigid = _rk4(lambda z: self.derivative(z, command, s0), rigid, h_step)
                integral = integral + h_step * integral_rate
                flap = flap @ phi.T + flap_noise[:, i] @ flap_factor.T
                wander_first = lag * wander_first + lag_sigma * wander_noise[:, i]
                wander_second = lag * wander_second + (1.0 - lag) * wander_first
            y[:, k] = np.stack([x[:, k, 4] + bias, -h_dot, x[:, k, 3], u_log[:, k, 0], u_log[:, k, 1]], -1)
            rigid = rigid + w_proc[:, k, :5]
            bias = decay * bias + bias_step_sigma * bias_noise[:, k] + w_proc[:, k, 5]
        return x, y, u_log, reference_log

    def _autopilot(self, rigid: np.ndarray, integral: np.ndarray, reference: np.ndarray):
        """Saturated LQR command (R, 2) and the rate of the altitude-error integral (R,)."""
        target = np.broadcast_to(self.trim_state, rigid.shape).copy()
        target[:, 4] = self.altitude + reference[:, 0]
        target[:, 0] = self.trim_state[0] + reference[:, 1]
        error = np.concatenate([rigid - target, integral[:, None]], axis=-1)
        command = self.trim_input - error @ self.gain.T
        saturated = np.stack([np.clip(command[:, 0], 0.0, 1.0), np.clip(command[:, 1], -self.tail_limit, self.tail_limit)], -1)
        # no integration while the throttle is saturated (anti-wind-up)
        integral_rate = np.where(saturated[:, 0] == command[:, 0], error[:, 4], 0.0)
        return saturated, integral_rate

    def model(self, noise) -> FlappingWingModel:
        """The logged channels and their noise (``noise.measurement_cov`` diagonal entries 0 and 1)."""
        cov = np.asarray(getattr(noise, "measurement_cov", None), float)
        if cov.shape != (5, 5):
            raise ConfigError("noise.measurement_cov must be 5 x 5 for plant flapping_wing; "
                              "allowed: a Gaussian noise model with n_y=5")
        return FlappingWingModel(dt=self.dt, output_names=self.output_names, gps_variance=float(cov[0, 0]),
                                 down_velocity_variance=float(cov[1, 1]), gps_bias_rate=self.gps_bias_rate,
                                 gps_bias_sigma=self.gps_bias_sigma)


def _rk4(rhs, x: np.ndarray, step: float) -> np.ndarray:
    k1 = rhs(x)
    k2 = rhs(x + 0.5 * step * k1)
    k3 = rhs(x + 0.5 * step * k2)
    k4 = rhs(x + step * k3)
    return x + step / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)


def _cascade_variance(lag: float) -> float:
    """Stationary variance of s₂ in s₁' = λ s₁ + √(1−λ²) ξ, s₂' = λ s₂ + (1−λ) s₁ (unit-variance s₁)."""
    # s₂ = (1−λ) Σ_j λ^j s₁(k−1−j) and Cov(s₁(i), s₁(j)) = λ^|i−j|, so Var s₂ = (1−λ)² Σ_m (2m+1) λ^(2m)
    return (1.0 - lag) ** 2 * (1.0 + lag**2) / ((1.0 - lag**2) ** 2)
