"""Paper 000's tables and figures as computations: Table 3, Table 4, Fig. 1 and the Pareto fronts.

Every chart of one fault is scored on the same test replications (paired); the optimisers and the
grids see the training runs only (docs/DECISIONS.md §5–6).
"""
from __future__ import annotations

import functools
import math
import time
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from ...detectors import Chart
from ...experiment import Tuned
from ...metrics import DetectionReport, Estimate
from ...metrics.summary import hypervolume
from ...validation import check_int
from .numbers import BASELINES, CAUSAL_OURS, FAULTS, PAPER_PRESETS, TUNED_MS_OEWMA, paper_error_bound
from .setup import BudgetPreset, FaultData, Reproduction, fault_data, make_solver


def evaluate_design(chart: Chart, study: Reproduction, data: FaultData) -> DetectionReport:
    """Fit ``chart``'s limit on Phase I and score it on the fault's test replications."""
    return study.experiment.evaluate(chart, data.prepared, test=data.test)[0]


def self_referenced_report(chart: Chart, data: FaultData) -> DetectionReport:
    """Score ``chart`` with the limit computed from the very sequence it monitors.

    A reading of eq. 27 in which E{l} and sd{l} are taken over each scored sequence
    {l_k}, faulty half included — what paper 000 appears to have done (docs/DECISIONS.md
    §3). The fault inflates both, so a small width K still gives a limit well above the
    in-control values. Not an honest detector (the limit uses the future and the fault
    itself); shown only to explain the paper-parameter rows.
    """
    width = chart.tunable_params()[list(chart.tunable)[1]]
    test = data.test_subgroups
    statistic = chart.statistic(test.z)
    ucl = statistic.mean(axis=-1, keepdims=True) + width * statistic.std(axis=-1, ddof=1, keepdims=True)
    return DetectionReport.of(statistic > ucl, test)


def error_anatomy(chart: Chart, data: FaultData, near: int = 10) -> dict[str, float]:
    """Where a design's errors fall on the test runs, in subgroups per run.

    ``missed_onset``: the first faulty subgroup not alarmed; ``missed_later``: other
    missed faulty subgroups; ``false_near_onset``: false alarms within ``near``
    subgroups before the onset (whole-series denoising spreads the step backwards);
    ``false_elsewhere``: the other false alarms. One subgroup per run is 0.1 % of a
    1,000-subgroup run (0.2 % of either half).
    """
    test = data.test_subgroups
    alarms, mask = chart.decide(data.prepared.phase1.z, test.z).decision != 0, test.fault_mask
    onset = np.argmax(mask, axis=1)
    position = np.arange(mask.shape[1]) - onset[:, None]
    missed, false = mask & ~alarms, ~mask & alarms
    runs = mask.shape[0]
    return {
        "missed_onset": float((missed & (position == 0)).sum() / runs),
        "missed_later": float((missed & (position > 0)).sum() / runs),
        "false_near_onset": float((false & (position >= -near)).sum() / runs),
        "false_elsewhere": float((false & (position < -near)).sum() / runs),
        "runs_with_false_alarm": float(false.any(axis=1).mean()),
    }


def make_evaluator(chart: Chart, study: Reproduction, data: FaultData):
    """The (FAR, MDR) map over the fault's training runs (eq. 36's objectives)."""
    return study.experiment.evaluator(data.prepared, chart)


def optimise(chart: Chart, study: Reproduction, data: FaultData, algorithm: str = "mopso", pop_size: int = 100,
             n_gen: int = 100, bounds: dict | None = None, n_jobs: int = 2, rule: str = "max_accuracy") -> Tuned:
    """Minimise (FAR, MDR) over the chart's parameters on the fault's training runs (eq. 36).

    :meth:`Experiment.tune` with the paper's optimiser (``algorithm``: Table 2's MOPSO
    or NSGA-II), ``pop_size`` particles × ``n_gen`` iterations (Table 2: 100 × 100),
    the search box ``bounds`` (Table 2: K_SD ∈ (0, 5)) and the choice rule
    (docs/DECISIONS.md §6).
    """
    from ...optim.selection import choose

    return study.experiment.tune(data.prepared, make_solver(algorithm, pop_size), ("n_gen", n_gen), n_jobs=n_jobs,
                                 bounds=bounds, choose=functools.partial(choose, rule=rule), detector=chart)


