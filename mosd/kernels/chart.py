"""The fused candidate evaluation of a mean–variance chart (SS-DEWMA and kin), compiled.

For one candidate (λ, K) and the features (U_k, V_k) of the calibration and the
training runs, the reference path (``Chart.population`` then
``objective_values``) computes the smoothed statistic of every run, denoises it,
fits the Phase-I limit E{l} + K·sd{l} on the calibration runs and scores the
training runs' alarms — materialising (P, R, K) statistics, limits and
decisions on the way. Here all of it is one compiled loop per candidate that
keeps only one candidate's (R, K) statistic, and returns per-run alarm counts
(P, R): healthy points that alarm and target-fault points that do not.

Each step reproduces the reference's arithmetic in its order (the recursion of
``ewma_time_major``, PyWavelets' sums via :mod:`mosd.kernels.wavelet`, NumPy's
pairwise summation for the mean and standard deviation of ``fit_statistic``),
so FAR and MDR come out bit-identical; ``tests/test_kernels.py`` checks it.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from .wavelet import denoise_row, work_size

_BLOCK = 128  # NumPy's pairwise-summation block (PW_BLOCKSIZE)


@njit(cache=True, nogil=True)
def _block_sum(a, start, n):
    """One leaf of NumPy's pairwise summation (n <= 128): eight accumulators, then the rest."""
    if n < 8:
        res = 0.0
        for i in range(start, start + n):
            res += a[i]
        return res
    r0, r1, r2, r3 = a[start], a[start + 1], a[start + 2], a[start + 3]
    r4, r5, r6, r7 = a[start + 4], a[start + 5], a[start + 6], a[start + 7]
    i = 8
    stop = n - n % 8
    while i < stop:
        b = start + i
        r0 += a[b]
        r1 += a[b + 1]
        r2 += a[b + 2]
        r3 += a[b + 3]
        r4 += a[b + 4]
        r5 += a[b + 5]
        r6 += a[b + 6]
        r7 += a[b + 7]
        i += 8
    res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < n:
        res += a[start + i]
        i += 1
    return res


@njit(cache=True, nogil=True)
def pairwise_sum(a, start, n):
    """NumPy's pairwise summation of a[start:start + n] (what ``np.add.reduce`` does on a contiguous float64 array).

    NumPy recurses: sum(a[:h]) + sum(a[h:]) with h = n//2 rounded down to a
    multiple of 8, down to blocks of at most 128. The recursion runs here on an
    explicit stack (numba's on-disk cache mishandles recursive functions).
    """
    if n <= _BLOCK:
        return _block_sum(a, start, n)
    starts = np.empty(128, np.int64)
    sizes = np.empty(128, np.int64)
    combine = np.zeros(128, np.bool_)
    values = np.empty(128)
    top = 1
    starts[0], sizes[0], combine[0] = start, n, False
    depth = 0
    while top > 0:
        top -= 1
        s, m, joining = starts[top], sizes[top], combine[top]
        if joining:
            depth -= 1
            values[depth - 1] = values[depth - 1] + values[depth]
        elif m <= _BLOCK:
            values[depth] = _block_sum(a, s, m)
            depth += 1
        else:
            half = m // 2
            half -= half % 8
            # popped in reverse: the left half first, then the right, then their sum
            starts[top], sizes[top], combine[top] = s, m, True
            starts[top + 1], sizes[top + 1], combine[top + 1] = s + half, m - half, False
            starts[top + 2], sizes[top + 2], combine[top + 2] = s, half, False
            top += 3
    return values[0]


@njit(cache=True, nogil=True)
def mean_std(values):
    """(np.mean(values), np.std(values, ddof=1)) of a contiguous 1-D array, bit for bit."""
    n = values.shape[0]
    center = pairwise_sum(values, 0, n) / n
    deviations = np.empty(n)
    for i in range(n):
        d = values[i] - center
        deviations[i] = d * d
    return center, math.sqrt(pairwise_sum(deviations, 0, n) / (n - 1))


@njit(cache=True, nogil=True)
def _statistics(u, v, gain, f1, f2, order, combine_max, stat, y):
    """Smoothed-and-combined statistic of every run: u, v time-major (K, C) -> stat (C, K).

    y: scratch (4, C) for the recursion's two past values of both parts. The
    recursion is the reference's: y_k = g·x_k, += y_{k−1}·f1, (+= y_{k−2}·f2);
    past values start at 0, and adding 0·f changes no value.
    """
    n_points, n_columns = u.shape
    u1, u2, v1, v2 = y[0], y[1], y[2], y[3]
    for c in range(n_columns):
        u1[c] = 0.0
        u2[c] = 0.0
        v1[c] = 0.0
        v2[c] = 0.0
    for k in range(n_points):
        uk, vk = u[k], v[k]
        for c in range(n_columns):
            a = gain * uk[c]
            a += u1[c] * f1
            b = gain * vk[c]
            b += v1[c] * f1
            if order == 2:
                a += u2[c] * f2
                b += v2[c] * f2
                u2[c] = u1[c]
                v2[c] = v1[c]
            u1[c] = a
            v1[c] = b
            if combine_max:
                stat[c, k] = max(abs(a), abs(b))
            else:
                s = a * a
                s += b * b
                stat[c, k] = s


