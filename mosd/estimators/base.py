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

from ..streaming import NoStreamingForm
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

    def residual_columns(self, outputs: Residuals) -> tuple[str, ...]:
        """The name of each residual channel as a stream's column: ``residual_<channel>``."""
        names = tuple(outputs.channels or ())
        return tuple(f"residual_{names[c]}" if c < len(names) else f"residual_{c}" for c in range(outputs.r.shape[-1]))

    def online(self, model: Any = None, source=None, trace: Trace | None = None):
        """The fitted estimator's causal form (:mod:`mosd.streaming`), or None when its outputs are its inputs.

        ``source`` describes the plant and noise the model is rebuilt from where the stream runs
        (:func:`mosd.streaming.describe`, with the plant's ``input_names``); ``trace`` holds the first test
        replication (its raw columns: :meth:`raw_stream`). Raises :class:`~mosd.streaming.NoStreamingForm`
        until the estimator is written as a recursion with explicit state; a deployed pipeline then
        starts from the estimator's outputs.
        """
        raise NoStreamingForm(f"the estimator {type(self).__name__} has no streaming form yet")

    def raw_stream(self, trace: Trace, model: Any, input_names) -> dict:
        """The first replication's raw columns the causal form reads (only for an estimator that has one)."""
        raise NoStreamingForm(f"the estimator {type(self).__name__} has no streaming form yet")

    def estimate(self, trace: Trace, model: Any) -> Residuals:
        """Residuals (and further outputs in ``extra``) of every replication of ``trace``.

        ``model`` is what the plant tells an estimator about itself
        (:meth:`mosd.plants.base.Plant.model`).
        """
        raise NotImplementedError


def plant_columns(trace: Trace, model: Any, input_names) -> dict[str, np.ndarray]:
    """The first replication's measurements and inputs as a plant stage's columns: ``y_<output>`` per output of
    ``model`` and ``u_<input>`` per input (``input_names``, or u0, u1, ... when the plant names none)."""
    y, u = np.asarray(trace.y, float)[0], np.asarray(trace.u, float)[0]
    columns = {f"y_{name}": y[:, j] for j, name in enumerate(model.output_names)}
    names = tuple(input_names or (f"u{i}" for i in range(u.shape[-1])))
    columns.update({f"u_{name}": u[:, j] for j, name in enumerate(names)})
    return columns