def _pair(tuned: Tuned) -> tuple[float, float]:
    """(FAR, MDR) of the chosen design on the training runs."""
    objectives = tuned.train_objectives
    return objectives["far"], objectives["mdr"]


def ms_oewma_grid(preset: BudgetPreset) -> tuple[np.ndarray, np.ndarray]:
    """λ and L axes of the MS-OEWMA tuning grid: λ ∈ (0, 1], L ∈ (0, 10]."""
    lam = np.round(np.arange(1, round(1.0 / preset.lam_step) + 1) * preset.lam_step, 10)
    width = np.round(np.arange(1, round(10.0 / preset.width_step) + 1) * preset.width_step, 10)
    return lam, width


# ------------------------------------------------------------------------------------
# Table 3
# ------------------------------------------------------------------------------------
@dataclass
class Row:
    """One method on one fault: its parameters, test report and (if tuned) training objectives."""

    method: str
    fault: str
    params: dict[str, float]
    report: DetectionReport
    train_objectives: tuple[float, float] | None = None
    seconds: float = 0.0
    #: whether the chart decides online (its statistic at k uses subgroups 1..k only)
    causal: bool | None = None

    def summary(self) -> dict[str, Estimate]:
        return self.report.summary()

    def error(self) -> Estimate:
        """FAR + MDR over test replications (1 − detection accuracy)."""
        return Estimate.of(1.0 - self.report.accuracy)


@dataclass(frozen=True)
class BarCheck:
    """One of issue 5's scientific bars, evaluated."""

    fault: str
    name: str
    estimate: Estimate
    threshold: float
    met: bool
    verdict: str


def compare_accuracy(ours: Row, baseline: Row) -> BarCheck:
    """Paired test-replication difference of accuracy, ours − baseline, with its 95 % CI.

    Met when the CI's upper end is >= 0, i.e. ours is not significantly worse.
    """
    diff = Estimate.of(ours.report.accuracy - baseline.report.accuracy)
    half = 0.0 if not math.isfinite(diff.half_width) else diff.half_width
    if diff.mean - half > 0:
        verdict = "better (CI above 0)"
    elif diff.mean + half < 0:
        verdict = "worse (CI below 0)"
    else:
        verdict = "tie (CI covers 0)"
    return BarCheck(ours.fault, f"accuracy vs {baseline.method}", diff, 0.0, diff.mean + half >= 0, verdict)


def compare_with_paper(ours: Row) -> BarCheck:
    """Test FAR + MDR against the paper's MO-SS-DEWMA value (Table 3)."""
    bound = paper_error_bound(ours.fault)
    error = ours.error()
    half = 0.0 if not math.isfinite(error.half_width) else error.half_width
    if error.mean <= bound:
        verdict = "met" if error.mean + half <= bound else "met (mean; CI straddles)"
    else:
        verdict = "not met, within CI" if error.mean - half <= bound else "not met"
    return BarCheck(ours.fault, "FAR + MDR <= paper", error, bound, error.mean <= bound, verdict)


@dataclass
class Table3:
    settings: dict[str, Any]
    rows: list[Row]
    bars: list[BarCheck]
    archives: dict[str, Tuned]
    timings: dict[str, float]
    #: the paper-parameter charts under the self-referenced limit (:func:`self_referenced_report`)
    self_referenced: list[Row] = field(default_factory=list)
    #: :func:`error_anatomy` of the optimised design per fault
    anatomy: dict[str, dict[str, float]] = field(default_factory=dict)
    #: :data:`CAUSAL_OURS` per fault (tuned and scored like MO-SS-DEWMA), when the main rows are not causal
    causal: list[Row] = field(default_factory=list)
    #: paired accuracy difference causal − literal MO-SS-DEWMA per fault
    causal_bars: list[BarCheck] = field(default_factory=list)

    def row(self, method: str, fault: str) -> Row:
        return next(r for r in self.rows if r.method == method and r.fault == fault)


