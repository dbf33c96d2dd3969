"""The noise contract: draw process and measurement noise for one replication.

``draw(rng, n_samples) -> (w, v)`` with w (N, n_x) and v (N, n_y), all randomness
from the generator passed in. Gaussian models also expose ``process_cov`` and
``measurement_cov`` for the plants whose estimators assume them; a non-Gaussian
model (bounded noise with a known density, paper 002) also provides ``pdf`` so
that its sampler can be checked against its density.
"""
from __future__ import annotations

import numpy as np


class NoiseModel:
    """Base class of every noise model (module docstring)."""

    def draw(self, rng: np.random.Generator, n_samples: int) -> tuple[np.ndarray, np.ndarray]:
        raise NotImplementedError
