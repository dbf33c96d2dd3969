"""Noise models: what disturbs the plant and its sensors.

A noise model draws process noise w_k and measurement noise v_k for a batch of
replications and tells the estimator the covariances it should assume.
"""
from __future__ import annotations

import numpy as np

from ..validation import Param
from .base import DIMENSIONS, NoiseModel, covariance


class GaussianNoise(NoiseModel):
    """Additive white Gaussian process and measurement noise.

    Paper 000 uses Ξ_ω = diag(0.01, 0.01, 0.01) (``noise=paper``). The default
    diag(0, 1e-8, 1e-2) keeps x_p tied to θ by the eccentric (x_p = A sin θ,
    no process noise of its own), allows θ a little model mismatch and keeps
    the paper's value on the speed n: with 0.01 on x_p and θ the
    dedicated-observer residual of x_p wanders by several σ (docs/DECISIONS.md
    decision 1; the table is in docs/DECISIONS.md).
    """

    params = {
        **DIMENSIONS,
        "process_cov": Param(covariance("n_x"), "Covariance Ξ_ω of w_k per sample: a scalar, the diagonal or the "
                             "symmetric positive semi-definite matrix.", kind="float, sequence or matrix"),
        "measurement_cov": Param(covariance("n_y"), "Covariance Ξ_ν of v_k (same forms).",
                                 kind="float, sequence or matrix"),
    }

    def __init__(self, process_cov=(0.0, 1e-8, 1e-2), measurement_cov=0.01, n_x: int = 3, n_y: int = 3):
        self._assign(locals())
        self._chol_q = _psd_sqrt(self.process_cov)
        self._chol_r = _psd_sqrt(self.measurement_cov)

    def draw(self, rng: np.random.Generator, n_samples: int) -> tuple[np.ndarray, np.ndarray]:
        """Process noise (N, n_x) and measurement noise (N, n_y) for one replication."""
        w = rng.standard_normal((n_samples, self.n_x)) @ self._chol_q.T
        v = rng.standard_normal((n_samples, self.n_y)) @ self._chol_r.T
        return w, v


def _psd_sqrt(cov: np.ndarray) -> np.ndarray:
    """A matrix A with A Aᵀ = cov that tolerates zero variances (eigen-decomposition)."""
    vals, vecs = np.linalg.eigh(cov)
    return vecs * np.sqrt(np.clip(vals, 0.0, None))
