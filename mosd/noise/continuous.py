"""Continuous-time white process noise and per-sample sensor noise (paper 001).

A continuous-time plant sampled at arbitrary instants (asynchronous sensors,
non-uniform periods) has no fixed sample period to attach a process-noise
covariance to: what is fixed is the intensity (power spectral density) Q_c of
the white noise w(t) in ẋ = A x + B u + w. The plant discretises it exactly
over whatever interval it needs (Van Loan, :mod:`mosd.plants.networked_target`)
and draws from the generator it is given; this object holds the two
covariances and draws the unit-interval sequence of the noise contract.
"""
from __future__ import annotations

import numpy as np

from ..validation import Param
from .base import DIMENSIONS, NoiseModel, covariance


class ContinuousWhiteNoise(NoiseModel):
    """White process noise of intensity Q_c and white sensor noise of covariance R.

    Paper 001's matrices were lost in extraction; the defaults are the
    reconstruction of ``docs/systems/paper001.md`` (Q_c = 0.01·I₂, R = 0.25·I₂ for
    every sensor).
    """

    params = {
        **DIMENSIONS,
        "process_intensity": Param(covariance("n_x"), "Q_c (units² per second): a scalar (times I), the diagonal or "
                                   "the symmetric positive semi-definite matrix.", kind="float, sequence or matrix"),
        "measurement_cov": Param(covariance("n_y"), "R of one sensor sample (the same for every sensor).",
                                 kind="float, sequence or matrix"),
    }

    def __init__(self, process_intensity=0.01, measurement_cov=0.25, n_x: int = 2, n_y: int = 2):
        self._assign(locals())

    def draw(self, rng: np.random.Generator, n_samples: int) -> tuple[np.ndarray, np.ndarray]:
        """Process noise integrated over unit intervals without dynamics (N(0, Q_c)) and sensor noise (N(0, R)).

        The networked plant does not use this sequence (it needs the noise
        integrated through its dynamics over its own intervals); it is the
        generic contract's view of the same two laws.
        """
        w = rng.standard_normal((n_samples, self.n_x)) @ psd_sqrt(self.process_intensity).T
        v = rng.standard_normal((n_samples, self.n_y)) @ psd_sqrt(self.measurement_cov).T
        return w, v


def psd_sqrt(cov: np.ndarray) -> np.ndarray:
    """A matrix L with L Lᵀ = cov for a batch (..., n, n) of PSD matrices (zero variances allowed)."""
    vals, vecs = np.linalg.eigh(cov)
    return vecs * np.sqrt(np.clip(vals, 0.0, None))[..., None, :]
