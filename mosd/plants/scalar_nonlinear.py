"""Paper 002's scalar nonlinear non-Gaussian plant with missing outputs (a reconstruction).

Wen, Zhang and Pan (2013) isolate a target fault δ from a nuisance fault η in a
scalar nonlinear system x_{k+1} = f(x_k, δ_k, η_k, ω_k), y_k = h(x_k, v_k) whose
outputs are partly missing; the simulated system's equations were lost with the
paper's formulas. The reconstruction (docs/systems/paper002.md):

    x_{k+1} = a x_k + b sin x_k + δ_k + η_k + ω_k,   y_k = x_k + σ_v v_k,

with a = 0.5, b = 0.2 (so ∂f/∂x = a + b cos x ∈ [0.3, 0.7] never vanishes, the
paper's assumption 3, and f(0, 0, 0, 0) = 0, its assumption 1), T = 0.1 s,
x_0 ~ U[0, 1] (stated in the paper), noise from :class:`mosd.noise.bounded.BoundedNoise`
and the faults of :mod:`mosd.faults.random_amplitude` entering the state equation.
A share ``missing_rate`` of the outputs goes missing (y_k = NaN there) by one of
the mechanisms of :mod:`mosd.plants.missingness`: completely at random (MCAR,
the default), in Markov bursts, or as one contiguous gap. The rate is a plant parameter — a property of the data acquisition — so
that the noise model stays a pair of densities.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from ..faults.sensor import unit_of
from ..types import Trace
from ..validation import ConfigError, Interval, Param
from .base import Plant
from .missingness import MECHANISMS, burst_switch_probability, missing_mask


@dataclass(frozen=True)
class ScalarNonlinearModel:
    """What an estimator may assume about :class:`ScalarNonlinearPlant` (reconstruction).

    f(x) = a x + b sin x is the fault- and noise-free state map, h(x) = x the
    output map, ``noise`` the known noise densities and x_0 ~ U[x0_low, x0_high].
    """

    a: float
    b: float
    dt: float
    noise: object
    x0_low: float
    x0_high: float

    def f(self, x: np.ndarray) -> np.ndarray:
        return self.a * x + self.b * np.sin(x)

    def dfdx(self, x: np.ndarray) -> np.ndarray:
        return self.a + self.b * np.cos(x)

    def h(self, x: np.ndarray) -> np.ndarray:
        return x

    def sample_x0(self, rng: np.random.Generator, size) -> np.ndarray:
        return rng.uniform(self.x0_low, self.x0_high, size)


class ScalarNonlinearPlant(Plant):
    """x_{k+1} = a x_k + b sin x_k + δ_k + η_k + ω_k, y_k = x_k + σ_v v_k, MCAR outputs (module docstring).

    Accepted faults: those acting on the state, e.g. :class:`~mosd.faults.random_amplitude.RandomAmplitudeFault`
    (target δ or nuisance η; both add to the state equation).
    """

    params = {
        "a": Param(Interval(0.0, 1.0, open_low=True, open_high=True), "Linear coefficient of f (reconstruction: 0.5)."),
        "b": Param(Interval(-1.0, 1.0), "Coefficient of sin x in f, also |b| < a so that ∂f/∂x ∈ [a − |b|, a + |b|] "
                   "excludes 0 (assumption 3) (reconstruction: 0.2)."),
        "dt": Param(Interval(0.0, 1e3, open_low=True), "Sampling period T in s (paper: 0.1)."),
        "missing_rate": Param(Interval(0.0, 0.9), "Probability that an output sample is missing (paper: 0, 0.05, "
                              "0.10, 0.20)."),
        "x0_low": Param(Interval(-1e6, 1e6), "x_0 ~ U[x0_low, x0_high] (paper: [0, 1])."),
        "x0_high": Param(Interval("x0_low", 1e6), "Upper end of x_0's law."),
        "missing_mechanism": Param(MECHANISMS, "How the outputs go missing (mosd.plants.missingness; the paper "
                                   "does not say; default MCAR)."),
        "burst_length": Param(Interval(1.0, 1000.0), "Mean length of a burst in samples (burst), also at least "
                              "missing_rate / (1 − missing_rate) (a Markov chain must exist)."),
        "gap_onset": Param(Interval(0.0, 1e6), "Start of the gap in s (gap; None: drawn uniformly per run).",
                           optional=True),
    }
    state_names = ("x",)
    input_names = ()
    output_names = ("y",)
    fault_targets = ("state",)  # δ_k and η_k enter the state equation (RandomAmplitudeFault)

    def __init__(self, a: float = 0.5, b: float = 0.2, dt: float = 0.1, missing_rate: float = 0.0,
                 x0_low: float = 0.0, x0_high: float = 1.0, missing_mechanism: str = "mcar",
                 burst_length: float = 5.0, gap_onset: float | None = None):
        self._assign(locals())
        if abs(self.b) >= self.a:
            raise ConfigError(f"plant.b={b!r} makes ∂f/∂x = a + b cos x vanish somewhere; "
                              f"allowed: |b| < plant.a={a!r}")
        if self.missing_mechanism == "burst" and burst_switch_probability(self.missing_rate, self.burst_length) > 1:
            raise ConfigError(f"plant.burst_length={self.burst_length!r} is too short for plant.missing_rate="
                              f"{self.missing_rate!r}; allowed: burst_length >= missing_rate / (1 - missing_rate)")

    def model(self, noise) -> ScalarNonlinearModel:
        """f, h, the noise densities and the law of x_0 (the paper's assumptions 1–2)."""
        return ScalarNonlinearModel(a=self.a, b=self.b, dt=self.dt, noise=noise, x0_low=self.x0_low,
                                    x0_high=self.x0_high)

    def simulate(self, n_samples: int, noise, fault, rngs: Sequence[np.random.Generator],
                 fault_scale: float | None = None) -> Trace:
        """``len(rngs)`` runs; ``fault`` None is fault-free, ``fault_scale`` is ignored (absolute faults).

        Draws per run, in this order: x_0, the noise (ω, v), the missing-sample
        uniforms, the fault amplitudes. The uniforms drive the missingness
        mechanism; under MCAR they are compared with ``missing_rate``, so the same
        seed gives nested missing sets across rates (common random numbers for
        the paper's 5/10/20 % comparison).
        """
        if fault is not None:
            self.check_fault(fault)
        n_reps, N = len(rngs), int(n_samples)
        t = np.arange(N) * self.dt
        model = self.model(noise)
        x0 = np.empty(n_reps)
        w = np.empty((n_reps, N))
        v = np.empty((n_reps, N))
        uniforms = np.empty((n_reps, N))
        g = np.zeros((n_reps, N))
        for r, rng in enumerate(rngs):
            x0[r] = model.sample_x0(rng, None)
            wr, vr = noise.draw(rng, N)
            w[r], v[r] = wr[:, 0], vr[:, 0]
            uniforms[r] = rng.random(N)
            if fault is not None:
                g[r] = fault.signal(t, unit_of(fault, fault_scale), rng)
        gap_start = None if self.gap_onset is None else int(round(self.gap_onset / self.dt))
        missing = missing_mask(uniforms, self.missing_rate, self.missing_mechanism, self.burst_length, gap_start)
        x = np.empty((n_reps, N))
        x[:, 0] = x0
        for k in range(N - 1):
            x[:, k + 1] = model.f(x[:, k]) + g[:, k] + w[:, k]
        y = np.where(missing, np.nan, model.h(x) + v)
        active = np.zeros(N, dtype=bool) if fault is None else fault.active(t)
        mask = np.broadcast_to(active, (n_reps, N)).copy()
        meta = {"fault": repr(fault), "missing_rate": self.missing_rate,
                "missing_mechanism": self.missing_mechanism, "output_names": self.output_names,
                "dt": self.dt}
        return Trace(t=t, u=np.zeros((n_reps, N, 0)), x=x[..., None], y=y[..., None], fault_mask=mask, meta=meta)

    def __repr__(self) -> str:
        return (f"ScalarNonlinearPlant(a={self.a:g}, b={self.b:g}, dt={self.dt:g}, "
                f"missing_rate={self.missing_rate:g}, missing_mechanism={self.missing_mechanism!r})")
