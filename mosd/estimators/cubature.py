"""State estimators and the residual generators built on them (paper 000, §1, eqs. 2–18).

Cubature rules
--------------
:class:`EmbeddedCubatureRule` is the composite embedded point set of eqs. 3–6
(2^{n+1}+1 points: the centre, 2^n corners √2·δ₂·(±1,…,±1) and 2^n corners
√2·δ₁·(±1,…,±1)); :class:`SphericalRadialRule` the third-degree spherical-radial
set of the ordinary CKF (2n points ±√n e_i). Both integrate every monomial of
degree ≤ 3 of N(0, I) exactly. The embedded set also gets every odd monomial
(the corner sets are symmetric under the sign flip of any coordinate) and x_i⁴
right whatever δ₁, but not x_i² x_j² (it gives 3 instead of 1): it is exact to
degree 5 in one dimension only.

Filters
-------
:class:`CESCKF` is the square-root filter of eqs. 2–18: embedded points are
propagated through f (eqs. 4–5), the predicted square root comes from a QR
"tria" (eqs. 10–11), points are *re-drawn* from S_{k|k−1} before the
measurement update (eq. 8), S_yy and S_{k|k} are QR "tria" factors (eqs. 15,
18) and the gain is eq. 13. :class:`CubatureKalmanFilter` is the same algorithm
in covariance form (Cholesky of P at every step) with the spherical-radial rule
by default. Both filter a whole batch of replications in one call: arrays carry
the replication on axis 0 and every step is a handful of stacked numpy
operations (``np.linalg.qr``/``solve`` on (R, ·, ·) stacks), so the cost per
step hardly grows with R. Time ordering: x̂_{0|−1} = x̂_0, P_{0|−1} = P_0 (no f
for the first sample); afterwards x̂_{k|k−1} uses u_{k−1}. NaN in y marks a
missing channel: replications are grouped by their pattern of missing channels
and each group is updated with its present channels only (the all-present case
is one batched update). ``filter(..., start=FilterStart(...))`` goes on from a
carried step instead of x̂_0, P_0 (x̂_{k−1|k−1}, S_{k−1|k−1}, u_{k−1}): the
residual generators' causal form filters a stream chunk by chunk with the batch's
own code (the compiled kernel resumes the same way), bit for bit one call.

Residual generators
-------------------
:class:`InnovationResidual` is the paper's eq. 7 innovation with every sensor
in the update. :class:`DedicatedObserverResidual` (the default, docs/DECISIONS.md
decision 1) updates the filter with the *other* sensors only and compares the
monitored sensor with its prediction. Why: a filter that updates with the
faulty sensor treats a constant sensor bias as information about the state and
moves its estimate to the biased reading. On the mould oscillator with the
default noise, the innovation's mean shift after a 2σ offset on x_p is 1.2σ
over the first 0.5 s, 0.5σ over the next 0.5 s and < 0.2σ after 1 s, so a chart
sees the fault only for about its first second. The dedicated observer never
feeds y_m back, so the bias stays in its residual for as long as the fault
lasts (``tests/test_fault_visibility.py`` shows both behaviours). This needs a
plant whose monitored output is observable through the others (x_p = A sin θ
ties x_p to θ) and a small process noise on x_p and θ — hence the default
noise in :class:`mosd.noise.GaussianNoise`.

This module imports neither Hydra nor MLflow.
"""
from __future__ import annotations

from dataclasses import dataclass
import math

import numpy as np

from ..model import StateSpaceModel
from ..validation import Component, ConfigError, Interval, Param, check_in, check_int

__all__ = [
    "EmbeddedCubatureRule",
    "SphericalRadialRule",
    "FilterResult",
    "FilterStart",
    "CubatureKalmanFilter",
    "CESCKF",
]

_DELTA1_RANGE = Interval(math.sqrt(0.5), math.inf, open_low=True)
RULES = ("embedded", "spherical_radial")