def run_table3(study: Reproduction, faults: Sequence[str] = tuple(FAULTS), include_tuned: bool = True) -> Table3:
    """Table 3: the paper-parameter charts and MO-SS-DEWMA (MOPSO, max accuracy) per fault.

    Every chart of one fault is scored on the same test replications (paired).
    """
    settings, preset = study.settings, study.settings.preset
    rows: list[Row] = []
    archives: dict[str, Tuned] = {}
    bars: list[BarCheck] = []
    self_referenced: list[Row] = []
    anatomy: dict[str, dict[str, float]] = {}
    causal: list[Row] = []
    causal_bars: list[BarCheck] = []
    for name in faults:
        data = fault_data(study, name)
        for method in BASELINES:
            t0 = time.perf_counter()
            params = PAPER_PRESETS[method][name]
            chart = study.chart(method, params)
            rows.append(Row(method, name, dict(params), evaluate_design(chart, study, data),
                            seconds=time.perf_counter() - t0, causal=chart.is_causal))
            self_referenced.append(Row(method, name, dict(params), self_referenced_report(chart, data)))
        if include_tuned:
            rows.append(tune_ms_oewma(study, data))
        opt = optimise(study.experiment.detector, study, data, "mopso",
                       preset.pop_size, preset.n_gen, settings.bounds, settings.n_jobs)
        archives[name] = opt
        t0 = time.perf_counter()
        chosen = study.chart("MO-SS-DEWMA", opt.params)
        report = evaluate_design(chosen, study, data)
        ours = Row("MO-SS-DEWMA", name, opt.params, report, _pair(opt),
                   opt.seconds + time.perf_counter() - t0, causal=chosen.is_causal)
        rows.append(ours)
        if not chosen.is_causal:
            online = tune_causal(study, data)
            causal.append(online)
            causal_bars.append(compare_accuracy(online, ours))
        anatomy[name] = error_anatomy(study.chart("MO-SS-DEWMA", opt.params), data)
        by_method = {r.method: r for r in rows if r.fault == name}
        bars.extend(compare_accuracy(ours, by_method[m]) for m in BASELINES)
        if include_tuned:
            bars.append(compare_accuracy(ours, by_method[TUNED_MS_OEWMA]))
        bars.append(compare_with_paper(ours))
    return Table3(study.describe(), rows, bars, archives, dict(study.timings), self_referenced, anatomy,
                  causal, causal_bars)


def tune_causal(study: Reproduction, data: FaultData) -> Row:
    """:data:`CAUSAL_OURS`: MO-SS-DEWMA's optimiser, box, budget and data on the raw statistic (online)."""
    settings, preset = study.settings, study.settings.preset
    chart = study.chart(CAUSAL_OURS, study.experiment.detector.tunable_params())
    opt = optimise(chart, study, data, "mopso", preset.pop_size, preset.n_gen, settings.bounds, settings.n_jobs)
    t0 = time.perf_counter()
    chosen = chart.with_params(**opt.params)
    report = evaluate_design(chosen, study, data)
    return Row(CAUSAL_OURS, data.name, opt.params, report, _pair(opt), opt.seconds + time.perf_counter() - t0,
               causal=chosen.is_causal)


def tune_ms_oewma(study: Reproduction, data: FaultData) -> Row:
    """MS-OEWMA tuned by its own rule on the training runs (:func:`constrained_grid_search`)."""
    from ...optim.grid import constrained_grid_search

    t0 = time.perf_counter()
    lam, width = ms_oewma_grid(study.settings.preset)
    chart = study.chart(TUNED_MS_OEWMA, PAPER_PRESETS["MS-OEWMA"][data.name])
    # an infeasible budget warns (SelectionWarning) and falls back to the lowest-FAR point
    params, objectives = constrained_grid_search(make_evaluator(chart, study, data), lam, width, study.settings.alpha)
    report = evaluate_design(chart.with_params(**params), study, data)
    return Row(TUNED_MS_OEWMA, data.name, params, report, objectives, time.perf_counter() - t0,
               causal=chart.is_causal)