@njit(cache=True, nogil=True)
def alarm_counts(u, v, n_calibration, gains, feedback, widths, combine_max, faulty, denoise,
                 lo, hi, rec_lo, rec_hi, level, per_level, source, rule, fixed, hard):
    """Per-run alarm counts of every candidate, fused (module docstring).

    Parameters
    ----------
    u, v : float64 (K, C), time-major
        U_k and V_k of the calibration runs (first ``n_calibration`` columns) then the training runs.
    gains : (P,); feedback : (P, order); widths : (P,)
        Each candidate's recursion coefficients (as ``ewma_time_major`` computes them) and its K.
    faulty : bool (R_train, K)
        Target-fault truth of the training runs.
    denoise : bool
        Apply the wavelet (remaining arguments: :func:`mosd.kernels.wavelet.denoise_row`).

    Returns
    -------
    healthy_alarms, faulty_misses : int64 (P, R_train)
    """
    n_points, n_columns = u.shape
    n_candidates, order = feedback.shape
    n_train = n_columns - n_calibration
    healthy_alarms = np.zeros((n_candidates, n_train), np.int64)
    faulty_misses = np.zeros((n_candidates, n_train), np.int64)
    raw = np.empty((n_columns, n_points))
    plotted = np.empty((n_columns, n_points)) if denoise else raw
    y = np.empty((4, n_columns))
    work = np.empty(work_size(n_points, lo.shape[0], level))
    calibration = np.empty(n_calibration * n_points)
    for p in range(n_candidates):
        f2 = feedback[p, 1] if order == 2 else 0.0
        _statistics(u, v, gains[p], feedback[p, 0], f2, order, combine_max, raw, y)
        if denoise:
            for c in range(n_columns):
                denoise_row(raw[c], plotted[c], work, lo, hi, rec_lo, rec_hi, level, per_level, source, rule,
                            fixed, hard)
        # the Phase-I limit: mean + K·sd over every calibration point (Chart.fit_statistic)
        for c in range(n_calibration):
            row = plotted[c]
            base = c * n_points
            for k in range(n_points):
                calibration[base + k] = row[k]
        center, scale = mean_std(calibration)
        limit = center + widths[p] * scale
        for r in range(n_train):
            row = plotted[n_calibration + r]
            truth = faulty[r]
            alarms = 0
            misses = 0
            for k in range(n_points):
                alarm = row[k] > limit
                if truth[k]:
                    misses += not alarm
                else:
                    alarms += alarm
            healthy_alarms[p, r] = alarms
            faulty_misses[p, r] = misses
    return healthy_alarms, faulty_misses


_FUSED_OBJECTIVES = ("far", "mdr")


