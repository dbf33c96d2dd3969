"""The fused candidate evaluation of a mean–variance chart: when the compiled kernel replaces the NumPy path.

The arithmetic is :func:`mosd.kernels.chart.alarm_counts` (one compiled loop over blocks of
candidates that returns per-run alarm counts); this module decides whether it reproduces a
detector, its denoiser, its limit rule and the objectives exactly, and turns its counts into the
objectives. It lives with the detectors because it knows them; the kernels know no component.

An evaluation is three steps, so that a threaded caller runs the Python parts once per
population and only the compiled part per chunk (:class:`FusedChartEvaluation`): ``plan``
(validation, coefficients), ``counts_of`` (the kernel on a slice of the plan's rows, the GIL
released) and ``objectives`` (FAR and MDR from the counts).
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .. import kernels
from ..denoisers.base import NoDenoiser
from ..denoisers.wavelet import WaveletDenoiser
from ..kernels.wavelet import plan as kernel_plan
from ..validation import check_in
from .chart import Chart
from .mean_variance import _MeanVarianceChart
from .statistics import ewma_coefficients

_FUSED_OBJECTIVES = ("far", "mdr")


class EvaluationPlan(NamedTuple):
    """A population's validated designs as the kernel takes them (:meth:`FusedChartEvaluation.plan`): each
    candidate's recursion gain (P,) and feedback (P, order), and its width K (P,), every array contiguous."""

    gains: np.ndarray
    feedback: np.ndarray
    widths: np.ndarray

    def __len__(self) -> int:
        return self.gains.shape[0]


