"""Paper 003's Table 2 and Figs. 6–8 as ours: observer windows N against ramp rates (plain dicts and arrays).

Wang et al. 2020 (paper 003) §2.2: ramp faults of 0.1 … 1.0 m/s are injected
into the GPS altitude at step 500 (100 s at 5 Hz) and observers of windows
N = 1 … 15 are compared by their mean detection step and detection rate
(Table 2), per ramp rate (Fig. 8); Fig. 7 shows the residual and the adaptive
threshold of N = 1 and of a multi-step observer; Fig. 6 the training loss.

:class:`Study` runs all of it on simulated flights of
:class:`~mosd.plants.flapping_wing.FlappingWingMAV`: one set of fault-free
training flights (seed stream ``"estimator"``) trains one observer per N;
the same test flights (stream ``"test"``) are replayed with every ramp rate
(the fault is injected into the log only, so the flights themselves do not
depend on the rate) and decided on by the adaptive-χ² detector for both
readings of the χ² statistic (``"observer_chi2"`` and the filter's ``"chi2"``).

Definitions (the paper does not define its two numbers; issue 20):

* detection step — the step that completes the first run of ``confirm`` (k)
  consecutive alarms starting at or after the onset, among the runs that have
  one (a run without is a miss). A single chance alarm cannot satisfy it: at
  the paper's tolerated rate α = 0.01 per independent point, a run of k = 3
  chance alarms within the 500 post-onset points has probability
  ≈ 500·α³ = 5·10⁻⁴ < α (k = 2 would give 0.05 > α): :data:`CONFIRM`;
* detection rate — the share of post-onset points that alarm (the point-wise
  fault detection rate), averaged over runs;
* run detection share — the share of runs with a detection (as above);
* false-alarm rate — the share of pre-onset points (after the first N) that alarm;
* the fault-free flights' first-alarm law (:func:`first_alarm_law`) — the
  points to the first single alarm, beside its geometric law at the measured
  per-point rate: what a detection step counting single alarms would measure
  without any fault.
"""
from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
from scipy import stats

from ..detectors.base import persistent
from ..faults.ramp import RampFault
from ..faults.sensor import sensor_fault_signals
from ..scenario import training_rng
from ..validation import ConfigError, Interval, check_in, check_int
from . import base, cli
from .base import TUNED, decorate, design_params, figure, prefixed

SYSTEM = "paper003"
STATISTICS = ("observer_chi2", "chi2")


#: k, consecutive alarms that make a detection (module docstring: 500·α^k < α at α = 0.01 needs k = 3)
CONFIRM = 3
#: the rule that does not build "N = 1 never detects" in (issue 30): a constant threshold T_D(α = KOFM_ALPHA),
#: no adaptive term, and a detection when KOFM_K of KOFM_M consecutive points at or after the onset alarm.
#: Under independent chance alarms at α = 0.01 a flight of 500 points holds such a window with probability
#: at most 500·C(8, 3)·α³ ≈ 0.03; unlike k = 3 in a row under the lagged adaptive threshold, it asks the
#: statistic to stay above a fixed level, not to keep rising.
KOFM_ALPHA, KOFM_K, KOFM_M = 0.01, 3, 8
#: the readings by number (docs/systems/paper003.md): 1 the filter's innovation χ², 2 the observer's residual
READINGS = {1: "chi2", 2: "observer_chi2"}
#: the second monitor output the studies hand the detector: E_k in units of the observer's N-step σ
SCALED_RESIDUAL = "observer_residual_scaled"