class FusedChartEvaluation:
    """Objectives (P, n_obj) of a population of chart designs through :func:`alarm_counts`.

    Built by :func:`fused_evaluation`, which returns None unless the detector,
    its denoiser, the limit rule and the objectives are exactly what the kernel
    reproduces; the caller then keeps the reference path.
    """

    def __init__(self, detector, calibration_features, features, fault_mask, objectives, wavelet_plan):
        self.detector = detector
        self.objectives = tuple(objectives)
        n_calibration = calibration_features.shape[0]
        both = np.concatenate([calibration_features, features], axis=0)  # (C, 2, K), as Chart.population stacks them
        self.u = np.ascontiguousarray(both[:, 0, :].T)
        self.v = np.ascontiguousarray(both[:, 1, :].T)
        self.n_calibration = n_calibration
        n_points = both.shape[-1]
        self.faulty = np.ascontiguousarray(np.broadcast_to(np.asarray(fault_mask, bool), (features.shape[0], n_points)))
        self.n_faulty = self.faulty.sum(axis=-1)
        self.n_healthy = (~self.faulty).sum(axis=-1)
        self.denoise = wavelet_plan is not None
        if wavelet_plan is None:
            from ..denoisers.wavelet import WaveletDenoiser

            from .wavelet import plan

            wavelet_plan = plan(WaveletDenoiser())  # placeholder arguments, unused
        self.wavelet_arguments = wavelet_plan.arguments(n_points)

    def counts(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per-run (healthy alarms, target-fault misses), each (P, R_train)."""
        from ..detectors.statistics import ewma_coefficients

        params = _validated(self.detector, X)
        gains, feedback = ewma_coefficients(params["lam"], self.detector.order)
        widths = np.asarray(params["K"], float)
        return alarm_counts(self.u, self.v, self.n_calibration, gains, feedback, widths,
                            self.detector.combine == "max", self.faulty, self.denoise, *self.wavelet_arguments)

    def __call__(self, X: np.ndarray) -> np.ndarray:
        import warnings

        alarms, misses = self.counts(X)
        columns = []
        for name in self.objectives:
            numerator, count = (alarms, self.n_healthy) if name == "far" else (misses, self.n_faulty)
            # mosd.metrics.detection._share, then the nan-mean of mosd.metrics.registry.objective_values
            with np.errstate(invalid="ignore", divide="ignore"):
                per_run = np.where(count > 0, numerator / np.maximum(count, 1), np.nan)
            with np.errstate(invalid="ignore"), warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                mean = np.nanmean(per_run, axis=-1)
            columns.append(np.where(np.isfinite(mean), mean, np.inf))
        return np.stack(columns, axis=-1)


def _validated(detector, X: np.ndarray) -> dict:
    """Each tunable parameter's column of X, validated and rounded as ``Detector.with_params`` does.

    Same checks and the same values as ``detector.candidates(X)``, without copying
    the detector once per row (which cost as much as the compiled evaluation):
    a column inside its interval is taken whole; a column with a value outside
    goes through ``check_in`` value by value, which raises its message.
    """
    from ..validation import check_in

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
    from ..denoisers.base import NoDenoiser
    from ..denoisers.wavelet import WaveletDenoiser
    from ..detectors.chart import Chart
    from ..detectors.mean_variance import _MeanVarianceChart

    from .wavelet import plan

    cls = type(detector)
    if not isinstance(detector, _MeanVarianceChart) or getattr(detector, "limit", None) != "phase1":
        return False
    same = [(name, owner) for owner, names in ((Chart, ("population", "population_limits", "fit_statistic",
                                                         "_phase1_limit", "plotted")),
                                                (_MeanVarianceChart, ("population_statistics", "_combine",
                                                                      "control_limit", "normalise", "features")))
            for name in names]
    if any(getattr(cls, name) is not getattr(owner, name) for name, owner in same):
        return False
    if detector.order not in (1, 2) or detector.combine not in ("ss", "max"):
        return False
    if not set(objectives) <= set(_FUSED_OBJECTIVES):
        return False
    denoiser = detector.denoiser
    return type(denoiser) is NoDenoiser or (type(denoiser) is WaveletDenoiser and plan(denoiser) is not None)


def applies(detector, objectives) -> bool:
    """Whether the compiled fused evaluation replaces the NumPy path: the one decision.

    Kernels on (:func:`mosd.kernels.enabled`) and :func:`supports`. The tuning
    problem's evaluator (``CandidateEvaluator.fused``), the choice of threads over
    processes (``mosd.optim.problem.uses_threads``, ``TuningProblem.in_threads``)
    and the experiment's early worker pool all ask this; :func:`fused_evaluation`
    then checks the data.
    """
    from . import enabled

    return enabled() and supports(detector, objectives)


def fused_evaluation(detector, calibration_features, features, truth, objectives):
    """A :class:`FusedChartEvaluation` when the kernel reproduces this set-up exactly, else None.

    :func:`applies` (kernels on; the detector and objectives :func:`supports`),
    then the data: features (R, 2, K) of floats, a fault mask of the runs, a
    wavelet plan that fits K points and finite features for a wavelet.
    """
    from ..denoisers.base import NoDenoiser
    from ..denoisers.wavelet import WaveletDenoiser

    from .wavelet import plan

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
        wavelet_plan = plan(denoiser)
        if wavelet_plan is None or not wavelet_plan.fits(n_points):
            return None
        if not (np.all(np.isfinite(calibration_features)) and np.all(np.isfinite(features))):
            return None  # the reference raises on non-finite statistics; let it
    else:
        return None
    return FusedChartEvaluation(detector, calibration_features, features, fault_mask, objectives, wavelet_plan)


def warm_up() -> None:
    """Load (or compile) the kernels for both denoising settings."""
    from ..denoisers.wavelet import WaveletDenoiser
    from .wavelet import plan

    u = np.zeros((64, 3))
    faulty = np.zeros((2, 64), bool)
    args = plan(WaveletDenoiser()).arguments(64)
    for denoise in (True, False):
        alarm_counts(u, u, 1, np.ones(1), np.zeros((1, 2)), np.ones(1), False, faulty, denoise, *args)