# ----------------------------------------------------------------------------------
# cubature rules
# ----------------------------------------------------------------------------------
class EmbeddedCubatureRule:
    """Composite embedded cubature points and weights (paper 000, eqs. 3–6).

    As printed in the paper: the weights w_i and δ₂ in the text under eq. 3,
    the unit points ε_i under eq. 5, used in eqs. 4 and 8; eq. 6's upper sum
    limit "2^{n+1}+n" is a misprint for 2^{n+1}+1 (its own index range says
    so). The weights sum to 1 and reproduce E[x] = 0, E[x xᵀ] = I and every
    third moment of N(0, I) (tests/test_estimator.py checks all monomials).

    Parameters
    ----------
    delta1 : float
        Free parameter δ₁ with δ₁² > 1/2 (eq. 3); δ₂ = δ₁√(4δ₁² − 2)/(2δ₁² − 1).
        The paper gives no value; δ₁ = 1 (δ₂ = √2, points at radius √2 and 2
        per coordinate) is the default. Every weight is positive for any
        admissible δ₁, which the square-root form (√w_i in eqs. 11, 16, 17)
        needs.
    """

    def __init__(self, delta1: float = 1.0):
        self.delta1 = check_in("estimator.filter.delta1", delta1, _DELTA1_RANGE)

    @property
    def delta2(self) -> float:
        """δ₂ = δ₁√(4δ₁² − 2)/(2δ₁² − 1) (text after eq. 3)."""
        d2 = self.delta1**2
        return self.delta1 * math.sqrt(4.0 * d2 - 2.0) / (2.0 * d2 - 1.0)

    def points(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        """Unit points ε_i, shape (2^{n+1}+1, n), and weights w_i (eq. 3), in eq. 4's order.

        Order: the centre, the 2^n δ₂ corners, the 2^n δ₁ corners.
        """
        n = check_int("n", n, 1, 20)
        cached = self.__dict__.setdefault("_points", {}).get((n, self.delta1))  # per filter call: made once
        if cached is not None:
            return cached
        d1sq = self.delta1**2
        corners = _sign_corners(n)
        eps = np.concatenate(
            [np.zeros((1, n)), math.sqrt(2.0) * self.delta2 * corners, math.sqrt(2.0) * self.delta1 * corners]
        )
        w_centre = (2.0 * d1sq - 1.0) * (2.0 * d1sq + 3.0) / (8.0 * d1sq**2)
        w_delta2 = (2.0 * d1sq - 1.0) ** 2 / (2.0 ** (n + 3) * d1sq**2)
        w_delta1 = 1.0 / (2.0 ** (n + 2) * d1sq**2)
        weights = np.concatenate([[w_centre], np.full(2**n, w_delta2), np.full(2**n, w_delta1)])
        eps.flags.writeable = weights.flags.writeable = False  # shared by every call
        self._points[(n, self.delta1)] = (eps, weights)
        return eps, weights


class SphericalRadialRule:
    """Third-degree spherical-radial cubature set: 2n points ±√n e_i, weights 1/(2n)."""

    def points(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        """Unit points, shape (2n, n), and weights."""
        n = check_int("n", n, 1)
        eye = np.eye(n) * math.sqrt(n)
        return np.concatenate([eye, -eye]), np.full(2 * n, 1.0 / (2 * n))


def _sign_corners(n: int) -> np.ndarray:
    """All 2^n vectors (±1, …, ±1), shape (2^n, n)."""
    codes = np.arange(2**n)[:, None] >> np.arange(n)[None, :]
    return 1.0 - 2.0 * (codes & 1)


def _make_rule(rule: str, delta1: float):
    if rule == "embedded":
        return EmbeddedCubatureRule(delta1)
    if rule == "spherical_radial":
        return SphericalRadialRule()
    raise ConfigError(f"estimator.rule={rule!r} is not allowed; allowed: embedded, spherical_radial")


# ----------------------------------------------------------------------------------
# filter result
# ----------------------------------------------------------------------------------
@dataclass(frozen=True)
class FilterResult:
    """Everything a batched filter run produces.

    Attributes
    ----------
    x_pred, x_filt : ndarray, shape (R, N, n_x)
        x̂_{k|k−1} (eq. 3) and x̂_{k|k} (eq. 12).
    sqrt_cov_pred, sqrt_cov_filt : ndarray, shape (R, N, n_x, n_x)
        Lower-triangular square roots S_{k|k−1} (eq. 10) and S_{k|k} (eq. 18),
        with a non-negative diagonal (the Cholesky factors of the covariances).
    y_pred : ndarray, shape (R, N, n_y)
        ŷ_{k|k−1} (eq. 6), for every channel, missing or not.
    innovation : ndarray, shape (R, N, n_y)
        r_k = y_k − ŷ_{k|k−1} (eq. 7); NaN where y_k is missing.
    innovation_cov : ndarray, shape (R, N, n_y, n_y)
        Predicted covariance S_yy S_yyᵀ of r_k (eq. 15) over all channels.
    """

    x_pred: np.ndarray
    x_filt: np.ndarray
    sqrt_cov_pred: np.ndarray
    sqrt_cov_filt: np.ndarray
    y_pred: np.ndarray
    innovation: np.ndarray
    innovation_cov: np.ndarray

    @property
    def cov_pred(self) -> np.ndarray:
        """P_{k|k−1} = S_{k|k−1} S_{k|k−1}ᵀ, shape (R, N, n_x, n_x)."""
        return self.sqrt_cov_pred @ np.swapaxes(self.sqrt_cov_pred, -1, -2)

    @property
    def cov_filt(self) -> np.ndarray:
        """P_{k|k} = S_{k|k} S_{k|k}ᵀ, shape (R, N, n_x, n_x)."""
        return self.sqrt_cov_filt @ np.swapaxes(self.sqrt_cov_filt, -1, -2)


@dataclass(frozen=True)
class FilterStart:
    """Where a filter goes on from: the step before the first sample it is given (a stream's next chunk).

    Attributes
    ----------
    x_filt : ndarray, shape (n_x,)
        x̂_{k−1|k−1} (eq. 12).
    sqrt_cov_filt : ndarray, shape (n_x, n_x)
        The lower square root S_{k−1|k−1} (eq. 18), diagonal ≥ 0 (as :class:`FilterResult` stores it).
    u : ndarray, shape (n_u,)
        u_{k−1}, the input that drives x_{k−1} → x_k (eqs. 4–5).

    The next sample's prediction is then the same step as any other (eqs. 3–5, 10–11), so a series
    filtered in chunks that each start from the last one's final row is bit for bit the series filtered
    in one call (``tests/test_streaming_cesckf.py``).
    """

    x_filt: np.ndarray
    sqrt_cov_filt: np.ndarray
    u: np.ndarray

    @classmethod
    def after(cls, result: "FilterResult", u: np.ndarray, rep: int = 0) -> "FilterStart":
        """The start after the last sample of replication ``rep`` of ``result``, whose last input was ``u``."""
        return cls(result.x_filt[rep, -1].copy(), result.sqrt_cov_filt[rep, -1].copy(), np.asarray(u, float).copy())


# ----------------------------------------------------------------------------------
# filters
# ----------------------------------------------------------------------------------
class _CubatureFilterBase(Component):
    """The batched time loop shared by both filters; subclasses supply one step.

    Internal layout (for speed, not for the reader's convenience): a state's
    square root is carried transposed, St = Sᵀ (upper triangular, what a QR
    returns), and cubature points are "point-major", shape (n_pts, R, n), so
    that means and centring over the points are single matrix products on a
    contiguous (n_pts, R·n) block instead of many tiny broadcasts.
    """

    config_group = "estimator.filter"  # a filter is configured under estimator.filter (conf/estimator/*.yaml)
    #: the compiled filter spreads a batch's replications over the cores itself (mosd.kernels.threads):
    #: :meth:`mosd.experiment.Experiment.residuals` adds no blocks of its own on top
    splits_replications = True
    params = {
        "delta1": Param(_DELTA1_RANGE, "δ₁ of the embedded rule (eq. 3), δ₁² > 1/2 (used with rule=embedded)."),
        "rule": Param(RULES, "Point set: embedded (the paper's) or spherical_radial (the third-degree CKF set)."),
    }

    #: True when ``_update`` returns the upper root of the innovation covariance, False for the matrix.
    _returns_root = True

    def filter(self, model: StateSpaceModel, y: np.ndarray, u: np.ndarray | None = None,
               start: FilterStart | None = None) -> FilterResult:
        """Filter a batch of replications.

        Parameters
        ----------
        model : StateSpaceModel
            f, h (broadcasting over leading axes), Q, R, x0, P0.
        y : ndarray, shape (R, N, n_y)
            Measurements; NaN marks a missing channel at that sample.
        u : ndarray, shape (R, N, n_u), optional
            Inputs; u_k drives x_k → x_{k+1}, so the prediction of sample k uses
            u_{k−1}. None means an input-free model (f receives an empty u).
        start : FilterStart, optional
            None: y[:, 0] is the first sample (x̂_{0|−1} = x̂_0, S_{0|−1} = chol(P_0)). Else the filter goes
            on from the step before y[:, 0] (every replication from the same state): a stream's next chunk.

        Returns
        -------
        FilterResult
        """
        y = np.asarray(y, dtype=float)
        if y.ndim != 3 or y.shape[-1] != model.n_y:
            raise ValueError(f"y has shape {y.shape}; expected (R, N, {model.n_y})")
        n_reps, n_steps, n_y = y.shape
        if u is None:
            u = np.zeros((n_reps, n_steps, 0))
        u = np.asarray(u, dtype=float)
        if u.ndim != 3 or u.shape[:2] != (n_reps, n_steps):
            raise ValueError(f"u has shape {u.shape}; expected ({n_reps}, {n_steps}, n_u)")
        compiled = self._compiled(model, y, u, start)
        if compiled is not None:
            return compiled
        n_x = model.n_x
        ctx = self._context(model)

        x_pred = np.empty((n_reps, n_steps, n_x))
        x_filt = np.empty((n_reps, n_steps, n_x))
        st_pred = np.empty((n_reps, n_steps, n_x, n_x))
        st_filt = np.empty((n_reps, n_steps, n_x, n_x))
        y_pred = np.empty((n_reps, n_steps, n_y))
        innov_store = np.empty((n_reps, n_steps, n_y, n_y))
        missing = np.isnan(y)
        step_has_missing = missing.any(axis=(0, 2))

        xp = np.broadcast_to(np.asarray(model.x0, float), (n_reps, n_x)).copy()
        stp = np.broadcast_to(_lower_sqrt(np.asarray(model.P0, float)).T, (n_reps, n_x, n_x)).copy()
        if start is not None:  # resumed: the carried step predicts the first sample like any other step
            xf = np.broadcast_to(np.asarray(start.x_filt, float), (n_reps, n_x)).copy()
            stf = np.broadcast_to(np.asarray(start.sqrt_cov_filt, float).T, (n_reps, n_x, n_x)).copy()
            u_before = np.broadcast_to(np.asarray(start.u, float), (n_reps, u.shape[-1]))
        for k in range(n_steps):
            if k > 0 or start is not None:
                xp, stp = self._predict(ctx, xf, stf, u[:, k - 1] if k > 0 else u_before)
            if step_has_missing[k]:
                xf, stf, yp, innov = self._update_with_gaps(ctx, xp, stp, y[:, k], missing[:, k])
            else:
                xf, stf, yp, innov = self._update(ctx, xp, stp, y[:, k])
            x_pred[:, k] = xp
            st_pred[:, k] = stp
            x_filt[:, k] = xf
            st_filt[:, k] = stf
            y_pred[:, k] = yp
            innov_store[:, k] = innov
        if self._returns_root:
            innov_store = np.swapaxes(innov_store, -1, -2) @ innov_store
        return FilterResult(
            x_pred=x_pred,
            x_filt=x_filt,
            sqrt_cov_pred=np.ascontiguousarray(np.swapaxes(st_pred, -1, -2)),
            sqrt_cov_filt=np.ascontiguousarray(np.swapaxes(st_filt, -1, -2)),
            y_pred=y_pred,
            innovation=y - y_pred,
            innovation_cov=innov_store,
        )

    def _compiled(self, model: StateSpaceModel, y: np.ndarray, u: np.ndarray,
                  start: FilterStart | None = None) -> FilterResult | None:
        """The compiled filter's result when one applies (see :class:`CESCKF`), else None."""
        return None

    def _update_with_gaps(self, ctx, xp, stp, yk, missing_k):
        """Update each group of replications sharing one pattern of missing channels."""
        present = ~missing_k
        patterns, group = np.unique(present, axis=0, return_inverse=True)
        group = group.ravel()
        xf = np.empty_like(xp)
        stf = np.empty_like(stp)
        yp = np.empty(yk.shape)
        innov = np.empty(yk.shape + (yk.shape[-1],))
        for j, pattern in enumerate(patterns):
            idx = np.flatnonzero(group == j)
            channels = None if pattern.all() else np.flatnonzero(pattern)
            xf[idx], stf[idx], yp[idx], innov[idx] = self._update(ctx, xp[idx], stp[idx], yk[idx], channels)
        return xf, stf, yp, innov


def _rule_context(rule, model: StateSpaceModel) -> dict:
    """Constant matrices of one filter run (point-major layout, see _CubatureFilterBase)."""
    eps, w = rule.points(model.n_x)
    n_pts = w.shape[0]
    sqrt_w = np.sqrt(w)
    ctx = {
        "f": model.f,
        "h": model.h,
        "n_pts": n_pts,
        "w": w,
        # [ε_i, 1]: one product with [Sᵀ; x̂] gives the points x̂ + S ε_i (eqs. 4, 8)
        "eps_aug": np.concatenate([eps, np.ones((n_pts, 1))], axis=1),
        # diag(√w)(I − 1 wᵀ): one product gives √w_i (z_i − Σ_j w_j z_j) (eqs. 11, 17)
        "centre": sqrt_w[:, None] * (np.eye(n_pts) - w[None, :]),
    }
    # rows [√w_i ε_i, 0] below [ε_i, 1]: the same product also gives √w_i (x_i − x̂) (eq. 16)
    deviations = np.concatenate([sqrt_w[:, None] * eps, np.zeros((n_pts, 1))], axis=1)
    ctx["eps_aug_dev"] = np.concatenate([ctx["eps_aug"], deviations])
    return ctx


def _points(ctx: dict, x: np.ndarray, st: np.ndarray, with_deviations: bool = False):
    """Cubature points x̂ + S ε_i, shape (n_pts, R, n) (eqs. 4, 8).

    With ``with_deviations`` also √w_i S ε_i = √w_i (x_i − x̂), the Rᵀ of
    eq. 16, from the same matrix product.
    """
    n_reps, n = x.shape
    basis = np.empty((n + 1, n_reps, n))
    basis[:n] = st.swapaxes(0, 1)
    basis[n] = x
    coef = ctx["eps_aug_dev"] if with_deviations else ctx["eps_aug"]
    out = (coef @ basis.reshape(n + 1, n_reps * n)).reshape(-1, n_reps, n)
    if with_deviations:
        n_pts = ctx["n_pts"]
        return out[:n_pts], out[n_pts:]
    return out


def _moments(ctx: dict, values: np.ndarray, bottom_t: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Weighted mean (R, m) and centred, √w-weighted values (n_pts, R, m) of point-major values.

    With ``bottom_t`` (b, m) the centred values come as the first n_pts rows of
    a point-major stack (n_pts + b, R, m) whose last b rows are ``bottom_t`` for
    every replication: the input of :func:`_tria`, written without a copy.
    """
    n_pts, n_reps, m = values.shape
    flat = values.reshape(n_pts, n_reps * m)
    mean = (ctx["w"] @ flat).reshape(n_reps, m)
    if bottom_t is None:
        return mean, (ctx["centre"] @ flat).reshape(n_pts, n_reps, m)
    stacked = np.empty((n_pts + bottom_t.shape[0], n_reps, m))
    np.matmul(ctx["centre"], flat, out=stacked[:n_pts].reshape(n_pts, n_reps * m))
    stacked[n_pts:] = bottom_t[:, None, :]
    return mean, stacked


class CESCKF(_CubatureFilterBase):
    """Composite embedded square-root cubature Kalman filter (paper 000, eqs. 2–18).

    ``rule="spherical_radial"`` gives the ordinary square-root CKF.

    Notes
    -----
    One step, batched over replications (S lower triangular, S Sᵀ = P):

    - eq. 2: S_0 = chol(P_0); the first sample is predicted by x̂_0, S_0 alone;
    - eqs. 4–5: X_i = x̂_{k−1|k−1} + S_{k−1|k−1} ε_i, X*_i = f(X_i, u_{k−1});
    - eq. 3: x̂_{k|k−1} = Σ w_i X*_i; eqs. 10–11: S_{k|k−1} = tria([M, S_Q]);
    - eq. 8: points re-drawn, X_i = x̂_{k|k−1} + S_{k|k−1} ε_i; eq. 9: Y*_i = h(X_i);
    - eqs. 6, 16, 17: ŷ, R (centred state points), N (centred output points);
    - eqs. 14, 15: P_xy = R Nᵀ, S_yy = tria([N, S_R]);
    - eq. 13: K = (P_xy / S_yyᵀ) / S_yy (two triangular solves);
    - eqs. 12, 18: x̂_{k|k} = x̂_{k|k−1} + K r_k, S_{k|k} = tria([R − K N, K S_R]).

    tria(A) is the lower-triangular L with L Lᵀ = A Aᵀ from a QR of Aᵀ, with the
    signs fixed so that diag(L) ≥ 0 (L is then the Cholesky factor). With some
    channels missing, N and S_R keep the rows of the present channels (the rows
    of any square root of R are a square root of that block of R).
    """

    def __init__(self, delta1: float = 1.0, rule: str = "embedded"):
        self._assign(locals())
        self._rule = _make_rule(self.rule, self.delta1)

    def __repr__(self) -> str:
        return f"CESCKF(delta1={self.delta1}, rule={self.rule!r})"

    def _context(self, model: StateSpaceModel) -> dict:
        ctx = _rule_context(self._rule, model)
        ctx["sq_t"] = _lower_sqrt(np.asarray(model.Q, float)).T  # S_Qᵀ (eq. 10)
        ctx["sr_t"] = _lower_sqrt(np.asarray(model.R, float)).T  # S_Rᵀ (eq. 15)
        ctx["mask_x"] = np.triu(np.ones((model.n_x, model.n_x)))
        ctx["mask_y"] = np.triu(np.ones((model.n_y, model.n_y)))
        return ctx

    def _compiled(self, model: StateSpaceModel, y: np.ndarray, u: np.ndarray,
                  start: FilterStart | None = None) -> FilterResult | None:
        """:func:`mosd.kernels.cubature.cesckf` when kernels are on and the model has a compiled form.

        Agrees with the NumPy steps below to ~1e-13 relative (not bit for bit:
        LAPACK's QR and BLAS sum in another order).
        """
        from .. import kernels

        pointwise = model.pointwise
        if pointwise is None or not kernels.enabled():
            return None
        from ..kernels.cubature import TRANSITIONS, filter_batch

        kind = TRANSITIONS.get(pointwise.transition)
        if kind is None:
            return None
        eps, weights = self._rule.points(model.n_x)
        x_pred, x_filt, sqrt_cov_pred, sqrt_cov_filt, y_pred, innovation, innovation_cov = filter_batch(
            kind, np.asarray(pointwise.params, float), np.asarray(pointwise.outputs, np.int64),
            np.ascontiguousarray(y), np.ascontiguousarray(u), np.asarray(model.x0, float),
            np.ascontiguousarray(_lower_sqrt(np.asarray(model.P0, float)).T), np.ascontiguousarray(eps), weights,
            np.ascontiguousarray(_lower_sqrt(np.asarray(model.Q, float)).T),
            np.ascontiguousarray(_lower_sqrt(np.asarray(model.R, float)).T),
            start=None if start is None else (start.x_filt, np.asarray(start.sqrt_cov_filt, float).T, start.u))
        return FilterResult(x_pred=x_pred, x_filt=x_filt, sqrt_cov_pred=sqrt_cov_pred, sqrt_cov_filt=sqrt_cov_filt,
                            y_pred=y_pred, innovation=innovation, innovation_cov=innovation_cov)

    def _predict(self, ctx, xf, stf, uk):
        """Eqs. 3–5, 10–11."""
        pts = _points(ctx, xf, stf)
        xp, stacked = _moments(ctx, ctx["f"](pts, uk[None]), ctx["sq_t"])  # [M, S_Q]ᵀ (eqs. 10–11)
        return xp, _tria_point_major(stacked, ctx["mask_x"])

    def _update(self, ctx, xp, stp, yk, channels=None):
        """Eqs. 6–9, 12–18; ``channels``: indices of the present outputs (None = all)."""
        n_reps, n = xp.shape
        pts, r_c = _points(ctx, xp, stp, with_deviations=True)  # r_c: Rᵀ (eq. 16)
        yp, stacked = _moments(ctx, ctx["h"](pts), ctx["sr_t"])  # ŷ (eq. 6), [N, S_R]ᵀ (eqs. 15, 17)
        n_c = stacked[: ctx["n_pts"]]
        syy_t_full = _tria_point_major(stacked, ctx["mask_y"])
        if channels is None:
            n_u, sr_t, syy_t, innov = n_c, ctx["sr_t"], syy_t_full, yk - yp
        elif len(channels) == 0:
            return xp, stp, yp, syy_t_full
        else:
            n_u = n_c[..., channels]
            sr_t = ctx["sr_t"][:, channels]
            innov = (yk - yp)[..., channels]
            syy_t = _tria(n_u, sr_t)
        pxy_t = n_u.transpose(1, 2, 0) @ r_c.swapaxes(0, 1)  # P_xyᵀ (eq. 14)
        gain_t = _gain_t(syy_t, pxy_t)
        xf = xp + (innov[:, None, :] @ gain_t)[:, 0]
        # eq. 18 with [R − K N, K S_R]ᵀ = [Rᵀ − Nᵀ Kᵀ; S_Rᵀ Kᵀ], built in place
        n_pts = r_c.shape[0]
        stacked = np.empty((n_reps, n_pts + sr_t.shape[0], n))
        top = stacked[:, :n_pts]
        np.matmul(n_u.swapaxes(0, 1), gain_t, out=top)
        np.subtract(r_c.swapaxes(0, 1), top, out=top)
        np.matmul(sr_t, gain_t, out=stacked[:, n_pts:])
        stf = _tria_stacked(stacked, ctx["mask_x"])
        return xf, stf, yp, syy_t_full


class CubatureKalmanFilter(_CubatureFilterBase):
    """Cubature Kalman filter in covariance form (Arasaratnam & Haykin 2009).

    The same steps as :class:`CESCKF` but propagating P itself: P_{k|k−1} =
    Σ w_i (X*_i − x̂)(X*_i − x̂)ᵀ + Q, P_yy = Σ w_i (Y_i − ŷ)(Y_i − ŷ)ᵀ + R,
    K = P_xy P_yy⁻¹, P_{k|k} = P_{k|k−1} − K P_yy Kᵀ, with a Cholesky factor
    drawn at every step for the points (re-drawn after the prediction as in
    eq. 8). Cheaper per step, but the subtraction can lose positive
    definiteness when Q is nearly singular; the square-root :class:`CESCKF`
    cannot. Default point set: the standard third-degree CKF set.
    """

    _returns_root = False

    def __init__(self, rule: str = "spherical_radial", delta1: float = 1.0):
        self._assign(locals())
        self._rule = _make_rule(self.rule, self.delta1)

    def __repr__(self) -> str:
        return f"CubatureKalmanFilter(rule={self.rule!r}, delta1={self.delta1})"

    def _context(self, model: StateSpaceModel) -> dict:
        ctx = _rule_context(self._rule, model)
        ctx["Q"] = np.asarray(model.Q, float)
        ctx["R"] = np.asarray(model.R, float)
        return ctx

    def _predict(self, ctx, xf, stf, uk):
        pts = _points(ctx, xf, stf)
        xp, centred = _moments(ctx, ctx["f"](pts, uk[None]))
        pp = centred.transpose(1, 2, 0) @ centred.swapaxes(0, 1) + ctx["Q"]
        return xp, _chol(pp).swapaxes(1, 2)

    def _update(self, ctx, xp, stp, yk, channels=None):
        pts, r_c = _points(ctx, xp, stp, with_deviations=True)
        yp, n_c = _moments(ctx, ctx["h"](pts))
        pyy_full = n_c.transpose(1, 2, 0) @ n_c.swapaxes(0, 1) + ctx["R"]
        if channels is None:
            n_u, pyy, innov = n_c, pyy_full, yk - yp
        elif len(channels) == 0:
            return xp, stp, yp, pyy_full
        else:
            n_u = n_c[..., channels]
            pyy = pyy_full[:, channels][:, :, channels]
            innov = (yk - yp)[..., channels]
        pxy_t = n_u.transpose(1, 2, 0) @ r_c.swapaxes(0, 1)
        gain_t = np.linalg.solve(pyy, pxy_t)
        xf = xp + (innov[:, None, :] @ gain_t)[:, 0]
        pf = stp.swapaxes(1, 2) @ stp - gain_t.swapaxes(1, 2) @ pyy @ gain_t
        pf = 0.5 * (pf + pf.swapaxes(1, 2))
        return xf, _chol(pf).swapaxes(1, 2), yp, pyy_full


def _tria(top: np.ndarray, bottom_t: np.ndarray, upper_mask: np.ndarray | None = None) -> np.ndarray:
    """Batched tria, returned transposed: upper U (R, m, m) with UᵀU = Σ_p top_pᵀtop_p + bottomᵀbottom.

    ``top`` is point-major, shape (n_pts, R, m) (the transposed left block of
    eqs. 10, 15 for every replication); ``bottom_t`` is (b, m), shared by all
    replications. Uᵀ is the lower-triangular tria factor.
    """
    n_pts, n_reps, m = top.shape
    stacked = np.empty((n_pts + bottom_t.shape[0], n_reps, m))
    stacked[:n_pts] = top
    stacked[n_pts:] = bottom_t[:, None, :]
    return _tria_stacked(stacked.swapaxes(0, 1), upper_mask)


def _tria_point_major(stacked: np.ndarray, upper_mask: np.ndarray | None = None) -> np.ndarray:
    """:func:`_tria` of a stack already built by :func:`_moments`."""
    return _tria_stacked(stacked.swapaxes(0, 1), upper_mask)


def _tria_stacked(stacked: np.ndarray, upper_mask: np.ndarray | None = None) -> np.ndarray:
    """Upper U (R, m, m), diag ≥ 0, with UᵀU = AᵀA for A = ``stacked`` (R, M, m): QR of A.

    ``upper_mask`` is triu(ones((m, m))), passed in by the time loop so that it
    is not rebuilt at every step.
    """
    m = stacked.shape[-1]
    # mode="raw" skips numpy's triu, which rebuilds a mask on every call; R
    # sits in the upper triangle of the transposed Householder array.
    householder, _ = np.linalg.qr(stacked, mode="raw")
    upper = householder[..., :m].swapaxes(1, 2)
    if upper_mask is None:
        upper_mask = np.triu(np.ones((m, m)))
    # QR leaves the sign of each row of R free; diag >= 0 makes Uᵀ the Cholesky
    # factor, so results do not depend on LAPACK's sign conventions.
    sign = np.copysign(1.0, upper.diagonal(0, 1, 2))
    return upper * (sign[:, :, None] * upper_mask)


def _gain_t(syy_t: np.ndarray, pxy_t: np.ndarray) -> np.ndarray:
    """Kᵀ from eq. 13, K = (P_xy / S_yyᵀ) / S_yy, i.e. Kᵀ = S_yy⁻ᵀ (S_yy⁻¹ P_xyᵀ), with S_yyᵀ = ``syy_t``.

    Two triangular solves. Which numpy route is fastest depends on the batch:
    a row-by-row substitution (a few array operations per output channel)
    for large batches, one LU inverse of the small triangular factor for
    small ones, where the per-call overhead dominates.
    """
    n_reps, m, _ = syy_t.shape
    if n_reps >= 32 and m <= 8:
        return _solve_upper(syy_t, _solve_lower(syy_t.swapaxes(1, 2), pxy_t))
    inv_t = np.linalg.inv(syy_t)  # S_yy⁻ᵀ (upper triangular)
    return inv_t @ (inv_t.swapaxes(1, 2) @ pxy_t)


def _solve_upper(upper: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """X with U X = B for a batch of upper-triangular U (R, m, m), B (R, m, c): back substitution."""
    m = upper.shape[-1]
    out = np.empty(rhs.shape)
    for i in range(m - 1, -1, -1):
        acc = rhs[:, i]
        if i < m - 1:
            acc = acc - (upper[:, i : i + 1, i + 1 :] @ out[:, i + 1 :])[:, 0]
        out[:, i] = acc / upper[:, i, i, None]
    return out


def _solve_lower(lower: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """X with L X = B for a batch of lower-triangular L: forward substitution."""
    m = lower.shape[-1]
    out = np.empty(rhs.shape)
    for i in range(m):
        acc = rhs[:, i]
        if i > 0:
            acc = acc - (lower[:, i : i + 1, :i] @ out[:, :i])[:, 0]
        out[:, i] = acc / lower[:, i, i, None]
    return out


def _chol(cov: np.ndarray) -> np.ndarray:
    try:
        return np.linalg.cholesky(cov)
    except np.linalg.LinAlgError:
        raise np.linalg.LinAlgError(
            "covariance lost positive definiteness in CubatureKalmanFilter; use the square-root CESCKF"
        ) from None


def _lower_sqrt(cov: np.ndarray) -> np.ndarray:
    """A lower-triangular square root of a PSD matrix (Cholesky, or tria of an eigen-root if singular)."""
    cov = np.atleast_2d(cov)
    if cov.size == 0:
        return cov.copy()
    try:
        return np.linalg.cholesky(cov)
    except np.linalg.LinAlgError:
        vals, vecs = np.linalg.eigh(cov)
        root = vecs * np.sqrt(np.clip(vals, 0.0, None))  # root rootᵀ = cov
        return _tria(root.T[:, None, :], np.zeros((0, cov.shape[0])))[0].T


# ----------------------------------------------------------------------------------
# residual generators
# ----------------------------------------------------------------------------------
