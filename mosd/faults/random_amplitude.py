"""Additive state faults of random amplitude with a known bounded density (paper 002, reconstruction).

Paper 002's target fault δ_k and nuisance fault η_k are bounded random inputs
of the state equation with known densities (its assumption 2); the densities
were lost with the equations. The reconstruction (docs/systems/paper002.md):

* target δ: γ_δ(τ) = (π/2) sin(π(τ − 0.5)) on [0.5, 1.5] (:class:`SineLaw`,
  sampled as 0.5 + arccos(1 − 2u)/π);
* nuisance η: γ_η(τ) = τ/0.18 on [0, 0.6] (:class:`RampLaw`, sampled as 0.6 √u).

How the amplitude varies in time is not recoverable from the paper. The default
``draw="per_run"`` is a constant fault of random size (one draw per run, held
from the onset on: a step of unknown height, the natural reading of "the fault
occurs at step 50" in the paper's figures); ``draw="per_step"`` redraws it at
every step (an i.i.d. random input, the reading of the paper's framework, Guo
et al. 2009). The plant (:class:`mosd.plants.scalar_nonlinear.ScalarNonlinearPlant`)
adds the signal to the state equation.
"""
from __future__ import annotations

import math

import numpy as np

from ..noise.bounded import BoundedLaw
from ..validation import Interval, Param, check_in
from .base import Fault

LAWS = ("sine", "ramp")
DRAWS = ("per_run", "per_step")


#: the support's parameters (shared by the laws and RandomAmplitudeFault's declaration)
_SUPPORT = {"low": Interval(-1e6, 1e6), "width": Interval(0.0, 1e6, open_low=True)}


class _IntervalLaw(BoundedLaw):
    """A law on [low, low + width]: the fault laws share their support's parametrisation."""

    def __init__(self, low: float, width: float):
        self.low = check_in("fault.low", low, _SUPPORT["low"])
        self.width = check_in("fault.width", width, _SUPPORT["width"])
        self.high = self.low + self.width

    def __repr__(self) -> str:
        return f"{type(self).__name__}(low={self.low:g}, width={self.width:g})"


class SineLaw(_IntervalLaw):
    """γ(τ) = π/(2w) sin(π(τ − a)/w) on [a, a + w] (paper: a = 0.5, w = 1; reconstruction).

    Parameters
    ----------
    low, width : float
        a (any real) and w (> 0).
    """

    def __init__(self, low: float = 0.5, width: float = 1.0):
        super().__init__(low, width)

    def sample(self, rng: np.random.Generator, size) -> np.ndarray:
        # inverse of the CDF F(τ) = (1 − cos(π(τ − a)/w))/2
        return self.low + self.width * np.arccos(1.0 - 2.0 * rng.random(size)) / math.pi

    def pdf(self, tau) -> np.ndarray:
        s = (np.asarray(tau, float) - self.low) / self.width
        inside = (s >= 0.0) & (s <= 1.0)
        return np.where(inside, math.pi / (2.0 * self.width) * np.sin(math.pi * np.clip(s, 0.0, 1.0)), 0.0)



class RampLaw(_IntervalLaw):
    """γ(τ) = 2(τ − a)/w² on [a, a + w] (paper: a = 0, w = 0.6, i.e. τ/0.18; reconstruction).

    Parameters
    ----------
    low, width : float
        a (any real) and w (> 0).
    """

    def __init__(self, low: float = 0.0, width: float = 0.6):
        super().__init__(low, width)

    def sample(self, rng: np.random.Generator, size) -> np.ndarray:
        # inverse of the CDF F(τ) = ((τ − a)/w)²
        return self.low + self.width * np.sqrt(rng.random(size))

    def pdf(self, tau) -> np.ndarray:
        s = (np.asarray(tau, float) - self.low) / self.width
        inside = (s >= 0.0) & (s <= 1.0)
        return np.where(inside, 2.0 * s / self.width, 0.0)



class RandomAmplitudeFault(Fault):
    """An additive state fault whose amplitude has a known bounded density (module docstring; paper: onset 5 s).

    ``density`` is the law object (:class:`SineLaw` or :class:`RampLaw`) built from ``law``, ``low``, ``width``.
    """

    params = {
        "law": Param(LAWS, "Shape of the density: sine (paper 002's target fault) or ramp (its nuisance fault)."),
        "low": Param(_SUPPORT["low"], "Lower end a of the support (None: 0.5 for sine, 0 for ramp).", optional=True),
        "width": Param(_SUPPORT["width"], "Width w of the support (None: 1 for sine, 0.6 for ramp).", optional=True),
        "draw": Param(DRAWS, "One amplitude per run held from the onset, or a new one at every step."),
    }
    relative = False  # amplitudes are in the state's own units
    acts_on = "state"  # added to the state equation

    def __init__(self, law: str = "sine", low: float | None = None, width: float | None = None,
                 draw: str = "per_run", onset: float = 5.0, role: str = "target"):
        super().__init__(onset=onset, role=role)
        self._assign(locals())
        if self.law == "sine":
            self.density = SineLaw(0.5 if low is None else low, 1.0 if width is None else width)
        else:
            self.density = RampLaw(0.0 if low is None else low, 0.6 if width is None else width)

    def amplitudes(self, rng: np.random.Generator, n_runs: int, n_samples: int) -> np.ndarray:
        """Amplitudes (n_runs, n_samples) ignoring the onset: one per run, or one per run and step."""
        if self.draw == "per_run":
            return np.repeat(self.density.sample(rng, (n_runs, 1)), n_samples, axis=1)
        return self.density.sample(rng, (n_runs, n_samples))

    def signal(self, t: np.ndarray, scale: float, rng: np.random.Generator) -> np.ndarray:
        """The fault input (N,) of one run: the amplitude where active, 0 before the onset.

        ``scale`` is ignored (an absolute fault).
        """
        t = np.asarray(t, float)
        return np.where(self.active(t), self.amplitudes(rng, 1, t.shape[0])[0], 0.0)

    def __repr__(self) -> str:
        return (f"RandomAmplitudeFault(law={self.density!r}, draw={self.draw!r}, onset={self.onset:g}, "
                f"role={self.role!r})")
