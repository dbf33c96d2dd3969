"""Cubature rules, the batched CKF/CESCKF and the residual generators (mosd.estimators)."""
from __future__ import annotations

import dataclasses
import itertools
import math

import numpy as np
import pytest
from filterpy.kalman import KalmanFilter, UnscentedKalmanFilter

from mosd.estimators import (
    CESCKF,
    CubatureKalmanFilter,
    DedicatedObserverResidual,
    EmbeddedCubatureRule,
    InnovationResidual,
    SphericalRadialRule,
)
from mosd.bench import benchmark_filter
from mosd.model import StateSpaceModel
from mosd.noise import GaussianNoise
from mosd.plants import MouldOscillator
from mosd.scenario import Scenario
from mosd.types import Trace
from mosd.validation import ConfigError


# ----------------------------------------------------------------------------------
# helpers
# ----------------------------------------------------------------------------------
def _gaussian_moment(exponents) -> float:
    """E[Π x_i^a_i] for x ~ N(0, I): Π (a_i − 1)!! over even a_i, 0 if any a_i is odd."""
    out = 1.0
    for a in exponents:
        if a % 2:
            return 0.0
        out *= math.prod(range(a - 1, 0, -2))
    return out


def _monomials(n: int, degree: int):
    """Exponent tuples of all monomials of exactly ``degree`` in n variables."""
    for combo in itertools.combinations_with_replacement(range(n), degree):
        yield tuple(combo.count(i) for i in range(n))


def _rule_error(eps, weights, exponents) -> float:
    values = np.prod(eps ** np.asarray(exponents), axis=1)
    return abs(weights @ values - _gaussian_moment(exponents))


def _paper_embedded_points(n: int, delta1: float):
    """Eqs. 3–6 of paper 000 written out independently of mosd (centre, δ₂ corners, δ₁ corners)."""
    d1sq = delta1**2
    delta2 = delta1 * math.sqrt(4 * d1sq - 2) / (2 * d1sq - 1)
    corners = np.array(list(itertools.product([1.0, -1.0], repeat=n)))
    eps = np.vstack([np.zeros(n), math.sqrt(2) * delta2 * corners, math.sqrt(2) * delta1 * corners])
    w = np.concatenate(
        [
            [(2 * d1sq - 1) * (2 * d1sq + 3) / (8 * d1sq**2)],
            np.full(2**n, (2 * d1sq - 1) ** 2 / (2 ** (n + 3) * d1sq**2)),
            np.full(2**n, 1 / (2 ** (n + 2) * d1sq**2)),
        ]
    )
    return eps, w


class _FixedPoints:
    """A filterpy sigma-point object with given unit points: X_i = x + chol(P) ε_i."""

    def __init__(self, eps, weights):
        self.eps = np.asarray(eps, float)
        self.Wm = np.asarray(weights, float)
        self.Wc = self.Wm

    def num_sigmas(self):
        return len(self.Wm)

    def sigma_points(self, x, P):
        return np.asarray(x, float) + self.eps @ np.linalg.cholesky(P).T


def _ukf_reference(model: StateSpaceModel, y, u, points):
    """Non-square-root reference for one replication on filterpy's UnscentedKalmanFilter.

    filterpy re-draws the sigma points from (x̂_{k|k−1}, P_{k|k−1}) at the end of
    predict(), as eq. 8 does, so predict/update reproduce eqs. 2–18 in covariance
    form. Its first update would use zeros as points: set them from (x̂_0, P_0).
    """
    n_x, n_y = model.n_x, model.n_y
    ukf = UnscentedKalmanFilter(
        dim_x=n_x, dim_z=n_y, dt=model.dt, hx=model.h, fx=lambda x, dt, u: model.f(x, u), points=points
    )
    ukf.x = np.array(model.x0, float)
    ukf.P = np.array(model.P0, float)
    ukf.Q = np.array(model.Q, float)
    ukf.R = np.array(model.R, float)
    out = {k: [] for k in ("x_pred", "P_pred", "x_filt", "P_filt", "innovation", "innovation_cov")}
    for k in range(y.shape[0]):
        if k == 0:
            ukf.sigmas_f = points.sigma_points(ukf.x, ukf.P)
        else:
            ukf.predict(u=u[k - 1])
        out["x_pred"].append(ukf.x.copy())
        out["P_pred"].append(ukf.P.copy())
        ukf.update(y[k])
        out["x_filt"].append(ukf.x.copy())
        out["P_filt"].append(ukf.P.copy())
        out["innovation"].append(ukf.y.copy())
        out["innovation_cov"].append(ukf.S.copy())
    return {k: np.array(v) for k, v in out.items()}


