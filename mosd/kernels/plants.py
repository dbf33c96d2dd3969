"""Plant physics at one point, compiled: what the compiled filter and simulation call.

numba cannot cache a kernel that receives another compiled function as an
argument (every process would compile it again), so the kernels dispatch on a
transition *number* (:data:`TRANSITIONS`) instead. Each transition repeats one
plant's NumPy ``f`` operation for operation (``tests/test_kernel_filter.py``
checks they agree bit for bit on this machine kind, where NumPy's and libm's
cosines coincide, and to 1e-14 anywhere).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from . import configure_compiler

configure_compiler()  # before this module's first compile

#: transition name -> the integer the kernel dispatches on
TRANSITIONS = {"mould_oscillator": 0}

_RPM_PER_RAD_S = 60.0 / (2.0 * math.pi)

#: a kernel's helper, called only from compiled code: no CPython or C-callable entry point (each would be
#: generated and compiled for every helper's signature, unboxing every array argument: compile time for nothing)
_inner = njit(cache=True, nogil=True, error_model="numpy", no_cpython_wrapper=True, no_cfunc_wrapper=True)


@_inner
def _mould_step(params, x_p, theta, n, i_q):
    """Euler step of :meth:`mosd.plants.MouldOscillator.f` (paper 000, eqs. 40–41) at one point.

    params: dt, amplitude, gear_ratio, coulomb_torque, gravity_torque,
    torque_constant, inertia, friction.
    """
    dt, amplitude, gear_ratio = params[0], params[1], params[2]
    coulomb, gravity, torque_constant, inertia, friction = params[3], params[4], params[5], params[6], params[7]
    cos_theta = math.cos(theta)
    omega = 2.0 * math.pi * n / (60.0 * gear_ratio)
    load = coulomb + gravity * cos_theta
    n_dot = (torque_constant / inertia * _RPM_PER_RAD_S * i_q - friction / inertia * n
             - _RPM_PER_RAD_S * load / inertia)
    return x_p + dt * (amplitude * omega * cos_theta), theta + dt * omega, n + dt * n_dot


@_inner
def _mould_oscillator(params, x, u, out):
    """:func:`_mould_step` on x (3,), u (1,) into out (3,)."""
    out[0], out[1], out[2] = _mould_step(params, x[0], x[1], x[2], u[0])


@_inner
def transition(kind, params, x, u, out):
    """out = f(x, u) of the transition numbered ``kind`` (see :data:`TRANSITIONS`)."""
    if kind == 0:
        _mould_oscillator(params, x, u, out)
    else:
        raise ValueError("unknown compiled transition")


@_inner
def transition_lanes(kind, params, x, u, out, n_lanes):
    """out[:, b] = f(x[:, b], u[:, b]) for the first ``n_lanes`` lanes (replications) of (n, lanes) arrays."""
    if kind == 0:
        for b in range(n_lanes):
            out[0, b], out[1, b], out[2, b] = _mould_step(params, x[0, b], x[1, b], x[2, b], u[0, b])
    else:
        raise ValueError("unknown compiled transition")


@njit(cache=True, nogil=True, error_model="numpy")
def transition_points(kind, params, points, u):
    """f at every row of ``points`` (P, n) with the same input u (the tests' view of :func:`transition`)."""
    out = np.empty_like(points)
    for i in range(points.shape[0]):
        transition(kind, params, points[i], u, out[i])
    return out



@njit(cache=True, nogil=True, error_model="numpy")
def simulate_mould_oscillator(params, controller, x0, v, g, w):
    """The closed loop of :meth:`mosd.plants.base.ClosedLoopPlant.simulate` for the mould oscillator.

    Per sample k and replication: y_k = (h(x_k) + v_k) + g_k; the speed PI
    (:class:`mosd.plants.mould_oscillator.SpeedPI`) maps y_k to u_k;
    x_{k+1} = f(x_k, u_k) + w_k — the reference's operations in its order.

    Parameters
    ----------
    params : the transition's parameters (:func:`_mould_oscillator`)
    controller : float64 (7,)
        n_ref, K_p, K_i, i_ff, i_max, the controller's T, the speed channel.
    x0 : (n_x,); v, g : (R, N, n_y); w : (R, N, n_x)

    Returns
    -------
    x (R, N, n_x), y (R, N, n_y), u (R, N, 1)
    """
    n_reps, n_steps, n_y = v.shape
    n_x = x0.shape[0]
    n_ref, kp, ki, i_ff, i_max = controller[0], controller[1], controller[2], controller[3], controller[4]
    dt = controller[5]
    speed = int(controller[6])
    x = np.empty((n_reps, n_steps, n_x))
    y = np.empty((n_reps, n_steps, n_y))
    u = np.empty((n_reps, n_steps, 1))
    xk = np.empty(n_x)
    nxt = np.empty(n_x)
    uk = np.empty(1)
    for r in range(n_reps):
        for i in range(n_x):  # a loop, not xk[:] = x0: the slice assignment compiles numba's broadcast checks (~4 s)
            xk[i] = x0[i]
        integral = 0.0
        for k in range(n_steps):
            for i in range(n_x):
                x[r, k, i] = xk[i]
            for c in range(n_y):
                y[r, k, c] = (xk[c] + v[r, k, c]) + g[r, k, c]
            e = n_ref - y[r, k, speed]
            if math.isnan(e):
                e = 0.0  # a lost speed sample holds the integral
            unsat = i_ff + kp * e + ki * (integral + dt * e)
            if abs(unsat) < i_max:
                integral = integral + dt * e
            i_q = i_ff + kp * e + ki * integral
            i_q = min(max(i_q, -i_max), i_max)
            u[r, k, 0] = i_q
            uk[0] = i_q
            _mould_oscillator(params, xk, uk, nxt)
            for i in range(n_x):
                xk[i] = nxt[i] + w[r, k, i]
    return x, y, u


#: the order of :func:`simulate_flapping_wing`'s ``constants`` (:meth:`mosd.plants.FlappingWingMAV._constants`)
FLIGHT_CONSTANTS = ("half_air_density", "wing_area", "chord", "c_l0", "c_l_alpha", "c_l_q", "c_l_delta_e", "c_d_p",
                    "induced_drag", "thrust_factor", "motor_constant", "mass", "c_m0", "c_m_alpha", "c_m_q",
                    "c_m_delta_e", "inertia_y", "gravity", "flap_heave", "flap_pitch")


@_inner
def _flight_derivative(c, x, throttle, tail, disturbance, out):
    """:meth:`mosd.plants.FlappingWingMAV.derivative` at one point, into out (5,): its expressions in its order."""
    u, w, q, theta = x[0], x[1], x[2], x[3]
    speed = math.sqrt(u * u + w * w)
    alpha = math.atan2(w, u)
    pressure_area = c[0] * (speed * speed) * c[1]
    rate_term = c[2] * q / (2.0 * speed)
    lift_static = c[3] + c[4] * alpha
    c_l = lift_static + c[5] * rate_term + c[6] * tail
    c_d = c[7] + (lift_static * lift_static) / c[8]
    pushed = c[10] * throttle
    thrust = c[9] * (pushed * pushed - speed * speed)
    sin_a, cos_a = math.sin(alpha), math.cos(alpha)
    sin_t, cos_t = math.sin(theta), math.cos(theta)
    out[0] = -q * w - c[17] * sin_t + (pressure_area * (c_l * sin_a - c_d * cos_a) + thrust) / c[11]
    out[1] = q * u + c[17] * cos_t - pressure_area * (c_l * cos_a + c_d * sin_a) / c[11] + c[18] * disturbance
    c_m = c[12] + c[13] * alpha + c[14] * rate_term + c[15] * tail
    out[2] = pressure_area * c[2] * c_m / c[16] + c[19] * disturbance
    out[3] = q
    out[4] = u * sin_t - w * cos_t


@njit(cache=True, nogil=True, error_model="numpy")
def simulate_flapping_wing(constants, trim_state, trim_input, gain, altitude, tail_limit, substeps, h_step, phi,
                           flap_factor, flap_draw, flap_root, lag, lag_sigma, wander_first, scale_ref, decay,
                           bias_step_sigma, bias, bias_noise, flap_noise, wander_noise, w_proc):
    """The flights of :meth:`mosd.plants.FlappingWingMAV.simulate` (paper 003's vehicle), without the sensor
    noise and fault the NumPy code adds afterwards.

    Per logged sample k and flight: the state logged; then ``substeps`` RK4 steps of
    :func:`_flight_derivative` under the saturated LQR autopilot (anti-wind-up integral), the flapping
    process and the two cascaded reference lags; then the process noise and the GPS bias. The NumPy code's
    operations in its order, each flight on its own, except its matrix products (BLAS's order there, a plain
    sum here): the same trajectories to about 1e-13 relative, not bit for bit.

    Returns
    -------
    x (R, N, 6), y (R, N, 5) without noise, u (R, N, 2), reference (R, N, 2)
    """
    n_reps, n_samples = bias_noise.shape
    x = np.empty((n_reps, n_samples, 6))
    y = np.empty((n_reps, n_samples, 5))
    u_log = np.empty((n_reps, n_samples, 2))
    reference_log = np.empty((n_reps, n_samples, 2))
    rigid, trial, k1, k2, k3, k4 = (np.empty(5), np.empty(5), np.empty(5), np.empty(5), np.empty(5), np.empty(5))
    error = np.empty(6)
    for r in range(n_reps):
        for j in range(5):
            rigid[j] = trim_state[j]
        level = bias[r]
        integral = 0.0
        # the flapping process starts stationary: its Cholesky factor times the flight's two draws
        s0 = flap_draw[r, 0] * flap_root[0, 0] + flap_draw[r, 1] * flap_root[0, 1]
        s1 = flap_draw[r, 0] * flap_root[1, 0] + flap_draw[r, 1] * flap_root[1, 1]
        first0, first1 = wander_first[r, 0], wander_first[r, 1]
        second0, second1 = 0.0, 0.0
        for k in range(n_samples):
            for j in range(5):
                x[r, k, j] = rigid[j]
            x[r, k, 5] = level
            h_dot = rigid[0] * math.sin(rigid[3]) - rigid[1] * math.cos(rigid[3])
            for m in range(substeps):
                i = k * substeps + m
                reference0, reference1 = second0 * scale_ref[0], second1 * scale_ref[1]
                # the autopilot: saturated LQR about trim on [rigid - target, integral]
                for j in range(5):
                    error[j] = rigid[j] - trim_state[j]
                error[4] = rigid[4] - (altitude + reference0)
                error[0] = rigid[0] - (trim_state[0] + reference1)
                error[5] = integral
                command0 = trim_input[0] - _row_dot(error, gain, 0)
                command1 = trim_input[1] - _row_dot(error, gain, 1)
                throttle = min(max(command0, 0.0), 1.0)
                tail = min(max(command1, -tail_limit), tail_limit)
                integral_rate = error[4] if throttle == command0 else 0.0
                if m == 0:
                    u_log[r, k, 0], u_log[r, k, 1] = throttle, tail
                    reference_log[r, k, 0] = reference0 + altitude
                    reference_log[r, k, 1] = reference1 + trim_state[0]
                _flight_derivative(constants, rigid, throttle, tail, s0, k1)
                for j in range(5):
                    trial[j] = rigid[j] + 0.5 * h_step * k1[j]
                _flight_derivative(constants, trial, throttle, tail, s0, k2)
                for j in range(5):
                    trial[j] = rigid[j] + 0.5 * h_step * k2[j]
                _flight_derivative(constants, trial, throttle, tail, s0, k3)
                for j in range(5):
                    trial[j] = rigid[j] + h_step * k3[j]
                _flight_derivative(constants, trial, throttle, tail, s0, k4)
                for j in range(5):
                    rigid[j] = rigid[j] + h_step / 6.0 * (k1[j] + 2.0 * k2[j] + 2.0 * k3[j] + k4[j])
                integral = integral + h_step * integral_rate
                n0, n1 = flap_noise[r, i, 0], flap_noise[r, i, 1]
                s0, s1 = ((s0 * phi[0, 0] + s1 * phi[0, 1]) + (n0 * flap_factor[0, 0] + n1 * flap_factor[0, 1]),
                          (s0 * phi[1, 0] + s1 * phi[1, 1]) + (n0 * flap_factor[1, 0] + n1 * flap_factor[1, 1]))
                first0 = lag * first0 + lag_sigma * wander_noise[r, i, 0]
                first1 = lag * first1 + lag_sigma * wander_noise[r, i, 1]
                second0 = lag * second0 + (1.0 - lag) * first0
                second1 = lag * second1 + (1.0 - lag) * first1
            y[r, k, 0] = x[r, k, 4] + level
            y[r, k, 1] = -h_dot
            y[r, k, 2] = x[r, k, 3]
            y[r, k, 3], y[r, k, 4] = u_log[r, k, 0], u_log[r, k, 1]
            for j in range(5):
                rigid[j] = rigid[j] + w_proc[r, k, j]
            level = decay * level + bias_step_sigma * bias_noise[r, k] + w_proc[r, k, 5]
    return x, y, u_log, reference_log


@_inner
def _row_dot(vector, matrix, row):
    total = 0.0
    for j in range(vector.shape[0]):
        total += vector[j] * matrix[row, j]
    return total


def warm_up() -> None:
    """Load (or compile) the closed-loop simulation (what a run calls; the filter's transitions compile with it)."""
    params = np.ones(8)
    simulate_mould_oscillator(params, np.array([1.0, 0.0, 0.0, 0.0, 1.0, 1.0, 2.0]), np.zeros(3),
                              np.zeros((1, 2, 3)), np.zeros((1, 2, 3)), np.zeros((1, 2, 3)))


def warm_up_flight() -> None:
    """Load (or compile) paper 003's flight simulation (:func:`simulate_flapping_wing`)."""
    two, one = np.eye(2), np.ones((1, 2))
    simulate_flapping_wing(np.ones(len(FLIGHT_CONSTANTS)), np.ones(5), np.full(2, 0.5), np.zeros((2, 6)), 50.0,
                           0.7, 1, 0.02, two, two, one, two, 0.9, 0.1, one, np.ones(2), 0.9, 0.1, np.zeros(1),
                           np.zeros((1, 1)), np.zeros((1, 1, 2)), np.zeros((1, 1, 2)), np.zeros((1, 1, 6)))


def warm_up_all() -> None:
    """The simulations and :func:`transition_points` (the tests' view of the transitions)."""
    warm_up()
    warm_up_flight()
    transition_points(0, np.ones(8), np.zeros((1, 3)), np.zeros(1))