class FusedChartEvaluation:
    """Objectives (P, n_obj) of a population of chart designs through :func:`alarm_counts`.

    Built by :func:`fused_evaluation`, which returns None unless the detector,
    its denoiser, the limit rule and the objectives are exactly what the kernel
    reproduces; the caller then keeps the reference path.

    ``evaluation(X)`` is ``evaluation.objectives(*evaluation.counts_of(evaluation.plan(X), 0, len(X)))``; a
    threaded caller plans once, runs :meth:`counts_of` on slices of the plan in its threads (each releases
    the GIL for all its work) and joins the counts for :meth:`objectives`. A candidate's counts do not depend
    on the slice it is in, so every split gives the same objectives, bit for bit.
    """

    def __init__(self, detector, calibration_features, features, fault_mask, objectives, wavelet_plan):
        from ..kernels import chart

        self.detector = detector
        #: the objectives' names, in their columns' order (FAR and/or MDR)
        self.objective_names = tuple(objectives)
        n_calibration = calibration_features.shape[0]
        both = np.concatenate([calibration_features, features], axis=0)  # (C, 2, K), as Chart.population stacks them
        # run-major (C, K): the kernel reads each run's points in time order, once per block of candidates
        self.u = np.ascontiguousarray(both[:, 0, :])
        self.v = np.ascontiguousarray(both[:, 1, :])
        self.n_calibration = n_calibration
        n_points = both.shape[-1]
        # a writable copy: a read-only mask (a broadcast view of a full-shape mask stays one) is another numba
        # signature than the one compiled ahead (kernels.chart._warm_up_arguments), so the run would compile again
        self.faulty = np.array(np.broadcast_to(np.asarray(fault_mask, bool), (features.shape[0], n_points)), order="C")
        self.n_faulty = self.faulty.sum(axis=-1)
        self.n_healthy = (~self.faulty).sum(axis=-1)
        self.denoise = wavelet_plan is not None
        self.wavelet_arguments = wavelet_plan.arguments(n_points) if self.denoise else ()
        self.combine_max = detector.combine == "max"
        self._kernel = chart.alarm_counts_denoised if self.denoise else chart.alarm_counts
        #: what a caller that splits a population should align its slices to: the kernel computes a slice's
        #: candidates rounded up to a multiple of this many lanes (chart._VECTOR, 4), so a slice of fewer costs
        #: as much as this many. A slice's cost grows with its lanes, plus a floor (each time step's latency):
        #: measured on AVX2, 4 candidates 0.4-0.6 of a block of 16, 6-8 0.6-0.75, so per candidate a slice of 6
        #: costs 1.5-2x one of 16. To fill n threads, cut a population into n slices (100 on 16 threads: 6-7
        #: each, each 0.6-0.75 of a block, against 7 threads with a block each); no slice shorter than this many
        self.lanes = chart._VECTOR

    def plan(self, X: np.ndarray) -> EvaluationPlan:
        """Every row of X validated (a bad design raises ``ConfigError`` naming its key) and turned into the
        kernel's coefficients: the Python part of an evaluation, done once per population."""
        params = _validated(self.detector, X)
        gains, feedback = ewma_coefficients(params["lam"], self.detector.order)
        return EvaluationPlan(np.ascontiguousarray(gains, float), np.ascontiguousarray(feedback, float),
                              np.ascontiguousarray(params["K"], float))

    def counts_of(self, plan: EvaluationPlan, start: int, stop: int) -> tuple[np.ndarray, np.ndarray]:
        """Per-run (healthy alarms, target-fault misses), each int64 (stop − start, R_train), of the plan's rows
        start..stop−1: the compiled kernel alone, which releases the GIL (threads run it side by side)."""
        return self._kernel(self.u, self.v, self.n_calibration, plan.gains[start:stop], plan.feedback[start:stop],
                            plan.widths[start:stop], self.combine_max, self.faulty, *self.wavelet_arguments)

    def objectives(self, alarms: np.ndarray, misses: np.ndarray) -> np.ndarray:
        """The objectives (P, n_obj) from per-run counts (P, R_train): each run's FAR (alarms over its healthy
        points) and MDR (misses over its target-fault points), their NaN-mean over the runs, inf where none
        is defined — ``objective_values`` on the reference path."""
        import warnings

        columns = []
        for name in self.objective_names:
            numerator, count = (alarms, self.n_healthy) if name == "far" else (misses, self.n_faulty)
            # mosd.metrics.detection._share, then the nan-mean of mosd.metrics.registry.objective_values
            with np.errstate(invalid="ignore", divide="ignore"):
                per_run = np.where(count > 0, numerator / np.maximum(count, 1), np.nan)
            with np.errstate(invalid="ignore"), warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                mean = np.nanmean(per_run, axis=-1)
            columns.append(np.where(np.isfinite(mean), mean, np.inf))
        return np.stack(columns, axis=-1).reshape(np.shape(alarms)[0], len(self.objective_names))

    def counts(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per-run (healthy alarms, target-fault misses), each (P, R_train)."""
        plan = self.plan(X)
        return self.counts_of(plan, 0, len(plan))

    def __call__(self, X: np.ndarray) -> np.ndarray:
        return self.objectives(*self.counts(X))


def _validated(detector, X: np.ndarray) -> dict:
    """Each tunable parameter's column of X, validated and rounded as ``Detector.with_params`` does.

    Same checks and the same values as ``detector.candidates(X)``, without copying
    the detector once per row (which cost as much as the compiled evaluation):
    a column inside its interval is taken whole; a column with a value outside
    goes through ``check_in`` value by value, which raises its message.
    """
    X = np.atleast_2d(np.asarray(X, float))
    params = {}
    for column, (name, interval) in enumerate(detector.tunable.items()):
        values = X[:, column]
        values = interval.round(values)
        low_ok = values > interval.low if interval.open_low else values >= interval.low
        high_ok = values < interval.high if interval.open_high else values <= interval.high
        if not np.all(low_ok & high_ok):
            values = np.array([check_in(f"detector.{name}", value, interval) for value in values], float)
        params[name] = values
    return params


def supports(detector, objectives) -> bool:
    """True when the fused kernel reproduces this detector and these objectives, whatever the data.

    A mean–variance chart with the Phase-I limit whose statistic, limit and
    decision code is the base classes' own (no override in a subclass), order
    1 or 2, combined by ``ss`` or ``max``, no denoiser or a whole-series
    wavelet the kernel supports, and objectives among FAR and MDR.
    :func:`fused_evaluation` adds the checks on the data.
    """
    cls = type(detector)
    if not isinstance(detector, _MeanVarianceChart) or getattr(detector, "limit", None) != "phase1":
        return False
    same = [(name, owner) for owner, names in ((Chart, ("population", "population_limits", "fit_statistic",
                                                         "_phase1_limit", "step_params", "scan", "_smoothed",
                                                         "_denoised")),
                                                (_MeanVarianceChart, ("control_limit", "features")))
            for name in names]
    if any(getattr(cls, name) is not getattr(owner, name) for name, owner in same):
        return False
    if detector.order not in (1, 2) or detector.combine not in ("ss", "max"):
        return False
    if not set(objectives) <= set(_FUSED_OBJECTIVES):
        return False
    denoiser = detector.denoiser
    return type(denoiser) is NoDenoiser or (type(denoiser) is WaveletDenoiser and kernel_plan(denoiser) is not None)


def applies(detector, objectives) -> bool:
    """Whether the compiled fused evaluation replaces the NumPy path: the one decision.

    Kernels on (:func:`mosd.kernels.enabled`) and :func:`supports`. The tuning
    problem's evaluator (``CandidateEvaluator.fused``), the choice of threads over
    processes (``mosd.optim.problem.uses_threads``, ``TuningProblem.in_threads``)
    and the experiment's early worker pool all ask this; :func:`fused_evaluation`
    then checks the data.
    """
    return kernels.enabled() and supports(detector, objectives)


def fused_evaluation(detector, calibration_features, features, truth, objectives):
    """A :class:`FusedChartEvaluation` when the kernel reproduces this set-up exactly, else None.

    :func:`applies` (kernels on; the detector and objectives :func:`supports`),
    then the data: features (R, 2, K) of floats, a fault mask of the runs, a
    wavelet plan that fits K points and finite features for a wavelet.
    """
    if not applies(detector, objectives):
        return None
    calibration_features = np.asarray(calibration_features)
    features = np.asarray(features)
    if (calibration_features.ndim != 3 or features.ndim != 3 or calibration_features.shape[1:] != features.shape[1:]
            or features.shape[1] != 2 or calibration_features.dtype != float or features.dtype != float
            or calibration_features.shape[0] < 1):
        return None
    n_points = features.shape[-1]
    if calibration_features.shape[0] * n_points < 2:
        return None
    fault_mask = getattr(truth, "fault_mask", None)
    if fault_mask is None or np.broadcast_shapes(np.shape(fault_mask), features.shape[::2]) != features.shape[::2]:
        return None
    denoiser = detector.denoiser
    if type(denoiser) is NoDenoiser:
        wavelet_plan = None
    elif type(denoiser) is WaveletDenoiser:
        wavelet_plan = kernel_plan(denoiser)
        if wavelet_plan is None or not wavelet_plan.fits(n_points):
            return None
        if not (np.all(np.isfinite(calibration_features)) and np.all(np.isfinite(features))):
            return None  # the reference raises on non-finite statistics; let it
    else:
        return None
    return FusedChartEvaluation(detector, calibration_features, features, fault_mask, objectives, wavelet_plan)