def _pendulum_model(dt=0.01, q=1e-4, r=0.01) -> StateSpaceModel:
    """Damped, torque-driven pendulum observed through the bob's (x, y) position and the rate."""
    g_over_l, damping, length = 9.81, 0.3, 1.5

    # slices keep the last axis so that concatenate (cheaper than stack) rebuilds the vector
    def f(x, u):
        theta, omega = x[..., :1], x[..., 1:]
        omega_next = omega + dt * (u - g_over_l * np.sin(theta) - damping * omega)
        return np.concatenate([theta + dt * omega, omega_next], axis=-1)

    def h(x):
        theta, omega = x[..., :1], x[..., 1:]
        return np.concatenate([length * np.sin(theta), -length * np.cos(theta), omega], axis=-1)

    return StateSpaceModel(
        f=f,
        h=h,
        Q=np.diag([q, 4 * q]),
        R=np.diag([r, r, 4 * r]),
        x0=np.array([0.8, 0.0]),
        P0=np.diag([0.05, 0.1]),
        dt=dt,
        state_names=("theta", "omega"),
        output_names=("bob_x", "bob_y", "omega"),
    )


def _psd_root(cov):
    vals, vecs = np.linalg.eigh(cov)
    return vecs * np.sqrt(np.clip(vals, 0.0, None))


def _simulate(model: StateSpaceModel, n_reps: int, n_steps: int, seed: int):
    """Open-loop simulation of ``model`` with its own Q, R and a sinusoidal input."""
    rng = np.random.default_rng(seed)
    n_x, n_y = model.n_x, model.n_y
    u = np.broadcast_to(np.sin(0.05 * np.arange(n_steps))[None, :, None], (n_reps, n_steps, 1)).copy()
    lq, lr = _psd_root(model.Q), _psd_root(model.R)
    w = rng.standard_normal((n_steps, n_reps, n_x)) @ lq.T
    x = np.empty((n_reps, n_steps, n_x))
    xk = model.x0 + rng.standard_normal((n_reps, n_x)) @ np.linalg.cholesky(model.P0).T
    for k in range(n_steps):
        x[:, k] = xk
        xk = model.f(xk, u[:, k]) + w[k]
    y = model.h(x) + rng.standard_normal((n_reps, n_steps, n_y)) @ lr.T
    return x, y, u


@pytest.fixture(scope="module")
def mould():
    plant = MouldOscillator()
    noise = GaussianNoise([0.0, 1e-8, 1e-2], [1e-2] * 3)
    trace = Scenario(plant, noise, fault=None, duration=0.4).simulate(seed=3, n_reps=4, stream="calibration")
    return plant.model(noise), trace


# ----------------------------------------------------------------------------------
# cubature rules
# ----------------------------------------------------------------------------------
@pytest.mark.parametrize("n", [1, 2, 3, 4])
@pytest.mark.parametrize("delta1", [0.75, 1.0, 1.3, 2.5])
def test_embedded_rule_integrates_all_monomials_up_to_degree_3(n, delta1):
    eps, w = EmbeddedCubatureRule(delta1).points(n)
    assert eps.shape == (2 ** (n + 1) + 1, n) and w.shape == (2 ** (n + 1) + 1,)
    assert np.all(w > 0)
    for degree in range(4):
        for mono in _monomials(n, degree):
            assert _rule_error(eps, w, mono) < 1e-12, (n, delta1, mono)


