"""Paper 002's Tables 1–2 as ours: isolation delay and error amplitude vs. the missing-data rate.

Wen, Zhang and Pan (2013) report, for 5 / 10 / 20 % missing outputs, the delay
with which the entropy-optimal filter's error shows the fault (target: 1.112 s,
2.451 s, fails at 20 %; nuisance: 1.176 s, 2.578 s, fails at 20 %) and how its
amplitude grows. The computation here (docs/systems/paper002.md, a
reconstruction) runs the reconstructed plant with the target fault on half the
runs and the nuisance fault on the other half (a FaultSet), fills missing
outputs by EM, estimates with :class:`~mosd.estimators.entropy_filter.EntropyIsolationFilter`
and the fixed-gain baseline, and decides with a
:class:`~mosd.detectors.threshold.ThresholdDetector` on |x − x̂|. Everything
returned is plain dicts, arrays and floats (the report command prints/plots them).
"""
from __future__ import annotations

import copy
import math
from pathlib import Path

import numpy as np

from ..estimators.entropy_filter import MISSING, FixedGainFilter
from ..estimators.imputation import EMImputer
from ..metrics import Estimate, detection
from ..plants.missingness import MECHANISMS
from ..scenario import Scenario
from ..validation import ConfigError, Interval, check_choice, check_in, check_int
from . import base, cli
from .base import TUNED, decorate, design_params, figure, prefixed, recorded_designs

SYSTEM = "paper002"
MISSING_RATES = (0.0, 0.05, 0.10, 0.20)
PAPER = {  # Tables 1–2 of the paper (delays in s; "fails" at 20 %)
    "target_delay": {0.05: 1.112, 0.10: 2.451, 0.20: math.nan},
    "nuisance_delay": {0.05: 1.176, 0.10: 2.578, 0.20: math.nan},
}
SETTLE = 10       # steps after the onset before the error's level is read
#: the per-rate numbers of each missingness mechanism × fill (study metrics ``{mechanism}_{fill}_{key}_r{r}``)
GRID_KEYS = ("target_run_detection", "nuisance_run_false_isolation", "target_point_detection",
             "nuisance_point_false_isolation", "delay_target_s", "error_fluct_target", "fill_rmse")
#: the amplitude laws of the sensitivity check, (target [low, high], nuisance [low, high]); the first is the
#: reconstruction's (docs/systems/paper002.md)
AMPLITUDE_LAWS = (((0.5, 1.5), (0.0, 0.6)), ((0.5, 1.5), (0.0, 0.8)), ((0.5, 1.5), (0.0, 1.0)),
                  ((0.3, 1.3), (0.0, 0.6)), ((0.7, 1.7), (0.0, 0.6)), ((0.5, 1.5), (0.0, 0.4)))


# ------------------------------------------------------------------------------------
# the study of the +experiment=paper002 preset, and its report command
# ------------------------------------------------------------------------------------
FILTER_PREFIXES = {"entropy": "", "baseline": "baseline_"}
THRESHOLD_GRID = np.round(np.arange(0.05, 3.0001, 0.01), 2)  # the threshold sweep of the ROC curves


def rate_tag(rate: float) -> str:
    """``r5`` for 5 %: the suffix of the study's per-rate metrics."""
    return f"r{int(round(100 * rate))}"