def detection_summary(decision: np.ndarray, onset_step: int, first_valid: int = 0,
                      confirm: int = 1) -> dict[str, np.ndarray]:
    """Per-design numbers of decisions (P, R, K) or (R, K) (module docstring for the definitions).

    Returns arrays over the leading design axis (scalars for (R, K)):
    ``detection_step`` (mean over detecting runs, NaN if none; absolute step),
    ``detection_rate``, ``run_detection_share``, ``false_alarm_rate`` and
    ``first_alarm`` (R,) per run: the step completing the first run of ``confirm``
    consecutive alarms that starts at or after the onset, -1 for a miss.
    """
    alarm = np.asarray(decision) > 0
    confirm = check_int("confirm", confirm, 1)
    complete = onset_step + confirm - 1  # the earliest step a run starting at the onset completes
    confirmed = persistent(alarm.reshape((-1,) + alarm.shape[-1:]), confirm).reshape(alarm.shape)[..., complete:]
    detected = confirmed.any(-1)
    first = np.where(detected, complete + confirmed.argmax(-1), -1)
    count = detected.sum(-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean_step = np.where(count > 0, np.where(detected, first, 0).sum(-1) / count, np.nan)
    return {"detection_step": mean_step, "detection_rate": alarm[..., onset_step:].mean((-1, -2)),
            "run_detection_share": detected.mean(-1),
            "false_alarm_rate": alarm[..., first_valid:onset_step].mean((-1, -2)), "first_alarm": first}


def k_of_m_detection(alarm: np.ndarray, start: int, k: int = KOFM_K, m: int = KOFM_M) -> dict[str, np.ndarray]:
    """Per flight: is there a window of ``m`` consecutive points from ``start`` on with ``k`` alarms, and where.

    ``alarm`` (R, K) booleans; alarms before ``start`` are ignored (the onset, or the first
    valid point of a fault-free flight). Returns ``detected`` (R,) and ``step`` (R,): the
    step completing the first such window (the k-th alarm in it), -1 where none.
    """
    a = np.asarray(alarm, bool).copy()
    a[..., :start] = False
    count = np.cumsum(a, axis=-1)
    window = count - np.concatenate([np.zeros(a.shape[:-1] + (m,), int), count[..., :-m]], axis=-1)
    hit = window >= k
    detected = hit.any(-1)
    return {"detected": detected, "step": np.where(detected, hit.argmax(-1), -1)}


def first_alarm_law(decision: np.ndarray, first_valid: int = 0, max_cells: int = 6) -> dict[str, float]:
    """The fault-free flights' first-alarm law beside the geometric law at their measured per-point rate.

    With alarms independent at rate p per point, the number of points W from the
    first valid point to the first alarm (inclusive) is geometric, P(W = j) =
    p(1 − p)^{j−1}, censored at the record's n points (P(no alarm) = (1 − p)^n).
    ``decision`` (R, K) are fault-free flights' single-point decisions.

    Returns
    -------
    dict
        ``rate`` p (all points from ``first_valid``), ``alarm_share`` (flights that
        alarm) and ``geometric_share`` (1 − (1 − p)^n), ``step_mean`` (mean W over
        the flights that alarm) and ``geometric_step_mean`` (E[W | W ≤ n]), and
        ``p_value``: Pearson's χ² test of the observed W against the censored
        geometric law, in cells of equal geometric probability plus the censored
        cell (at most ``max_cells``, at least 5 expected flights each; the censored
        flights join the last cell when fewer than 5 are expected; NaN when fewer
        than 3 cells fit). p comes from every point, not from the first alarms, so
        no degree of freedom is taken off: under independent alarms the test holds
        its level (5.3 % rejections at 5 % over 300 sets of 20 or 100 flights).
    """
    alarm = np.asarray(decision)[..., first_valid:] > 0
    n_runs, n = alarm.shape
    p = float(alarm.mean())
    hit = alarm.any(-1)
    wait = np.where(hit, alarm.argmax(-1) + 1, n + 1)  # n + 1: censored
    j = np.arange(1, n + 1)
    pmf = p * (1.0 - p) ** (j - 1)
    share = float(1.0 - (1.0 - p) ** n)
    out = {"rate": p, "alarm_share": float(hit.mean()), "geometric_share": share,
           "step_mean": float(wait[hit].mean()) if hit.any() else math.nan,
           "geometric_step_mean": float((j * pmf).sum() / pmf.sum()) if p > 0 else math.nan, "p_value": math.nan}
    censored = n_runs * (1.0 - share) >= 5  # the censored cell stands alone only with 5 expected flights
    cells = min(max_cells - int(censored), int(n_runs * share // 5))  # alarm cells, 5 expected flights each
    if p <= 0 or cells < 1:
        return out
    cdf = np.cumsum(pmf)
    edges = np.searchsorted(cdf, share * np.arange(1, cells) / cells) + 1  # first W of each further cell
    bounds = np.r_[1, edges, n + 1] if censored else np.r_[1, edges]
    top = n + 2  # the last cell runs to the censored value n + 1 unless that has a cell of its own
    probability = np.diff(np.r_[np.r_[0.0, cdf][bounds - 1], 1.0])
    observed = np.histogram(wait, bins=np.r_[bounds, top])[0]
    expected = probability * n_runs
    if expected.size >= 3 and np.all(expected >= 5):
        out["p_value"] = float(stats.chisquare(observed, expected * observed.sum() / expected.sum()).pvalue)
    return out


def relative_range(threshold: np.ndarray, base_threshold: float) -> float:
    """Median over flights of (max − min)/T_D of a threshold T_k (R, K) (NaN points ignored)."""
    t = np.asarray(threshold, float)
    seen = np.isfinite(t).any(-1)
    if not seen.any() or base_threshold <= 0:
        return math.nan
    t = t[seen]
    return float(np.median((np.nanmax(t, -1) - np.nanmin(t, -1)) / base_threshold))


def speedup(step_n1: float, step_best: float) -> float:
    """How much sooner the best window detects: step(N = 1)/step(best) − 1 (paper: 134/16 − 1 = 737.5 %)."""
    return float(step_n1) / float(step_best) - 1.0


def rate_gain(rate_n1: float, rate_best: float) -> float:
    """The detection rate's relative gain: rate(best)/rate(N = 1) − 1 (paper: 65.5/33.4 − 1 = 96.1 %)."""
    return float(rate_best) / float(rate_n1) - 1.0


# ------------------------------------------------------------------------------------
# the study of the +experiment=paper003 preset, and its report command
# ------------------------------------------------------------------------------------
#: the study's default windows (six trainings: about 1.5 min cold on 2 cores); the report command's: 1 … 15
STUDY_WINDOWS = (1, 2, 4, 8, 12, 15)
FULL_WINDOWS = tuple(range(1, 16))
RATES = tuple(float(r) for r in np.round(np.arange(1, 11) / 10, 1))
#: the other reading's metric prefix, by the statistic the preset's monitor tests
READING_PREFIX = {"observer_chi2": "observer_", "chi2": "innovation_"}


def with_fault(trace, fault):
    """A fault-free flight log with ``fault`` added to its channel, as the plant injects a log fault.

    The flapping-wing plant adds a sensor fault to the log after the flight
    (:func:`mosd.faults.sensor_fault_signals`, called here too), so every ramp
    rate can replay the same flights (common random numbers) without simulating
    them again; ``tests/test_studies.py`` checks this equals simulating the
    plant with the fault. The replications' own generators are gone by now: a
    fault whose signal draws random numbers (a variance fault) would get fresh
    ones, so the ramp faults of this study (which draw nothing) are what it replays.
    """
    rngs = [np.random.default_rng([0, r]) for r in range(trace.y.shape[0])]
    g, mask = sensor_fault_signals(fault, trace.t, rngs, trace.y.shape[-1])
    return replace(trace, y=trace.y + g, fault_mask=mask)


#: how the figures name the two statistics
STATISTIC_NAMES = {"observer_chi2": "observer's χ² (reading 2)",
                   "chi2": "filter's innovation χ² (reading 1)"}


class Study(base.Study):
    """Paper 003's Table 2 and Figs. 6–8 for a tuned adaptive-χ² design, windows N against ramp rates.

    One observer per window N is trained like the experiment's (the same
    fault-free flights of the ``estimator`` stream, the same generator: the
    experiment's own window is a cache hit). ``n_runs`` flights of the ``test``
    stream are replayed with every ramp rate (the fault is in the log only)
    and once fault-free. The tuned detector (``result.detector``) and the
    paper's (α = 0.01, a = b = 1; metrics prefixed ``paper_``) decide on both
    readings of the χ² statistic (docs/systems/paper003.md); the unprefixed
    metrics use the reading of the experiment's monitor, the other reading's
    carry its prefix (``innovation_`` for the filter's χ², ``observer_`` for
    the observer's standardised residual).

    Parameters
    ----------
    windows : sequence of int
        Observer windows N, distinct integers in [1, 100], including 1.
        Default (1, 2, 4, 8, 12, 15): six trainings, about 1.5 min cold on 2
        cores (seconds once cached); the report command runs 1 … 15.
    rates : sequence of float
        Ramp rates in m/s (the paper: 0.1 … 1.0), non-zero in [-100, 100].
    n_runs : int
        Test flights per rate (the paper's full scale: 20).
    trace_rate : float
        The rate whose first flight Fig. 7 shows (one of ``rates``).
    confirm : int
        k, consecutive alarms that make a detection (default :data:`CONFIRM` = 3,
        module docstring), 1..100; 1 is the former first-alarm definition.
    figures : bool
        Write the PNG figures into ``out_dir``.

    Notes
    -----
    ``detection_step_n1`` / ``detection_step_best``: steps from the onset to
    the step completing the first run of k consecutive alarms that starts at or
    after it, mean over the detecting flights, then over the rates (the paper's
    Table 2 counts absolute steps: 634 for N = 1 is 134 after the onset at
    500); ``best_window``: the N with the smallest;
    ``detection_rate_*``: share of post-onset points that alarm, mean over
    rates; the best window minimises the censored step (a flight that never
    alarms after the onset counts as the whole faulty horizon), not the step
    over detecting flights alone; ``run_detection_share_n1`` / ``_best``: flights
    with a detection, mean over rates; ``far`` / ``far_n1``: share of the fault-free flights' points (after
    the first N) that alarm, for the best N and for N = 1;
    ``detection_step_speedup`` = :func:`speedup` (step N = 1 / best − 1) and
    ``detection_rate_gain`` = :func:`rate_gain` (rate best / N = 1 − 1).
    The fault-free flights' first-alarm law at the best N (:func:`first_alarm_law`):
    ``chance_alarm_step_mean`` (points from the first valid one to the first single
    alarm, mean over the flights that alarm; ``_n1`` for N = 1),
    ``chance_alarm_step_geometric`` (the geometric law's mean at the measured
    per-point rate), ``chance_alarm_share`` (flights with any alarm),
    ``chance_alarm_p_value`` (the χ² test against the geometric law) and
    ``chance_detection_share`` (fault-free flights with a run of k alarms: a
    false detection under the definition above).
    ``threshold_relative_range``: the median over the faulty flights (every rate)
    of (max − min)/T_D of the adaptive threshold T_k at the best N.
    ``censored_step_n1`` / ``_best``: the step after the onset with a flight that never
    detects counted as the whole faulty horizon (defined for every design), and
    ``censored_step_speedup`` = :func:`speedup` of the two: the paper's speed-up where
    ``detection_step_speedup`` is undefined (N = 1 never detects). A number undefined
    for a design (no detecting flight, no fault-free alarm) is not reported for it.
    ``base_threshold``: a·T_D(α), the threshold's constant part; with b = 0 it is
    the whole threshold, and α and a are this one number.

    The rule that does not build the window effect in (:data:`KOFM_ALPHA`,
    :data:`KOFM_K`, :data:`KOFM_M`; the same for every design, so without a design
    prefix), per reading r (1: the filter's innovation χ², 2: the observer's
    residual) and window N, mean over the rates: ``kofm_reading{r}_detected_n{N}``
    (flights with k of m alarms at or after the onset), ``kofm_reading{r}_step_n{N}``
    (the step completing the first such window, after the onset, over the detecting
    flights), ``kofm_reading{r}_point_rate_n{N}`` (post-onset points above T_D) and
    ``kofm_reading{r}_chance_detected_n{N}`` (fault-free flights with such a window
    after the first N points: false detections).
    """

    system = SYSTEM

    def __init__(self, windows=STUDY_WINDOWS, rates=RATES, n_runs: int = 20, trace_rate: float = 0.1,
                 confirm: int = CONFIRM, figures: bool = True):
        super().__init__(figures=figures)
        self.confirm = check_int("study.confirm", confirm, 1, 100)
        if isinstance(windows, (str, bytes)) or not hasattr(windows, "__len__") or not len(windows):
            raise ConfigError(f"study.windows={windows!r} is not allowed; allowed: a list of integers in [1, 100] "
                              f"including 1")
        self.windows = tuple(check_int("study.windows", w, 1, 100) for w in windows)
        if 1 not in self.windows or len(set(self.windows)) != len(self.windows):
            raise ConfigError(f"study.windows={list(windows)!r} is not allowed; allowed: distinct integers in "
                              f"[1, 100] including 1 (the classic observer)")
        if isinstance(rates, (str, bytes)) or not hasattr(rates, "__len__") or not len(rates):
            raise ConfigError(f"study.rates={rates!r} is not allowed; allowed: a list of ramp rates (m/s)")
        self.rates = tuple(float(check_in("study.rates", r, Interval(-100.0, 100.0))) for r in rates)
        if 0.0 in self.rates:
            raise ConfigError("study.rates contains 0; allowed: non-zero ramp rates in [-100, 100] m/s")
        self.n_runs = check_int("study.n_runs", n_runs, 1)
        self.trace_rate = float(trace_rate)
        if self.trace_rate not in self.rates:
            raise ConfigError(f"study.trace_rate={trace_rate!r} is not allowed; allowed: one of study.rates "
                              f"{list(self.rates)}")

    # -- computation --------------------------------------------------------------------
    def compute(self, experiment, designs: dict) -> dict:
        """Table 2 per design and reading, fault-free false alarms, Fig. 7 traces and the loss curves."""
        outputs_read = tuple(getattr(experiment.monitor, "outputs", ("observer_chi2",)))
        statistic = outputs_read[0] if outputs_read[0] in STATISTICS else "observer_chi2"
        dt = float(experiment.plant.dt)
        onset_step = int(round(experiment.fault.onset / dt))
        channel = int(getattr(experiment.fault, "channel", 0))
        training = experiment.simulate(None, experiment.budget.n_estimator, "estimator")
        clean = experiment.simulate(None, self.n_runs, "test")
        tests = {rate: with_fault(clean, RampFault(rate=rate, channel=channel, onset=experiment.fault.onset))
                 for rate in self.rates}
        shape = (len(self.windows), len(self.rates))
        keys = ("detection_step", "detection_rate", "run_detection_share", "censored_step")
        horizon = clean.y.shape[1] - onset_step  # a flight that never alarms counts as the whole faulty horizon
        table = {d: {s: {k: np.full(shape, np.nan) for k in keys} for s in STATISTICS} for d in designs}
        far = {d: {s: np.full(len(self.windows), np.nan) for s in STATISTICS} for d in designs}
        law_keys = ("rate", "alarm_share", "geometric_share", "step_mean", "geometric_step_mean", "p_value",
                    "detection_share", "threshold_range")
        law = {d: {s: {k: np.full(len(self.windows), np.nan) for k in law_keys} for s in STATISTICS} for d in designs}
        ranges = {d: {s: [[] for _ in self.windows] for s in STATISTICS} for d in designs}
        # the rule that does not build the window effect in (KOFM_*): the same for every design
        t_fixed = float(next(iter(designs.values())).chi2_threshold(KOFM_ALPHA))
        kofm_keys = ("detected", "step", "point_rate")
        kofm = {s: {k: np.full(shape, np.nan) for k in kofm_keys} for s in STATISTICS}
        kofm_chance = {s: np.full(len(self.windows), np.nan) for s in STATISTICS}
        traces, loss, sigma = {}, {}, {}
        for i, window in enumerate(self.windows):
            estimator = experiment.estimator
            if getattr(estimator, "window", None) != window or not hasattr(estimator, "params_"):
                # an untrained observer like the experiment's (same network, training and filter settings)
                # of window N, trained with the experiment's generator: its own window is the same network
                estimator = experiment.estimator.with_params(window=window)
                estimator.fit(training, experiment.model, training_rng(experiment.seed))
            loss[window] = {k: np.asarray(v, float) for k, v in estimator.history_.items()}
            sigma[window] = float(estimator.residual_std_)
            free = estimator.estimate(clean, experiment.model)
            for j, rate in enumerate(self.rates):
                outputs = estimator.estimate(tests[rate], experiment.model)
                for s in STATISTICS:
                    alarm = np.asarray(outputs.extra[s], float) > t_fixed
                    found = k_of_m_detection(alarm, onset_step)
                    kofm[s]["detected"][i, j] = float(found["detected"].mean())
                    if found["detected"].any():
                        kofm[s]["step"][i, j] = float(found["step"][found["detected"]].mean()) - onset_step
                    kofm[s]["point_rate"][i, j] = float(alarm[:, onset_step:].mean())
                for name, detector in designs.items():
                    for s in STATISTICS:
                        z = np.stack([outputs.extra[s], outputs.extra[SCALED_RESIDUAL]], -1)
                        decided = detector.decide(z, z)
                        summary = detection_summary(decided.decision, onset_step, first_valid=window,
                                                    confirm=self.confirm)
                        t_d = float(detector.chi2_threshold(detector.alpha))
                        threshold = np.broadcast_to(decided.threshold, decided.statistic.shape)
                        ranges[name][s][i].append(relative_range(threshold[:, window:], t_d))
                        first = summary["first_alarm"]
                        summary["censored_step"] = float(np.mean(np.where(first >= 0, first, onset_step + horizon)))
                        for k in keys:
                            table[name][s][k][i, j] = summary[k] - (onset_step if k == "detection_step" else 0)
                        if rate == self.trace_rate:
                            traces[(name, s, window)] = {
                                "observer_residual": outputs.extra["observer_residual"][0],
                                "statistic": decided.statistic[0],
                                "threshold": np.broadcast_to(decided.threshold, decided.statistic.shape)[0],
                                "first_alarm": int(summary["first_alarm"][0])}
            for s in STATISTICS:
                chance = k_of_m_detection(np.asarray(free.extra[s], float) > t_fixed, window)
                kofm_chance[s][i] = float(chance["detected"].mean())
            for name, detector in designs.items():
                for s in STATISTICS:
                    z = np.stack([free.extra[s], free.extra[SCALED_RESIDUAL]], -1)
                    decision = detector.decide(z, z).decision
                    far[name][s][i] = float(np.mean(decision[:, window:] != 0))
                    for k, v in first_alarm_law(decision, first_valid=window).items():
                        law[name][s][k][i] = v
                    confirmed = persistent(decision[None, :, window:] != 0, self.confirm)[0]
                    law[name][s]["detection_share"][i] = float(confirmed.any(-1).mean())
                    law[name][s]["threshold_range"][i] = float(np.median(ranges[name][s][i]))
        return {"windows": self.windows, "rates": self.rates, "n_runs": self.n_runs, "onset_step": onset_step,
                "dt": dt, "statistic": statistic, "table": table, "far": far, "law": law, "confirm": self.confirm,
                "traces": traces, "loss": loss, "sigma": sigma, "trace_rate": self.trace_rate,
                "kofm": kofm, "kofm_chance": kofm_chance, "kofm_threshold": t_fixed,
                "base_threshold": {name: float(d.a * d.chi2_threshold(d.alpha)) for name, d in designs.items()},
                "params": {name: design_params(d) for name, d in designs.items()}}

    @staticmethod
    def _over_rates(values: np.ndarray) -> np.ndarray:
        """Mean over the rates (axis 1) of the finite entries (NaN where no rate detected anything)."""
        seen = np.isfinite(values)
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(seen.any(1), np.where(seen, values, 0.0).sum(1) / np.maximum(seen.sum(1), 1), np.nan)

    @classmethod
    def summary(cls, data: dict, design: str, statistic: str) -> dict[str, float]:
        """The headline numbers of one design and reading (class docstring)."""
        t = data["table"][design][statistic]
        step = cls._over_rates(t["detection_step"])
        rate = cls._over_rates(t["detection_rate"])
        share = cls._over_rates(t["run_detection_share"])
        far = data["far"][design][statistic]
        i1 = data["windows"].index(1)
        # the best window by the censored step, so that a window whose few detecting flights alarm early by
        # chance (a high threshold) does not win over one that detects every flight
        best = int(np.argmin(cls._over_rates(t["censored_step"])))
        law = data["law"][design][statistic]
        censored = cls._over_rates(t["censored_step"]) - data["onset_step"]
        numbers = {"detection_step_n1": float(step[i1]), "detection_step_best": float(step[best]),
                   "censored_step_n1": float(censored[i1]), "censored_step_best": float(censored[best]),
                   "best_window": float(data["windows"][best]), "detection_rate_n1": float(rate[i1]),
                   "detection_rate_best": float(rate[best]), "far": float(far[best]), "far_n1": float(far[i1]),
                   "run_detection_share_n1": float(share[i1]), "run_detection_share_best": float(share[best]),
                   "detection_step_speedup": speedup(step[i1], step[best]) if step[best] > 0 else math.nan,
                   "censored_step_speedup": speedup(censored[i1], censored[best]) if censored[best] > 0 else math.nan,
                   "detection_rate_gain": rate_gain(rate[i1], rate[best]) if rate[i1] > 0 else math.nan,
                   "chance_alarm_step_mean": float(law["step_mean"][best]),
                   "chance_alarm_step_mean_n1": float(law["step_mean"][i1]),
                   "chance_alarm_step_geometric": float(law["geometric_step_mean"][best]),
                   "chance_alarm_share": float(law["alarm_share"][best]),
                   "chance_alarm_p_value": float(law["p_value"][best]),
                   "chance_detection_share": float(law["detection_share"][best]),
                   "threshold_relative_range": float(law["threshold_range"][best])}
        # a number undefined for this design (no detecting flight at N = 1, no fault-free alarm) is left out
        return {k: v for k, v in numbers.items() if math.isfinite(v)}

    def metrics(self, data: dict) -> dict[str, float]:
        """The study's metrics by name (class docstring)."""
        out = {}
        preset = data["statistic"]
        other = next(s for s in STATISTICS if s != preset)
        for design in data["table"]:
            prefix = prefixed(design)
            out.update({prefix + k: v for k, v in self.summary(data, design, preset).items()})
            out.update({prefix + READING_PREFIX[other] + k: v for k, v in self.summary(data, design, other).items()})
            out[prefix + "base_threshold"] = data["base_threshold"][design]
        for reading, s in READINGS.items():
            for i, window in enumerate(data["windows"]):
                cells = {"detected": self._over_rates(data["kofm"][s]["detected"])[i],
                         "step": self._over_rates(data["kofm"][s]["step"])[i],
                         "point_rate": self._over_rates(data["kofm"][s]["point_rate"])[i],
                         "chance_detected": data["kofm_chance"][s][i]}
                out.update({f"kofm_reading{reading}_{k}_n{window}": float(v) for k, v in cells.items()
                            if math.isfinite(v)})
        return out

    # -- figures --------------------------------------------------------------------------
    def write_figures(self, data: dict, out_dir: Path) -> list[Path]:
        """Table 2 (step and rate against N), Fig. 8 (per rate), Fig. 7 (residual vs threshold), Fig. 6 (loss)."""
        return self.draw_figure_jobs(data, out_dir)

    def figure_jobs(self, data: dict, out_dir: Path) -> list[tuple[str, dict]]:
        """The four figures of :meth:`write_figures`, each a job of its own (drawn side by side where the app has
        the cores)."""
        path = Path(out_dir) / f"{self.system}_"
        return [(method, {"data": data, "path": Path(f"{path}{name}.png")}) for method, name in (
            ("_table2_figure", "table2"), ("_detection_point_figure", "detection_point"),
            ("_residual_threshold_figure", "residual_threshold"), ("_training_loss_figure", "training_loss"))]

    def _table2_figure(self, data: dict, path: Path) -> Path:
        windows, rates = data["windows"], data["rates"]
        fig = figure(9.0, 3.4)
        ax, bx = fig.subplots(1, 2)
        for design, ls in (("tuned", "-"), ("paper", "--")):
            for s, color in (("observer_chi2", "tab:blue"), ("chi2", "tab:orange")):
                if design not in data["table"]:
                    continue
                t = data["table"][design][s]
                label = f"{design}, {STATISTIC_NAMES[s]}"
                ax.plot(windows, self._over_rates(t["detection_step"]), ls=ls, color=color, marker="o", label=label)
                bx.plot(windows, 100 * self._over_rates(t["detection_rate"]), ls=ls, color=color, marker="o",
                        label=label)
        ax.set_xlabel("window N")
        ax.set_ylabel("detection step after the onset")
        ax.set_title(f"Table 2: mean over rates {rates[0]:g}…{rates[-1]:g} m/s", fontsize=10)
        bx.set_xlabel("window N")
        bx.set_ylabel("post-onset points alarmed (%)")
        bx.set_title("Table 2: detection rate", fontsize=10)
        for a in (ax, bx):
            a.grid(alpha=0.3)
        bx.legend(fontsize=7)
        fig.savefig(path, dpi=110)
        return path

    @staticmethod
    def _detection_point_figure(data: dict, path: Path) -> Path:
        windows, rates, s0 = data["windows"], data["rates"], data["statistic"]
        fig = figure(6.5, 3.6)
        ax = fig.add_subplot()
        steps = data["table"]["tuned"][s0]["detection_step"]
        colors = _colormap(len(rates))
        for j, rate in enumerate(rates):
            ax.plot(windows, data["onset_step"] + steps[:, j], marker=".", color=colors[j], label=f"{rate:g} m/s")
        ax.axhline(data["onset_step"], color="grey", ls=":", lw=0.8)
        ax.set_xlabel("window N")
        ax.set_ylabel("mean detection step")
        ax.set_title(f"Fig. 8: detection point per ramp rate (tuned design, {STATISTIC_NAMES[s0]})", fontsize=9)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, ncol=2)
        fig.savefig(path, dpi=110)
        return path

    def _residual_threshold_figure(self, data: dict, path: Path) -> Path:
        s0 = data["statistic"]
        best = int(self.summary(data, "tuned", s0)["best_window"])
        fig = figure(9.0, 5.0)
        axes = fig.subplots(2, 1, sharex=True)
        lo, hi = max(data["onset_step"] - 60, 0), data["onset_step"] + 120
        for ax, window in zip(axes, (1, best)):
            tr = data["traces"][("tuned", s0, window)]
            k = np.arange(tr["statistic"].size)
            ax.plot(k[lo:hi], tr["statistic"][lo:hi], lw=0.9, label=f"statistic ({STATISTIC_NAMES[s0]})")
            ax.plot(k[lo:hi], tr["threshold"][lo:hi], lw=0.9, color="r", label="adaptive threshold a·T_D + b·(E_{k−d}/σ_N)²")
            ax.axvline(data["onset_step"], color="grey", ls=":", lw=0.8)
            if tr["first_alarm"] >= 0:
                ax.axvline(tr["first_alarm"], color="k", ls="--", lw=0.8, label=f"first alarm, step {tr['first_alarm']}")
            ax.set_yscale("symlog", linthresh=1.0)
            ax.set_ylim(bottom=0.0)
            ax.set_title(f"Fig. 7: N = {window}, ramp {data['trace_rate']:g} m/s, one flight (tuned design)",
                         fontsize=9)
            ax.set_ylabel("χ² value")
            ax.grid(alpha=0.3)
            ax.legend(fontsize=7, loc="upper left")
        axes[-1].set_xlabel("log step")
        fig.savefig(path, dpi=110)
        return path

    def _training_loss_figure(self, data: dict, path: Path) -> Path:
        best = int(self.summary(data, "tuned", data["statistic"])["best_window"])
        fig = figure(6.5, 3.4)
        ax = fig.add_subplot()
        for window, color in zip(sorted({1, best, data["windows"][-1]}), ("tab:blue", "tab:green", "tab:red")):
            curves = data["loss"][window]
            ax.plot(curves["train_loss"], color=color, label=f"N = {window}, training")
            ax.plot(curves["validation_loss"], color=color, ls="--", label=f"N = {window}, validation")
        ax.set_yscale("log")
        decorate(ax, "epoch", "weighted multi-step loss (standardised)",
                 "Fig. 6: training loss (early stopping, patience 10)", legend_size=7)
        fig.savefig(path, dpi=110)
        return path


def _colormap(n: int) -> list:
    from matplotlib import colormaps

    cmap = colormaps["viridis"]
    return [cmap(i / max(n - 1, 1)) for i in range(n)]


def format_report(data: dict) -> str:
    """Table 2 per design and reading as markdown (steps after the onset and absolute)."""
    lines = []
    onset = data["onset_step"]
    for design in data["table"]:
        p = data["params"][design]
        for s in (data["statistic"], *(x for x in STATISTICS if x != data["statistic"])):
            t = data["table"][design][s]
            step, rate = Study._over_rates(t["detection_step"]), Study._over_rates(t["detection_rate"])
            share = Study._over_rates(t["run_detection_share"])
            lines += [f"**{design} design** (α = {p['alpha']:.4g}, a = {p['a']:.4g}, b = {p['b']:.4g}), "
                      f"statistic `{s}`{' (the preset)' if s == data['statistic'] else ''}:", "",
                      "| N | detection step after onset | mean step | detection rate | runs detected "
                      "| FAR fault-free | fault-free flights alarming (geometric) | their first alarm, points "
                      "(geometric) | p (geometric law) | fault-free flights detected | threshold range / T_D |",
                      "|---|---|---|---|---|---|---|---|---|---|---|"]
            law = data["law"][design][s]
            for i, window in enumerate(data["windows"]):
                lines.append(f"| {window} | {step[i]:.1f} | {onset + step[i]:.1f} | {100 * rate[i]:.1f} % "
                             f"| {100 * share[i]:.1f} % | {100 * data['far'][design][s][i]:.2f} % "
                             f"| {100 * law['alarm_share'][i]:.0f} % ({100 * law['geometric_share'][i]:.0f} %) "
                             f"| {law['step_mean'][i]:.1f} ({law['geometric_step_mean'][i]:.1f}) "
                             f"| {law['p_value'][i]:.3g} | {100 * law['detection_share'][i]:.0f} % "
                             f"| {law['threshold_range'][i]:.3g} |")
            lines.append("")
    lines += [f"**Rule without the adaptive term**: statistic > T_D(α = {KOFM_ALPHA:g}) = {data['kofm_threshold']:.3g}, "
              f"a detection at {KOFM_K} alarms in {KOFM_M} consecutive points at or after the onset (every design):",
              "", "| N | reading 1 (innovation): flights detected | step after onset | points above T_D "
              "| fault-free flights detected | reading 2 (observer): flights detected | step after onset "
              "| points above T_D | fault-free flights detected |", "|---|---|---|---|---|---|---|---|---|"]
    for i, window in enumerate(data["windows"]):
        cells = []
        for s in (READINGS[1], READINGS[2]):
            k = data["kofm"][s]
            cells += [f"{100 * Study._over_rates(k['detected'])[i]:.1f} %", f"{Study._over_rates(k['step'])[i]:.1f}",
                      f"{100 * Study._over_rates(k['point_rate'])[i]:.1f} %",
                      f"{100 * data['kofm_chance'][s][i]:.0f} %"]
        lines.append(f"| {window} | " + " | ".join(cells) + " |")
    lines.append("")
    return "\n".join(lines)


def parse_windows(text: str) -> tuple[int, ...]:
    """``--windows``: ``'A-B'`` (a range) or a comma list of integers."""
    try:
        if "-" in text:
            low, high = (int(v) for v in text.split("-"))
            return tuple(range(low, high + 1))
        return tuple(int(v) for v in text.split(","))
    except ValueError:
        raise ConfigError(f"--windows={text!r} is not allowed; allowed: 'A-B' or a comma list of integers, "
                          f"e.g. 1-15 or 1,4,12") from None


def main(argv=None) -> int:
    """``python -m mosd.systems.paper003 [--n-runs 20] [--windows 1-15] [--seed 0] [--out DIR]``."""
    parser = cli.report_parser("python -m mosd.systems.paper003", "Paper 003's Table 2 and Figs. 6-8 at full scale "
                               "without the optimiser: the tuned design beside the paper's (alpha 0.01, a = b = 1).",
                               out="outputs/systems/paper003")
    parser.add_argument("--n-runs", type=int, default=20, help="test flights per ramp rate (default 20)")
    parser.add_argument("--windows", default="1-15",
                        help="observer windows: 'A-B' or a comma list including 1 (default 1-15; trains one each)")
    cli.design_options(parser, SYSTEM)  # --alpha, --a, --b
    parser.add_argument("--confirm", type=int, default=CONFIRM,
                        help=f"consecutive alarms that make a detection (default {CONFIRM})")

    def body(args):
        windows = parse_windows(args.windows)
        study = Study(windows=windows, n_runs=args.n_runs, confirm=args.confirm)
        experiment = cli.preset(SYSTEM, [f"seed={args.seed}"]).experiment
        designs = {TUNED: experiment.detector.with_params(**cli.tuned_design(args, SYSTEM)),
                   **study.reference_designs(experiment, experiment.detector)}
        data, metrics, files = cli.score(study, experiment, designs, Path(args.out), windows=list(windows),
                                         rates=list(study.rates), n_runs=args.n_runs, seed=args.seed,
                                         confirm=args.confirm, observer_sigma=lambda d: d["sigma"], table=lambda d: {
                                             design: {s: {k: v.tolist() for k, v in t.items()} for s, t in by_s.items()}
                                             for design, by_s in d["table"].items()},
                                         far=lambda d: {design: {s: v.tolist() for s, v in by_s.items()}
                                                        for design, by_s in d["far"].items()},
                                         first_alarm_law=lambda d: {
                                             design: {s: {k: v.tolist() for k, v in t.items()} for s, t in by_s.items()}
                                             for design, by_s in d["law"].items()})
        print(f"## Paper 003: windows {windows[0]}..{windows[-1]}, rates {study.rates[0]:g}..{study.rates[-1]:g} m/s, "
              f"{args.n_runs} flights each, seed {args.seed}\n")
        print(format_report(data))
        print(cli.markdown_table(("metric", "value"), ((k, f"{v:.4g}") for k, v in metrics.items())) + "\n")
        return files

    return cli.run_report(parser, argv, body)


if __name__ == "__main__":
    raise SystemExit(main())
