"""Bounded non-Gaussian noise with a known density (paper 002, a reconstruction).

Paper 002 (Wen, Zhang, Pan 2013, entropy-optimal fault isolation with missing
data) drives its scalar plant with bounded random inputs whose densities are
known (its assumption 2); the densities themselves were lost with the paper's
equations. This module holds the laws as classes with a sampler and a density
(so that each sampler can be checked against its own density) and the noise
model of the reconstruction (docs/systems/paper002.md):

* process noise ω_k with γ_ω(τ) = 3/(4c) (1 − τ²/c²) on |τ| <= c, c = 0.1
  (the Epanechnikov shape; sampled as c(2B − 1), B ~ Beta(2, 2));
* measurement noise 0.2 v_k with v_k ~ N(0, 1) (the paper: "v_k obeys N(0, 1)").
"""
from __future__ import annotations

import math

import numpy as np

from ..validation import Interval, Param, check_in
from .base import NoiseModel


_HALF_WIDTH = Interval(0.0, 1e6, open_low=True)  # c of the Epanechnikov law


class BoundedLaw:
    """A law on a bounded interval with a sampler and a density.

    Subclasses set ``low``/``high`` and implement :meth:`sample` and :meth:`pdf`;
    the density is zero outside [low, high] and integrates to one.
    """

    low: float
    high: float

    def sample(self, rng: np.random.Generator, size) -> np.ndarray:
        """Independent draws of shape ``size`` from ``rng``."""
        raise NotImplementedError

    def pdf(self, tau) -> np.ndarray:
        """The density γ(τ), elementwise."""
        raise NotImplementedError

    @property
    def support(self) -> tuple[float, float]:
        return self.low, self.high


class EpanechnikovLaw(BoundedLaw):
    """γ(τ) = 3/(4c) (1 − τ²/c²) on [−c, c] — paper 002's process-noise density (reconstruction).

    Parameters
    ----------
    c : float
        Half-width of the support, > 0.
    name : str
        Config key prefix used in error messages.
    """

    def __init__(self, c: float = 0.1, name: str = "noise.c"):
        self.c = check_in(name, c, _HALF_WIDTH)
        self.low, self.high = -self.c, self.c

    def sample(self, rng: np.random.Generator, size) -> np.ndarray:
        # the density of (1 + τ/c)/2 is 6 u (1 − u), i.e. Beta(2, 2)
        return self.c * (2.0 * rng.beta(2.0, 2.0, size) - 1.0)

    def pdf(self, tau) -> np.ndarray:
        tau = np.asarray(tau, float)
        inside = np.abs(tau) <= self.c
        return np.where(inside, 0.75 / self.c * (1.0 - (tau / self.c) ** 2), 0.0)

    @property
    def std(self) -> float:
        """Standard deviation c/√5."""
        return self.c / math.sqrt(5.0)

    def __repr__(self) -> str:
        return f"EpanechnikovLaw(c={self.c:g})"


class BoundedNoise(NoiseModel):
    """Additive bounded process noise and Gaussian measurement noise (paper 002, reconstruction).

    x_{k+1} = f(x_k) + δ_k + η_k + ω_k, y_k = x_k + σ_v v_k with ω_k ~ γ_ω
    (:class:`EpanechnikovLaw`) and v_k ~ N(0, 1), all independent.
    """

    params = {
        "c": Param(_HALF_WIDTH, "Half-width of the process-noise support (paper reconstruction: 0.1)."),
        "measurement_std": Param(Interval(0.0, 1e6), "σ_v, the gain on the N(0, 1) measurement noise "
                                 "(reconstruction: 0.2)."),
    }

    def __init__(self, c: float = 0.1, measurement_std: float = 0.2):
        self._assign(locals())
        self.process_law = EpanechnikovLaw(self.c, name="noise.c")

    def pdf(self, tau) -> np.ndarray:
        """The process-noise density γ_ω(τ)."""
        return self.process_law.pdf(tau)

    def draw(self, rng: np.random.Generator, n_samples: int) -> tuple[np.ndarray, np.ndarray]:
        """Process noise ω (N, 1) and measurement noise σ_v v (N, 1) for one replication."""
        w = self.process_law.sample(rng, (n_samples, 1))
        v = self.measurement_std * rng.standard_normal((n_samples, 1))
        return w, v

    def __repr__(self) -> str:
        return f"BoundedNoise(c={self.c:g}, measurement_std={self.measurement_std:g})"