class Study(base.Study):
    """Paper 002's comparison over missing-data rates (Tables 1–2, Figs. 3–10) for a tuned design.

    For each missing rate, ``n_runs`` target-fault and ``n_runs`` nuisance-fault
    runs of the experiment's scenario (its ``FaultSet``; the plant's
    ``missing_rate`` replaced) are drawn from the ``test`` seed stream, the
    same seeds at every rate (nested missing sets). The experiment's trained
    entropy-optimal filter and the fixed-gain baseline estimate them; the tuned
    detector (``result.detector``: threshold and L) decides on both; the report
    command adds the reconstruction's fixed design (metrics prefixed ``midway_``).

    Parameters
    ----------
    n_runs : int
        Runs per fault role and rate (>= 2; the paper's figures: one run each).
    missing_rates : sequence of float
        MCAR rates of the outputs in [0, 0.9] (the paper: 0, 5, 10, 20 %).
    baseline_gain : float
        U of the fixed-gain baseline, in [-2, 2] (docs/systems/paper002.md: 0.27).
    mechanisms : sequence of {"mcar", "burst", "gap"}
        Missingness mechanisms of the grid (:mod:`mosd.plants.missingness`).
    fills : sequence of {"em", "hold", "skip"}
        Fills of a missing output in the grid (the filters' ``missing``).
    amplitude_laws : sequence of ((low, high), (low, high))
        Supports of the target's and the nuisance's amplitude laws for the sensitivity
        check (the laws' shapes kept), 0 <= low < high <= 10; empty: no check.
    burst_length : float
        Mean burst length in samples of the ``burst`` mechanism, in [1, 1000] and
        at least rate / (1 − rate) for every rate.
    figures : bool
        Write the PNG figures into ``out_dir``.

    Notes
    -----
    Metrics per rate r (suffix ``r0``, ``r5``, ``r10``, ``r20``), for the
    entropy filter and with the prefix ``baseline_`` for the fixed gain:

    * ``delay_target_s_r{r}``: mean over detected target runs of the time from
      the onset to the first alarm at or after it (s);
    * per run, the units of the paper's claim ("the target fault is isolated"):
      ``target_run_detection_r{r}``, the share of target runs with an alarm at or
      after the onset, and ``nuisance_run_false_isolation_r{r}``, the share of
      nuisance runs with an alarm at or after the nuisance onset (such a run is
      declared the target fault);
    * per point: ``target_point_detection_r{r}``, the share of target-fault
      points that alarm (1 − the point MDR), and
      ``nuisance_point_false_isolation_r{r}``, the share of the nuisance runs'
      points after the onset that alarm (what the preset's objective
      ``nuisance_alarm_rate`` counts);
    * ``error_level_target_r{r}``, ``error_level_nuisance_r{r}``: mean steady
      error x − x̂ (10 steps after the onset to the end), whose meeting is the
      paper's failure at 20 %.

    Each filter is scored at its own threshold: a design given as one detector
    (the tuned one) is the entropy filter's; the baseline gets the lowest
    threshold of :data:`THRESHOLD_GRID` (same L) whose share of alarmed nuisance
    points on ``2 n_runs`` calibration-stream runs does not exceed the entropy
    design's on the same runs (equal false isolation); ``baseline_threshold``
    records it. A design given as ``{"entropy": detector, "baseline": detector}``
    (the report's midway design) is used as given.

    Mechanism × fill grid (entropy filter, the tuned design, the same seeds):
    ``{mechanism}_{fill}_{key}_r{r}`` for key in :data:`GRID_KEYS`, where
    ``error_fluct_target`` is the mean over target runs of the sd of the error
    over the steady steps and ``fill_rmse`` the RMS of filled minus true output
    h(x_k) over the missing samples (not reported for ``skip`` and complete
    data, where nothing is filled).

    Amplitude-law sensitivity (complete data, entropy filter, the tuned design, the
    ``test`` runs drawn again with other supports of the two laws,
    :data:`AMPLITUDE_LAWS`): ``laws_{tag}_target_run_detection`` and
    ``laws_{tag}_nuisance_run_false_isolation``, ``{tag}`` =
    ``t{low}_{high}_n{low}_{high}`` in hundredths (the reconstruction's:
    ``t50_150_n0_60``).

    Separation (complete data, the tuned L, thresholds swept over
    :data:`THRESHOLD_GRID`): ``roc_auc`` and ``baseline_roc_auc`` (area under
    target point-detection against nuisance point false alarms), and
    ``equal_fa_target_detection`` / ``baseline_equal_fa_target_detection``: the
    share of target points detected at the nuisance false-alarm rate of the
    tuned design on the entropy filter (interpolated on the sweep).
    """

    system = SYSTEM

    def __init__(self, n_runs: int = 200, missing_rates=MISSING_RATES, baseline_gain: float = 0.27,
                 mechanisms=MECHANISMS, fills=MISSING, burst_length: float = 5.0, figures: bool = True,
                 amplitude_laws=AMPLITUDE_LAWS):
        super().__init__(figures=figures)
        self.amplitude_laws = _check_laws(amplitude_laws)
        self.n_runs = check_int("study.n_runs", n_runs, 2)
        if isinstance(missing_rates, (str, bytes)) or not hasattr(missing_rates, "__len__") or not len(missing_rates):
            raise ConfigError(f"study.missing_rates={missing_rates!r} is not allowed; allowed: a list of rates in "
                              f"[0, 0.9], e.g. [0.0, 0.05, 0.1, 0.2]")
        self.missing_rates = tuple(check_in("study.missing_rates", r, Interval(0.0, 0.9)) for r in missing_rates)
        if len(set(map(rate_tag, self.missing_rates))) != len(self.missing_rates):
            raise ConfigError(f"study.missing_rates={list(missing_rates)!r} repeats a rate (in whole per cent); "
                              f"allowed: distinct rates")
        self.baseline_gain = check_in("study.baseline_gain", baseline_gain, Interval(-2.0, 2.0))
        self.mechanisms = _choices("study.mechanisms", mechanisms, MECHANISMS)
        self.fills = _choices("study.fills", fills, MISSING)
        self.burst_length = check_in("study.burst_length", burst_length, Interval(1.0, 1000.0))
        if "burst" in self.mechanisms and self.burst_length < max(r / (1 - r) for r in self.missing_rates):
            raise ConfigError(f"study.burst_length={burst_length!r} is too short for the largest rate; allowed: "
                              f">= rate / (1 - rate) = {max(r / (1 - r) for r in self.missing_rates):.3g}")

    # -- computation --------------------------------------------------------------------
    def baseline(self, estimator) -> FixedGainFilter:
        """The fixed-gain filter with the entropy filter's handling of missing outputs."""
        return FixedGainFilter(gain=self.baseline_gain, missing=getattr(estimator, "missing", "em"),
                               em_half_width=getattr(estimator, "em_half_width", 1))

    def own_thresholds(self, experiment, designs: dict) -> dict[str, dict]:
        """Each design as ``{filter: detector}``: the baseline at its own threshold (class docstring)."""
        filters = {"entropy": experiment.estimator, "baseline": self.baseline(experiment.estimator)}
        out, points = {}, {}
        for design, detector in designs.items():
            if isinstance(detector, dict):
                out[design] = {name: detector[name] for name in FILTER_PREFIXES}
                continue
            if not points:
                trace = Scenario(experiment.plant, experiment.noise, experiment.fault, experiment.duration).simulate(
                    experiment.seed, 2 * self.n_runs, "calibration")
                points = {name: experiment.monitor.transform(est.estimate(trace, experiment.model))
                          for name, est in filters.items()}
            target = self._roc(detector, points["entropy"], [float(detector.threshold)])["false_alarm"][0]
            fa = self._roc(detector, points["baseline"])["false_alarm"]
            ok = np.flatnonzero(fa <= target)
            threshold = float(THRESHOLD_GRID[ok[0]] if ok.size else THRESHOLD_GRID[-1])
            out[design] = {"entropy": detector, "baseline": detector.with_params(threshold=threshold)}
        return out

    def compute(self, experiment, designs: dict) -> dict:
        """Per rate and filter: mean error curves and, per design, the scores; the ROC on complete data; the grid."""
        filters = {"entropy": experiment.estimator, "baseline": self.baseline(experiment.estimator)}
        designs = self.own_thresholds(experiment, designs)
        dt = float(experiment.plant.dt)
        out = {"rates": self.missing_rates, "dt": dt, "n_runs": self.n_runs, "curves": {},
               "gain": np.asarray(getattr(experiment.estimator, "gain_", np.full(1, np.nan))),
               "baseline_gain": self.baseline_gain,
               "params": {name: design_params(d["entropy"]) for name, d in designs.items()},
               "baseline_params": {name: design_params(d["baseline"]) for name, d in designs.items()},
               "designs": {name: {"results": {}, "roc": {}} for name in designs}}
        first = self.missing_rates[0]

        def at_rate(rate) -> dict:
            """Each filter's curves, scores (and, at the first rate, ROC and time axis) on the runs at ``rate``."""
            trace = self._simulate(experiment, rate)
            found = {}
            for name, est in filters.items():
                outputs = est.estimate(trace, experiment.model)
                points = experiment.monitor.transform(outputs)
                found[name] = {
                    "curves": self._curves(outputs),
                    "results": {design: self._score(detectors[name], outputs, points, dt)
                                for design, detectors in designs.items()},
                    "roc": {design: self._roc(detectors[name], points) for design, detectors in designs.items()}
                    if rate == first else {},
                    "onset_s": float(outputs.t[int(np.argmax(outputs.fault_label.max(axis=0) > 0))]),
                    "t": np.asarray(outputs.t, float)}
            return found

        # the rates are independent: on threads, as the grid's cells (:meth:`_grid`); merged in the rates' order
        for rate, found in zip(self.missing_rates, self._on_threads(at_rate, self.missing_rates)):
            for name, part in found.items():
                out["curves"][(name, rate)] = part["curves"]
                for design in designs:
                    scored = out["designs"][design]
                    scored["results"][(name, rate)] = part["results"][design]
                    if rate == first:
                        scored["roc"][name] = part["roc"][design]
                if rate == first:
                    out["onset_s"], out["t"] = part["onset_s"], part["t"]
        shown = designs.get(TUNED) or next(iter(designs.values()))
        out["grid"] = self._grid(experiment, shown["entropy"], dt)
        out["laws"] = self._laws(experiment, shown["entropy"], dt)
        return out

    def _laws(self, experiment, detector, dt: float) -> dict:
        """Per-run isolation on complete data with other supports of the amplitude laws (class docstring)."""
        out = {}
        members = getattr(experiment.fault, "members", ())
        roles = [getattr(f, "role", None) for f in members]
        if "target" not in roles or "nuisance" not in roles:
            return out
        plant = experiment.plant.with_params(missing_rate=0.0)
        for target, nuisance in self.amplitude_laws:
            faults = [f.with_params(low=law[0], width=law[1] - law[0])
                      for f, law in ((f, target if f.role == "target" else nuisance) for f in members)]
            fault = type(experiment.fault)(faults)
            trace = Scenario(plant, experiment.noise, fault, experiment.duration).simulate(
                experiment.seed, 2 * self.n_runs, "test")
            outputs = experiment.estimator.estimate(trace, experiment.model)
            scores = self._score(detector, outputs, experiment.monitor.transform(outputs), dt)
            out[(target, nuisance)] = {k: scores[k] for k in ("target_run_detection", "nuisance_run_false_isolation",
                                                               "target_point_detection",
                                                               "nuisance_point_false_isolation")}
        return out

    def _simulate(self, experiment, rate: float, mechanism: str | None = None):
        """The ``test`` runs at ``rate`` (the plant's own mechanism unless ``mechanism``), same seeds at every rate."""
        extra = {} if mechanism is None else {"missing_mechanism": mechanism, "burst_length": self.burst_length}
        plant = experiment.plant.with_params(missing_rate=rate, **extra)
        return Scenario(plant, experiment.noise, experiment.fault, experiment.duration).simulate(
            experiment.seed, 2 * self.n_runs, "test")

    def _grid(self, experiment, detector, dt: float) -> dict:
        """The entropy filter's numbers for every mechanism × fill × rate (class docstring).

        The (mechanism, rate) cells are independent (their own simulation, filters and scores) and run on up to
        :func:`mosd.kernels.threads` threads (:meth:`_on_threads`): most of a cell is the EM fill's NumPy work,
        which releases Python's lock (5.6 s on one thread, 4.0-4.4 s on two on the project's 2-core machine,
        issue 32); the numbers and their order are the same whatever the threads.
        """
        def cell(mechanism_rate) -> dict:
            mechanism, rate = mechanism_rate
            trace = self._simulate(experiment, rate, mechanism)
            gap = np.isnan(np.asarray(trace.y, float)[..., 0])
            truth = experiment.model.h(np.asarray(trace.x, float)[..., 0])
            scored = {}
            for fill in self.fills:
                outputs = with_fill(experiment.estimator, fill).estimate(trace, experiment.model)
                scores = self._score(detector, outputs, experiment.monitor.transform(outputs), dt)
                filled = outputs.extra["y_filled"][gap]
                error = (filled - truth[gap])[np.isfinite(filled)]
                if fill != "skip" and error.size:  # nothing filled: no fill error to report
                    scores["fill_rmse"] = float(np.sqrt(np.mean(error**2)))
                scored[(mechanism, fill, rate)] = scores
            return scored

        grid: dict = {}
        for scored in self._on_threads(cell, [(mechanism, rate) for mechanism in self.mechanisms
                                              for rate in self.missing_rates]):
            grid.update(scored)
        return grid

    @staticmethod
    def _on_threads(work, items) -> list:
        """``[work(item) for item in items]``, on up to :func:`mosd.kernels.threads` threads."""
        from concurrent.futures import ThreadPoolExecutor

        from .. import kernels

        items = list(items)
        if kernels.threads() <= 1 or len(items) <= 1:
            return [work(item) for item in items]
        with ThreadPoolExecutor(min(kernels.threads(), len(items))) as pool:
            return list(pool.map(work, items))

    @staticmethod
    def _roles(labels: np.ndarray, roles) -> np.ndarray:
        role_of_label = np.array(["none", *roles])
        return role_of_label[labels.max(axis=1)] == "target"

    def _score(self, detector, outputs, points, dt: float) -> dict:
        d = detector.decide(points.z[:1], points.z).decision
        is_target = self._roles(points.fault_label, points.fault_roles)
        active = points.fault_label > 0
        error = outputs.extra["error"]
        onset = int(np.argmax(outputs.fault_label.max(axis=0) > 0))
        level = error[:, onset + SETTLE:].mean(axis=1)
        fluct = error[:, onset + SETTLE:].std(axis=1)
        delay = detection.detection_delay(d[is_target], points.fault_mask[is_target]) * dt
        nuisance = (d[~is_target] != 0) & active[~is_target]
        target = (d[is_target] != 0) & active[is_target]
        scores = {
            "delay_target_ci95": Estimate.of(delay).half_width,
            "target_run_detection": float(np.mean(detection.detection_rate(d[is_target],
                                                                           points.fault_mask[is_target]))),
            "nuisance_run_false_isolation": float(np.mean(nuisance.any(axis=-1))),
            "target_point_detection": float(target.sum() / max(active[is_target].sum(), 1)),
            "nuisance_point_false_isolation": float(nuisance.sum() / max(active[~is_target].sum(), 1)),
            "error_level_target": float(level[is_target].mean()),
            "error_level_nuisance": float(level[~is_target].mean()),
            "error_fluct_target": float(fluct[is_target].mean()),
            "nuisance_level_p95": float(np.percentile(level[~is_target], 95)),
        }
        if np.isfinite(delay).any():  # no detected target run: no delay to report
            scores["delay_target_s"] = float(np.nanmean(delay))
        return scores

    def _curves(self, outputs) -> dict:
        """Error curves of target and nuisance runs: mean, 5 and 95 % quantiles, and the first run of each."""
        error = np.asarray(outputs.extra["error"], float)
        is_target = self._roles(outputs.fault_label, outputs.fault_roles)
        curves = {}
        for role, rows in (("target", is_target), ("nuisance", ~is_target)):
            e = error[rows]
            curves[role] = {"mean": e.mean(0), "low": np.percentile(e, 5, axis=0),
                            "high": np.percentile(e, 95, axis=0), "example": e[0]}
        return curves

    def _roc(self, detector, points, thresholds=THRESHOLD_GRID) -> dict:
        """Target point detection against nuisance point false alarms over a threshold sweep (the design's L)."""
        thresholds = np.asarray(thresholds, float)
        X = np.column_stack([thresholds, np.full(thresholds.size, float(getattr(detector, "persistence", 1)))])
        d = detector.population(None, detector.features(points.z), X).decision != 0   # (P, R, K)
        is_target = self._roles(points.fault_label, points.fault_roles)
        active = points.fault_label > 0
        hit = (d[:, is_target] & active[is_target]).sum((1, 2)) / active[is_target].sum()
        fa = (d[:, ~is_target] & active[~is_target]).sum((1, 2)) / active[~is_target].sum()
        return {"threshold": thresholds, "detection": hit, "false_alarm": fa}

    @staticmethod
    def _at_false_alarm(roc: dict, level: float) -> float:
        fa, hit = roc["false_alarm"][::-1], roc["detection"][::-1]  # increasing false alarms
        return float(np.interp(level, fa, hit))

    @staticmethod
    def _auc(roc: dict) -> float:
        fa = np.concatenate([[0.0], roc["false_alarm"][::-1], [1.0]])
        hit = np.concatenate([[0.0], roc["detection"][::-1], [1.0]])
        return float(np.sum(np.diff(fa) * (hit[1:] + hit[:-1]) / 2))

    def metrics(self, data: dict) -> dict[str, float]:
        """The study's metrics by name (class docstring); a design other than the tuned one prefixed."""
        out = {}
        for design, scored in data["designs"].items():
            for name, prefix in FILTER_PREFIXES.items():
                for rate in data["rates"]:
                    tag = rate_tag(rate)
                    for key, value in scored["results"][(name, rate)].items():
                        if key in ("delay_target_ci95", "nuisance_level_p95", "error_fluct_target"):
                            continue
                        out[f"{prefixed(design)}{prefix}{key}_{tag}"] = float(value)
            out[f"{prefixed(design)}baseline_threshold"] = float(data["baseline_params"][design]["threshold"])
            own_fa = scored["results"][("entropy", data["rates"][0])]["nuisance_point_false_isolation"]
            for name, prefix in FILTER_PREFIXES.items():
                roc = scored["roc"][name]
                out[f"{prefixed(design)}{prefix}roc_auc"] = self._auc(roc)
                out[f"{prefixed(design)}{prefix}equal_fa_target_detection"] = self._at_false_alarm(roc, own_fa)
        for (mechanism, fill, rate), scores in data.get("grid", {}).items():
            for key in GRID_KEYS:
                if key in scores:
                    out[f"{mechanism}_{fill}_{key}_{rate_tag(rate)}"] = float(scores[key])
        for laws, scores in data.get("laws", {}).items():
            for key, value in scores.items():
                out[f"laws_{laws_tag(laws)}_{key}"] = float(value)
        return out

    # -- figures --------------------------------------------------------------------------
    def write_figures(self, data: dict, out_dir: Path) -> list[Path]:
        """Figs. 3–10 (error responses per rate and role), the gain, the ROC and the delay over the rate.

        The thresholds, ROC and delays shown are the tuned design's (the first design if none is tuned).
        """
        return self.draw_figure_jobs(data, out_dir)

    def figure_jobs(self, data: dict, out_dir: Path) -> list[tuple[str, dict]]:
        """The three figures of :meth:`write_figures`, each a job of its own (drawn side by side where the app
        has the cores)."""
        path = Path(out_dir) / f"{self.system}_"
        return [("_errors_figure", {"data": data, "path": Path(f"{path}errors.png")}),
                ("_gain_figure", {"data": data, "path": Path(f"{path}gain.png")}),
                ("_separation_figure", {"data": data, "path": Path(f"{path}separation_delay.png")})]

    @staticmethod
    def _shown(data: dict) -> tuple[dict, dict]:
        """The shown design's results and parameters: the tuned design's, else the first design's."""
        name = TUNED if TUNED in data["designs"] else next(iter(data["designs"]))
        return data["designs"][name], data["params"][name]

    def _errors_figure(self, data: dict, path: Path) -> Path:
        t, onset, rates = data["t"], data["onset_s"], data["rates"]
        threshold = self._shown(data)[1].get("threshold", math.nan)
        fig = figure(9.0, 2.2 * len(rates))
        axes = fig.subplots(len(rates), 2, sharex=True, sharey=True, squeeze=False)
        for i, rate in enumerate(rates):
            for j, role in enumerate(("target", "nuisance")):
                ax = axes[i, j]
                for name, color in (("entropy", "tab:blue"), ("baseline", "tab:orange")):
                    c = data["curves"][(name, rate)][role]
                    label = "entropy gain" if name == "entropy" else f"fixed gain {data['baseline_gain']:g}"
                    ax.fill_between(t, c["low"], c["high"], color=color, alpha=0.15, lw=0)
                    ax.plot(t, c["mean"], color=color, lw=1.2, label=f"{label}: mean, 5-95 %")
                    if name == "entropy":
                        ax.plot(t, c["example"], color=color, lw=0.6, alpha=0.7, label="entropy gain: one run")
                ax.axhline(threshold, color="r", ls="--", lw=0.8, label=f"tuned threshold {threshold:.3g}")
                ax.axhline(-threshold, color="r", ls="--", lw=0.8)
                ax.axvline(onset, color="grey", ls=":", lw=0.8)
                ax.set_title(f"Fig. {3 + 2 * i + j}: {role} fault only, {100 * rate:g} % missing", fontsize=9)
                ax.grid(alpha=0.3)
                if j == 0:
                    ax.set_ylabel("error x − x̂")
                if i == len(rates) - 1:
                    ax.set_xlabel("t (s)")
        axes[0, 0].legend(fontsize=7, loc="upper left")
        fig.savefig(path, dpi=100)
        return path

    @staticmethod
    def _gain_figure(data: dict, path: Path) -> Path:
        t, onset = data["t"], data["onset_s"]
        fig = figure(6.0, 3.2)
        ax = fig.add_subplot()
        gain = data["gain"]
        ax.step(t[: gain.size], gain, where="post", label="entropy-optimal U_k (R1 = 1, R2 = 20)")
        ax.axhline(data["baseline_gain"], color="tab:orange", ls="--", label=f"fixed gain {data['baseline_gain']:g}")
        ax.axvline(onset, color="grey", ls=":", lw=0.8)
        decorate(ax, "t (s)", "gain U", "Gain schedule: entropy-optimal vs fixed")
        fig.savefig(path, dpi=110)
        return path

    def _separation_figure(self, data: dict, path: Path) -> Path:
        rates = data["rates"]
        shown, params = self._shown(data)
        fig = figure(9.0, 3.4)
        ax, bx = fig.subplots(1, 2)
        for name, color in (("entropy", "tab:blue"), ("baseline", "tab:orange")):
            roc = shown["roc"][name]
            label = "entropy gain" if name == "entropy" else f"fixed gain {data['baseline_gain']:g}"
            ax.plot(roc["false_alarm"], roc["detection"], color=color, label=label)
            delays = [shown["results"][(name, r)].get("delay_target_s", math.nan) for r in rates]
            cis = [shown["results"][(name, r)]["delay_target_ci95"] for r in rates]
            bx.errorbar([100 * r for r in rates], delays, yerr=cis, color=color, marker="o", capsize=3, label=label)
        tuned = shown["results"][("entropy", rates[0])]
        ax.axvline(tuned["nuisance_point_false_isolation"], color="r", ls="--", lw=0.8,
                   label="tuned design's nuisance FA")
        ax.set_xscale("symlog", linthresh=1e-3)
        ax.set_xlim(0.0, 1.0)
        decorate(ax, "nuisance points alarmed", "target points detected",
                 f"Separation, complete data, L = {int(params.get('persistence', 1))}")
        paper = [(100 * r, PAPER["target_delay"][r]) for r in rates if r in PAPER["target_delay"]]
        bx.plot([p[0] for p in paper], [p[1] for p in paper], "k^", label="paper (target; fails at 20 %)")
        decorate(bx, "missing outputs (%)", "target isolation delay (s)", "Delay over the missing rate (tuned design)")
        fig.savefig(path, dpi=110)
        return path


