"""Entropy-optimal fault-isolation filter on EM-imputed outputs (paper 002, a reconstruction).

Paper 002 (Wen, Zhang, Pan 2013, after Guo, Yin, Wang et al., IEEE TAC 54(4),
2009) estimates the state of x_{k+1} = f(x_k, δ_k, η_k, ω_k), y_k = h(x_k, v_k)
with the filter

    x̂_{k+1} = f(x̂_k, 0, 0, 0) + U_k (y_k − h(x̂_k, 0))

whose gain U_k makes the error e^1 caused by the target fault δ as spread out
as possible and the error e^2 caused by the nuisance fault η as concentrated as
possible, measured by Rényi's quadratic entropy (α = 2), with the instantaneous
cost J_k = R₂ H₂(e²_{k+1}) − R₁ H₂(e¹_{k+1}) (R₁ = 1, R₂ = 20) minimised by a
Taylor (Newton) step around U_{k−1}; missing outputs are filled by EM first.
The paper's density formulas (its theorems 1–4, multiple integrals over the
fault and noise densities) were lost; this reconstruction (docs/systems/paper002.md)
computes the entropies from particles instead:

* two ensembles of N simulated runs of plant and filter, S1 with the target
  fault only, S2 with the nuisance fault only, drawn from the known densities
  of x_0, ω, v, δ and η (the paper's assumption 2) with the faults acting from
  their onsets; at step k the next error of particle i is affine in the gain,
  e_i(U) = a_i − U b_i with a_i = f(x_i) + fault_i + ω_i − f(x̂_i) and
  b_i = h(x_i) + v_i − h(x̂_i);
* H₂(e) = −ln V(U), V(U) = N⁻² Σ_ij G_σ(z_ij), z_ij = Δa_ij − U Δb_ij,
  σ = √2 s (Parzen estimate of the information potential ∫γ_e², Príncipe,
  *Information Theoretic Learning*, 2010, §2.6), s = 1.06 std(e) N^(−1/5)
  (Silverman's rule) fixed at U_{k−1} within the step;
* closed forms: V′ = N⁻² Σ G_σ(z) z Δb / σ², V″ = −N⁻² Σ G_σ(z) Δb² (1 − z²/σ²) / σ²,
  H′ = −V′/V, H″ = −(V″V − V′²)/V²;
* U_k = U_{k−1} − J′/J″ when J″ > 0, else a signed gradient step
  U_{k−1} − step·sign(J′); U_k clipped to [gain_low, gain_high];
* the ensembles then advance with U_k. The schedule U_0..U_{N−1} is the same
  for every run; it is designed once in :meth:`EntropyIsolationFilter.fit` from
  the generator the experiment passes (the estimator's own seed stream).

Rényi entropy is shift-invariant: the gain reacts to the spread of each fault's
effect, not to its mean. The gain design assumes complete outputs (the paper's
case 1); missing outputs are EM-filled (:mod:`.imputation`) and the filled y
enters the same recursion (the paper's case 2: "repair, then filter").
"""
from __future__ import annotations

import math

import numpy as np

from ..faults.random_amplitude import RandomAmplitudeFault
from ..streaming import COUNT, FINITE, NoStreamingForm, StateVar, build
from ..types import Residuals, Trace
from ..validation import ConfigError, Interval, Param
from .imputation import HALF_WIDTHS, EMImputer, hold_last
from .step import StepEstimator

#: fills of a missing output: EM on lag windows (the paper), hold the last sample, or skip the correction
MISSING = ("em", "hold", "skip")
_BACKTRACKS = 12  # halvings of a step that does not lower J before the gain is kept


def gaussian_kernel(z: np.ndarray, sigma: float) -> np.ndarray:
    return np.exp(-0.5 * (z / sigma) ** 2) / (math.sqrt(2.0 * math.pi) * sigma)


def silverman_bandwidth(e: np.ndarray) -> float:
    """s = 1.06 std(e) N^(−1/5) (Silverman 1986, eq. 3.28), floored to stay positive."""
    return max(1.06 * float(np.std(e)) * e.shape[-1] ** -0.2, 1e-12)


