"""The estimator contract: from a :class:`~mosd.types.Trace` to residuals and other outputs.

An estimator (residual generator, filter, observer) has its parameters in
``__init__`` and one verb, :meth:`Estimator.estimate`. An estimator that must be
trained before use (a neural observer) sets ``requires_fit = True`` and
implements :meth:`Estimator.fit`; the experiment then simulates training runs on
the estimator's own seed stream (``"estimator"``), which neither calibration,
the optimiser nor the test runs ever see, and passes a generator drawn from the
same stream for the training's own randomness.
"""
from __future__ import annotations

from typing import Any, ClassVar

import numpy as np

from ..types import Residuals, Trace
from ..validation import Component


class Estimator(Component):
    """Base class of every estimator (module docstring)."""

    config_group = "estimator"
    #: True when :meth:`fit` must run before :meth:`estimate`.
    requires_fit: ClassVar[bool] = False
    #: Fault-free (False) or faulty (True) training runs for :meth:`fit`.
    fit_on_faults: ClassVar[bool] = False

    def fit(self, trace: Trace, model: Any, rng: np.random.Generator) -> "Estimator":
        """Train on ``trace`` (the estimator's own replications); the default does nothing."""
        return self

    def estimate(self, trace: Trace, model: Any) -> Residuals:
        """Residuals (and further outputs in ``extra``) of every replication of ``trace``.

        ``model`` is what the plant tells an estimator about itself
        (:meth:`mosd.plants.base.Plant.model`).
        """
        raise NotImplementedError
