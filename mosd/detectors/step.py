"""One step per decision: a detector's recursion written once, run by tuning, test and serving alike.

A :class:`StepDetector` defines its decision as one causal recursion over the monitor's points::

    params = detector.step_params(X, calibration_features)   # per design, leading axis P
    outputs = detector.scan(params, state, features)         # over leading batch axes (P, R)

``scan`` takes the carried state (named arrays broadcastable to the batch: the designs × runs of a
tuning or a test, or one design × one stream when served) and the points' features (R, K, ...), and
returns per point the ``statistic``, its ``limit`` and the ``decision`` (0 none, i fault i); asked for
the trajectory, also the value of every state variable after each point. The state is declared once,
in :meth:`StepDetector.step_state` (names, domains, start values).

:meth:`StepDetector.population` (tuning, the test evaluation) runs ``scan`` from the start state on a
population of designs; :class:`StepStage` (``mosd monitor``, the served model) runs the very same
``scan`` with one design's ``step_params`` on the rows it is given, from the state it is given. There
is no second implementation of the decision to keep equal: a stream scored whole, in chunks or row by
row gives the same decisions as the population (``tests/test_step.py``). Where the recursion has a
compiled kernel (the persistence rule, :func:`mosd.detectors.base.persistent`; the charts' EWMA step,
:mod:`mosd.kernels.ewma`), the scan calls it for both.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar
from functools import cached_property

import numpy as np

from ..streaming import LEGACY_STAGES, PointDecision, StateVar, mosd_class, points_of, spread
from .base import Decisions, Detector


class StepDetector(Detector):
    """A detector whose decision is one causal recursion (module docstring).

    Subclasses implement :meth:`step_params`, :meth:`step_state` and :meth:`scan`; ``features`` (the
    parameter-free part) as any detector. A detector on other points than the monitor's ``point`` rows
    (a chart's subgroups) names their column in :attr:`points` and, where its scan needs the points'
    numbers or gives more outputs, overrides :meth:`scan_points` and :meth:`stage_outputs`.
    """

    #: the input column numbering the points (0: a row that completes none) of the served form
    points: ClassVar[str] = "point"

    def step_params(self, X: np.ndarray, calibration_features: np.ndarray | None = None) -> dict[str, np.ndarray]:
        """Each design's parameters of the step, arrays with leading axis P (one per row of X (P, d))."""
        raise NotImplementedError

    def step_state(self, n: int) -> dict[str, tuple[StateVar, float]]:
        """The carried state on points of ``n`` values: name → (declaration, value at a stream's start)."""
        raise NotImplementedError

    def scan(self, params: dict, state: dict, features: np.ndarray, trajectory: bool = False) -> dict[str, np.ndarray]:
        """Statistic, limit and decision of every design (P) on every run (R) at every point (K).

        Parameters
        ----------
        params : dict of ndarray
            :meth:`step_params`, leading axis P.
        state : dict of ndarray
            Every declared state variable before the first point, broadcastable to (P, R).
        features : ndarray, shape (R, K, ...)
            :meth:`features` of the points.
        trajectory : bool
            Also return each state variable after each point, shape (P, R, K).

        Returns
        -------
        dict of ndarray
            ``statistic``, ``limit`` (broadcastable to (P, R, K)) and ``decision`` (P, R, K); with
            ``trajectory`` also the state variables.
        """
        raise NotImplementedError

    def start(self, n: int) -> dict[str, np.ndarray]:
        """The state at a stream's start as arrays of shape (1, 1) (broadcast over any batch)."""
        return {name: np.full((1, 1), value) for name, (_, value) in self.step_state(n).items()}

    def population(self, calibration_features: np.ndarray, features: np.ndarray, X: np.ndarray) -> Decisions:
        """Every design of X (P, d) from a stream's start on every run of ``features``: :meth:`scan`."""
        X = np.atleast_2d(np.asarray(X, float))
        features = np.asarray(features, float)
        width = features.shape[-1] if features.ndim > 2 else 1
        out = self.scan(self.step_params(X, calibration_features), self.start(width), features)
        return Decisions(statistic=out["statistic"], threshold=out["limit"], decision=out["decision"])

    def online(self, calibration_z, inputs=None) -> "StepStage":
        """This design's causal form on points of ``calibration_z``'s width: its step parameters, nothing else."""
        calibration_z = np.asarray(calibration_z, float)
        params = self.step_params(self.design(), self.features(calibration_z))
        cls = type(self)
        return StepStage(detector=f"{cls.__module__}.{cls.__qualname__}", design=_plain(self.stage_design()),
                         step={k: _plain(np.asarray(v).reshape(-1)[0]) for k, v in params.items()},
                         n=int(calibration_z.shape[-1]))

    # -- the served form's hooks (StepStage) -------------------------------------------------
    def stage_design(self) -> dict:
        """The parameters the served form rebuilds this detector from (JSON-able): ``get_params``."""
        return self.get_params()

    def stage_outputs(self) -> tuple[str, ...]:
        """The served form's per-row outputs."""
        return ("statistic", "limit", "decision", "alarm")

    def scan_points(self, params: dict, state: dict, Z: np.ndarray, number: np.ndarray) -> dict[str, np.ndarray]:
        """:meth:`scan` of one stream's points Z (k, n), numbered ``number`` (k,), with its trajectory: the served
        form's call. Returns the outputs of :meth:`stage_outputs` but ``alarm``, and the state variables, each
        broadcastable to (1, 1, k)."""
        return self.scan(params, state, self.features(Z[None]), trajectory=True)


def _plain(value):
    """JSON-able: NumPy scalars as Python numbers, tuples as lists."""
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, (tuple, list)):
        return [_plain(v) for v in value]
    return value.item() if isinstance(value, np.generic) else value