def information_potential(a: np.ndarray, b: np.ndarray, gain: float, s: float):
    """V, V′, V″ of e = a − U b at U = ``gain`` (module docstring; reconstruction).

    Parameters
    ----------
    a, b : ndarray, shape (N,)
        The affine coefficients of each particle's next error.
    gain : float
        U.
    s : float
        Parzen bandwidth of e (the kernel of the pairwise differences has σ = √2 s).

    Returns
    -------
    V, dV, d2V : float
        The information potential N⁻² Σ_ij G_σ(Δa_ij − U Δb_ij) and its first
        two derivatives in U.
    """
    sigma = math.sqrt(2.0) * s
    da = a[:, None] - a[None, :]
    db = b[:, None] - b[None, :]
    z = da - gain * db
    G = gaussian_kernel(z, sigma)
    n2 = a.shape[0] ** 2
    V = G.sum() / n2
    dV = (G * z * db).sum() / (n2 * sigma**2)
    d2V = -(G * db**2 * (1.0 - (z / sigma) ** 2)).sum() / (n2 * sigma**2)
    return V, dV, d2V


def renyi_quadratic(a: np.ndarray, b: np.ndarray, gain: float, s: float):
    """H₂ = −ln V and its first two derivatives in U (module docstring)."""
    V, dV, d2V = information_potential(a, b, gain, s)
    return -math.log(V), -dV / V, -(d2V * V - dV**2) / V**2


_GAINS = Interval(-2.0, 2.0)  # the gains U a filter may use
#: the stream column of the simulated state x_k (paper 002's monitor reads the error x − x̂)
TRUTH = "x_true"


def gain_step(model, x_hat: np.ndarray, y_filled: np.ndarray, gain: float) -> np.ndarray:
    """x̂_{k+1} = f(x̂_k) + U_k (ỹ_k − h(x̂_k)) (module docstring): the one arithmetic of the batch estimate
    and the causal form (:meth:`_GainFilter.scan`). A missing ỹ_k (``skip``, and ``hold`` before the first
    sample) leaves the prediction uncorrected."""
    return model.f(x_hat) + gain * np.nan_to_num(y_filled - model.h(x_hat))


def _design_fault(law: str, role: str):
    """A ``Param`` validator: a RandomAmplitudeFault, None giving the paper's ``law`` with ``role``."""
    def check(key, value, estimator):
        if value is None:
            return RandomAmplitudeFault(law, role=role)
        if not isinstance(value, RandomAmplitudeFault):
            raise ConfigError(f"{key}={value!r} is not allowed; allowed: a RandomAmplitudeFault")
        return value
    return check


def gain_recursion(model, x_start: np.ndarray, y_filled: np.ndarray, gains: np.ndarray):
    """(x̂_k, x̂_{k+1}) of every run (R, N) by :func:`gain_step` from x̂ = ``x_start`` (R,) over ỹ (R, N) with the
    gains U_k (N,): the recursion of the batch estimate and of :meth:`_GainFilter.scan`."""
    runs, rows = y_filled.shape
    x_hat, x_next = np.empty((runs, rows)), np.empty((runs, rows))
    xk = np.array(np.broadcast_to(np.asarray(x_start, float), (runs,)))
    for k in range(rows):
        x_hat[:, k] = xk
        xk = gain_step(model, xk, y_filled[:, k], gains[k])
        x_next[:, k] = xk
    return x_hat, x_next


