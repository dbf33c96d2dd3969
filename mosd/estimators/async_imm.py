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

from ..streaming import COUNT, FINITE, LEGACY_STAGES, NoStreamingForm, StateVar, build
from ..types import Residuals, Trace
from ..validation import ConfigError, Interval, Param, check_in, check_names
from .step import EstimatorStage, StepEstimator, build_params, each_run

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


class AsyncIMMFusion(StepEstimator):
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

    #: a replication's mode probabilities move in the last bit with the batch it is filtered in (the mixing's
    #: matrix product over replications): :meth:`mosd.experiment.Experiment.residuals` keeps one batch
    independent_replications = False

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

        start = (mu0, np.broadcast_to(models[0].x0, (n_models, n_aug)),
                 np.broadcast_to(models[0].P0, (n_models, n_aug, n_aug)))
        out_mu, out_x, out_P, out_ll, fused_x, fused_P = self._filter(meas, grid, step, H, Rm, trans, start)
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

    def _filter(self, meas, grid, step, H, Rm, trans, start):
        """(μ, x̂_m, P_m, log Λ_m, fused x̂, fused P) on every row of ``grid``: the one time loop of the batch
        estimate and the causal form (:meth:`scan`).

        ``start`` = (μ (M,), x̂ (M, n), P (M, n, n)) is the state before row 0, which is not updated (the
        prior at t_0 of a run, or the state a stream carries with ``grid[0]`` its last fusion instant).
        The compiled loop (:mod:`mosd.kernels.imm`) when kernels are on, else (and where the kernel leaves
        the decision to it: a non-finite packet, an innovation covariance that is not positive definite)
        the NumPy reference.
        """
        from .. import kernels

        mu0, x0, P0 = (np.asarray(a, float) for a in start)
        if kernels.enabled():
            from ..kernels.imm import filter_batch

            compiled = filter_batch(self.fusion == "sequential", meas, grid, step, H, Rm, trans, mu0, x0, P0)
            if compiled is not None:
                return compiled
        n_reps, n_points = meas.valid.shape[:2]
        n_models, n_aug = x0.shape
        mu = np.broadcast_to(mu0, (n_reps, n_models)).copy()
        x = np.broadcast_to(x0, (n_reps, n_models, n_aug)).copy()
        P = np.broadcast_to(P0, (n_reps, n_models, n_aug, n_aug)).copy()
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
        return out_mu, out_x, out_P, out_ll, fused_x, fused_P

    # -- the step (mosd.estimators.step) ---------------------------------------------------
    def _start_params(self, model) -> dict[str, np.ndarray]:
        """μ_0, x̂_0 and P_0 of every model (the state before a stream's first row)."""
        models = self.model_set(model)
        M, n = len(models), models[0].n_x
        _, mu0 = self._probabilities(M)
        return {"mu0": np.asarray(mu0, float), "x0": np.array(np.broadcast_to(models[0].x0, (M, n)), float),
                "P0": np.array(np.broadcast_to(models[0].P0, (M, n, n)), float)}

    def step_params(self, model, trace: Trace | None = None) -> dict[str, np.ndarray]:
        """The start state, the fusion grid t0 + k·period of ``trace`` and the packet slots a row holds."""
        grid = np.asarray(trace.t, float)
        out = self._start_params(model)
        out.update({"t0": np.asarray(float(grid[0])), "period": np.asarray(float(grid[1] - grid[0])),
                    "slots": np.asarray(float(self._slots(trace, model))),
                    "n_y": np.asarray(float(model.sensors[0].H.shape[0])), "n_x": np.asarray(float(model.n_x))})
        return out

    def step_state(self, params: dict, reads: tuple = ()) -> dict:
        M, n = np.shape(params["x0"])
        mus, xs, Ps = state_names(M, n)
        declared = {"imm_step": (StateVar("Fusion instants seen since the stream's start.", COUNT), 0)}
        declared.update({k: (StateVar("A model's probability after the row.", Interval(0.0, 1.0)), float(v))
                         for k, v in zip(mus, np.ravel(params["mu0"]))})
        declared.update({k: (StateVar("An entry of a model's state estimate after the row.", FINITE), float(v))
                         for k, v in zip(xs, np.ravel(params["x0"]))})
        declared.update({k: (StateVar("An entry of a model's covariance after the row.", FINITE), float(v))
                         for k, v in zip(Ps, np.ravel(params["P0"]))})
        return declared

    def _setup(self, model):
        """(the model set, transition matrix, H, R, the plant's sensor index → the fused one, the transitions),
        made once per model."""
        cached = self.__dict__.get("_stream_setup")
        if cached is None or cached[0] is not model:
            names = tuple(self.sensors or model.sensor_names)
            models = self.model_set(model)
            trans, _ = self._probabilities(len(models))
            index = [model.sensor_names.index(n) for n in names]
            H = np.stack([models[0].sensors[i].H for i in index])
            Rm = np.stack([models[0].sensors[i].R for i in index])
            fused = np.full(len(model.sensor_names), -1)
            fused[index] = np.arange(len(index))     # the plant's sensor index -> the fused one (-1: not fused)
            cached = self.__dict__["_stream_setup"] = (model, (trans, H, Rm, fused, _Transitions(models)))
        return cached[1]

    def scan(self, model, params: dict, state: dict, columns: dict, trajectory: bool = False) -> dict:
        """One row per fusion instant t_k = t0 + k·period, its packets in (:meth:`StepEstimator.scan`; each run
        on its own, R = 1 when served).

        In per row: slot j ``packet<j>_sensor`` (the sensor's index in the plant's sensor list),
        ``packet<j>_time`` (its sample instant τ) and ``packet<j>_y<c>`` (its measurement); a slot with no
        packet is NaN. Packets may come in any slot order (out-of-order arrival): they are fused in the
        order of their sample instants (ties: sensor order), as the batch orders an interval's packets. A
        lost packet is simply absent. A packet sampled in (t_{k−1}, t_k] belongs to row k (the batch's
        grouping, within 1e-9 s of t_k); one that arrives later than its interval (τ <= t_{k−1}) can no
        longer be fused and is counted in ``late_packets`` (the batch's trace with that packet lost); one
        sampled after t_k is refused (one line). Row 0 of a stream is the prior at t0 (no update: its
        packets are ignored, as the batch ignores samples at or before t_0); packets of sensors the design
        does not fuse are ignored.

        Out per row: ``mode_probabilities_<m>`` (m = 0 the normal model), ``x_filt_<i>``,
        ``fault_amplitudes_<m>``, ``fault_estimate_<m>``, ``n_measurements``, ``late_packets``; state
        ``imm_step`` (rows seen) and each model's μ, x̂ and P after the row. The time loop is the batch's
        (:meth:`_filter`: the compiled kernel, or the NumPy reference).
        """
        return each_run(lambda run_state, run_columns: self._scan_run(model, params, run_state, run_columns),
                        state, columns)

    def _scan_run(self, model, params: dict, state: dict, columns: dict) -> dict:
        """:meth:`scan` of one run (columns (N,), state scalars)."""
        trans, H, Rm, fused, step = self._setup(model)
        rows = len(next(iter(columns.values())))
        first = int(state["imm_step"])
        M, n = np.shape(params["x0"])
        n_x, t0, period = int(params["n_x"]), float(params["t0"]), float(params["period"])
        mus, xs, Ps = state_names(M, n)
        if rows == 0:   # an empty request: no row scored, the state stays where it was
            counts = ("n_measurements", "late_packets", "imm_step")
            return {k: np.empty(0, np.int64 if k in counts else float)
                    for k in (*output_names(M, n_x), "imm_step", *mus, *xs, *Ps)}
        t, y, sensor, valid, late = _packets(columns, rows, first, fused, params)
        # the batch's loop on a grid whose row 0 is the state carried in (not updated): the last fusion instant
        # before the chunk, or at the stream's start the chunk's first row (the prior at t0)
        lead = 0 if first == 0 else 1
        tail = 1 if rows + lead < 2 else 0    # the loop runs on two rows at least; an extra empty one is dropped
        grid = t0 + (first - lead + np.arange(lead + rows + tail)) * period

        def pad(a, fill):
            return np.concatenate([np.full((1, lead) + a.shape[2:], fill, a.dtype), a,
                                   np.full((1, tail) + a.shape[2:], fill, a.dtype)], axis=1)

        meas = IntervalMeasurements(pad(t, np.nan), pad(y, np.nan), pad(sensor, 0), pad(valid, False))
        start = (np.array([float(state[k]) for k in mus]), np.array([float(state[k]) for k in xs]).reshape(M, n),
                 np.array([float(state[k]) for k in Ps]).reshape(M, n, n))
        out_mu, out_x, out_P, _, fused_x, _ = self._filter(meas, grid, step, H, Rm, trans, start)
        keep = slice(lead, lead + rows)
        mu, x, P, fx = out_mu[0, keep], out_x[0, keep], out_P[0, keep], fused_x[0, keep]
        out = {f"mode_probabilities_{m}": mu[:, m] for m in range(M)}
        out.update({f"x_filt_{i}": fx[:, i] for i in range(n_x)})
        out.update({f"fault_amplitudes_{m}": x[:, m + 1, n_x] for m in range(M - 1)})
        out.update({f"fault_estimate_{m}": mu[:, m + 1] * x[:, m + 1, n_x] for m in range(M - 1)})
        out["n_measurements"] = valid[0].sum(axis=1).astype(np.int64)
        out["late_packets"] = late.astype(np.int64)
        out["imm_step"] = first + np.arange(1, rows + 1, dtype=np.int64)
        out.update({k: mu[:, m] for m, k in enumerate(mus)})
        flat_x, flat_P = x.reshape(rows, -1), P.reshape(rows, -1)
        out.update({k: flat_x[:, i] for i, k in enumerate(xs)})
        out.update({k: flat_P[:, i] for i, k in enumerate(Ps)})
        return out

    # -- the causal form ----------------------------------------------------------------
    def online(self, model=None, source=None, trace: Trace | None = None):
        """The filter as a stream of raw packets, one row per fusion instant t_k (:meth:`scan`, served by the
        generic :class:`~mosd.estimators.step.EstimatorStage`).

        ``source`` describes the plant and noise the model is rebuilt from (:func:`mosd.streaming.describe`);
        ``trace`` gives the fusion grid and each sensor's shortest sampling period, which bound the packets
        one fusion interval can hold (the stream's packet slots).
        """
        if source is None or trace is None:
            return super().online(model)
        grid = np.asarray(trace.t, float)
        if grid.size < 2 or not np.allclose(np.diff(grid), grid[1] - grid[0], rtol=0.0, atol=1e-12):
            raise NoStreamingForm("the IMM's causal form needs fusion instants on a uniform grid (t0 + k·T)")
        n_y = int(model.sensors[0].H.shape[0])
        return self.stage(model, source, packet_names(self._slots(trace, model), n_y),
                          output_names(len(self.model_set(model)), model.n_x), trace)

    @staticmethod
    def _slots(trace: Trace, model) -> int:
        """Packet slots per stream row: per sensor the most samples a fusion interval T can hold at its
        shortest sampling period in ``trace`` (⌈T / period⌉), and never fewer than ``trace`` needs."""
        grid = np.asarray(trace.t, float)
        period, slots = float(grid[1] - grid[0]), 0
        for name in model.sensor_names:
            spacing = np.diff(np.asarray(trace.sensors[name].t, float), axis=-1)
            spacing = spacing[np.isfinite(spacing) & (spacing > 0)]
            slots += int(math.ceil(period / spacing.min() - 1e-9)) if spacing.size else 1
        grouped = IntervalMeasurements.of(trace, model.sensor_names, grid)
        return max(slots, int(grouped.valid.sum(axis=-1).max(initial=0)))

    def raw_stream(self, trace: Trace, model, input_names) -> dict[str, np.ndarray]:
        """The first replication's received packets as the causal form's columns, row k holding those sampled
        in (t_{k−1}, t_k] (the batch's grouping); ``packet<j>_sensor`` is the sensor's index in the plant's list."""
        grouped = IntervalMeasurements.of(trace, model.sensor_names, np.asarray(trace.t, float))
        return packet_columns(grouped, self._slots(trace, model), int(model.sensors[0].H.shape[0]))

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