@dataclass
class StepStage(PointDecision):
    """A :class:`StepDetector`'s causal form: points in (``point``, ``z_1`` ... ``z_n``; a chart's ``subgroup``:
    the detector's :attr:`~StepDetector.points`); ``statistic``, ``limit``, ``decision`` and ``alarm`` out
    (:meth:`~StepDetector.stage_outputs`: a chart's U_k, V_k too); the state the detector declares, carried.

    Attributes
    ----------
    detector : str
        The detector's class (``module.Class``).
    design : dict
        Its parameters (``get_params``).
    step : dict
        Its :meth:`~StepDetector.step_params` (one design: scalars), fitted when the model was made.
    n : int
        Values per point.
    """

    detector: str
    design: dict
    step: dict
    n: int

    @property
    def inputs(self) -> tuple[str, ...]:
        return (self._detector.points, *(f"z_{j}" for j in range(1, self.n + 1)))

    @property
    def outputs(self) -> tuple[str, ...]:
        return self._detector.stage_outputs()

    @cached_property
    def _detector(self) -> StepDetector:
        return mosd_class(self.detector, "detector class")(**self.design)

    def declared_state(self) -> dict:
        cached = self.__dict__.get("_state")
        if cached is None:
            cached = self.__dict__["_state"] = self._detector.step_state(self.n)
        return cached

    def update(self, columns, state) -> dict[str, np.ndarray]:
        detector = self._detector
        rows, at, Z = points_of(columns, self.n, detector.points)
        number = np.asarray(columns[detector.points], np.int64)[at]
        params = {k: np.asarray([v]) for k, v in self.step.items()}
        carried = {name: np.full((1, 1), float(state[name])) for name in self.declared_state()}
        out = detector.scan_points(params, carried, Z, number)
        count = len(at)
        per_point = {name: np.broadcast_to(out[name], (1, 1, count))[0, 0]
                     for name in self.outputs if name != "alarm"}
        per_point["decision"] = per_point["decision"].astype(np.int64)
        per_point["alarm"] = per_point["decision"] > 0
        for name, (var, _) in self.declared_state().items():
            values = np.asarray(out[name])[0, 0]
            per_point[name] = values.astype(np.int64) if var.integer else values.astype(float)
        return spread(rows, at, per_point, state)


#: stage classes of models saved before :class:`StepStage`: class → (detector class, design, step) from its fields
LEGACY = {
    "mosd.detectors.threshold.OnlineThreshold": lambda f: (
        "mosd.detectors.threshold.ThresholdDetector",
        {"threshold": f["threshold"], "persistence": f["persistence"],
         "threshold_max": max(10.0, f["threshold"]), "persistence_max": max(20, f["persistence"])},
        {"threshold": f["threshold"], "persistence": f["persistence"]}),
    "mosd.detectors.cusum.OnlineCusum": lambda f: (
        "mosd.detectors.cusum.Cusum", {"k": f["k"], "h": f["h"], "persistence": f["persistence"]},
        {"k": f["k"], "h": f["h"], "persistence": f["persistence"]}),
    "mosd.detectors.adaptive_chi2.OnlineAdaptiveChi2": lambda f: (
        "mosd.detectors.adaptive_chi2.AdaptiveChi2Detector",
        {"b": f["b"], "lag": f["lag"], "persistence": f["persistence"]},
        {"chi2_threshold": f["chi2_threshold"], "b": f["b"], "persistence": f["persistence"]}),
    "mosd.detectors.mode_probability.OnlineModeProbability": lambda f: (
        "mosd.detectors.mode_probability.ModeProbabilityDetector",
        {"mu_T": f["mu_T"], "persistence": f["persistence"], "labels": list(f["labels"]["tuple"])
         if isinstance(f["labels"], dict) else list(f["labels"])},
        {"mu_T": f["mu_T"], "persistence": f["persistence"]}),
    # a chart's causal form before the chart was a StepDetector: the same state variables, read by name
    "mosd.detectors.chart.OnlineChart": lambda f: (
        f["detector"], {**f["design"], "denoiser": f.get("denoiser") or None},
        {"lam": f["design"]["lam"], "width": f["design"]["L" if "L" in f["design"] else "K"],
         "limit": f["limit_value"]}),
}


def legacy_stage(path: str, fields: dict) -> StepStage | None:
    """The :class:`StepStage` of a stage an older model saved as ``path`` with ``fields``; None if not one."""
    translate = LEGACY.get(path)
    if translate is None:
        return None
    detector, design, step = translate(fields)
    n = int(fields.get("n", 2))
    return StepStage(detector=detector, design=design, step=step, n=n)


# each old class's module imports this one, so a model naming it finds its translation when loaded
LEGACY_STAGES.update({path: (lambda fields, path=path: legacy_stage(path, fields)) for path in LEGACY})