def _choices(key: str, values, allowed) -> tuple[str, ...]:
    """A non-empty list of distinct names from ``allowed``, or a one-line :class:`ConfigError`."""
    if isinstance(values, (str, bytes)) or not hasattr(values, "__len__") or not len(values) \
            or len(set(values)) != len(values):
        raise ConfigError(f"{key}={values!r} is not allowed; allowed: a list of distinct names from "
                          f"{', '.join(allowed)}")
    return tuple(check_choice(key, v, allowed) for v in values)


def laws_tag(laws) -> str:
    """``t50_150_n0_60`` for target [0.5, 1.5] and nuisance [0, 0.6]: the sensitivity metrics' infix."""
    (tl, th), (nl, nh) = laws
    return "t{}_{}_n{}_{}".format(*(int(round(100 * v)) for v in (tl, th, nl, nh)))


def _check_laws(laws) -> tuple:
    """``study.amplitude_laws``: pairs of supports ((low, high), (low, high)), or a one-line ConfigError."""
    allowed = "a list of [[target low, high], [nuisance low, high]] with 0 <= low < high <= 10"
    try:
        out = tuple(tuple((float(low), float(high)) for low, high in pair) for pair in laws)
    except (TypeError, ValueError):
        raise ConfigError(f"study.amplitude_laws={laws!r} is not allowed; allowed: {allowed}") from None
    if any(len(pair) != 2 or not all(0.0 <= low < high <= 10.0 for low, high in pair) for pair in out):
        raise ConfigError(f"study.amplitude_laws={laws!r} is not allowed; allowed: {allowed}")
    return out


