"""Control charts: a decision statistic over standardised subgroups and its limit (paper 000).

Every chart follows the same lifecycle::

    chart = SSDEWMA(lam=0.3, K=3.0)          # parameters only in __init__
    chart.fit(phase1_subgroups.z)            # limit from fault-free Phase-I data (eq. 27)
    alarms = chart.alarms(subgroups.z)       # bool (R, K)

and declares its parameters once in ``params`` (:class:`~mosd.validation.Param`;
those an optimiser may tune form ``tunable``). :meth:`Chart.features` computes what does not depend on the
tunable parameters once (U_k, V_k of eqs. 19–20). The rest is the chart's one step, a
:class:`~mosd.detectors.step.StepDetector`'s :meth:`Chart.scan`: the EWMA update of the features from the
smoothed parts of the last ``order`` subgroups (:func:`mosd.kernels.ewma.ewma_step`), the statistic of the
smoothed parts (:func:`mosd.kernels.ewma.combine_step`), the normalisation, the denoiser (a causal one on its
window of earlier statistics), the limit and the decision statistic > limit. The population (tuning, the test
evaluation), the served chart (:class:`~mosd.detectors.step.StepStage` on the ``subgroup`` rows) and
``statistic``/``alarms`` run that scan; the fused tuning kernel (:mod:`mosd.kernels.chart`) calls the same
step functions.

Limits (docs/DECISIONS.md §3):

* ``"phase1"`` — eq. 27: UCL = E{l} + K·sd{l}, E and sd pooled over independent
  fault-free Phase-I replications, never over the data being scored.
* ``"theoretical"`` — eq. 35: UCL_k = 2σ²_{W_k}(1 + K), from L_k/σ²_{W_k} ~ χ²₂ in
  control; time-varying through σ²_{W_k} (eq. 31).
* ``"normalised"`` — the statistic is divided by σ²_{W_k} (so it is χ²₂ at every
  k in control) and compared with a constant from Phase-I: E{·} + K·sd{·}.

What each limit claims in control (docs/DECISIONS.md §10; tests/test_limits.py checks
every one within Monte Carlo error):

* model limits (``model_limits``: SS/M charts' ``"theoretical"``, the EWMA's
  ``"asymptotic"`` and ``"time_varying"``) state the exact law of the *raw*
  statistic of i.i.d. N(0, 1) subgroups — a point alarm rate (e^{−(1+K)} for SS
  charts) or an ARL0 (Crowder's integral equation). A denoiser changes that law
  (measured: 0.028 ± 0.001 instead of 0.050 for SS-DEWMA, λ = 0.3, K = 2, the paper's
  wavelet), so a model limit on a denoised statistic is refused at construction;
* Phase-I limits (``"phase1"``, ``"normalised"``) claim only what they estimate:
  the alarm rate on fresh in-control data equals the statistic's in-control
  probability of exceeding E{l} + K·sd{l}, up to the estimation error of E and sd
  from the Phase-I runs — with or without a denoiser.
"""
from __future__ import annotations

from collections.abc import Mapping
from typing import ClassVar

import numpy as np

from ..denoisers.base import NoDenoiser
from ..streaming import FINITE, NoStreamingForm, StateVar, build, describe
from ..validation import ConfigError, Param, check_choice
from .statistics import ewma_coefficients, mean_and_sd
from .step import StepDetector


def _denoiser(key: str, value, owner):
    """None -> the identity; a saved description ({"class", "params"}) -> its denoiser; otherwise anything
    with ``denoise(x)``."""
    if value is None:
        return NoDenoiser()
    if isinstance(value, Mapping) and "class" in value:
        value = build(value)
    if not callable(getattr(value, "denoise", None)):
        raise ConfigError(f"{key}={value!r} is not a denoiser; allowed: an object with denoise(x), e.g. denoise=wavelet")
    return value


