"""The experiment on recorded data: the same verbs, the data source's named splits for the seed streams.

:class:`RecordedExperiment` is an :class:`~mosd.experiment.Experiment` whose
runs come from a :class:`~mosd.data.base.RecordedData` source instead of a
simulated scenario: :meth:`calibrate` reads the ``calibration`` split,
:meth:`prepare` the ``training`` split, :meth:`test_data` the ``test`` split;
:meth:`evaluator`, :meth:`tune`, :meth:`evaluate` and :meth:`run` are the
experiment's own, so any detector, metric and optimiser works as on a
simulated system. There is no plant, noise, fault or seed stream: the seed
only seeds the optimiser, and the fault truth is the recording's labels.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from .experiment import Budget, Experiment, PreparedData
from .metrics import check_objectives
from .types import Residuals, Subgroups
from .validation import ConfigError, check_int


class RecordedExperiment(Experiment):
    """Data source, estimator, monitor and detector, with the seed and objectives (module docstring).

    Parameters
    ----------
    data : mosd.data.base.RecordedData
    estimator, monitor, detector :
        As for :class:`~mosd.experiment.Experiment`; the estimator receives the recorded
        trace (``y``: the selected variables) and ``model=None``.
    budget : Budget, optional
        Unused by the splits (a recording has the runs it has); kept for the app's config.
    seed : int
        The optimiser's seed.
    objectives : sequence of str
    """

    def __init__(self, data, estimator, monitor, detector, budget: Budget | None = None, seed: int = 0,
                 objectives: Sequence[str] = ("far", "mdr")):
        self.data = data
        self.plant, self.noise, self.fault, self.model = data, None, None, None
        self.estimator, self.monitor, self.detector = estimator, monitor, detector
        self.duration = None
        self.budget = budget or Budget()
        self.seed = check_int("seed", seed, 0, 2**63 - 1)
        self.objectives = check_objectives(objectives)

    def simulate(self, fault, n_reps: int, stream: str):
        """The recorded runs of split ``stream`` (``fault`` and ``n_reps`` do not apply)."""
        return self.data.trace(stream)

    def fit_estimator(self) -> None:
        """A trainable estimator learns from the calibration split (fault-free rows)."""
        if getattr(self.estimator, "requires_fit", False):
            rng = np.random.default_rng([self.seed, 3, 2**31])
            self.estimator.fit(self.data.trace("calibration"), None, rng)

    def calibrate(self, n_jobs: int = 1) -> Residuals:
        residuals = super().calibrate()
        a = getattr(self.detector, "n_components", None)
        if a is not None:
            y = self.data.trace("calibration").y
            rows = int(np.count_nonzero(np.all(np.isfinite(y), axis=-1)))
            if rows <= int(a):
                where = "; ".join(self.data.describe()["calibration"][:3])
                raise ConfigError(f"data split calibration ({where}) has {rows} complete rows, not more than "
                                  f"detector.n_components={a}; allowed: more calibration rows than components")
        return residuals

    def prepare(self, calibration: Residuals | None = None, fault=None, n_jobs: int = 1) -> PreparedData:
        """Calibration and the training split: what the optimiser caches (``fault`` and ``n_jobs`` do not apply:
        the splits are read, not simulated)."""
        phase1_res = self.calibrate() if calibration is None else calibration
        train_res = self.residuals(None, 0, "training")
        if not np.asarray(train_res.fault_mask).any():
            raise ConfigError("data split training has no faulty row (no label other than 0); allowed: training "
                              "rows with faults, or the report python -m mosd.systems.tep for monitoring only")
        return PreparedData(sigma=1.0, phase1=self.monitor.transform(phase1_res),
                            train=self.monitor.transform(train_res), phase1_residuals=phase1_res,
                            train_residuals=train_res)

    def test_data(self, data: PreparedData, n_test: int | None = None, fault=None,
                  n_jobs: int = 1) -> tuple[Subgroups, Residuals]:
        """The test split (held out; ``n_jobs`` does not apply)."""
        test_res = self.residuals(None, 0, "test")
        return self.monitor.transform(test_res), test_res

    def evaluate(self, detector, data: PreparedData, n_test: int | None = None, test: tuple | None = None):
        """As :meth:`Experiment.evaluate`; the example carries no residual trace.

        The "residual" of recorded data is a raw measured variable, without a fault channel
        or a σ to draw bands with: the run's residual figure would mislead (the TE study draws
        the statistics against their limits instead).
        """
        report, example = super().evaluate(detector, data, n_test=n_test, test=test)
        return report, {**example, "residual": None}

    def describe(self) -> dict:
        """Which rows of which recording each split used (summary.json, MLflow)."""
        return self.data.describe()

    def dry_run(self, design: np.ndarray) -> None:
        """The calibration, one evaluation of ``design`` on the training split and the test split's shape."""
        data = self.prepare()
        self.evaluator(data)(design)
        self.data.trace("test")