# ------------------------------------------------------------------------------------
# Table 4
# ------------------------------------------------------------------------------------
@dataclass
class Table4:
    settings: dict[str, Any]
    params: dict[str, float]
    train_objectives: tuple[float, float]
    rows: list[Row]


def run_table4(study: Reproduction, optimised: Tuned | None = None) -> Table4:
    """Table 4: optimise on offset+variance training runs, score that design on every fault."""
    settings, preset = study.settings, study.settings.preset
    if optimised is None:
        optimised = optimise(study.experiment.detector, study,
                             fault_data(study, "offset_var"), "mopso", preset.pop_size, preset.n_gen,
                             settings.bounds, settings.n_jobs)
    chart = study.chart("MO-SS-DEWMA", optimised.params)
    rows = [Row("MO-SS-DEWMA", name, optimised.params, evaluate_design(chart, study, fault_data(study, name)),
                causal=chart.is_causal) for name in FAULTS]
    return Table4(study.describe(), optimised.params, _pair(optimised), rows)


# ------------------------------------------------------------------------------------
# Fig. 1 and the Pareto fronts
# ------------------------------------------------------------------------------------
def fig1_axes(n: int = 20) -> tuple[np.ndarray, np.ndarray]:
    """Fig. 1's grid: λ ∈ (0, 1) and K_SD ∈ (0, 10) each cut into n equal parts, at the midpoints."""
    n = check_int("n", n, 1)
    centres = (np.arange(n) + 0.5) / n
    return centres, 10.0 * centres


@dataclass
class GridScan:
    fault: str
    lam: np.ndarray
    K: np.ndarray
    far: np.ndarray
    mdr: np.ndarray
    seconds: float

    def good_region(self, below: float = 0.01) -> dict[str, Any]:
        """Grid points with MDR and FAR both < ``below`` and their bounding box."""
        good = (self.far < below) & (self.mdr < below)
        i, j = np.nonzero(good)
        box = None if i.size == 0 else {"lam": (float(self.lam[i].min()), float(self.lam[i].max())),
                                        "K": (float(self.K[j].min()), float(self.K[j].max()))}
        return {"count": int(good.sum()), "of": int(good.size), "box": box}


def run_fig1(study: Reproduction, fault: str = "offset", n: int = 20) -> GridScan:
    """FAR and MDR of SS-DEWMA over the n×n (λ, K_SD) grid on the training runs (Fig. 1)."""
    from ...optim.grid import grid_objectives

    t0 = time.perf_counter()
    lam, K = fig1_axes(n)
    chart = study.experiment.detector
    far, mdr = grid_objectives(make_evaluator(chart, study, fault_data(study, fault)), lam, K)
    return GridScan(fault, lam, K, far, mdr, time.perf_counter() - t0)


@dataclass
class ParetoComparison:
    fault: str
    fronts: dict[str, Tuned]
    hypervolume: dict[str, float]
    grid: GridScan | None


def run_pareto(study: Reproduction, fault: str = "offset_var", grid: GridScan | None = None) -> ParetoComparison:
    """MOPSO against NSGA-II with the same budget and bounds on one fault's training runs.

    Hypervolume of each front up to the reference point (FAR, MDR) = (1.1, 1.1)
    (:func:`mosd.metrics.summary.hypervolume`, the convention of every mosd report).
    """
    settings, preset = study.settings, study.settings.preset
    data = fault_data(study, fault)
    fronts = {
        algo: optimise(study.experiment.detector, study, data, algo,
                       preset.pop_size, preset.n_gen, settings.bounds, settings.n_jobs)
        for algo in ("mopso", "nsga2")
    }
    hv = {algo: hypervolume(front.F) for algo, front in fronts.items()}
    return ParetoComparison(fault, fronts, hv, grid)