class Chart(StepDetector):
    """Base class: subclasses declare their tunable ``params`` (λ ``lam`` and the limit's width, named
    :attr:`width`) and define ``features``, :attr:`combine` and ``control_limit``."""

    params = {
        "limit": Param(lambda key, value, chart: check_choice(key, value, chart.limits),
                       "The control limit, one of the chart's ``limits`` (module docstring).", kind="str"),
        "denoiser": Param(_denoiser, "Applied along the time axis to the raw statistic (paper 000 §3.2); "
                          "None: none.", kind="Denoiser"),
    }
    limits: ClassVar[tuple[str, ...]] = ("phase1",)
    #: limits derived from the in-control law of the raw statistic: valid without denoising only
    model_limits: ClassVar[tuple[str, ...]] = ()
    #: the smoothed features, in the order of :meth:`features` (empty: the chart has no causal form)
    parts: ClassVar[tuple[str, ...]] = ()
    #: how many times the features are smoothed (1: EWMA, 2: double EWMA)
    order: ClassVar[int] = 1
    #: the statistic of the smoothed parts (:func:`mosd.kernels.ewma.combine_step`): "abs", "ss" or "max"
    combine: ClassVar[str] = "abs"
    #: the tunable parameter that is the limit's width (K, or the EWMA chart's L)
    width: ClassVar[str] = "K"
    #: the served chart's points: the monitor's completed subgroups
    points: ClassVar[str] = "subgroup"

    def __init__(self, limit: str = "phase1", denoiser=None):
        self._assign(locals())
        self._check_model_limit("denoise", self.denoiser)

    def _check_model_limit(self, key: str, filter_) -> None:
        """Refuse a model limit when ``filter_`` (the denoiser or a prefilter, config key ``key``) is not the identity.

        The law behind a model limit is that of the raw statistic; after any
        filtering it no longer holds, and there is no stated law to replace it.
        """
        if self.limit in self.model_limits and not isinstance(filter_, NoDenoiser):
            allowed = "|".join(lim for lim in self.limits if lim not in self.model_limits)
            identity = "none" if key == "denoise" else "NoDenoiser()"
            raise ConfigError(
                f"detector.limit={self.limit} is the in-control law of the raw statistic and does not hold with "
                f"{key}={type(filter_).__name__}; allowed: detector.limit={allowed} with {key}, or {key}={identity}")

    @property
    def is_causal(self) -> bool:
        """True when l_k depends on subgroups 1..k only (needed for run lengths)."""
        return bool(getattr(self.denoiser, "is_causal", True))

    @property
    def _window(self) -> int:
        """Earlier raw statistics a causal denoiser's window needs (0: no denoiser, or a whole-series one)."""
        if isinstance(self.denoiser, NoDenoiser) or not self.is_causal:
            return 0
        return max(int(getattr(self.denoiser, "window", 1) or 1) - 1, 0)

    # -- the statistic ----------------------------------------------------------------
    def features(self, z: np.ndarray) -> np.ndarray:
        """Everything that does not depend on the tunable parameters, shape (..., F, K)."""
        raise NotImplementedError

    def control_limit(self, n_points: int) -> np.ndarray:
        """UCL_k for k = 1..n_points."""
        raise NotImplementedError

    def _scale(self, n_points: int, lam=None) -> np.ndarray:
        """σ²_k (or σ_k) of the raw statistic in control, k = 1..n_points: what ``"normalised"`` divides by;
        for this chart's λ, or for every λ of ``lam`` (P, 1): (P, n_points)."""
        raise NotImplementedError

    def raw_statistic(self, features: np.ndarray) -> np.ndarray:
        """The chart statistic before normalising and denoising, shape (..., K): :meth:`scan`'s first part."""
        flat = np.asarray(features, float)
        runs = flat.reshape((-1,) + flat.shape[-2:])
        raw, _ = self._smoothed(self._own(), self.start(0), runs, False)
        return raw[0].reshape(flat.shape[:-2] + flat.shape[-1:])

    def statistic(self, z: np.ndarray) -> np.ndarray:
        """The plotted statistic l_k for standardised subgroups z (..., K, n): :meth:`scan` from a stream's start."""
        features = np.asarray(self.features(z), float)
        runs = features.reshape((-1,) + features.shape[-2:])
        out = self.scan(self._own(), self.start(0), runs)["statistic"][0]
        return out.reshape(features.shape[:-2] + features.shape[-1:])

    def population_statistics(self, features: np.ndarray, X: np.ndarray) -> np.ndarray:
        """Plotted statistics for a population of parameter vectors X (P, d) on features (R, F, K): (P, R, K)."""
        return self.scan(self._design_params(X), self.start(0), features)["statistic"]

    def population_limits(self, phase1_statistics: np.ndarray, X: np.ndarray) -> np.ndarray:
        """Control limits (P, K) for parameter vectors X given each one's Phase-I statistic (P, ..., K)."""
        n_points = phase1_statistics.shape[-1]
        return np.stack([
            chart.fit_statistic(l1).control_limit(n_points)
            for chart, l1 in zip(self.candidates(X), phase1_statistics)
        ])

    # -- the one step (mosd.detectors.step) ---------------------------------------------
    def _design_params(self, X: np.ndarray) -> dict[str, np.ndarray]:
        """λ and the width of every design of X (P, d), validated as ``candidates`` validates them; no limit."""
        charts = self.candidates(X)
        return {"lam": np.array([c.lam for c in charts], float),
                "width": np.array([getattr(c, self.width) for c in charts], float),
                "limit": np.full(len(charts), np.nan)}

    def _own(self) -> dict[str, np.ndarray]:
        """This chart's own λ and width as a population of one, without a limit."""
        return {"lam": np.array([float(self.lam)]), "width": np.array([float(getattr(self, self.width))]),
                "limit": np.array([np.nan])}

    def step_params(self, X: np.ndarray, calibration_features: np.ndarray | None = None) -> dict[str, np.ndarray]:
        """λ, width and limit per design of X (P, d): a Phase-I limit (``"phase1"``, ``"normalised"``, eq. 27)
        fitted on the scan of ``calibration_features`` (R, F, K) from a stream's start; NaN for a model limit,
        which :meth:`scan` computes at each subgroup."""
        params = self._design_params(X)
        if self.limit not in self.model_limits:
            if calibration_features is None:
                raise ValueError(f"{type(self).__name__} with limit={self.limit!r} needs the calibration features")
            phase1 = self.scan(params, self.start(0), calibration_features)["statistic"]
            params["limit"] = self.population_limits(phase1, X)[:, 0]
        return params

    def step_state(self, n: int) -> dict[str, tuple[StateVar, float]]:
        """The smoothed parts of the last ``order`` subgroups, and a causal denoiser's window of raw statistics."""
        state = {f"smooth_{part}_{lag}": (StateVar(f"Smoothed {part} of the subgroup {lag} back.", FINITE), 0.0)
                 for part in self.parts for lag in range(1, self.order + 1)}
        state.update({f"raw_{lag}": (StateVar(f"The statistic before denoising, {lag} subgroups back.", FINITE), 0.0)
                      for lag in range(1, self._window + 1)})
        return state

    def scan(self, params, state, features, trajectory=False, number=None) -> dict[str, np.ndarray]:
        """Statistic, limit and decision of every design (P) on every run (R) at every subgroup (K).

        Parameters
        ----------
        params : dict of ndarray
            :meth:`step_params` (``lam``, ``width``, ``limit``), leading axis P.
        state : dict of ndarray
            :meth:`step_state`'s variables before the first subgroup, broadcastable to (P, R).
        features : ndarray, shape (R, F, K)
            :meth:`features` of the subgroups.
        trajectory : bool
            Also return each state variable after each subgroup, shape (P, R, K).
        number : ndarray of int, shape (K,), optional
            The subgroups' numbers since the stream's start (1-based, consecutive; default 1..K): where a
            model limit, the normalisation and a causal denoiser's prefix stand.

        Returns
        -------
        dict of ndarray
            ``statistic`` (P, R, K), ``limit`` (broadcastable to it), ``decision`` (P, R, K) int8; with
            ``trajectory`` also the state variables.
        """
        features = np.asarray(features, float)
        n_points = features.shape[-1]
        number = np.arange(1, n_points + 1) if number is None else np.asarray(number, np.int64)
        raw, smoothed = self._smoothed(params, state, features, trajectory)
        lams, widths = np.asarray(params["lam"], float), np.asarray(params["width"], float)
        if self.limit == "normalised" and n_points:   # eq. 31 (or 29): χ²₂ at every k in control
            raw = raw / self._scale(int(number[-1]), lams[:, None])[:, None, number - 1]
        statistic = self._denoised(raw, state, int(number[0]) - 1 if n_points else 0)
        if self.limit in self.model_limits:
            limit = np.stack([self.with_params(**{"lam": lam, self.width: width}).control_limit(
                int(number[-1]) if n_points else 0)[number - 1] for lam, width in zip(lams, widths)])[:, None, :]
        else:
            limit = np.asarray(params["limit"], float).reshape(-1, 1, 1)
        out = {"statistic": statistic, "limit": limit, "decision": (statistic > limit).astype(np.int8)}
        if trajectory:
            out.update(smoothed)
            out.update(self._raw_trajectory(raw, state))
        return out

    def _smoothed(self, params, state, features, trajectory) -> tuple[np.ndarray, dict]:
        """The raw statistic (P, R, K) of every design: each part's ``order``-fold EWMA continued from the
        carried ``smooth_*`` state, combined (:func:`mosd.kernels.ewma.chart_recursion`); with ``trajectory``
        the ``smooth_*`` state after every subgroup."""
        from ..kernels.ewma import COMBINE_ABS, COMBINE_MAX, COMBINE_SS, chart_recursion

        runs, n_parts, n_points = features.shape
        lams = np.asarray(params["lam"], float)
        gains, feedback = ewma_coefficients(lams, self.order)
        combine = {"abs": COMBINE_ABS, "ss": COMBINE_SS, "max": COMBINE_MAX}[self.combine]
        # time-major and part-major: column f·R + r is part f of run r
        columns = np.ascontiguousarray(np.moveaxis(features, -1, 0).transpose(0, 2, 1).reshape(n_points, n_parts * runs))
        parts = self.parts if len(self.parts) == n_parts else tuple(f"part{f}" for f in range(n_parts))
        names = [[f"smooth_{part}_{lag}" for lag in range(1, self.order + 1)] for part in parts]
        # every design's carried values, laid out as the columns: (P, order, F·R)
        pasts = np.stack([np.concatenate([np.broadcast_to(np.asarray(state.get(names[f][lag], 0.0), float),
                                                          (len(lams), runs)) for f in range(n_parts)], axis=-1)
                          for lag in range(self.order)], axis=1)
        raw = np.empty((len(lams), runs, n_points))
        history = {}
        smoothed = np.empty_like(columns)
        statistic = np.empty((n_points, runs))
        for p in range(len(lams)):
            past = pasts[p].copy()   # contiguous: continued in place by the recursion
            start = pasts[p]
            chart_recursion(columns, float(gains[p]), np.ascontiguousarray(feedback[p]), past, combine, smoothed,
                            statistic)
            raw[p] = statistic.T
            if trajectory:
                for f in range(n_parts):
                    values = np.concatenate([start[::-1, f * runs:(f + 1) * runs], smoothed[:, f * runs:(f + 1) * runs]])
                    for lag in range(1, self.order + 1):   # after subgroup k: the smoothed part lag − 1 before
                        history.setdefault(names[f][lag - 1], np.empty((len(lams), runs, n_points)))[p] = \
                            values[self.order - lag + 1:self.order - lag + 1 + n_points].T
        return raw, history

    def _denoised(self, raw: np.ndarray, state: dict, seen: int) -> np.ndarray:
        """The denoiser on the raw statistic (P, R, K) after ``seen`` earlier subgroups: a causal one's window
        continues from the carried ``raw_*`` (denoising them and these together gives each new point its
        window, or its prefix while fewer than the window came before); a whole-series one from a stream's
        start only."""
        if isinstance(self.denoiser, NoDenoiser):
            return raw
        carried = min(seen, self._window)
        if seen and not carried:
            raise NoStreamingForm(f"the denoiser {type(self.denoiser).__name__} filters the whole series")
        if carried:
            before = np.stack([np.broadcast_to(np.asarray(state[f"raw_{lag}"], float), raw.shape[:2])
                               for lag in range(carried, 0, -1)], axis=-1)
            raw = np.concatenate([before, raw], axis=-1)
        if raw.shape[-1] == carried:
            return raw[..., carried:]
        return self.denoiser.denoise(raw)[..., carried:]

    def _raw_trajectory(self, raw: np.ndarray, state: dict) -> dict[str, np.ndarray]:
        """The ``raw_*`` window after every subgroup: the carried values, then this scan's raw statistics."""
        w = self._window
        if not w:
            return {}
        before = [np.broadcast_to(np.asarray(state[f"raw_{lag}"], float), raw.shape[:2]) for lag in range(w, 0, -1)]
        values = np.concatenate([np.stack(before, axis=-1), raw], axis=-1)
        n_points = raw.shape[-1]
        return {f"raw_{lag}": values[..., w - lag + 1:w - lag + 1 + n_points] for lag in range(1, w + 1)}

    # -- the causal form ----------------------------------------------------------------
    def online(self, calibration_z: np.ndarray, inputs=None):
        """This tuned chart, its limit fitted on ``calibration_z`` (R, K, n), as a served
        :class:`~mosd.detectors.step.StepStage` on the monitor's ``subgroup`` rows.

        Raises :class:`~mosd.streaming.NoStreamingForm` where no causal form exists: a whole-series
        denoiser (the paper's wavelet needs the whole series; the causal wavelet streams, its window of
        earlier statistics carried as state) or a chart without ``parts`` (MS-OEWMA's whole-series prefilter).
        """
        if not self.parts:
            raise NoStreamingForm(f"{type(self).__name__} filters the whole residual series before charting it: "
                                  "no decision exists before the series ends")
        if not isinstance(self.denoiser, NoDenoiser):
            if not self.is_causal:
                raise NoStreamingForm(f"the denoiser {type(self.denoiser).__name__} filters the whole series: no "
                                      "decision exists before the series ends (with denoise=none or "
                                      "denoise=wavelet_causal the chart streams)")
            if not getattr(self.denoiser, "window", None):
                raise NoStreamingForm(f"the causal denoiser {type(self.denoiser).__name__} has no streaming form")
        return super().online(calibration_z, inputs)

    def stage_design(self) -> dict:
        """The tuned parameters, the limit rule and the denoiser as its description (None: none)."""
        design = {**{k: float(v) for k, v in self.tunable_params().items()}, "limit": self.limit}
        design["denoiser"] = None if isinstance(self.denoiser, NoDenoiser) else describe(self.denoiser)
        return design

    def stage_outputs(self) -> tuple[str, ...]:
        """The features of each completed subgroup (U_k as ``u``, V_k as ``v``), then the decision's outputs."""
        return (*self.parts, "statistic", "limit", "decision", "alarm")

    def scan_points(self, params, state, Z, number) -> dict[str, np.ndarray]:
        features = self.features(Z[None])                                       # (1, F, k)
        out = self.scan(params, state, features, trajectory=True, number=number)
        out.update({part: features[:, f][None] for f, part in enumerate(self.parts)})
        return out

    # -- the limit --------------------------------------------------------------------
    def fit(self, z_phase1: np.ndarray) -> "Chart":
        """Set the control limit from fault-free Phase-I subgroups (R, K, n)."""
        return self.fit_statistic(self.statistic(z_phase1))

    def fit_statistic(self, l_phase1: np.ndarray) -> "Chart":
        """Set the limit from an already computed Phase-I plotted statistic (..., K) (eq. 27's E{l}, sd{l})."""
        self.center_, self.scale_ = mean_and_sd(l_phase1)
        return self

    def alarms(self, z: np.ndarray) -> np.ndarray:
        """Boolean alarms (..., K): plotted statistic above the control limit."""
        l = self.statistic(z)
        return l > self.control_limit(l.shape[-1])

    def _phase1_limit(self, width: float, n_points: int) -> np.ndarray:
        if not hasattr(self, "center_"):
            raise RuntimeError(f"{type(self).__name__} with limit={self.limit!r} is not fitted: call fit(phase1_z) first")
        return np.full(n_points, self.center_ + width * self.scale_)

    def __repr__(self) -> str:
        params = ", ".join(f"{k}={getattr(self, k):.6g}" for k in self.tunable)
        return f"{type(self).__name__}({params}, limit={self.limit!r}, denoiser={self.denoiser!r})"