@pytest.mark.parametrize("delta1", [0.75, 1.0, 1.3, 2.5])
def test_embedded_rule_matches_the_paper_formulas(delta1):
    """Points and weights as printed in eqs. 3–6 (the moments above decide; they agree)."""
    for n in (1, 2, 3):
        eps, w = EmbeddedCubatureRule(delta1).points(n)
        eps_ref, w_ref = _paper_embedded_points(n, delta1)
        # same multiset of (point, weight) pairs
        got = sorted(map(tuple, np.column_stack([eps, w]).round(12)))
        ref = sorted(map(tuple, np.column_stack([eps_ref, w_ref]).round(12)))
        assert got == ref


def test_embedded_rule_at_delta1_one_by_hand():
    # δ₁ = 1: δ₂ = √2; weights 5/8, 1/2^{n+3}, 1/2^{n+2}; corners at √2·√2 = 2 and √2
    rule = EmbeddedCubatureRule(1.0)
    assert rule.delta2 == pytest.approx(math.sqrt(2))
    eps, w = rule.points(2)
    assert w[0] == pytest.approx(5 / 8)
    np.testing.assert_allclose(w[1:5], 1 / 32)
    np.testing.assert_allclose(w[5:], 1 / 16)
    np.testing.assert_allclose(np.abs(eps[1:5]), 2.0)
    np.testing.assert_allclose(np.abs(eps[5:]), math.sqrt(2))


def test_embedded_rule_degree_4_and_5_monomials():
    """Which degree-4/5 monomials of N(0, I) the embedded set also integrates exactly.

    Exact: every odd monomial (all of degree 5; x_i³x_j, x_i²x_jx_k, x_ix_jx_kx_l)
    and x_i⁴, whatever δ₁. Wrong: x_i²x_j² (i ≠ j), which the corner points give as
    3 instead of 1 — so the set is of degree 5 in one dimension only.
    """
    report = {}
    for n in (1, 2, 3, 4):
        for delta1 in (0.75, 1.0, 2.5):
            eps, w = EmbeddedCubatureRule(delta1).points(n)
            for degree in (4, 5):
                wrong = {m for m in _monomials(n, degree) if _rule_error(eps, w, m) > 1e-10}
                right = set(_monomials(n, degree)) - wrong
                report[(n, delta1, degree)] = (sorted(right), sorted(wrong))
                if degree == 5:
                    assert not wrong
                else:
                    squares_of_two = {m for m in _monomials(n, 4) if sorted(m, reverse=True)[:2] == [2, 2]}
                    assert wrong == squares_of_two
                    fourth_powers = {m for m in _monomials(n, 4) if max(m) == 4}
                    assert fourth_powers <= right
                    for m in wrong:
                        values = np.prod(eps ** np.asarray(m), axis=1)
                        assert w @ values == pytest.approx(3.0)
    right4, wrong4 = report[(3, 1.0, 4)]
    print(f"\nn=3 degree 4: exact {len(right4)} monomials, wrong {wrong4}; degree 5: all exact")


@pytest.mark.parametrize("n", [1, 2, 3, 5])
def test_spherical_radial_rule_is_third_degree(n):
    eps, w = SphericalRadialRule().points(n)
    assert eps.shape == (2 * n, n)
    np.testing.assert_allclose(w, 1 / (2 * n))
    for degree in range(4):
        for mono in _monomials(n, degree):
            assert _rule_error(eps, w, mono) < 1e-12
    if n >= 2:  # x_i² x_j² is 0 on the axes: not of degree 4
        assert _rule_error(eps, w, (2, 2) + (0,) * (n - 2)) == pytest.approx(1.0)


