"""The tuned chart of a simulated system as an MLflow pyfunc model: paper 000's monitor and chart on a residual stream.

A finished run of the main command (``python -m mosd +fault=offset_var optimizer=mopso``: CESCKF
residuals → :class:`~mosd.monitors.subgroups.SubgroupMonitor` → SS-DEWMA) leaves the part of its
pipeline after the estimator as the run's model ``detector`` (:mod:`mosd.app.detector_model` logs
it): the monitor (burn-in, subgroup size, the Phase-I μ and σ of the monitored residual channel)
and the chart with the tuned λ, K and the control limit the run's test evaluation used.

Input: the residual stream, one row per sample, one column per monitored channel named
``residual_<output>`` (``residual_x_p`` for the mould oscillator), from the start of a run (the
first ``burn_in`` rows are the filter's transient and are skipped, as in training). The estimator
is not part of the model: the CESCKF is the plant's model in code (its dynamics, inputs and noise
covariances), and a residual is what a plant's own observer, or a historian, gives; carrying the
filter would tie the model to simulated data (README, "The main command's chart as an MLflow model").

The two-sided EWMA chart (``detector=ewma``, :class:`~mosd.detectors.ewma_chart.EWMA`) is the same
model with one smoothed feature: E_k, the EWMA of U_k (order 1), plotted |E_k|; its L is stored as
``K`` (the limit width) and its limits are ``phase1``, ``asymptotic`` (constants: the run's value) and
``time_varying`` (L·σ_{E_k}, computed per k as the chart does).

Output, one row per input row: ``subgroup`` (the number k = 1, 2, ... of the subgroup this row
completes, 0 on the rows that complete none), the features ``u`` and ``v`` (U_k, V_k of eqs. 19–20;
``u`` alone for the EWMA chart), the plotted ``statistic`` and its ``limit``, ``alarm`` (statistic >
limit; False on rows that complete no subgroup), and the state after the row.

State. What the next row needs: ``samples_seen`` (rows since the stream's start: the burn-in
and the position in the current subgroup), the smoothed U and V of the last ``order`` subgroups
(``smooth_u_1``, ``smooth_u_2``, ``smooth_v_1``, ``smooth_v_2``; ``smooth_u_1`` for the EWMA chart)
and the residuals of the unfinished subgroup (``pending_1`` ... ``pending_{n-1}``; only the first ``(samples_seen - burn_in)
mod n`` count). Every output row carries it; ``predict`` takes it as params of the same names
(default: a stream's start). The recursion is the one of the run's evaluation
(:func:`mosd.detectors.statistics.ewma_time_major`: y_k = g x_k + Σ_lag f_lag y_{k−lag}, in that
order), so a stream scored in one call, chunk by chunk or row by row gives bit-identical
statistics and the run's own alarms (tests/test_chart_model.py).

Not logged (``fitted_chart_of_run`` returns None): a chart with a denoiser (the paper's wavelet
needs the whole series: no decision exists before the series ends; ``wavelet_causal`` would need
its window of past statistics as state), MS-OEWMA (its wavelet prefilter filters the whole residual
series), other detectors, other monitors.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping

import numpy as np

from ..validation import ConfigError
from . import model_state
from .model_files import read_arrays, save_arrays

STATE_FILE = "chart_detector.npz"
#: charts this model reproduces (mosd.detectors.mean_variance): class name → (order, combine)
CHARTS = ("SSDEWMA", "SSEWMA", "MDEWMA", "MaxEWMA")
#: the two-sided EWMA chart on U_k alone (mosd.detectors.ewma_chart.EWMA): the same recursion, order 1, |E_k|
EWMA_CHART = "EWMA"
#: limits that change with k (computed from the chart), the others are the run's constant limit
VARYING_LIMITS = ("theoretical", "time_varying")


def check_columns(columns, tags) -> None:
    """A missing or an extra input column is a one-line :class:`ConfigError` naming it."""
    missing = [t for t in tags if t not in columns]
    if missing:
        raise ConfigError(f"input column {missing[0]!r} is missing ({len(missing)} of the model's "
                          f"{len(tags)} inputs missing); allowed: {', '.join(tags[:5])}{', ...' if len(tags) > 5 else ''}")
    extra = [c for c in columns if c not in tags]
    if extra:
        raise ConfigError(f"input column {extra[0]!r} is not an input of the model; allowed: the model's "
                          f"{len(tags)} inputs ({', '.join(tags[:5])}{', ...' if len(tags) > 5 else ''}), in any order")


@dataclass
class FittedChart:
    """The monitor and the tuned chart of a simulated-system run (module docstring)."""

    columns: tuple[str, ...]   # input columns, one per monitored residual channel
    mean: np.ndarray           # Phase-I μ per monitored channel
    std: np.ndarray            # Phase-I σ per monitored channel
    subgroup: str              # window | channels (mosd.monitors.subgroups)
    n: int                     # subgroup size
    burn_in: int
    chart: str                 # a name of CHARTS, or EWMA_CHART
    lam: float
    K: float                   # the limit width: K_SD of the mean–variance charts, L of the EWMA chart
    limit: str                 # phase1 | theoretical | normalised; EWMA: phase1 | asymptotic | time_varying
    limit_value: float         # the constant limit (the run's evaluation's); NaN for VARYING_LIMITS
    fill: str = "none"         # no missing-value policy: a residual stream has no gaps (mosd monitor reads this)

    # -- building and storing ----------------------------------------------------------
    def _chart(self):
        if self.chart == EWMA_CHART:
            from ..detectors.ewma_chart import EWMA

            return EWMA(lam=self.lam, L=self.K, limit=self.limit)
        from ..detectors import mean_variance

        return getattr(mean_variance, self.chart)(lam=self.lam, K=self.K, limit=self.limit)

    @property
    def order(self) -> int:
        return 1 if self.chart == EWMA_CHART else int(self._chart().order)

    @property
    def parts(self) -> tuple[str, ...]:
        """The smoothed features: U and V, or U alone for the EWMA chart."""
        return ("u",) if self.chart == EWMA_CHART else ("u", "v")

    @property
    def state_names(self) -> tuple[str, ...]:
        smooth = tuple(f"smooth_{s}_{lag}" for s in self.parts for lag in range(1, self.order + 1))
        pending = tuple(f"pending_{j}" for j in range(1, self.n)) if self.subgroup == "window" else ()
        return ("samples_seen", *smooth, *pending)

    @property
    def outputs(self) -> tuple[str, ...]:
        return ("subgroup", *self.parts, "statistic", "limit", "alarm", *self.state_names)

    def initial_state(self) -> dict:
        return {name: (0 if name == "samples_seen" else 0.0) for name in self.state_names}

    def save(self, directory: str | Path) -> Path:
        meta = {k: getattr(self, k) for k in ("subgroup", "n", "burn_in", "chart", "lam", "K", "limit",
                                              "limit_value", "fill")}
        return save_arrays(Path(directory) / STATE_FILE, meta, mean=self.mean, std=self.std,
                           columns=np.array(self.columns))

    @classmethod
    def load(cls, path: str | Path) -> "FittedChart":
        arrays, meta = read_arrays(path, STATE_FILE)
        return cls(columns=tuple(str(c) for c in arrays.pop("columns")), **arrays, **meta)

    # -- scoring ------------------------------------------------------------------------
    def rows(self, frame) -> np.ndarray:
        """The input columns of ``frame`` (any order) as floats (n, c); a non-number is a one-line error."""
        import pandas as pd

        columns = [str(c) for c in frame.columns]
        check_columns(columns, self.columns)
        frame = frame.set_axis(columns, axis=1)
        X = np.empty((len(frame), len(self.columns)))
        for j, name in enumerate(self.columns):
            X[:, j] = pd.to_numeric(frame[name], errors="coerce").to_numpy(dtype=float, na_value=np.nan)
            bad = ~np.isfinite(X[:, j])
            if bad.any():
                row = int(np.argmax(bad))
                raise ConfigError(f"input column {name!r} row {row} is {frame[name].iloc[row]!r}, not a finite "
                                  f"number; allowed: residuals as numbers (the chart has no policy for a gap)")
        return X

    def score(self, X: np.ndarray, state: Mapping | None = None) -> dict[str, np.ndarray]:
        """Per row of X (rows, channels in the model's order): subgroup, features, statistic, limit, alarm, state."""
        state = model_state.checked_state(self, state)  # declared domains (mosd.app.model_state)
        chart = self._chart()
        X = np.asarray(X, float).reshape(-1, len(self.columns))
        rows, n, order, parts = len(X), int(self.n), self.order, self.parts
        seen = int(state["samples_seen"])
        if seen < 0:
            raise ConfigError(f"samples_seen={seen} is out of range; allowed: integers >= 0")
        after = seen + np.arange(rows) - self.burn_in          # sample index past the burn-in (< 0: in it)
        live = after >= 0
        done_before = max(seen - self.burn_in, 0)               # post-burn-in samples before this call
        if self.subgroup == "window":
            held = done_before % n                              # samples of the unfinished subgroup carried in
            pending = np.array([float(state[f"pending_{j}"]) for j in range(1, n)])[:held]
            raw = np.concatenate([pending, X[live, 0]])         # post-burn-in samples from the subgroup's start
            first = (done_before - held) // n                   # subgroups completed before this call
            complete = len(raw) // n
            z = ((raw[:complete * n, None] - self.mean) / self.std)[:, 0].reshape(complete, n)
            closes = live & ((after + 1) % n == 0)
        else:
            first, z = done_before, (X[live] - self.mean) / self.std
            complete = len(z)
            closes = live
        features = chart.features(z[None])[0] if complete else np.empty((len(parts), 0))   # (parts, k): U_k, V_k
        gain, feedback = chart_coefficients(chart)
        smoothed = np.empty_like(features)
        for s, name in enumerate(parts):
            past = [float(state[f"smooth_{name}_{lag}"]) for lag in range(1, order + 1)]
            series = features[s]
            out = smoothed[s]
            for k in range(complete):
                # mosd.kernels.ewma / statistics._ewma_time_major_numpy: the same operations in the same order
                y = gain * float(series[k])
                for lag in range(order):
                    y += past[lag] * feedback[lag]
                past = [y, *past[:-1]]
                out[k] = y
        number = first + np.arange(1, complete + 1)             # k of each completed subgroup
        if not complete:
            statistic = np.empty(0)
        elif self.chart == EWMA_CHART:
            statistic = np.abs(smoothed[0])                     # EWMA.raw_statistic
        else:
            statistic = chart._combine(smoothed, axis=0)
        if self.limit == "normalised" and complete:
            statistic = statistic / chart._scale(int(number[-1]))[number - 1]
        if self.limit in VARYING_LIMITS:
            limit = chart.control_limit(int(number[-1]))[number - 1] if complete else np.empty(0)
        else:
            limit = np.full(complete, self.limit_value)
        out: dict[str, np.ndarray] = {}
        at = np.flatnonzero(closes)
        subgroup = np.zeros(rows, np.int64)
        subgroup[at] = number
        out["subgroup"] = subgroup
        for name, values in (*zip(parts, features), ("statistic", statistic), ("limit", limit)):
            column = np.full(rows, np.nan)
            column[at] = values
            out[name] = column
        alarm = np.zeros(rows, bool)
        alarm[at] = statistic > limit
        out["alarm"] = alarm
        # the state after every row: the last completed subgroup's smoothed values carried forward
        out["samples_seen"] = seen + np.arange(1, rows + 1, dtype=np.int64)
        last = np.maximum.accumulate(np.where(closes, np.cumsum(closes) - 1, -1)) if rows else np.zeros(0, int)
        for s, name in enumerate(parts):
            history = [*(float(state[f"smooth_{name}_{lag}"]) for lag in range(order, 0, -1)), *smoothed[s]]
            history = np.asarray(history)                     # oldest first: the carried values, then this call's
            for lag in range(1, order + 1):
                out[f"smooth_{name}_{lag}"] = history[last + order - lag + 1]
        if self.subgroup == "window":
            position = np.where(live, after % n, -1)            # index of the row's sample in its subgroup
            base = done_before - held                           # post-burn-in index of raw[0]
            for j in range(1, n):
                source = after - position + (j - 1) - base      # raw index of the subgroup's j-th sample
                valid = live & (position < n - 1) & (j - 1 <= position)
                column = np.zeros(rows)
                column[valid] = raw[source[valid]]
                out[f"pending_{j}"] = column
        return out

    def predict_frame(self, frame, state: Mapping | None = None):
        """``score`` of a DataFrame's rows as a DataFrame (columns: :attr:`outputs`)."""
        import pandas as pd

        out = self.score(self.rows(frame), state)
        return pd.DataFrame({k: out[k] for k in self.outputs}, index=frame.index)

    def example(self):
        """An input example: the Phase-I mean residual, one subgroup's worth of rows."""
        import pandas as pd

        return pd.DataFrame(np.tile(self.mean, (max(self.n, 2), 1)), columns=list(self.columns))


def chart_coefficients(chart) -> tuple[float, list[float]]:
    """Gain λ^order and feedback f_1..f_order of the chart's recursion, as the evaluation computes them."""
    from ..detectors.statistics import ewma_coefficients

    gain, feedback = ewma_coefficients([chart.lam], getattr(chart, "order", 1))  # the EWMA chart: order 1
    return float(gain[0]), [float(f) for f in feedback[0]]


def fitted_chart_of_run(setup, result) -> FittedChart | None:
    """The run's monitor and chart, or None where no chart model is logged (module docstring)."""
    from ..denoisers.base import NoDenoiser
    from ..monitors.subgroups import SubgroupMonitor

    from ..detectors.ewma_chart import EWMA

    detector, monitor = result.detector, setup.experiment.monitor
    mean_variance = type(detector).__name__ in CHARTS and type(detector).__module__ == "mosd.detectors.mean_variance"
    if (not (mean_variance or type(detector) is EWMA)   # MS-OEWMA's prefilter is another whole-series filter
            or not isinstance(detector.denoiser, NoDenoiser) or type(monitor) is not SubgroupMonitor
            or not hasattr(monitor, "std_")):
        return None
    limit_value = math.nan
    if detector.limit not in VARYING_LIMITS:
        ucl = np.asarray(result.example["ucl"], float)
        if not np.all(ucl == ucl[0]):
            return None
        limit_value = float(ucl[0])
    names = tuple(getattr(setup.experiment.plant, "output_names", ()) or ())
    columns = tuple(f"residual_{names[c]}" if c < len(names) else f"residual_{c}" for c in monitor.channels)
    return FittedChart(columns=columns, mean=np.asarray(monitor.mean_, float), std=np.asarray(monitor.std_, float),
                       subgroup=str(monitor.subgroup), n=int(monitor.subgroup_size), burn_in=int(monitor.burn_in),
                       chart=type(detector).__name__, lam=float(detector.lam),
                       K=float(detector.L if type(detector) is EWMA else detector.K),
                       limit=str(detector.limit), limit_value=limit_value)