class _GainFilter(StepEstimator):
    """x̂_{k+1} = f(x̂_k) + U_k (ỹ_k − h(x̂_k)) on EM-filled outputs ỹ, vectorised over runs.

    Its step (:mod:`mosd.estimators.step`): :func:`gain_recursion` from the carried x̂ (``x_hat_next``, x̂_0 = 0)
    with the fitted schedule U_0, U_1, ... (``filter_step``: rows seen, the index into it; a fixed gain
    repeats its one gain, ``constant``). A missing output is filled as the batch fills it: ``skip`` leaves
    it missing (no correction), ``hold`` takes the last observed output (state ``last_output``; NaN before
    the first). ``em`` fills a gap from the whole run's lag windows (it needs the outputs after the gap:
    not causal), so the scan refuses a gap of an ``em`` design in one line; with no gap the EM fill is
    the identity and the scan equals the batch.
    """

    params = {
        "missing": Param(MISSING, "Fill missing outputs by EM on lag windows (em), hold the last observed output "
                         "(hold), or skip the correction there (skip)."),
        "em_half_width": Param(HALF_WIDTHS, "Half-width h of the EM lag windows."),
    }

    def __init__(self, missing: str = "em", em_half_width: int = 1):
        self._assign(locals())
        self.imputer = EMImputer(half_width=self.em_half_width) if self.missing == "em" else None

    def _gains(self, n_samples: int) -> np.ndarray:
        raise NotImplementedError

    def fill(self, y: np.ndarray) -> np.ndarray:
        """The outputs ỹ the recursion uses: EM- or hold-filled, or ``y`` itself (``skip``: NaN stays)."""
        if self.missing == "em":
            return self.imputer.impute(y)
        if self.missing == "hold":
            return hold_last(y)
        return y

    def estimate(self, trace: Trace, model) -> Residuals:
        """Outputs of every run of ``trace`` (R runs of N samples).

        ``r`` is y − h(x̂) (R, N, 1), NaN where y is missing; ``extra`` holds
        ``error`` x − x̂ (R, N) (the simulated truth), ``gain`` U_k (R, N),
        ``x_hat`` (R, N), ``y_filled`` (R, N) and ``innovation`` ỹ − h(x̂)
        (R, N; NaN where a missing sample was skipped).
        """
        y = np.asarray(trace.y, float)[..., 0]
        R, N = y.shape
        gains = self._gains(N)
        y_filled = self.fill(y)
        x_hat, _ = gain_recursion(model, np.zeros(R), y_filled, gains)  # x̂_0 = 0 (paper)
        r = y - model.h(x_hat)
        extra = {"error": np.asarray(trace.x, float)[..., 0] - x_hat, "gain": np.broadcast_to(gains, (R, N)).copy(),
                 "x_hat": x_hat, "y_filled": y_filled, "innovation": y_filled - model.h(x_hat)}
        return Residuals.of(trace, r[..., None], ("y",), extra=extra)

    # -- the step (mosd.estimators.step) ---------------------------------------------------
    def _schedule(self) -> tuple[np.ndarray, bool]:
        """(the gains U_0, U_1, ... a stream uses, whether the last repeats forever)."""
        return self._gains(1), True

    def step_params(self, model=None, trace: Trace | None = None) -> dict[str, np.ndarray]:
        """The gain schedule (``gains``) and whether its last gain repeats forever (``constant``)."""
        gains, constant = self._schedule()
        return {"gains": np.asarray(gains, float), "constant": np.asarray(bool(constant))}

    def step_state(self, params: dict, reads: tuple = ()) -> dict:
        out = {"x_hat_next": (StateVar("The filter's estimate x̂ of the next row's state.", FINITE), 0.0),
               "filter_step": (StateVar("Rows filtered since the stream's start (the index into the gain schedule).",
                                        COUNT), 0)}
        if self.missing == "hold":
            out["last_output"] = (StateVar("The last observed output (NaN before the first).", FINITE, missing=True),
                                  math.nan)
        return out

    def scan(self, model, params: dict, state: dict, columns: dict, trajectory: bool = False) -> dict:
        """The batch estimate's outputs row by row (:meth:`StepEstimator.scan`): in, the raw output ``y_<output>``
        (NaN where missing) and optionally the simulated state ``x_true``; out ``residual_<output>`` y − h(x̂),
        ``innovation`` ỹ − h(x̂), ``x_hat``, ``gain`` U_k, ``y_filled`` ỹ and, with ``x_true``, ``error`` x − x̂."""
        column = next(name for name in columns if name.startswith("y_"))
        y = np.asarray(columns[column], float)
        runs, rows = y.shape
        gains = self._stream_gains(params, int(np.ravel(state["filter_step"])[0]), rows)
        y_filled = self._causal_fill(y, state, column)
        x_hat, x_next = gain_recursion(model, state["x_hat_next"], y_filled, gains)
        out = {f"residual_{column[2:]}": y - model.h(x_hat), "innovation": y_filled - model.h(x_hat),
               "x_hat": x_hat, "gain": np.broadcast_to(np.asarray(gains, float), (runs, rows)), "y_filled": y_filled}
        if TRUTH in columns:
            out["error"] = np.asarray(columns[TRUTH], float) - x_hat
        if trajectory:
            out["x_hat_next"] = x_next
            out["filter_step"] = np.broadcast_to(np.ravel(state["filter_step"])[0] + np.arange(1, rows + 1), (runs, rows))
            if self.missing == "hold":
                out["last_output"] = y_filled
        return out

    @staticmethod
    def _stream_gains(params: dict, first: int, rows: int) -> np.ndarray:
        """U_first ... U_{first+rows−1}; a stream longer than a designed schedule is refused, as the batch refuses
        runs longer than it."""
        gains = np.asarray(params["gains"], float)
        if bool(params["constant"]):
            return np.broadcast_to(gains[-1], (rows,))
        if first + rows > gains.shape[0]:
            raise ConfigError(f"the stream is longer than the designed gain schedule ({gains.shape[0]} rows; "
                              f"row {gains.shape[0] - first} of this chunk is past it); allowed: streams of at "
                              f"most {gains.shape[0]} rows (fit on longer runs)")
        return gains[first:first + rows]

    def _causal_fill(self, y: np.ndarray, state: dict, column: str) -> np.ndarray:
        """ỹ of the rows ``y`` (R, N) from what the stream has seen (class docstring)."""
        if self.missing == "hold":
            last = np.broadcast_to(np.asarray(state["last_output"], float), (y.shape[0],))
            return hold_last(np.concatenate([last[:, None], y], axis=1))[:, 1:]
        if self.missing == "em" and np.isnan(y).any():
            row = int(np.flatnonzero(np.isnan(y).any(axis=0))[0])
            raise ConfigError(f"input column {column!r} row {row} is missing: this design fills a gap "
                              f"by EM on the whole run's lag windows (estimator.missing=em needs the outputs after "
                              f"the gap), which a stream has not seen; allowed: no gap, or a design with "
                              f"estimator.missing=hold or skip")
        return y

    def example_row(self, model, params: dict, reads: tuple) -> np.ndarray:
        return np.zeros(len(reads))

    # -- the causal form ----------------------------------------------------------------
    def online(self, model=None, source=None, trace: Trace | None = None, truth: bool = True):
        """The filter as a stream of raw outputs: ``y_<output>`` (NaN where missing) in, one row per sample
        (:class:`~mosd.estimators.step.EstimatorStage` of :meth:`scan`).

        ``source`` describes the plant and noise the model is rebuilt from (:func:`mosd.streaming.describe`).
        ``truth``: the stream also carries the simulated state (column ``x_true``) and the stage outputs the
        estimation error x − x̂ (``error``) that paper 002's monitor reads (the paper evaluates isolation
        in simulation, where the state is known); a deployment without it monitors ``residual`` instead.
        """
        if source is None:
            return super().online(model)
        plant = build(source["plant"])
        gappy = getattr(plant, "missing_rate", 0.0) > 0 or (trace is not None and np.isnan(trace.y).any())
        if self.missing == "em" and gappy:
            # a stream would meet gaps this design fills from outputs it has not seen: refused, not approximated
            raise NoStreamingForm("the EM fill of missing outputs (estimator.missing=em) uses the whole run's lag "
                                  "windows, outputs after each gap included: not causal (estimator.missing=hold "
                                  "or skip streams)")
        name = plant.output_names[0]
        return self.stage(model, source, (f"y_{name}", *((TRUTH,) if truth else ())),
                          (f"residual_{name}", "innovation", "x_hat", "gain", "y_filled", *(("error",) if truth else ())))

    def raw_stream(self, trace: Trace, model, input_names) -> dict[str, np.ndarray]:
        """The first replication's outputs (NaN where missing) and simulated state as the causal form's columns."""
        name = (trace.meta.get("output_names") or ("y",))[0]
        return {f"y_{name}": np.asarray(trace.y, float)[0, :, 0], TRUTH: np.asarray(trace.x, float)[0, :, 0]}