def with_fill(estimator, fill: str):
    """A shallow copy of a trained gain filter that fills missing outputs by ``fill`` (em, hold, skip)."""
    est = copy.copy(estimator)
    est.missing = fill
    if fill == "em" and getattr(est, "imputer", None) is None:
        est.imputer = EMImputer(half_width=getattr(estimator, "em_half_width", 1))
    return est


def midway_threshold(experiment, n_runs: int, estimator=None) -> float:
    """The reconstruction's fixed threshold: midway between the steady error levels of calibration-stream runs.

    Drawn from the ``calibration`` stream with both faults (never the test runs), estimated
    by ``estimator`` (default: the experiment's): each filter has its own midway threshold.
    """
    sc = Scenario(experiment.plant, experiment.noise, experiment.fault, experiment.duration)
    outputs = (estimator or experiment.estimator).estimate(sc.simulate(experiment.seed, 2 * n_runs, "calibration"), experiment.model)
    error = outputs.extra["error"]
    onset = int(np.argmax(outputs.fault_label.max(axis=0) > 0))
    level = error[:, onset + SETTLE:].mean(axis=1)
    is_target = Study._roles(outputs.fault_label, outputs.fault_roles)
    return float(0.5 * (level[is_target].mean() + level[~is_target].mean()))


def format_report(designs: dict[str, dict], metrics: dict[str, float], mechanisms=MECHANISMS,
                  fills=MISSING) -> str:
    """Markdown: per design, filter and rate, the study's numbers beside the paper's delays; the grid.

    ``designs`` maps a design's name to ``{"entropy": params, "baseline": params}``: each
    filter's row shows its own threshold.
    """
    lines = ["| design | filter | missing | target runs detected | nuisance runs falsely isolated "
             "| target points detected | nuisance points alarmed | target delay (s) | paper delay (s) "
             "| error level target / nuisance |", "|---|---|---|---|---|---|---|---|---|---|"]
    for design, by_filter in designs.items():
        for name, filter_prefix in FILTER_PREFIXES.items():
            prefix = prefixed(design) + filter_prefix
            p = by_filter[name]
            for tag, rate in ((rate_tag(r), r) for r in MISSING_RATES):
                if f"{prefix}target_run_detection_{tag}" not in metrics:
                    continue
                paper = PAPER["target_delay"].get(rate, "–")
                paper = "fails" if isinstance(paper, float) and math.isnan(paper) else paper
                delay = metrics.get(f"{prefix}delay_target_s_{tag}")
                lines.append(
                    f"| {design} (threshold {p['threshold']:.3g}, L {int(p['persistence'])}) | {name} | {100 * rate:g} % "
                    f"| {metrics[f'{prefix}target_run_detection_{tag}']:.3f} "
                    f"| {metrics[f'{prefix}nuisance_run_false_isolation_{tag}']:.3f} "
                    f"| {metrics[f'{prefix}target_point_detection_{tag}']:.3f} "
                    f"| {metrics[f'{prefix}nuisance_point_false_isolation_{tag}']:.4f} "
                    f"| {'–' if delay is None else f'{delay:.3f}'} | {paper} "
                    f"| {metrics[f'{prefix}error_level_target_{tag}']:.3f} / "
                    f"{metrics[f'{prefix}error_level_nuisance_{tag}']:.3f} |")
    lines += ["", "| design | filter | ROC AUC (complete data) | target points detected at the design's own "
              "nuisance false-alarm rate on the entropy filter |", "|---|---|---|---|"]
    for design in designs:
        for name, filter_prefix in FILTER_PREFIXES.items():
            prefix = prefixed(design) + filter_prefix
            lines.append(f"| {design} | {name} | {metrics[prefix + 'roc_auc']:.4f} "
                         f"| {metrics[prefix + 'equal_fa_target_detection']:.4f} |")
    lines += ["", "Entropy filter, tuned design, per missingness mechanism and fill (0 / 5 / 10 / 20 % ...):", "",
              "| mechanism | fill | target runs detected | nuisance runs falsely isolated | target points detected "
              "| nuisance points alarmed | target delay (s) | target error fluct. | fill RMSE |",
              "|---|---|---|---|---|---|---|---|---|"]
    for mechanism in mechanisms:
        for fill in fills:
            tags = [rate_tag(r) for r in MISSING_RATES
                    if f"{mechanism}_{fill}_target_run_detection_{rate_tag(r)}" in metrics]
            if not tags:
                continue
            cells = [" / ".join(f"{metrics[f'{mechanism}_{fill}_{key}_{t}']:{fmt}}"
                                if f"{mechanism}_{fill}_{key}_{t}" in metrics else "–" for t in tags)
                     for key, fmt in zip(GRID_KEYS, (".3f", ".3f", ".3f", ".4f", ".2f", ".3f", ".3f"))]
            lines.append(f"| {mechanism} | {fill} | " + " | ".join(cells) + " |")
    laws = sorted({k[len("laws_"):].split("_target_run_detection")[0] for k in metrics
                   if k.startswith("laws_") and k.endswith("_target_run_detection")})
    if laws:
        lines += ["", "Amplitude-law sensitivity (complete data, entropy filter, tuned design; supports in "
                  "hundredths):", "", "| laws | target runs detected | nuisance runs falsely isolated "
                  "| target points detected | nuisance points alarmed |", "|---|---|---|---|---|"]
        for tag in laws:
            lines.append(f"| {tag} | {metrics[f'laws_{tag}_target_run_detection']:.3f} "
                         f"| {metrics[f'laws_{tag}_nuisance_run_false_isolation']:.3f} "
                         f"| {metrics[f'laws_{tag}_target_point_detection']:.3f} "
                         f"| {metrics[f'laws_{tag}_nuisance_point_false_isolation']:.4f} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    """``python -m mosd.systems.paper002 [--n-runs 200] [--seed 0] [--threshold T] [--persistence L] [--out DIR]``."""
    recorded = recorded_designs(SYSTEM)
    parser = cli.report_parser("python -m mosd.systems.paper002", "Paper 002's study over missing rates (Tables "
                               "1-2, Figs. 3-10) without the optimiser: the tuned design beside the "
                               "reconstruction's fixed one (midway threshold, L = 3).", out="outputs/systems/paper002")
    parser.add_argument("--n-runs", type=int, default=200, help="target and nuisance runs each, per rate (default 200)")
    cli.design_options(parser, SYSTEM)  # --threshold, --persistence

    def body(args):
        study = Study(n_runs=args.n_runs)
        experiment = cli.preset(SYSTEM, [f"seed={args.seed}"]).experiment
        tuned = experiment.detector.with_params(**cli.tuned_design(args, SYSTEM))
        experiment.fit_estimator()
        # each filter at its own midway threshold (issue 20: the baseline used the entropy filter's)
        midway = {name: experiment.detector.with_params(threshold=midway_threshold(experiment, args.n_runs, est),
                                                        **recorded["midway"])
                  for name, est in (("entropy", experiment.estimator),
                                    ("baseline", study.baseline(experiment.estimator)))}
        data, metrics, files = cli.score(study, experiment, {TUNED: tuned, "midway": midway}, Path(args.out),
                                         n_runs=args.n_runs, seed=args.seed)
        params = {name: {"entropy": data["params"][name], "baseline": data["baseline_params"][name]}
                  for name in data["designs"]}
        print(f"## Paper 002: {args.n_runs} target + {args.n_runs} nuisance runs per missing rate, seed {args.seed} "
              f"(test stream)\n")
        print(format_report(params, metrics, study.mechanisms, study.fills) + "\n")
        return files

    return cli.run_report(parser, argv, body)


if __name__ == "__main__":
    raise SystemExit(main())
