"""Control charts: a decision statistic over standardised subgroups and its limit (paper 000).

Every chart follows the same lifecycle::

    chart = SSDEWMA(lam=0.3, K=3.0)          # parameters only in __init__
    chart.fit(phase1_subgroups.z)            # limit from fault-free Phase-I data (eq. 27)
    alarms = chart.alarms(subgroups.z)       # bool (R, K)

and declares its parameters once in ``params`` (:class:`~mosd.validation.Param`;
those an optimiser may tune form ``tunable``). The statistic is split so that tuning is cheap: :meth:`Chart.features`
computes what does not depend on the tunable parameters once (U_k, V_k of
eqs. 19–20), :meth:`Chart.raw_statistic` the part that does (the EWMA
recursions), and the denoiser runs on a whole population of candidates at once
(:meth:`Chart.population_statistics`). :meth:`Chart.population` is the
:class:`~mosd.detectors.base.Detector` contract: statistic > limit.

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

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from ..denoisers.base import NoDenoiser
from ..streaming import FINITE, NoStreamingForm, OnlineStage, StateVar, build, mosd_class
from ..validation import ConfigError, Param, check_choice
from .base import Decisions, Detector
from .statistics import ewma_continue, mean_and_sd


def _denoiser(key: str, value, owner):
    """None -> the identity; otherwise anything with ``denoise(x)``."""
    if value is None:
        return NoDenoiser()
    if not callable(getattr(value, "denoise", None)):
        raise ConfigError(f"{key}={value!r} is not a denoiser; allowed: an object with denoise(x), e.g. denoise=wavelet")
    return value


class Chart(Detector):
    """Base class: subclasses declare their tunable ``params`` and define ``features`` and ``raw_statistic``."""

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

    # -- the statistic ----------------------------------------------------------------
    def features(self, z: np.ndarray) -> np.ndarray:
        """Everything that does not depend on the tunable parameters, shape (..., F, K)."""
        raise NotImplementedError

    def raw_statistic(self, features: np.ndarray) -> np.ndarray:
        """The chart statistic before denoising, shape (..., K)."""
        raise NotImplementedError

    def normalise(self, raw: np.ndarray) -> np.ndarray:
        """Parameter-dependent rescaling applied before denoising (identity by default)."""
        return raw

    def plotted(self, raw: np.ndarray) -> np.ndarray:
        """Map a raw statistic to the plotted one: normalise, then denoise."""
        return self.denoiser.denoise(self.normalise(raw))

    def statistic(self, z: np.ndarray) -> np.ndarray:
        """The plotted statistic l_k for standardised subgroups z (..., K, n)."""
        return self.plotted(self.raw_statistic(self.features(z)))

    def population_statistics(self, features: np.ndarray, X: np.ndarray) -> np.ndarray:
        """Plotted statistics for a population of parameter vectors X (P, d): (P, ..., K).

        The parameter-dependent recursion runs once per candidate; the denoiser
        runs once on the whole stack.
        """
        charts = self.candidates(X)
        return self.denoiser.denoise(np.stack([c.normalise(c.raw_statistic(features)) for c in charts]))

    def population_limits(self, phase1_statistics: np.ndarray, X: np.ndarray) -> np.ndarray:
        """Control limits (P, K) for parameter vectors X given each one's Phase-I statistic (P, ..., K)."""
        n_points = phase1_statistics.shape[-1]
        return np.stack([
            chart.fit_statistic(l1).control_limit(n_points)
            for chart, l1 in zip(self.candidates(X), phase1_statistics)
        ])

    def population(self, calibration_features: np.ndarray, features: np.ndarray, X: np.ndarray) -> Decisions:
        """Plotted statistics, limits fitted on the calibration (Phase-I) statistics, alarms = statistic > limit."""
        X = np.atleast_2d(np.asarray(X, float))
        n_calibration = calibration_features.shape[0]
        stats = self.population_statistics(np.concatenate([calibration_features, features], axis=0), X)
        limits = self.population_limits(stats[:, :n_calibration], X)[:, None, :]  # (P, 1, K)
        statistic = stats[:, n_calibration:]
        return Decisions(statistic, limits, (statistic > limits).astype(np.int8))

    def statistic_of_smoothed(self, smoothed: np.ndarray) -> np.ndarray:
        """The raw statistic from the smoothed features (parts first, shape (F, ...)): the part of
        :meth:`raw_statistic` after the EWMA, which the causal form continues."""
        raise NotImplementedError

    # -- the causal form ----------------------------------------------------------------
    def online(self, calibration_z: np.ndarray, inputs=None) -> OnlineChart:
        """This tuned chart with its limit fitted on ``calibration_z`` (R, K, n) as an :class:`OnlineChart`.

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
            if not callable(getattr(self.denoiser, "causal_tail", None)):
                raise NoStreamingForm(f"the causal denoiser {type(self.denoiser).__name__} has no streaming form")
        fitted = self.clone()
        limit_value = np.nan
        if self.limit not in ("theoretical", "time_varying"):
            fitted.fit(np.asarray(calibration_z, float))
            limit_value = float(fitted.control_limit(1)[0])
        design = {**self.tunable_params(), "limit": self.limit}
        design = {k: (float(v) if not isinstance(v, str) else v) for k, v in design.items()}
        cls = type(self)
        n = int(np.shape(calibration_z)[-1])
        denoiser = {}
        if not isinstance(self.denoiser, NoDenoiser):
            kind = type(self.denoiser)
            denoiser = {"class": f"{kind.__module__}.{kind.__qualname__}", "params": self.denoiser.get_params()}
        return OnlineChart(detector=f"{cls.__module__}.{cls.__qualname__}", design=design, limit_value=limit_value, n=n,
                           denoiser=denoiser)

    # -- the limit --------------------------------------------------------------------
    def fit(self, z_phase1: np.ndarray) -> "Chart":
        """Set the control limit from fault-free Phase-I subgroups (R, K, n)."""
        return self.fit_statistic(self.statistic(z_phase1))

    def fit_statistic(self, l_phase1: np.ndarray) -> "Chart":
        """Set the limit from an already computed Phase-I plotted statistic (..., K)."""
        self.center_, self.scale_ = mean_and_sd(l_phase1)
        return self

    def control_limit(self, n_points: int) -> np.ndarray:
        """UCL_k for k = 1..n_points."""
        raise NotImplementedError

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


@dataclass
class OnlineChart(OnlineStage):
    """A tuned chart's causal form: standardised subgroups in (``subgroup``, ``z_1`` ... ``z_n``), decisions out.

    On each row that completes subgroup k: the features (U_k, V_k of eqs. 19–20; U_k alone for the
    EWMA chart) as ``u``/``v``, the plotted ``statistic`` and its ``limit``, ``alarm`` (statistic >
    limit). Rows that complete no subgroup give NaN and no alarm. The recursion is the charts' one
    (:func:`~mosd.detectors.statistics.ewma_continue`), continued from the carried state: the smoothed
    features of the last ``order`` subgroups (``smooth_u_1``, ``smooth_u_2``, ``smooth_v_1``, ...).

    Attributes
    ----------
    detector : str
        The chart's class (``module.Class``).
    design : dict
        Its parameters (the tuned ones and the limit rule).
    limit_value : float
        The constant limit fitted on the calibration runs; NaN for a limit that changes with k.
    n : int
        Points per subgroup.
    """

    detector: str
    design: dict
    limit_value: float
    n: int
    denoiser: dict = None   # a causal denoiser: {"class": "module.Class", "params": {...}}; empty: none

    def _chart(self) -> "Chart":
        cached = self.__dict__.get("_chart_object")
        if cached is None:
            denoiser = build(self.denoiser) if self.denoiser else None
            cached = self.__dict__["_chart_object"] = mosd_class(self.detector)(**self.design, denoiser=denoiser)
        return cached

    @property
    def window(self) -> int:
        """Raw statistics the causal denoiser's window carries (0 without one)."""
        return int(self._chart().denoiser.window) - 1 if self.denoiser else 0

    @property
    def parts(self) -> tuple[str, ...]:
        return tuple(self._chart().parts)

    @property
    def order(self) -> int:
        return int(self._chart().order)

    @property
    def inputs(self) -> tuple[str, ...]:
        return ("subgroup", *(f"z_{j}" for j in range(1, self.n + 1)))

    @property
    def outputs(self) -> tuple[str, ...]:
        return (*self.parts, "statistic", "limit", "alarm")

    def state_vars(self) -> dict[str, StateVar]:
        out = {f"smooth_{part}_{lag}": StateVar(f"Smoothed {part} of the subgroup {lag} back.", FINITE)
               for part in self.parts for lag in range(1, self.order + 1)}
        out.update({f"raw_{lag}": StateVar(f"The statistic before denoising, {lag} subgroups back.", FINITE)
                    for lag in range(1, self.window + 1)})
        return out

    def initial_state(self) -> dict:
        return {name: 0.0 for name in self.state_vars()}

    def update(self, columns, state) -> dict[str, np.ndarray]:
        chart, parts, order = self._chart(), self.parts, self.order
        number_of_row = np.asarray(columns["subgroup"], np.int64)
        rows = len(number_of_row)
        at = np.flatnonzero(number_of_row > 0)
        complete = len(at)
        z = np.column_stack([np.asarray(columns[f"z_{j}"], float) for j in range(1, self.n + 1)])[at]
        features = chart.features(z[None])[0] if complete else np.empty((len(parts), 0))   # (parts, k)
        past = np.array([[float(state[f"smooth_{part}_{lag}"]) for part in parts] for lag in range(1, order + 1)])
        smoothed = ewma_continue(features.T, chart.lam, order, past)[0].T                 # (parts, k)
        number = number_of_row[at]
        statistic = chart.statistic_of_smoothed(smoothed) if complete else np.empty(0)
        if self.design.get("limit") == "normalised" and complete:
            statistic = statistic / chart._scale(int(number[-1]))[number - 1]
        raw = statistic
        if self.window and complete:   # the causal denoiser: its window of earlier statistics, then these
            seen = int(number[0]) - 1                                       # subgroups before this chunk
            carried = np.array([float(state[f"raw_{lag}"]) for lag in range(min(seen, self.window), 0, -1)])
            history = np.concatenate([carried, raw])
            statistic = chart.denoiser.causal_tail(history, complete, seen - len(carried))
        if np.isnan(self.limit_value):
            limit = chart.control_limit(int(number[-1]))[number - 1] if complete else np.empty(0)
        else:
            limit = np.full(complete, self.limit_value)
        out: dict[str, np.ndarray] = {}
        for name, values in (*zip(parts, features), ("statistic", statistic), ("limit", limit)):
            column = np.full(rows, np.nan)
            column[at] = values
            out[name] = column
        out["alarm"] = np.zeros(rows, bool)
        out["alarm"][at] = statistic > limit
        # the state after every row: the last completed subgroup's smoothed values carried forward
        closes = number_of_row > 0
        last = np.maximum.accumulate(np.where(closes, np.cumsum(closes) - 1, -1)) if rows else np.zeros(0, int)
        for s, part in enumerate(parts):
            history = np.asarray([*(float(state[f"smooth_{part}_{lag}"]) for lag in range(order, 0, -1)),
                                  *smoothed[s]])                # oldest first: the carried values, then this chunk's
            for lag in range(1, order + 1):
                out[f"smooth_{part}_{lag}"] = history[last + order - lag + 1]
        if self.window:
            w = self.window
            history = np.asarray([*(float(state[f"raw_{lag}"]) for lag in range(w, 0, -1)), *raw])
            for lag in range(1, w + 1):
                out[f"raw_{lag}"] = history[last + w - lag + 1]
        return out