class FixedGainFilter(_GainFilter):
    """The baseline: the same filter with a constant gain U (paper 002's comparison; reconstruction)."""

    params = {"gain": Param(_GAINS, "U, the constant gain.")}

    def __init__(self, gain: float = 0.27, missing: str = "em", em_half_width: int = 1):
        super().__init__(missing, em_half_width)
        self._assign(locals())

    def _gains(self, n_samples: int) -> np.ndarray:
        return np.full(n_samples, self.gain)

    def __repr__(self) -> str:
        return f"FixedGainFilter(gain={self.gain:g}, missing={self.missing!r})"


class EntropyIsolationFilter(_GainFilter):
    """The entropy-optimal isolation filter (module docstring; a reconstruction of paper 002)."""

    params = {
        "n_particles": Param(Interval(50, 5000, integer=True), "N, particles per design ensemble (cost ∝ N² per "
                             "step)."),
        "R1": Param(Interval(0.0, 1e6), "Weight of the target-error entropy (maximised; paper: 1); R1 + R2 > 0."),
        "R2": Param(Interval(0.0, 1e6), "Weight of the nuisance-error entropy (minimised; paper: 20)."),
        "gain_low": Param(_GAINS, "Lower end of the box U_k is clipped to."),
        "gain_high": Param(Interval("gain_low", _GAINS.high, open_low=True), "Upper end of that box."),
        "initial_gain": Param(Interval("gain_low", "gain_high"), "U_{−1}, the starting point of the first Newton "
                              "step (paper: U_0 = 0)."),
        "gradient_step": Param(Interval(0.0, 1.0, open_low=True), "Size of the signed gradient step taken where "
                               "J″ <= 0."),
        "max_step": Param(Interval(0.0, 4.0, open_low=True), "Trust region: no step moves U by more than this; a "
                          "step that does not lower J is halved (up to 12 times) and else not taken."),
        "newton_steps": Param(Interval(1, 20, integer=True), "Newton iterations per time step (paper: one Taylor "
                              "step)."),
        "target": Param(_design_fault("sine", "target"), "The target fault law and onset of the design ensembles "
                        "(None: the paper's sine law on [0.5, 1.5], per run, from 5 s; onset 0 for a design that "
                        "does not know the onset).", kind="RandomAmplitudeFault"),
        "nuisance": Param(_design_fault("ramp", "nuisance"), "The nuisance fault law and onset (None: the paper's "
                          "ramp law on [0, 0.6], per run, from 5 s).", kind="RandomAmplitudeFault"),
    }
    requires_fit = True

    def __init__(self, n_particles: int = 500, R1: float = 1.0, R2: float = 20.0, initial_gain: float = 0.0,
                 gain_low: float = 0.0, gain_high: float = 1.0, gradient_step: float = 0.02, max_step: float = 0.1,
                 newton_steps: int = 1,
                 target: RandomAmplitudeFault | None = None, nuisance: RandomAmplitudeFault | None = None,
                 missing: str = "em", em_half_width: int = 1):
        super().__init__(missing, em_half_width)
        self._assign(locals())
        if self.R1 == 0.0 and self.R2 == 0.0:
            raise ConfigError("estimator.R1=0 and estimator.R2=0 leave no cost; allowed: R1 + R2 > 0")

    def cost(self, a1, b1, a2, b2, gain: float, s1: float, s2: float):
        """J = R₂ H₂(e²) − R₁ H₂(e¹) and its first two derivatives in U.

        With kernels on, the compiled :func:`mosd.kernels.entropy.cost` (one
        pass over the particle pairs, no (N, N) array; ~1e-15 relative to this
        NumPy reference, which ``with kernels.disabled():`` runs).
        """
        from .. import kernels

        if kernels.enabled():
            from ..kernels.entropy import cost

            return cost(np.ascontiguousarray(a1, float), np.ascontiguousarray(b1, float),
                        np.ascontiguousarray(a2, float), np.ascontiguousarray(b2, float),
                        float(gain), float(s1), float(s2), self.R1, self.R2)
        H1, dH1, d2H1 = renyi_quadratic(a1, b1, gain, s1)
        H2, dH2, d2H2 = renyi_quadratic(a2, b2, gain, s2)
        return (self.R2 * H2 - self.R1 * H1, self.R2 * dH2 - self.R1 * dH1, self.R2 * d2H2 - self.R1 * d2H1)

    def _step(self, a1, b1, a2, b2, previous: float) -> float:
        s1 = silverman_bandwidth(a1 - previous * b1)
        s2 = silverman_bandwidth(a2 - previous * b2)
        gain = previous
        J, dJ, d2J = self.cost(a1, b1, a2, b2, gain, s1, s2)
        for _ in range(self.newton_steps):
            # J is not convex in U everywhere: where J″ <= 0 go downhill by a fixed step
            step = -dJ / d2J if d2J > 0 else -self.gradient_step * math.copysign(1.0, dJ)
            # a flat J″ sends the quadratic model's minimum far off: trust it only within max_step
            step = max(-self.max_step, min(self.max_step, step))
            for _ in range(_BACKTRACKS):
                trial = min(max(gain + step, self.gain_low), self.gain_high)
                J_trial, dJ_trial, d2J_trial = self.cost(a1, b1, a2, b2, trial, s1, s2)
                if J_trial <= J:
                    break
                step *= 0.5
            else:
                break
            gain, J, dJ, d2J = trial, J_trial, dJ_trial, d2J_trial
        return gain

    def fit(self, trace: Trace, model, rng: np.random.Generator) -> "EntropyIsolationFilter":
        """Design the gain schedule U_0..U_{N−1} for runs as long as ``trace`` (its data are not used).

        Sets ``gain_`` (N,) and ``design_``: the particle errors of both
        ensembles, ``target_error`` and ``nuisance_error`` (N, n_particles), the
        errors e_k = x_k − x̂_k of S1 and S2 under the designed schedule.
        """
        t = np.asarray(trace.t, float)
        N, P = t.shape[0], self.n_particles
        laws = model.noise
        x = model.sample_x0(rng, (2, P))          # row 0: S1 (target), row 1: S2 (nuisance)
        x_hat = np.zeros((2, P))
        amplitude = np.stack([self.target.amplitudes(rng, P, N), self.nuisance.amplitudes(rng, P, N)])
        active = np.stack([self.target.active(t), self.nuisance.active(t)])  # (2, N)
        gains = np.empty(N)
        errors = np.empty((2, N, P))
        previous = self.initial_gain
        for k in range(N):
            errors[:, k] = x - x_hat
            w = laws.process_law.sample(rng, (2, P))
            v = laws.measurement_std * rng.standard_normal((2, P))
            x_next = model.f(x) + active[:, k, None] * amplitude[:, :, k] + w
            a = x_next - model.f(x_hat)
            b = model.h(x) + v - model.h(x_hat)
            previous = gains[k] = self._step(a[0], b[0], a[1], b[1], previous)
            x, x_hat = x_next, model.f(x_hat) + gains[k] * b
        self.gain_ = gains
        self.design_ = {"target_error": errors[0], "nuisance_error": errors[1]}
        return self

    def _gains(self, n_samples: int) -> np.ndarray:
        gains = getattr(self, "gain_", None)
        if gains is None:
            raise ConfigError("EntropyIsolationFilter.estimate before fit: the gain schedule is designed by fit")
        if n_samples > gains.shape[0]:
            raise ConfigError(f"runs of {n_samples} samples are longer than the designed gain schedule "
                              f"({gains.shape[0]}); fit on runs at least as long")
        return gains[:n_samples]

    def _schedule(self) -> tuple[np.ndarray, bool]:
        gains = getattr(self, "gain_", None)
        return self._gains(0 if gains is None else gains.shape[0]), False

    def __repr__(self) -> str:
        return (f"EntropyIsolationFilter(n_particles={self.n_particles}, R1={self.R1:g}, R2={self.R2:g}, "
                f"gain_box=[{self.gain_low:g}, {self.gain_high:g}], missing={self.missing!r})")
