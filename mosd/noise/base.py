"""The noise contract: draw process and measurement noise for one replication.

``draw(rng, n_samples) -> (w, v)`` with w (N, n_x) and v (N, n_y), all randomness
from the generator passed in. Gaussian models also expose ``process_cov`` and
``measurement_cov`` for the plants whose estimators assume them; a non-Gaussian
model (bounded noise with a known density, paper 002) also provides ``pdf`` so
that its sampler can be checked against its density.
"""
from __future__ import annotations

import math

import numpy as np

from ..validation import Component, Interval, Param, check_matrix


class NoiseModel(Component):
    """Base class of every noise model (module docstring)."""

    config_group = "noise"

    def draw(self, rng: np.random.Generator, n_samples: int) -> tuple[np.ndarray, np.ndarray]:
        raise NotImplementedError


#: the state and output dimensions a Gaussian model's matrices have (the app fills them in from the plant)
DIMENSIONS = {
    "n_x": Param(Interval(1, math.inf, integer=True), "State dimension (the app fills it in from the plant)."),
    "n_y": Param(Interval(1, math.inf, integer=True), "Output dimension, per sensor (the app fills it in)."),
}


def covariance(dimension: str):
    """A ``Param`` validator: a covariance-like matrix of shape (d, d), d the component's ``dimension``."""
    def check(key, value, owner):
        d = getattr(owner, dimension)
        return check_matrix(key, value, (d, d))
    return check