@pytest.mark.parametrize("bad", [0.7, 0.5, 0.0, -1.0, float("nan"), "x"])
def test_delta1_must_satisfy_delta1_squared_above_half(bad):
    with pytest.raises(ConfigError, match="delta1"):
        EmbeddedCubatureRule(bad)
    with pytest.raises(ConfigError, match="delta1"):
        CESCKF(delta1=bad)


def test_unknown_rule_is_a_config_error():
    with pytest.raises(ConfigError, match="rule"):
        CESCKF(rule="gauss_hermite")


# ----------------------------------------------------------------------------------
# filters against references
# ----------------------------------------------------------------------------------
def _linear_model():
    rng = np.random.default_rng(11)
    F = np.array([[1.0, 0.1, 0.0], [-0.2, 0.95, 0.1], [0.0, 0.05, 0.9]])
    B = np.array([[0.0], [0.1], [0.3]])
    H = np.array([[1.0, 0.0, 0.5], [0.0, 2.0, -1.0]])
    a = rng.standard_normal((3, 3))
    Q = 0.01 * (a @ a.T) + 1e-3 * np.eye(3)
    R = np.array([[0.04, 0.01], [0.01, 0.09]])
    model = StateSpaceModel(
        f=lambda x, u: x @ F.T + u @ B.T,
        h=lambda x: x @ H.T,
        Q=Q,
        R=R,
        x0=np.array([1.0, -0.5, 0.2]),
        P0=np.diag([0.5, 0.3, 1.0]),
        dt=0.1,
        state_names=("a", "b", "c"),
        output_names=("y1", "y2"),
    )
    return model, F, B, H


@pytest.mark.parametrize("flt", [CESCKF(), CESCKF(delta1=2.0), CubatureKalmanFilter()], ids=repr)
def test_linear_gaussian_model_matches_kalman_filter(flt):
    model, F, B, H = _linear_model()
    _, y, u = _simulate(model, n_reps=2, n_steps=200, seed=5)
    res = flt.filter(model, y, u)
    for r in range(2):
        kf = KalmanFilter(dim_x=3, dim_z=2, dim_u=1)
        kf.F, kf.B, kf.H, kf.Q, kf.R = F, B, H, model.Q, model.R
        kf.x, kf.P = model.x0.copy(), model.P0.copy()
        for k in range(y.shape[1]):
            if k > 0:
                kf.predict(u=u[r, k - 1])
            np.testing.assert_allclose(res.x_pred[r, k], kf.x, atol=1e-10)
            np.testing.assert_allclose(res.cov_pred[r, k], kf.P, atol=1e-10)
            kf.update(y[r, k])
            np.testing.assert_allclose(res.x_filt[r, k], kf.x, atol=1e-10)
            np.testing.assert_allclose(res.cov_filt[r, k], kf.P, atol=1e-10)
            np.testing.assert_allclose(res.innovation[r, k], kf.y, atol=1e-10)
            np.testing.assert_allclose(res.innovation_cov[r, k], kf.S, atol=1e-10)


def _compare_to_ukf(res, ref, r, scale):
    for key, got in (
        ("x_pred", res.x_pred),
        ("x_filt", res.x_filt),
        ("P_pred", res.cov_pred),
        ("P_filt", res.cov_filt),
        ("innovation", res.innovation),
        ("innovation_cov", res.innovation_cov),
    ):
        np.testing.assert_allclose(got[r], ref[key], rtol=1e-9, atol=1e-11 * scale, err_msg=key)


@pytest.mark.parametrize("delta1", [1.0, 1.7])
def test_cesckf_matches_non_square_root_reference_on_pendulum(delta1):
    model = _pendulum_model()
    _, y, u = _simulate(model, n_reps=2, n_steps=300, seed=2)
    res = CESCKF(delta1=delta1).filter(model, y, u)
    points = _FixedPoints(*_paper_embedded_points(model.n_x, delta1))
    for r in range(2):
        _compare_to_ukf(res, _ukf_reference(model, y[r], u[r], points), r, scale=1.0)


