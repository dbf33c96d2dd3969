"""Networked asynchronous IMM fusion filter for fault diagnosis (paper 001, §§2–4; reconstruction).

Hu, Jin, Xue, Sun, Acta Automatica Sinica 43(8), 2017. The model set holds the
normal model (m = 0) and one model per fault direction e_m (m = 1..d_f), each
with the unknown fault amplitude f appended to the state (eqs. 15–19,
:meth:`~mosd.plants.networked_target.ContinuousLinearModel.augment`). At every
fusion instant t_k the filter runs the paper's four steps over the fusion
interval (t_{k−1}, t_k]:

1. *Filter restart* (§3.1, eqs. 20–23, reconstructed as the standard IMM mixing):
   c̄_m = Σ_i λ_{i,m} μ_i,  μ_{i|m} = λ_{i,m} μ_i / c̄_m,
   x̂⁰_m = Σ_i μ_{i|m} x̂_i,  P⁰_m = Σ_i μ_{i|m} [P_i + (x̂_i − x̂⁰_m)(x̂_i − x̂⁰_m)ᵀ].
2. *Fault-conditioned asynchronous fusion filtering* (§3.2, Lemmas 1–2,
   Theorem 1, reconstructed). The measurements that reached the fusion centre
   in the interval, ordered in time, τ_1 <= ... <= τ_{N_k}, sensor s(i), are
   written as one "equivalent measurement" of x(t_k). With Δ_i = t_k − τ_i,
   Φ_i = e^{AΔ_i}, Γ_i u the input's effect and w_i = w(t_k, τ_i) the process
   noise over (τ_i, t_k] (covariance Q_i = Q_d(Δ_i))::

       x(τ_i) = Φ_i⁻¹ [x(t_k) − Γ_i u − w_i]
       z̄_i := z_i + H̄_i Γ_i u = H̄_i x(t_k) + ṽ_i,   H̄_i = H_{s(i)} Φ_i⁻¹,   ṽ_i = v_i − H̄_i w_i
       Cov(ṽ_i, ṽ_j) = δ_ij R_{s(i)} + H̄_i Q_{max(i,j)} H̄_jᵀ            (Lemma 2)
       Cov(w_T, ṽ_i) = −Q_i H̄_iᵀ =: C_i,   w_T the noise of x(t_k) = Φ_T x(t_{k−1}) + Γ_T u + w_T

   (Q_{max(i,j)}: the noise after the later of the two instants is shared.)
   The optimal linear update with noise correlated to the state noise (the
   paper's ref. 19, Li 2003) is then::

       x̂⁻ = Φ_T x̂⁰ + Γ_T u,   P⁻ = Φ_T P⁰ Φ_Tᵀ + Q_T
       S = H̄ P⁻ H̄ᵀ + H̄ C + Cᵀ H̄ᵀ + R̃,   K = (P⁻ H̄ᵀ + C) S⁻¹
       x̂ = x̂⁻ + K (z̄ − H̄ x̂⁻),   P = P⁻ − K S Kᵀ

   and the model's likelihood of the interval is N(z̄ − H̄ x̂⁻; 0, S) (1 when
   no packet arrived). ``fusion="sequential"`` computes the same posterior by
   predicting from measurement to measurement and updating with each in turn,
   then predicting to t_k; the two agree to rounding (a test oracle).
3. *Mode probability update* (§3.3): μ_m ∝ Λ_m c̄_m with Λ_m that likelihood.
4. *Output fusion* (§3.4): x̂ = Σ_m μ_m x̂_m, P = Σ_m μ_m [P_m + (x̂_m − x̂)(x̂_m − x̂)ᵀ].

The decision (§4, step 3: fault i when μ_i > μ_T for L steps) belongs to
:class:`~mosd.detectors.mode_probability.ModeProbabilityDetector`.
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from ..types import Residuals, Trace
from ..validation import ConfigError, Interval, Param, check_in, check_names
from .base import Estimator

FUSION_RULES = ("equivalent_measurement", "sequential")
_LOG_2PI = math.log(2.0 * math.pi)
_SAME_INSTANT = 1e-9  # s


# -- validation -------------------------------------------------------------------------
def _check_transition(value) -> np.ndarray:
    arr = np.asarray(value, float) if not isinstance(value, str) else np.array(np.nan)
    if arr.ndim == 0:
        return np.asarray(check_in("estimator.transition", value, Interval(0.0, 1.0, open_low=True)))
    ok = arr.ndim == 2 and arr.shape[0] == arr.shape[1] >= 2 and np.all((arr >= 0) & (arr <= 1))
    if not ok or not np.allclose(arr.sum(axis=1), 1.0, atol=1e-9):
        raise ConfigError(f"estimator.transition={value!r} is not allowed; allowed: a float in (0, 1] or a square "
                          f"matrix with entries in [0, 1] and rows summing to 1")
    return arr


def _check_initial(value) -> np.ndarray:
    arr = np.asarray(value, float) if not isinstance(value, str) else np.array(np.nan)
    if arr.ndim == 0:
        return np.asarray(check_in("estimator.initial_probabilities", value, Interval(0.0, 1.0, True, True)))
    if arr.ndim != 1 or arr.size < 2 or np.any(arr < 0) or not np.isclose(arr.sum(), 1.0, atol=1e-9):
        raise ConfigError(f"estimator.initial_probabilities={value!r} is not allowed; allowed: a float in (0, 1) "
                          f"or one probability per model (>= 0, summing to 1)")
    return arr


class AsyncIMMFusion(Estimator):
    """IMM over {normal, fault 1..d_f} models fusing asynchronous lossy sensors (module docstring).

    Outputs, in ``Residuals.extra`` on the fusion grid (index 0 = the prior at t_0):

    * ``mode_probabilities`` (R, N, M): μ_m, column 0 the normal model;
    * ``x_filt`` (R, N, n), ``x_cov`` (R, N, n, n): fused state and covariance;
    * ``fault_estimate`` (R, N, d_f): the fused estimate of the fault input
      vector, entry m−1 = μ_m f̂_m (under the normal model it is 0);
    * ``fault_amplitudes`` (R, N, d_f): f̂_m conditioned on fault model m
      (the paper's amplitude estimate "under the corresponding model");
    * ``fused_augmented`` (R, N, n + 1): the paper's literal output fusion
      Σ_m μ_m [x̂_m; f̂_m] (its last entry mixes in the normal model's f̂,
      which has no physical meaning);
    * ``model_log_likelihood`` (R, N, M): log Λ_m of each interval;
    * ``n_measurements`` (R, N): packets used in each interval.

    ``Residuals.r`` has no channels: the detector reads mode probabilities.
    """

    params = {
        "transition": Param(lambda key, value, est: _check_transition(value), "Λ with λ_{i,m} = P(model i at t_{k−1} "
                            "→ model m at t_k), rows summing to 1; a float p in (0, 1] means p on the diagonal and "
                            "(1 − p)/(M − 1) elsewhere (reconstruction: 0.95).", kind="float or matrix"),
        "initial_probabilities": Param(lambda key, value, est: _check_initial(value), "μ at t_0: a float p in (0, 1) "
                                       "gives the normal model p and the fault models (1 − p)/d_f each "
                                       "(reconstruction: 0.9); or all M values (>= 0, sum 1).",
                                       kind="float or sequence"),
        "fault_intensity": Param(Interval(0.0, 1e6), "Intensity q_f of the random walk of f (slowly varying "
                                 "amplitude; 1e-4)."),
        "fault_variance": Param(Interval(0.0, 1e12, open_low=True), "Prior variance of f at t_0 (1)."),
        "sensors": Param(lambda key, value, est: check_names(key, value, "null (all sensors) or sensor names"), "Sensors to fuse (None: all); one name gives a single-sensor filter.",
                         optional=True, kind="sequence of str"),
        "fusion": Param(FUSION_RULES, "Theorem 1's batch update (the paper) or measurement-by-measurement updates."),
    }

    def __init__(self, transition=0.95, initial_probabilities=0.9, fault_intensity: float = 1e-4,
                 fault_variance: float = 1.0, sensors: Sequence[str] | None = None,
                 fusion: str = "equivalent_measurement"):
        self._assign(locals())

    def __repr__(self) -> str:
        return (f"AsyncIMMFusion(fusion={self.fusion!r}, sensors={self.sensors!r}, "
                f"fault_intensity={self.fault_intensity:g})")

    # -- set-up -----------------------------------------------------------------------
    def _sensor_names(self, trace: Trace, model) -> tuple[str, ...]:
        names = self.sensors or model.sensor_names
        for name in names:
            if name not in model.sensor_names or name not in trace.sensors:
                raise ConfigError(f"estimator.sensors: {name!r} is not a sensor of the plant; "
                                  f"allowed: {', '.join(model.sensor_names)}")
        return names

    def model_set(self, model) -> list:
        """The paper's model set: normal model (m = 0) and one augmented model per fault direction."""
        directions = np.asarray(model.fault_directions, float)
        if directions.ndim != 2 or directions.shape[1] < 1:
            raise ConfigError("estimator: the plant declares no fault direction; allowed: a plant with actuators")
        columns = [np.zeros(model.n_x)] + [directions[:, m] for m in range(directions.shape[1])]
        return [model.augment(d, self.fault_intensity, self.fault_variance) for d in columns]

    def _probabilities(self, n_models: int) -> tuple[np.ndarray, np.ndarray]:
        trans = self.transition
        if trans.ndim == 0:
            off = (1.0 - float(trans)) / (n_models - 1)
            trans = np.full((n_models, n_models), off) + np.eye(n_models) * (float(trans) - off)
        elif trans.shape != (n_models, n_models):
            raise ConfigError(f"estimator.transition has shape {trans.shape}; allowed: ({n_models}, {n_models}) "
                              f"for the normal model and {n_models - 1} fault models, or a float")
        mu0 = self.initial_probabilities
        if mu0.ndim == 0:
            mu0 = np.r_[float(mu0), np.full(n_models - 1, (1.0 - float(mu0)) / (n_models - 1))]
        elif mu0.shape != (n_models,):
            raise ConfigError(f"estimator.initial_probabilities has {mu0.size} entries; allowed: {n_models} or a float")
        return trans, mu0

    # -- the filter -------------------------------------------------------------------
    def estimate(self, trace: Trace, model) -> Residuals:
        """Run the IMM over every replication of ``trace`` (vectorised over replications and models)."""
        names = self._sensor_names(trace, model)
        models = self.model_set(model)
        n_models, n_aug, n_x = len(models), models[0].n_x, model.n_x
        trans, mu0 = self._probabilities(n_models)
        grid = np.asarray(trace.t, float)
        meas = IntervalMeasurements.of(trace, names, grid)
        H = np.stack([models[0].sensors[model.sensor_names.index(n)].H for n in names])  # (S, m, n_aug)
        Rm = np.stack([models[0].sensors[model.sensor_names.index(n)].R for n in names])  # (S, m, m)
        step = _Transitions(models)
        n_reps, n_points = trace.n_reps, grid.size

        compiled = self._compiled(meas, grid, step, H, Rm, trans, mu0, models[0])
        if compiled is not None:
            out_mu, out_x, out_P, out_ll, fused_x, fused_P = compiled
        else:
            mu = np.broadcast_to(mu0, (n_reps, n_models)).copy()
            x = np.broadcast_to(models[0].x0, (n_reps, n_models, n_aug)).copy()
            P = np.broadcast_to(models[0].P0, (n_reps, n_models, n_aug, n_aug)).copy()
            out_mu = np.empty((n_reps, n_points, n_models))
            out_x = np.empty((n_reps, n_points, n_models, n_aug))
            out_P = np.empty((n_reps, n_points, n_models, n_aug, n_aug))
            out_ll = np.zeros((n_reps, n_points, n_models))
            out_mu[:, 0], out_x[:, 0], out_P[:, 0] = mu, x, P
            interval = self._sequential if self.fusion == "sequential" else self._equivalent_measurement
            for k in range(1, n_points):
                x0, P0, cbar = mix(mu, x, P, trans)
                x, P, loglik = interval(x0, P0, meas, k, grid, step, H, Rm)
                mu = mode_update(cbar, loglik)
                out_mu[:, k], out_x[:, k], out_P[:, k], out_ll[:, k] = mu, x, P, loglik
            fused_x, fused_P = fuse(out_mu, out_x, out_P)
        extra = {
            "mode_probabilities": out_mu,
            "x_filt": fused_x[..., :n_x],
            "x_cov": fused_P[..., :n_x, :n_x],
            "fault_estimate": out_mu[..., 1:] * out_x[..., 1:, n_x],
            "fault_amplitudes": out_x[..., 1:, n_x],
            "fused_augmented": fused_x,
            "model_states": out_x,
            "model_covariances": out_P,
            "model_log_likelihood": out_ll,
            "n_measurements": meas.valid.sum(axis=-1),
            "sensors": names,
        }
        return Residuals.of(trace, r=np.empty((n_reps, n_points, 0)), channels=(), extra=extra)

    def _compiled(self, meas, grid, step, H, Rm, trans, mu0, prior):
        """The compiled time loop's outputs (:mod:`mosd.kernels.imm`) when kernels are on, else None.

        None also when the kernel leaves the decision to this reference (a
        non-finite packet, an innovation covariance that is not positive definite).
        """
        from .. import kernels

        if not kernels.enabled():
            return None
        from ..kernels.imm import filter_batch

        return filter_batch(self.fusion == "sequential", meas, grid, step, H, Rm, trans, mu0, prior.x0, prior.P0)

    @staticmethod
    def _sequential(x, P, meas, k, grid, step, H, Rm):
        """Predict from measurement to measurement, update with each, predict to t_k (the oracle form)."""
        n_reps = x.shape[0]
        loglik = np.zeros(x.shape[:2])
        t_prev = np.full(n_reps, grid[k - 1])
        for j in range(meas.count(k)):
            valid = meas.valid[:, k, j]
            tau = np.where(valid, meas.t[:, k, j], t_prev)
            x, P = predict(x, P, *step(tau - t_prev))
            sensor = meas.sensor[:, k, j]
            x_new, P_new, ll = kalman_update(x, P, meas.y[:, k, j], H[sensor][:, None], Rm[sensor][:, None])
            x = np.where(valid[:, None, None], x_new, x)
            P = np.where(valid[:, None, None, None], P_new, P)
            loglik += np.where(valid[:, None], ll, 0.0)
            t_prev = tau
        x, P = predict(x, P, *step(np.maximum(grid[k] - t_prev, 0.0)))
        return x, P, loglik

    @staticmethod
    def _equivalent_measurement(x, P, meas, k, grid, step, H, Rm):
        """Theorem 1 (reconstructed): one update of x(t_k) with the interval's equivalent measurement."""
        x, P = predict(x, P, *step(np.full(x.shape[0], grid[k] - grid[k - 1])))
        n_slots = meas.count(k)
        if n_slots == 0:
            return x, P, np.zeros(x.shape[:2])
        valid = meas.valid[:, k, :n_slots]  # (R, J)
        sensor = meas.sensor[:, k, :n_slots]
        phi, drive, q = step(np.where(valid, np.maximum(grid[k] - meas.t[:, k, :n_slots], 0.0), 0.0))  # (R, J, M, ...)
        h_eq = H[sensor][:, :, None] @ np.linalg.inv(phi)  # H̄_i = H Φ_i⁻¹, (R, J, M, m, n)
        h_eq = np.where(valid[..., None, None, None], h_eq, 0.0)
        y = np.where(valid[..., None], meas.y[:, k, :n_slots], 0.0)
        z_eq = y[:, :, None] + (h_eq @ drive[..., None])[..., 0]  # z̄_i = z_i + H̄_i Γ_i u, (R, J, M, m)
        n_reps, _, n_models, m, n = h_eq.shape
        # noise shared after the later instant of each pair: Q_{max(i, j)}
        later = np.maximum.outer(np.arange(n_slots), np.arange(n_slots))
        r_eq = h_eq[:, :, None] @ q[:, later] @ np.swapaxes(h_eq[:, None], -1, -2)  # (R, J, J, M, m, m)
        own = np.where(valid[..., None, None], Rm[sensor], np.eye(m))  # padded slots: an uninformative unit
        r_eq[:, np.arange(n_slots), np.arange(n_slots)] += own[:, :, None]
        cross = -q @ np.swapaxes(h_eq, -1, -2)  # C_i = −Q_i H̄_iᵀ, (R, J, M, n, m)
        # stack the slots: (R, M, J·m, ...)
        h_bar = np.moveaxis(h_eq, 1, 2).reshape(n_reps, n_models, n_slots * m, n)
        z_bar = np.moveaxis(z_eq, 1, 2).reshape(n_reps, n_models, n_slots * m)
        r_bar = np.moveaxis(r_eq, 3, 1).swapaxes(3, 4).reshape(n_reps, n_models, n_slots * m, n_slots * m)
        c_bar = np.moveaxis(cross, 1, 2).swapaxes(2, 3).reshape(n_reps, n_models, n, n_slots * m)
        pht_c = P @ np.swapaxes(h_bar, -1, -2) + c_bar
        s = h_bar @ pht_c + np.swapaxes(c_bar, -1, -2) @ np.swapaxes(h_bar, -1, -2) + r_bar
        s = 0.5 * (s + np.swapaxes(s, -1, -2))
        nu = z_bar - (h_bar @ x[..., None])[..., 0]
        gain_t = np.linalg.solve(s, np.swapaxes(pht_c, -1, -2))  # Kᵀ = S⁻¹ (P H̄ᵀ + C)ᵀ
        x = x + (nu[..., None, :] @ gain_t)[..., 0, :]
        P = P - np.swapaxes(gain_t, -1, -2) @ s @ gain_t
        loglik = gaussian_loglik(nu, s) + 0.5 * m * _LOG_2PI * (~valid).sum(axis=1)[:, None]
        return x, 0.5 * (P + np.swapaxes(P, -1, -2)), loglik


class IntervalMeasurements:
    """The packets that reached the fusion centre, grouped by fusion interval (t_{k−1}, t_k] and time-ordered.

    Attributes
    ----------
    t : ndarray (R, N, J)
        Sample instant of slot j of interval k (NaN in unused slots).
    y : ndarray (R, N, J, m)
    sensor : ndarray of int (R, N, J)
        Index into the fused sensors.
    valid : ndarray of bool (R, N, J)
    """

    def __init__(self, t, y, sensor, valid):
        self.t, self.y, self.sensor, self.valid = t, y, sensor, valid
        self._counts = valid.sum(axis=-1).max(axis=0) if valid.size else np.zeros(t.shape[1], int)

    def count(self, k: int) -> int:
        """Slots needed for interval k (the most packets any replication has in it)."""
        return int(self._counts[k])

    @classmethod
    def of(cls, trace: Trace, names: Sequence[str], grid: np.ndarray) -> "IntervalMeasurements":
        """Gather the received samples of ``names``; a sample at τ belongs to the k with t_{k−1} < τ <= t_k."""
        parts = [trace.sensors[name] for name in names]
        t = np.concatenate([p.t for p in parts], axis=1)
        y = np.concatenate([p.y for p in parts], axis=1)
        sensor = np.concatenate([np.full(p.t.shape[1], i) for i, p in enumerate(parts)])
        ok = np.concatenate([p.received for p in parts], axis=1) & (t > grid[0]) & (t <= grid[-1])
        order = np.argsort(np.where(ok, t, np.inf), axis=1, kind="stable")
        t, ok = np.take_along_axis(t, order, 1), np.take_along_axis(ok, order, 1)
        y, sensor = np.take_along_axis(y, order[..., None], 1), sensor[order]
        # a sample within rounding of t_k belongs to interval k, not k + 1
        k = np.searchsorted(grid, np.where(ok, t - _SAME_INSTANT, np.inf), side="left")
        # slot within the interval: position minus the position where the interval's run began
        position = np.broadcast_to(np.arange(t.shape[1]), t.shape)
        starts = np.ones(t.shape, bool)
        starts[:, 1:] = k[:, 1:] != k[:, :-1]
        slot = position - np.maximum.accumulate(np.where(starts, position, 0), axis=1)
        n_reps, n_points = t.shape[0], grid.size
        n_slots = int(slot[ok].max()) + 1 if ok.any() else 0
        out_t = np.full((n_reps, n_points, n_slots), np.nan)
        out_y = np.full((n_reps, n_points, n_slots, y.shape[-1]), np.nan)
        out_s = np.zeros((n_reps, n_points, n_slots), int)
        valid = np.zeros((n_reps, n_points, n_slots), bool)
        rr, cc = np.nonzero(ok)
        index = (rr, k[rr, cc], slot[rr, cc])
        out_t[index], out_y[index], out_s[index], valid[index] = t[rr, cc], y[rr, cc], sensor[rr, cc], True
        return cls(out_t, out_y, out_s, valid)


class _Transitions:
    """Φ, Γu and Q_d of every model over intervals Δ, cached by Δ (the same few intervals recur)."""

    def __init__(self, models):
        self.models = models
        self._cache: dict[float, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}

    def __call__(self, delta: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(Φ, Γu, Q_d) with shapes delta.shape + (M, n, n), (M, n), (M, n, n)."""
        delta = np.asarray(delta, float)
        keys, inverse = np.unique(np.round(delta, 12), return_inverse=True)
        missing = [key for key in keys if key not in self._cache]
        if missing:
            parts = [m.discretise(np.asarray(missing)) for m in self.models]
            phi = np.stack([p[0] for p in parts], axis=1)
            drive = np.stack([p[1] @ m.u for p, m in zip(parts, self.models)], axis=1)
            q = np.stack([p[2] for p in parts], axis=1)
            for i, key in enumerate(missing):
                self._cache[key] = (phi[i], drive[i], q[i])
        table = [self._cache[key] for key in keys]
        shape = delta.shape
        return tuple(np.stack([entry[i] for entry in table])[inverse.reshape(shape)] for i in range(3))


# -- the IMM steps (batched over replications R and models M) -------------------------------
def mix(mu: np.ndarray, x: np.ndarray, P: np.ndarray, trans: np.ndarray):
    """Filter restart (§3.1): mixed initial conditions and the predicted mode probabilities c̄ (R, M)."""
    cbar = mu @ trans
    weights = mu[:, :, None] * trans[None]  # μ_i λ_{i,m}, indexed [r, i, m]
    reachable = cbar > 0
    weights = np.where(reachable[:, None, :], weights / np.where(reachable, cbar, 1.0)[:, None, :],
                       np.eye(mu.shape[1])[None])  # an unreachable model keeps its own estimate
    x0 = np.einsum("rim,rin->rmn", weights, x)
    d = x[:, :, None, :] - x0[:, None, :, :]
    P0 = np.einsum("rim,rimab->rmab", weights, P[:, :, None] + d[..., :, None] * d[..., None, :])
    return x0, P0, cbar


def predict(x, P, phi, drive, q):
    """x ← Φ x + Γu, P ← Φ P Φᵀ + Q_d (per replication and model)."""
    x = (phi @ x[..., None])[..., 0] + drive
    P = phi @ P @ np.swapaxes(phi, -1, -2) + q
    return x, 0.5 * (P + np.swapaxes(P, -1, -2))


def kalman_update(x, P, y, H, R):
    """One Kalman update of (R, M) filters with y (R, m), H (R, 1, m, n), R (R, 1, m, m); NaN y gives NaN."""
    nu = np.nan_to_num(y)[:, None] - (H @ x[..., None])[..., 0]
    hp = H @ P
    s = hp @ np.swapaxes(H, -1, -2) + R
    s = 0.5 * (s + np.swapaxes(s, -1, -2))
    gain_t = np.linalg.solve(s, hp)  # Kᵀ = S⁻¹ H P
    x = x + (nu[..., None, :] @ gain_t)[..., 0, :]
    P = P - np.swapaxes(gain_t, -1, -2) @ hp
    return x, 0.5 * (P + np.swapaxes(P, -1, -2)), gaussian_loglik(nu, s)


def gaussian_loglik(nu: np.ndarray, s: np.ndarray) -> np.ndarray:
    """log N(ν; 0, S) over leading axes."""
    chol = np.linalg.cholesky(s)
    white = np.linalg.solve(chol, nu[..., None])[..., 0]
    logdet = 2.0 * np.log(np.diagonal(chol, axis1=-2, axis2=-1)).sum(axis=-1)
    return -0.5 * (np.sum(white**2, axis=-1) + logdet + nu.shape[-1] * _LOG_2PI)


def mode_update(cbar: np.ndarray, loglik: np.ndarray) -> np.ndarray:
    """§3.3: μ_m ∝ Λ_m c̄_m, computed in logs so that small likelihoods do not underflow."""
    with np.errstate(divide="ignore"):
        log_post = np.log(cbar) + loglik
    log_post -= log_post.max(axis=-1, keepdims=True)
    post = np.exp(log_post)
    return post / post.sum(axis=-1, keepdims=True)


def fuse(mu: np.ndarray, x: np.ndarray, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """§3.4 output fusion over the model axis (second to last of x)."""
    fused = np.einsum("...m,...mn->...n", mu, x)
    d = x - fused[..., None, :]
    cov = np.einsum("...m,...mab->...ab", mu, P + d[..., :, None] * d[..., None, :])
    return fused, cov