def packet_columns(grouped: "IntervalMeasurements", slots: int, n_y: int) -> dict[str, np.ndarray]:
    """Replication 0 of ``grouped`` as stream columns: per fusion row, slot j's ``packet<j>_sensor``,
    ``packet<j>_time`` (the sample instant) and ``packet<j>_y<c>``; NaN in a slot no packet filled."""
    valid = grouped.valid[0]
    rows, used = valid.shape
    if valid.sum(axis=1).max(initial=0) > slots:
        raise ValueError(f"an interval holds {valid.sum(axis=1).max()} packets, more than the stream's {slots} slots")
    out = {}
    for j in range(slots):
        here = valid[:, j] if j < used else np.zeros(rows, bool)
        out[f"packet{j}_sensor"] = np.where(here, grouped.sensor[0, :, j] if j < used else 0, np.nan).astype(float)
        out[f"packet{j}_time"] = np.where(here, grouped.t[0, :, j] if j < used else 0.0, np.nan)
        for c in range(n_y):
            out[f"packet{j}_y{c}"] = np.where(here, grouped.y[0, :, j, c] if j < used else 0.0, np.nan)
    return out


def _packets(columns, rows: int, first: int, fused, p: dict):
    """Per row the fusable packets, time-ordered, as (R = 1) slot arrays, and the late ones counted
    (:meth:`AsyncIMMFusion.scan`; ``p``: the step's scalars t0, period, slots, n_y)."""
    slots, n_y, t0, period = int(p["slots"]), int(p["n_y"]), float(p["t0"]), float(p["period"])
    sensor = np.column_stack([np.asarray(columns[f"packet{j}_sensor"], float) for j in range(slots)])
    tau = np.column_stack([np.asarray(columns[f"packet{j}_time"], float) for j in range(slots)])
    y = np.stack([np.column_stack([np.asarray(columns[f"packet{j}_y{c}"], float) for c in range(n_y)])
                  for j in range(slots)], axis=1).reshape(rows, slots, n_y)
    present = np.isfinite(sensor) & np.isfinite(tau)
    known = present & (sensor >= 0) & (sensor < len(fused)) & (sensor == np.round(sensor))
    if (present & ~known).any():
        row, j = np.argwhere(present & ~known)[0]
        raise ConfigError(f"input column 'packet{j}_sensor' row {row} is {float(sensor[row, j])!r}; allowed: a sensor's "
                          f"index 0..{len(fused) - 1} (NaN: no packet)")
    index = np.where(known, sensor, 0).astype(np.int64)
    use = known & (fused[index] >= 0)
    k = first + np.arange(rows)
    t_k = t0 + k * period
    t_prev = t0 + (k - 1) * period
    # the batch's grouping: τ belongs to k when t_{k−1} < τ − 1e-9 <= t_k
    shifted = tau - _SAME_INSTANT
    future = use & ~(shifted <= t_k[:, None])
    if future.any():
        row, j = np.argwhere(future)[0]
        raise ConfigError(f"input column 'packet{j}_time' row {row} is {float(tau[row, j])!r}, after the row's fusion "
                          f"instant {float(t_k[row])!r}; allowed: sample instants up to the row's fusion instant "
                          f"(t0 + k·{period:g} s)")
    late = use & ~(shifted > t_prev[:, None]) & (k[:, None] > 0)
    use &= ~late & (k[:, None] > 0)
    n_valid = use.sum(axis=1)
    width = int(n_valid.max(initial=0))
    out_t = np.full((1, rows, width), np.nan)
    out_y = np.full((1, rows, width, n_y), np.nan)
    out_s = np.zeros((1, rows, width), np.int64)
    valid = np.zeros((1, rows, width), bool)
    for r in np.flatnonzero(n_valid):
        at = np.flatnonzero(use[r])
        at = at[np.lexsort((fused[index[r, at]], tau[r, at]))]
        count = len(at)
        out_t[0, r, :count], out_y[0, r, :count] = tau[r, at], y[r, at]
        out_s[0, r, :count], valid[0, r, :count] = fused[index[r, at]], True
    return out_t, out_y, out_s, valid, late.sum(axis=1)