def test_cesckf_matches_non_square_root_reference_on_mould_oscillator(mould):
    model, trace = mould
    model = dataclasses.replace(model, Q=np.diag([1e-4, 1e-4, 1e-2]))
    res = CESCKF().filter(model, trace.y[:2, :200], trace.u[:2, :200])
    points = _FixedPoints(*_paper_embedded_points(model.n_x, 1.0))
    for r in range(2):
        ref = _ukf_reference(model, trace.y[r, :200], trace.u[r, :200], points)
        _compare_to_ukf(res, ref, r, scale=1e3)  # n ≈ 612 r/min


def test_covariance_form_ckf_matches_filterpy_with_spherical_radial_points():
    model = _pendulum_model()
    _, y, u = _simulate(model, n_reps=1, n_steps=300, seed=4)
    res = CubatureKalmanFilter().filter(model, y, u)
    n = model.n_x
    points = _FixedPoints(np.vstack([math.sqrt(n) * np.eye(n), -math.sqrt(n) * np.eye(n)]), np.full(2 * n, 0.5 / n))
    _compare_to_ukf(res, _ukf_reference(model, y[0], u[0], points), 0, scale=1.0)


def test_square_root_factors_stay_finite_over_100000_steps():
    """Singular Q and accurate sensors: P shrinks towards 0 for 100,000 steps, S must stay a valid root."""
    model = _pendulum_model(dt=0.01, q=1e-12, r=1e-4)
    model = dataclasses.replace(model, Q=np.diag([0.0, 1e-12]))
    n_steps = 100_000
    x, y, u = _simulate(model, n_reps=3, n_steps=n_steps, seed=9)
    res = CESCKF().filter(model, y, u)
    assert np.all(np.isfinite(res.sqrt_cov_filt)) and np.all(np.isfinite(res.sqrt_cov_pred))
    assert np.all(np.isfinite(res.x_filt))
    assert np.all(np.diagonal(res.sqrt_cov_filt, axis1=-2, axis2=-1) >= 0.0)
    assert np.all(np.triu(res.sqrt_cov_filt, k=1) == 0.0)  # lower triangular throughout
    eig = np.linalg.eigvalsh(res.cov_filt[:, ::97])
    assert eig.min() >= 0.0
    assert eig[:, -1].max() < 1e-3
    # still a consistent filter at the end: innovations have the predicted covariance
    # (normalised innovation squared ≈ n_y) and the state error is tiny
    late = slice(n_steps - 10_000, None)
    innov = res.innovation[:, late]
    nis = np.einsum("rki,rki->rk", innov, np.linalg.solve(res.innovation_cov[:, late], innov[..., None])[..., 0])
    assert nis.mean() == pytest.approx(model.n_y, rel=0.05)
    assert np.abs(res.x_filt[:, late] - x[:, late]).max() < 0.01


def test_batched_equals_one_replication_at_a_time(mould):
    model, trace = mould
    y = trace.y.copy()
    y[1, 50, 0] = np.nan
    y[2, 50:60, 1:] = np.nan
    for flt in (CESCKF(), CubatureKalmanFilter()):
        batch = flt.filter(model, y, trace.u)
        for r in range(y.shape[0]):
            one = flt.filter(model, y[r : r + 1], trace.u[r : r + 1])
            for field in ("x_pred", "x_filt", "sqrt_cov_pred", "sqrt_cov_filt", "y_pred", "innovation_cov"):
                np.testing.assert_allclose(
                    getattr(batch, field)[r], getattr(one, field)[0], rtol=1e-10, atol=1e-12, err_msg=field
                )
            np.testing.assert_array_equal(np.isnan(batch.innovation[r]), np.isnan(one.innovation[0]))


