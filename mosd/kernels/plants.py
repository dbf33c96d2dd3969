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


def warm_up() -> None:
    """Load (or compile) the closed-loop simulation (what a run calls; the filter's transitions compile with it)."""
    params = np.ones(8)
    simulate_mould_oscillator(params, np.array([1.0, 0.0, 0.0, 0.0, 1.0, 1.0, 2.0]), np.zeros(3),
                              np.zeros((1, 2, 3)), np.zeros((1, 2, 3)), np.zeros((1, 2, 3)))


def warm_up_all() -> None:
    """The simulation and :func:`transition_points` (the tests' view of the transitions)."""
    warm_up()
    transition_points(0, np.ones(8), np.zeros((1, 3)), np.zeros(1))