def packet_names(slots: int, n_y: int) -> tuple[str, ...]:
    """The causal form's input columns: per slot j ``packet<j>_sensor``, ``packet<j>_time``, ``packet<j>_y<c>``."""
    names = []
    for j in range(slots):
        names += [f"packet{j}_sensor", f"packet{j}_time", *(f"packet{j}_y{c}" for c in range(n_y))]
    return tuple(names)


def output_names(n_models: int, n_x: int) -> tuple[str, ...]:
    """The causal form's output columns (:meth:`AsyncIMMFusion.scan`)."""
    d_f = n_models - 1
    return (*(f"mode_probabilities_{m}" for m in range(n_models)), *(f"x_filt_{i}" for i in range(n_x)),
            *(f"fault_amplitudes_{m}" for m in range(d_f)), *(f"fault_estimate_{m}" for m in range(d_f)),
            "n_measurements", "late_packets")


def state_names(n_models: int, n_aug: int):
    """(μ, x̂, P) state names of every model: ``imm_mu_<m>``, ``imm_x_<m>_<i>``, ``imm_P_<m>_<i>_<j>``."""
    M, n = n_models, n_aug
    return ([f"imm_mu_{m}" for m in range(M)], [f"imm_x_{m}_{i}" for m in range(M) for i in range(n)],
            [f"imm_P_{m}_{i}_{j}" for m in range(M) for i in range(n) for j in range(n)])


def _legacy_imm(fields) -> EstimatorStage:
    """An old ``OnlineIMM`` (plant, noise, estimator, t0, period, slots, n_models, n_aug, n_x, n_y) as the
    :class:`~mosd.estimators.step.EstimatorStage` of its :class:`AsyncIMMFusion` (the start state from the
    rebuilt model, as the old stage took it)."""
    estimator = build(fields["estimator"])
    model = build(fields["plant"]).model(build(fields["noise"]))
    params = estimator._start_params(model)
    params.update({k: np.asarray(float(fields[k])) for k in ("t0", "period", "slots", "n_y", "n_x")})
    build_params(fields["estimator"]["params"])   # a design that does not rebuild fails here, not when scoring
    return EstimatorStage(estimator=fields["estimator"]["class"], design=dict(fields["estimator"]["params"]),
                          fitted=params, plant=dict(fields["plant"]), noise=dict(fields["noise"]),
                          reads=packet_names(int(fields["slots"]), int(fields["n_y"])),
                          writes=output_names(int(fields["n_models"]), int(fields["n_x"])))


LEGACY_STAGES["mosd.estimators.async_imm.OnlineIMM"] = _legacy_imm