def test_missing_channel_is_left_out_of_the_update(mould):
    """Per replication, a different pattern of NaN at step k == a filter on the restricted model."""
    model, trace = mould
    k = 120
    y = trace.y.copy()
    y[0, k, 0] = np.nan  # x_p missing
    y[1, k, 1:] = np.nan  # θ and n missing
    y[2, k, :] = np.nan  # everything missing
    for flt in (CESCKF(), CubatureKalmanFilter()):
        res = flt.filter(model, y, trace.u)
        full = flt.filter(model, trace.y, trace.u)
        # complete replication untouched; batched LAPACK rounds differently with a different batch
        # composition (a few 1e-14 absolute on values ~1e-2, seen with numpy 2.4), hence the atol
        np.testing.assert_allclose(res.x_filt[3], full.x_filt[3], rtol=1e-12, atol=1e-13)
        np.testing.assert_allclose(res.x_pred[:, : k + 1], full.x_pred[:, : k + 1], rtol=1e-12)
        for r, keep in ((0, [1, 2]), (1, [0])):
            step_model = dataclasses.replace(model, x0=res.x_pred[r, k], P0=res.cov_pred[r, k])
            one = flt.filter(
                step_model.restrict_outputs(keep), y[r : r + 1, k : k + 1, keep], trace.u[r : r + 1, k : k + 1]
            )
            np.testing.assert_allclose(res.x_filt[r, k], one.x_filt[0, 0], rtol=1e-10, atol=1e-12)
            np.testing.assert_allclose(res.sqrt_cov_filt[r, k], one.sqrt_cov_filt[0, 0], rtol=1e-8, atol=1e-12)
            assert np.isnan(res.innovation[r, k, [c for c in range(3) if c not in keep]]).all()
            assert np.isfinite(res.innovation[r, k, keep]).all()
            assert not np.allclose(res.x_filt[r, k], full.x_filt[r, k])
        np.testing.assert_array_equal(res.x_filt[2, k], res.x_pred[2, k])  # nothing to update with
        np.testing.assert_array_equal(res.sqrt_cov_filt[2, k], res.sqrt_cov_pred[2, k])
        assert np.all(np.isfinite(res.x_filt[:, k + 1 :]))


def test_first_sample_is_predicted_by_x0_and_inputs_are_lagged(mould):
    model, trace = mould
    res = CESCKF().filter(model, trace.y[:1, :5], trace.u[:1, :5])
    np.testing.assert_array_equal(res.x_pred[0, 0], model.x0)
    np.testing.assert_allclose(res.cov_pred[0, 0], model.P0, atol=1e-15)
    # changing u at the last sample changes nothing; changing u_0 changes x̂_{1|0}
    u = trace.u[:1, :5].copy()
    u[0, -1] += 10.0
    np.testing.assert_array_equal(CESCKF().filter(model, trace.y[:1, :5], u).x_filt, res.x_filt)
    u[0, 0] += 10.0
    assert not np.allclose(CESCKF().filter(model, trace.y[:1, :5], u).x_pred[0, 1], res.x_pred[0, 1])


def test_bad_shapes_are_rejected(mould):
    model, trace = mould
    with pytest.raises(ValueError, match="y has shape"):
        CESCKF().filter(model, trace.y[0], trace.u[0])
    with pytest.raises(ValueError, match="u has shape"):
        CESCKF().filter(model, trace.y, trace.u[:, :-1])


# ----------------------------------------------------------------------------------
# residual generators
# ----------------------------------------------------------------------------------
def test_innovation_residual_is_the_filter_innovation(mould):
    model, trace = mould
    res = InnovationResidual().estimate(trace, model)
    ref = CESCKF().filter(model, trace.y, trace.u)
    np.testing.assert_array_equal(res.r, ref.innovation)
    np.testing.assert_array_equal(res.cov, ref.innovation_cov)
    assert res.channels == model.output_names
    assert res.fault_mask is trace.fault_mask


def test_dedicated_observer_never_uses_the_monitored_sensor(mould):
    model, trace = mould
    gen = DedicatedObserverResidual(monitored=(0,))
    res = gen.estimate(trace, model)
    shifted = dataclasses.replace(trace, y=trace.y + np.array([5.0, 0.0, 0.0]))
    res_shifted = gen.estimate(shifted, model)
    # the state estimate ignores y_0, so a bias on it passes 1:1 into its residual
    np.testing.assert_array_equal(res_shifted.extra["x_filt"], res.extra["x_filt"])
    np.testing.assert_allclose(res_shifted.r[..., 0] - res.r[..., 0], 5.0, rtol=1e-12)
    np.testing.assert_array_equal(res_shifted.r[..., 1:], res.r[..., 1:])


def test_dedicated_observer_residual_and_covariance(mould):
    model, trace = mould
    res = DedicatedObserverResidual(monitored=(0,)).estimate(trace, model)
    sub = CESCKF().filter(model.restrict_outputs([1, 2]), trace.y[..., 1:], trace.u)
    # h is the identity: the monitored residual is y_0 − x̂_{0,k|k−1}, cov = P_pred + R
    np.testing.assert_allclose(res.r[..., 0], trace.y[..., 0] - sub.x_pred[..., 0], rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(res.r[..., 1:], sub.innovation)
    np.testing.assert_allclose(res.cov, sub.cov_pred + model.R, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(res.cov[..., 1:, 1:], sub.innovation_cov, rtol=1e-9, atol=1e-12)
    assert res.channels == model.output_names


def test_dedicated_observer_with_nonlinear_output_uses_the_cubature_prediction():
    model = _pendulum_model()
    x, y, u = _simulate(model, n_reps=2, n_steps=200, seed=8)
    trace = Trace(t=np.arange(200) * model.dt, u=u, x=x, y=y, fault_mask=np.zeros((2, 200), bool))
    res = DedicatedObserverResidual(monitored=(1,)).estimate(trace, model)
    sub = CESCKF().filter(model.restrict_outputs([0, 2]), y[..., [0, 2]], u)
    eps, w = _paper_embedded_points(2, 1.0)
    pts = sub.x_pred[..., None, :] + np.einsum("rkij,pj->rkpi", sub.sqrt_cov_pred, eps)
    y1_hat = np.einsum("p,rkp->rk", w, model.h(pts)[..., 1])
    np.testing.assert_allclose(res.r[..., 1], y[..., 1] - y1_hat, rtol=1e-10, atol=1e-12)
    np.testing.assert_array_equal(res.r[..., [0, 2]], sub.innovation)
    assert np.all(np.linalg.eigvalsh(res.cov) > 0)


@pytest.mark.parametrize("monitored", [(3,), (0, 1, 2), (0, 0)])
def test_dedicated_observer_rejects_bad_channels(mould, monitored):
    model, trace = mould
    with pytest.raises(ConfigError, match="monitored"):
        DedicatedObserverResidual(monitored=monitored).estimate(trace, model)


def test_residual_generators_reject_an_object_without_filter():
    with pytest.raises(ConfigError, match="filter"):
        InnovationResidual(filter="cesckf")


def test_benchmark_filter_reports_both_rates():
    """The batched and the one-at-a-time rates are replication-steps over their own measured seconds."""
    out = benchmark_filter(n_reps=4, n_steps=50, single_reps=2)
    assert out["n_reps"] == 4 and out["n_steps"] == 50 and out["single_reps"] == 2
    assert out["batched_steps_per_s"] == pytest.approx(4 * 50 / out["batched_seconds"], rel=1e-12)
    assert out["single_steps_per_s"] == pytest.approx(2 * 50 / out["single_seconds"], rel=1e-12)
    # the speed-ups are ratios of those rates (NumPy batched against NumPy one at a time; compiled against NumPy)
    assert out["speedup"] == pytest.approx(out["numpy_steps_per_s"] / out["single_steps_per_s"], rel=1e-12)
    assert out["speedup_vs_numpy"] == pytest.approx(out["batched_steps_per_s"] / out["numpy_steps_per_s"], rel=1e-12)
    # the rates were measured on the same numbers: the compiled filter agrees with the NumPy reference
    assert out["max_relative_difference"] < 1e-10
