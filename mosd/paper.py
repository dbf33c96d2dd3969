"""Paper 000's comparison on our simulation: Table 3, Table 4 and Fig. 1 (issue 5).

Commands (plain Python, no Hydra, no MLflow)::

    python -m mosd.paper table3 [--budget paper|small|tiny] [--seed S]
    python -m mosd.paper table4 [--budget ...] [--seed S]
    python -m mosd.paper fig1   [--fault offset] [--budget ...]
    python -m mosd.paper pareto [--fault offset_var] [--budget ...]
    python -m mosd.paper all    [--budget ...]

Each prints a markdown table beside the paper's numbers and writes CSV/JSON/PNG
files under ``outputs/paper/`` (``--out`` to change). Sensitivity options:
``--k-max`` (K_SD search box, Table 2: 5), ``--wavelet paper|sln|none`` (denoiser
of the SS/M-DEWMA statistic), ``--subgroups window|channels`` (docs/DECISIONS.md §2),
``--n-jobs``. docs/RESULTS.md shows what these commands produce.

The default set-up (docs/DECISIONS.md §1–7; docs/DECISIONS.md):

* plant :class:`~mosd.plants.MouldOscillator`, noise :class:`~mosd.noise.GaussianNoise`
  (defaults), 5.2 s per replication, sensor fault on x_p from t = 2.7 s;
* residual: :class:`~mosd.estimators.DedicatedObserverResidual` around a CESCKF
  (decision 1), windows of n = 5 consecutive residuals of x_p after a 200-sample
  burn-in (decision 2): 1,000 subgroups per replication, faulty from 501 on;
* every SS/M-DEWMA chart (the paper-parameter baselines and the optimised one) uses
  the same Phase-I limit of eq. 27 and the same wavelet denoiser (§3.2; paper-literal
  setting by default), so within that family only the parameters differ;
* MS-OEWMA is :class:`mosd.detectors.MSOEWMA` (this project's documented interpretation);
* calibration, training and test replications come from disjoint seed streams
  (decision 5); every chart of one fault is scored on the *same* test replications,
  so differences between charts are paired.

The paper's whole-series wavelet is non-causal (l_k depends on later subgroups): every
table says which rows are online. Beside the literal MO-SS-DEWMA, ``table3`` tunes and
scores its causal counterpart, :data:`CAUSAL_OURS` (the same MOPSO, box and data, on the
raw statistic — what ``python -m mosd`` runs by default), and writes both to
``table3_causal.md``: FAR, MDR, the share of runs detected, the mean delay over detected
runs and the median delay with missed runs counted beyond the horizon.
"""
from __future__ import annotations

import argparse
import functools
import csv
import json
import math
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from .detectors import MDEWMA, MSOEWMA, SSDEWMA, Chart
from .denoisers import NoDenoiser, WaveletDenoiser
from .estimators import CESCKF, DedicatedObserverResidual
from .experiment import Budget, Experiment, PreparedData, Tuned
from .faults import SensorFault
from .metrics import DetectionReport, Estimate
from .monitors import SubgroupMonitor as Monitor
from .optim.mopso import PAPER_PRESET
from .noise import GaussianNoise
from .plants import MouldOscillator
from .types import Subgroups
from .validation import ConfigError, Interval, check_choice, check_in, check_int

# ------------------------------------------------------------------------------------
# the paper's numbers (data, not code)
# ------------------------------------------------------------------------------------
#: The three simulated faults of §3.3 in units of the in-control residual σ
#: (r ~ N(μ + aσ, b²σ²) after the onset).
FAULTS: dict[str, dict[str, float | str]] = {
    "offset": {"kind": "offset", "a": 2.0, "b": 1.0},
    "variance": {"kind": "variance", "a": 0.0, "b": 2.0},
    "offset_var": {"kind": "offset_var", "a": 2.0, "b": 2.0},
}
FAULT_LABELS = {"offset": "offset a = 2", "variance": "variance b = 2", "offset_var": "offset + variance a = b = 2"}

#: Fixed parameters of the comparison charts, paper 000 Table 3 (λ and K_SD columns;
#: MS-OEWMA's width is its L).
PAPER_PRESETS: dict[str, dict[str, dict[str, float]]] = {
    "M-DEWMA": {
        "offset": {"lam": 0.4, "K": 1.5},
        "variance": {"lam": 0.3, "K": 0.2},
        "offset_var": {"lam": 0.3, "K": 0.3},
    },
    "SS-DEWMA": {
        "offset": {"lam": 0.4, "K": 3.0},
        "variance": {"lam": 0.3, "K": 0.15},
        "offset_var": {"lam": 0.3, "K": 0.2},
    },
    "MS-OEWMA": {
        "offset": {"lam": 0.3388, "L": 4.8621},
        "variance": {"lam": 0.3388, "L": 4.8621},
        "offset_var": {"lam": 0.3388, "L": 4.8621},
    },
}

#: Paper 000 Table 3: (MDR %, FAR %, λ, K_SD) per method and fault.
PAPER_TABLE3: dict[str, dict[str, tuple[float, float, float, float]]] = {
    "M-DEWMA": {"offset": (1.4, 0.0, 0.4, 1.5), "variance": (15.0, 18.4, 0.3, 0.2),
                "offset_var": (17.0, 17.2, 0.3, 0.3)},
    "MS-OEWMA": {"offset": (0.0, 2.2, 0.3388, 4.8621), "variance": (19.8, 0.0, 0.3388, 4.8621),
                 "offset_var": (15.2, 6.2, 0.3388, 4.8621)},
    "SS-DEWMA": {"offset": (1.2, 0.0, 0.4, 3.0), "variance": (14.0, 9.6, 0.3, 0.15),
                 "offset_var": (14.8, 8.8, 0.3, 0.2)},
    "MO-SS-DEWMA": {"offset": (0.0, 0.2, 0.3247, 3.4703), "variance": (8.4, 5.2, 0.3214, 0.1415),
                    "offset_var": (7.8, 6.2, 0.3030, 0.2158)},
}

#: Paper 000 Table 4: the design optimised on offset+variance data, (λ, K_SD), and its
#: (MDR %, FAR %) on each fault.
PAPER_TABLE4_PARAMS = {"lam": 0.3030, "K": 0.2158}
PAPER_TABLE4: dict[str, tuple[float, float]] = {
    "offset": (0.0, 1.4),
    "variance": (8.8, 5.4),
    "offset_var": (7.8, 6.2),
}

#: Fig. 1 / §2.3: after optimisation MDR and FAR were below 1 % for
#: λ ∈ [0.25, 0.45], K_SD ∈ [3.5, 5] (offset fault).
PAPER_GOOD_REGION = {"lam": (0.25, 0.45), "K": (3.5, 5.0), "below": 0.01}

#: Table 2's MOPSO, literally: constriction (eqs. 38–39, w = 0.7298, c = 1.4962), velocity
#: reversed at a bound, Coello's mutation, roulette leaders on the adaptive grid.
PAPER_MOPSO: dict[str, Any] = dict(PAPER_PRESET)

#: MOPSO search box of Table 2 (K_SD ∈ (0, 5); λ keeps its open (0, 1)).
PAPER_BOUNDS = {"K": (0.0, 5.0)}

METHODS = ("M-DEWMA", "MS-OEWMA", "SS-DEWMA", "MO-SS-DEWMA")
#: The extra row: MS-OEWMA with its own tuning rule on our training data.
TUNED_MS_OEWMA = "MS-OEWMA (tuned)"
#: The causal counterpart of MO-SS-DEWMA: tuned the same way on the raw (undenoised) statistic.
CAUSAL_OURS = "MO-SS-DEWMA, causal"
BASELINES = ("M-DEWMA", "MS-OEWMA", "SS-DEWMA")


def paper_error_bound(fault: str) -> float:
    """FAR + MDR of the paper's MO-SS-DEWMA for ``fault`` (Table 3), as a rate."""
    mdr, far, _, _ = PAPER_TABLE3["MO-SS-DEWMA"][fault]
    return (mdr + far) / 100.0


# ------------------------------------------------------------------------------------
# settings
# ------------------------------------------------------------------------------------
@dataclass(frozen=True)
class BudgetPreset:
    """Replications and optimiser effort of one ``--budget`` choice."""

    replications: Budget
    pop_size: int
    n_gen: int
    #: MS-OEWMA tuning grid: λ steps over (0, 1], L steps over (0, 10]
    lam_step: float
    width_step: float


BUDGETS: dict[str, BudgetPreset] = {
    # paper scale: Table 2 (100 particles × 100 iterations), 10 training runs,
    # 100 fresh test runs for the confidence intervals
    "paper": BudgetPreset(Budget(10, 10, 100), pop_size=100, n_gen=100, lam_step=0.05, width_step=0.05),
    "small": BudgetPreset(Budget(4, 4, 20), pop_size=30, n_gen=20, lam_step=0.05, width_step=0.1),
    # smoke tests: every code path, seconds
    "tiny": BudgetPreset(Budget(2, 2, 3), pop_size=8, n_gen=3, lam_step=0.25, width_step=1.0),
}

#: ``--subgroups`` choices: (monitor, run duration in s, fault onset in s). Both give
#: 1,000 subgroups per run after a 200-sample burn-in, the fault on subgroups 501–1000.
SUBGROUPS = ("window", "channels")
_SCENARIO_TIMES = {"window": (5.2, 2.7), "channels": (1.2, 0.7)}


def make_monitor(subgroups: str = "window") -> Monitor:
    """The monitor of a ``--subgroups`` choice (see :class:`PaperSettings`)."""
    if check_choice("subgroups", subgroups, SUBGROUPS) == "window":
        return Monitor(subgroup="window", n=5, channels=[0], burn_in=200)
    return Monitor(subgroup="channels", channels=[0, 1, 2], burn_in=200)


#: ``--wavelet`` choices for the statistic of the SS/M-DEWMA charts.
WAVELETS = ("paper", "sln", "none")


def make_denoiser(wavelet: str):
    """The denoiser of the SS/M-DEWMA statistic.

    ``"paper"`` (default): MATLAB's literal calls of §3.2 — db3, level 3, ``thselect(D,
    'rigrsure')`` on the coarsest details ``D`` without noise rescaling, one global
    soft threshold (``scaling="one", global_source="coarsest"``); whole-series, so
    non-causal; in control it keeps no detail, so l_k is the level-3 approximation
    (docs/DECISIONS.md §4). ``"sln"``: SURE over all details rescaled by
    σ̂ = median|cD₁|/0.6745 (MATLAB ``wden`` 'sln'). ``"none"``: the raw statistic (causal).
    """
    check_choice("wavelet", wavelet, WAVELETS)
    # every setting is spelled out: the class defaults have changed before
    if wavelet == "paper":
        return WaveletDenoiser(scaling="one", scope="global", global_source="coarsest")
    if wavelet == "sln":
        return WaveletDenoiser(scaling="sln", scope="global", global_source="all")
    return NoDenoiser()


def make_prefilter():
    """MS-OEWMA's residual prefilter, pinned: db3, level 3, rigrsure on all details rescaled by σ̂
    (``sln``) — noise removal at every scale, as :class:`mosd.detectors.MSOEWMA` documents it."""
    return WaveletDenoiser(scaling="sln", scope="global", global_source="all")


@dataclass(frozen=True)
class PaperSettings:
    """What one study runs with.

    Parameters
    ----------
    budget : {"paper", "small", "tiny"}
        See :data:`BUDGETS`.
    seed : int
        Root seed: simulation streams and the optimisers.
    wavelet : {"paper", "sln", "none"}
        Denoiser of the SS/M-DEWMA statistic (:func:`make_denoiser`).
    n_jobs : int
        Worker processes for the optimisers' fitness evaluations.
    alpha : float in [0, 1]
        FAR budget of the MS-OEWMA tuning rule (extra row).
    k_max : float in (0, 10]
        Upper end of the K_SD search box (Table 2: 5; Fig. 1 scans up to 10).
    subgroups : {"window", "channels"}
        ``"window"`` (default, docs/DECISIONS.md §2): n = 5 consecutive x_p residuals,
        5.2 s runs, onset 2.7 s. ``"channels"``: the paper's literal reading — the three
        residual channels of one sample form a subgroup, 1.2 s runs (1,000 samples after
        the 200-sample burn-in), onset 0.7 s; the fault on x_p then moves U_k by a/√3 only.
    """

    budget: str = "paper"
    seed: int = 0
    wavelet: str = "paper"
    n_jobs: int = 2
    alpha: float = 0.05
    k_max: float = 5.0
    subgroups: str = "window"

    def __post_init__(self):
        check_choice("budget", self.budget, tuple(BUDGETS))
        check_int("seed", self.seed, 0, 2**63 - 1)
        check_choice("wavelet", self.wavelet, WAVELETS)
        check_int("n_jobs", self.n_jobs, 1, 64)
        check_in("alpha", self.alpha, Interval(0.0, 1.0))
        check_in("k_max", self.k_max, Interval(0.0, 10.0, open_low=True))
        check_choice("subgroups", self.subgroups, SUBGROUPS)

    @property
    def preset(self) -> BudgetPreset:
        return BUDGETS[self.budget]

    @property
    def bounds(self) -> dict[str, tuple[float, float]]:
        """The optimiser's search box: λ ∈ (0, 1), K_SD ∈ (0, k_max)."""
        return {"K": (0.0, float(self.k_max))}

    def describe(self) -> dict[str, Any]:
        p = self.preset
        return {
            "budget": self.budget, "seed": self.seed, "wavelet": self.wavelet, "n_jobs": self.n_jobs,
            "n_calibration": p.replications.n_calibration, "n_train": p.replications.n_train,
            "n_test": p.replications.n_test, "pop_size": p.pop_size, "n_gen": p.n_gen,
            "ms_oewma_alpha": self.alpha, "k_max": self.k_max, "subgroups": self.subgroups,
            "denoiser": repr(make_denoiser(self.wavelet)),
        }


def make_fault(name: str, onset: float = 2.7) -> SensorFault:
    """The :class:`SensorFault` of one of :data:`FAULTS` on channel 0 (x_p)."""
    spec = FAULTS[check_choice("fault", name, tuple(FAULTS))]
    return SensorFault(str(spec["kind"]), channel=0, onset=onset, a=float(spec["a"]), b=float(spec["b"]))


def make_chart(method: str, params: dict[str, float], wavelet: str = "paper") -> Chart:
    """A comparison chart with the given parameters (limit of eq. 27 for all)."""
    if method == "M-DEWMA":
        return MDEWMA(limit="phase1", denoiser=make_denoiser(wavelet), **params)
    if method in ("SS-DEWMA", "MO-SS-DEWMA"):
        return SSDEWMA(limit="phase1", denoiser=make_denoiser(wavelet), **params)
    if method == CAUSAL_OURS:
        return SSDEWMA(limit="phase1", denoiser=NoDenoiser(), **params)
    if method in ("MS-OEWMA", TUNED_MS_OEWMA):
        return MSOEWMA(limit="phase1", prefilter=make_prefilter(), **params)
    raise ConfigError(f"method={method!r} is not allowed; allowed: "
                      f"{', '.join(METHODS + (TUNED_MS_OEWMA, CAUSAL_OURS))}")


# ------------------------------------------------------------------------------------
# data: Phase I once, training and test runs once per fault
# ------------------------------------------------------------------------------------
@dataclass
class FaultData:
    """One fault's cached data: Phase I and training (the optimiser's), test (reported)."""

    name: str
    fault: SensorFault
    prepared: PreparedData
    test: tuple  # (Subgroups, Residuals) of Experiment.test_data

    @property
    def test_subgroups(self) -> Subgroups:
        return self.test[0]


@dataclass
class Study:
    """The paper's experiment, its settings and the per-fault data cache of one reproduction.

    Build with :func:`build_study`; :func:`fault_data` fills ``faults`` on demand.
    Every stage is a verb of :class:`~mosd.experiment.Experiment`: this module only
    chooses the paper's set-ups and formats tables and figures.
    """

    settings: PaperSettings
    experiment: Experiment
    calibration: Any
    faults: dict[str, FaultData] = field(default_factory=dict)
    timings: dict[str, float] = field(default_factory=dict)


def build_study(settings: PaperSettings | None = None) -> Study:
    """The paper's experiment and its Phase-I calibration (shared by all faults: the stream is fault-free)."""
    settings = settings or PaperSettings()
    t0 = time.perf_counter()
    duration, onset = _SCENARIO_TIMES[settings.subgroups]
    experiment = Experiment(
        MouldOscillator(), GaussianNoise(), make_fault("offset_var", onset),
        DedicatedObserverResidual(CESCKF(), monitored=[0]), make_monitor(settings.subgroups),
        make_chart("MO-SS-DEWMA", {"lam": 0.3, "K": 3.0}, settings.wavelet),
        duration=duration, budget=settings.preset.replications, seed=settings.seed,
    )
    study = Study(settings, experiment, experiment.calibrate())
    study.timings["calibration_s"] = time.perf_counter() - t0
    return study


def fault_data(study: Study, name: str) -> FaultData:
    """Training and test data of one fault (simulated once, then cached on ``study``)."""
    if name in study.faults:
        return study.faults[name]
    t0 = time.perf_counter()
    exp = study.experiment
    fault = make_fault(name, onset=exp.fault.onset)
    prepared = exp.prepare(calibration=study.calibration, fault=fault)
    data = FaultData(name, fault, prepared, exp.test_data(prepared, fault=fault))
    study.faults[name] = data
    study.timings[f"simulate_{name}_s"] = time.perf_counter() - t0
    return data


# ------------------------------------------------------------------------------------
# scoring and tuning: Experiment's verbs
# ------------------------------------------------------------------------------------
def evaluate_design(chart: Chart, study: Study, data: FaultData) -> DetectionReport:
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
    width = chart.get_params()[list(chart.tunable)[1]]
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


def make_evaluator(chart: Chart, study: Study, data: FaultData):
    """The (FAR, MDR) map over the fault's training runs (eq. 36's objectives)."""
    return study.experiment.evaluator(data.prepared, chart)


def make_solver(algorithm: str, pop_size: int):
    """The paper's MOPSO (Table 2, literal) or pymoo's NSGA-II."""
    check_choice("algorithm", algorithm, ("mopso", "nsga2"))
    if algorithm == "mopso":
        from .optim.mopso import MOPSO

        return MOPSO(pop_size=pop_size, **PAPER_MOPSO)
    from pymoo.algorithms.moo.nsga2 import NSGA2

    return NSGA2(pop_size=pop_size)


def optimise(chart: Chart, study: Study, data: FaultData, algorithm: str = "mopso", pop_size: int = 100,
             n_gen: int = 100, bounds: dict | None = None, n_jobs: int = 2, rule: str = "max_accuracy") -> Tuned:
    """Minimise (FAR, MDR) over the chart's parameters on the fault's training runs (eq. 36).

    :meth:`Experiment.tune` with the paper's optimiser (``algorithm``: Table 2's MOPSO
    or NSGA-II), ``pop_size`` particles × ``n_gen`` iterations (Table 2: 100 × 100),
    the search box ``bounds`` (Table 2: K_SD ∈ (0, 5)) and the choice rule
    (docs/DECISIONS.md §6).
    """
    from .optim.selection import choose

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


def run_table3(study: Study, faults: Sequence[str] = tuple(FAULTS), include_tuned: bool = True) -> Table3:
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
            chart = make_chart(method, params, settings.wavelet)
            rows.append(Row(method, name, dict(params), evaluate_design(chart, study, data),
                            seconds=time.perf_counter() - t0, causal=chart.is_causal))
            self_referenced.append(Row(method, name, dict(params), self_referenced_report(chart, data)))
        if include_tuned:
            rows.append(tune_ms_oewma(study, data))
        opt = optimise(make_chart("MO-SS-DEWMA", {"lam": 0.3, "K": 3.0}, settings.wavelet), study, data, "mopso",
                       preset.pop_size, preset.n_gen, settings.bounds, settings.n_jobs)
        archives[name] = opt
        t0 = time.perf_counter()
        chosen = make_chart("MO-SS-DEWMA", opt.params, settings.wavelet)
        report = evaluate_design(chosen, study, data)
        ours = Row("MO-SS-DEWMA", name, opt.params, report, _pair(opt),
                   opt.seconds + time.perf_counter() - t0, causal=chosen.is_causal)
        rows.append(ours)
        if not chosen.is_causal:
            online = tune_causal(study, data)
            causal.append(online)
            causal_bars.append(compare_accuracy(online, ours))
        anatomy[name] = error_anatomy(make_chart("MO-SS-DEWMA", opt.params, settings.wavelet), data)
        by_method = {r.method: r for r in rows if r.fault == name}
        bars.extend(compare_accuracy(ours, by_method[m]) for m in BASELINES)
        if include_tuned:
            bars.append(compare_accuracy(ours, by_method[TUNED_MS_OEWMA]))
        bars.append(compare_with_paper(ours))
    return Table3(settings.describe(), rows, bars, archives, dict(study.timings), self_referenced, anatomy,
                  causal, causal_bars)


def tune_causal(study: Study, data: FaultData) -> Row:
    """:data:`CAUSAL_OURS`: MO-SS-DEWMA's optimiser, box, budget and data on the raw statistic (online)."""
    settings, preset = study.settings, study.settings.preset
    chart = make_chart(CAUSAL_OURS, {"lam": 0.3, "K": 3.0})
    opt = optimise(chart, study, data, "mopso", preset.pop_size, preset.n_gen, settings.bounds, settings.n_jobs)
    t0 = time.perf_counter()
    chosen = chart.with_params(**opt.params)
    report = evaluate_design(chosen, study, data)
    return Row(CAUSAL_OURS, data.name, opt.params, report, _pair(opt), opt.seconds + time.perf_counter() - t0,
               causal=chosen.is_causal)


def tune_ms_oewma(study: Study, data: FaultData) -> Row:
    """MS-OEWMA tuned by its own rule on the training runs (:func:`constrained_grid_search`)."""
    from .optim.grid import constrained_grid_search

    t0 = time.perf_counter()
    lam, width = ms_oewma_grid(study.settings.preset)
    chart = make_chart(TUNED_MS_OEWMA, PAPER_PRESETS["MS-OEWMA"][data.name])
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


def run_table4(study: Study, optimised: Tuned | None = None) -> Table4:
    """Table 4: optimise on offset+variance training runs, score that design on every fault."""
    settings, preset = study.settings, study.settings.preset
    if optimised is None:
        optimised = optimise(make_chart("MO-SS-DEWMA", {"lam": 0.3, "K": 3.0}, settings.wavelet), study,
                             fault_data(study, "offset_var"), "mopso", preset.pop_size, preset.n_gen,
                             settings.bounds, settings.n_jobs)
    chart = make_chart("MO-SS-DEWMA", optimised.params, settings.wavelet)
    rows = [Row("MO-SS-DEWMA", name, optimised.params, evaluate_design(chart, study, fault_data(study, name)),
                causal=chart.is_causal) for name in FAULTS]
    return Table4(settings.describe(), optimised.params, _pair(optimised), rows)


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


def run_fig1(study: Study, fault: str = "offset", n: int = 20) -> GridScan:
    """FAR and MDR of SS-DEWMA over the n×n (λ, K_SD) grid on the training runs (Fig. 1)."""
    from .optim.grid import grid_objectives

    t0 = time.perf_counter()
    lam, K = fig1_axes(n)
    chart = make_chart("SS-DEWMA", {"lam": 0.3, "K": 3.0}, study.settings.wavelet)
    far, mdr = grid_objectives(make_evaluator(chart, study, fault_data(study, fault)), lam, K)
    return GridScan(fault, lam, K, far, mdr, time.perf_counter() - t0)


@dataclass
class ParetoComparison:
    fault: str
    fronts: dict[str, Tuned]
    hypervolume: dict[str, float]
    grid: GridScan | None


def run_pareto(study: Study, fault: str = "offset_var", grid: GridScan | None = None) -> ParetoComparison:
    """MOPSO against NSGA-II with the same budget and bounds on one fault's training runs.

    Hypervolume of each front with reference point (FAR, MDR) = (1, 1).
    """
    from pymoo.indicators.hv import HV

    settings, preset = study.settings, study.settings.preset
    data = fault_data(study, fault)
    fronts = {
        algo: optimise(make_chart("MO-SS-DEWMA", {"lam": 0.3, "K": 3.0}, settings.wavelet), study, data, algo,
                       preset.pop_size, preset.n_gen, settings.bounds, settings.n_jobs)
        for algo in ("mopso", "nsga2")
    }
    indicator = HV(ref_point=np.array([1.0, 1.0]))
    hv = {algo: float(indicator(front.F)) for algo, front in fronts.items()}
    return ParetoComparison(fault, fronts, hv, grid)


# ------------------------------------------------------------------------------------
# formatting
# ------------------------------------------------------------------------------------
def _pct(estimate: Estimate) -> str:
    half = estimate.half_width
    if not math.isfinite(half):
        return f"{100 * estimate.mean:.2f}"
    return f"{100 * estimate.mean:.2f} ± {100 * half:.2f}"


def _params_text(method: str, params: dict[str, float]) -> tuple[str, str]:
    lam = params.get("lam", float("nan"))
    width = params.get("K", params.get("L", float("nan")))
    return f"{lam:.4f}", f"{width:.4f}"


def _online(row: Row) -> str:
    return "—" if row.causal is None else ("yes" if row.causal else "**no**")


def _detection_cells(row: Row) -> str:
    """Detected runs %, mean delay over detected runs and median censored delay (subgroups)."""
    s = row.summary()
    detected = s.get("detection_rate")
    delay = s.get("delay")
    median = row.report.median_censored_delay()
    det = "—" if detected is None or not math.isfinite(detected.mean) else f"{100 * detected.mean:.0f}"
    mean = "—" if delay is None or not math.isfinite(delay.mean) else (
        f"{delay.mean:.2f}" if not math.isfinite(delay.half_width) else f"{delay.mean:.2f} ± {delay.half_width:.2f}")
    med = "—" if math.isnan(median) else ("beyond horizon" if math.isinf(median) else f"{median:g}")
    return f"{det} | {mean} | {med}"


_DETECTION_HEADER = "detected % | delay (detected runs) | median delay, missed = ∞"


def format_table3(table: Table3) -> str:
    """Markdown: ours (mean ± 95 % CI over test replications) beside the paper's Table 3.

    ``online`` says whether the chart is causal; delays are in subgroups.
    """
    lines = [
        "| fault | method | online | MDR % (ours) | MDR % (paper) | FAR % (ours) | FAR % (paper) | λ (ours) "
        f"| λ (paper) | K (ours) | K (paper) | {_DETECTION_HEADER} |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for row in table.rows:
        s = row.summary()
        paper = PAPER_TABLE3.get(row.method, {}).get(row.fault)
        lam, width = _params_text(row.method, row.params)
        if paper is None:
            p_mdr = p_far = p_lam = p_k = "—"
        else:
            p_mdr, p_far, p_lam, p_k = (f"{paper[0]:g}", f"{paper[1]:g}", f"{paper[2]:g}", f"{paper[3]:g}")
        lines.append(f"| {FAULT_LABELS[row.fault]} | {row.method} | {_online(row)} | {_pct(s['mdr'])} | {p_mdr} "
                     f"| {_pct(s['far'])} | {p_far} | {lam} | {p_lam} | {width} | {p_k} | {_detection_cells(row)} |")
    return "\n".join(lines)


def format_causal(table: Table3) -> str:
    """Markdown: the literal (non-causal) MO-SS-DEWMA beside its causal counterpart, per fault.

    Faults are named by their key (``offset``, ...); accuracy difference causal − literal is paired
    over the same test runs (95 % CI).
    """
    literal = {r.fault: r for r in table.rows if r.method == "MO-SS-DEWMA"}
    bars = {b.fault: b for b in table.causal_bars}
    lines = [f"| fault | design | online | λ | K | MDR % | FAR % | {_DETECTION_HEADER} | accuracy causal − literal (pp) |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for online in table.causal:
        for row in (literal[online.fault], online):
            s = row.summary()
            lam, width = _params_text(row.method, row.params)
            diff = f"{_pct(bars[row.fault].estimate)} ({bars[row.fault].verdict})" if row is online else ""
            lines.append(f"| {row.fault} | {row.method} | {_online(row)} | {lam} | {width} | {_pct(s['mdr'])} "
                         f"| {_pct(s['far'])} | {_detection_cells(row)} | {diff} |")
    return "\n".join(lines)


def format_self_referenced(table: Table3) -> str:
    """Markdown: paper-parameter charts with the Phase-I limit and with the self-referenced one."""
    honest = {(r.method, r.fault): r for r in table.rows}
    lines = ["| fault | method | MDR % Phase-I limit | FAR % Phase-I limit | MDR % self-referenced | "
             "FAR % self-referenced | MDR % (paper) | FAR % (paper) |", "|---|---|---|---|---|---|---|---|"]
    for row in table.self_referenced:
        s, h = row.summary(), honest[(row.method, row.fault)].summary()
        paper = PAPER_TABLE3[row.method][row.fault]
        lines.append(f"| {FAULT_LABELS[row.fault]} | {row.method} | {_pct(h['mdr'])} | {_pct(h['far'])} "
                     f"| {_pct(s['mdr'])} | {_pct(s['far'])} | {paper[0]:g} | {paper[1]:g} |")
    return "\n".join(lines)


def format_anatomy(table: Table3) -> str:
    """Markdown: where MO-SS-DEWMA's test errors fall (subgroups per run)."""
    lines = ["| fault | missed: first faulty subgroup | missed: later | false: ≤ 10 before onset | "
             "false: elsewhere | runs with a false alarm |", "|---|---|---|---|---|---|"]
    for fault, a in table.anatomy.items():
        lines.append(f"| {FAULT_LABELS[fault]} | {a['missed_onset']:.2f} | {a['missed_later']:.2f} "
                     f"| {a['false_near_onset']:.2f} | {a['false_elsewhere']:.2f} "
                     f"| {100 * a['runs_with_false_alarm']:.0f} % |")
    return "\n".join(lines)


def format_bars(bars: Sequence[BarCheck]) -> str:
    lines = ["| fault | bar | estimate (pp, 95 % CI) | threshold | met | verdict |", "|---|---|---|---|---|---|"]
    for bar in bars:
        lines.append(f"| {FAULT_LABELS[bar.fault]} | {bar.name} | {_pct(bar.estimate)} | {100 * bar.threshold:g} "
                     f"| {'yes' if bar.met else 'no'} | {bar.verdict} |")
    return "\n".join(lines)


def format_table4(table: Table4) -> str:
    lam, K = table.params["lam"], table.params["K"]
    lines = [
        f"Design optimised on offset + variance: λ = {lam:.4f}, K = {K:.4f} (paper: "
        f"{PAPER_TABLE4_PARAMS['lam']:.4f}, {PAPER_TABLE4_PARAMS['K']:.4f}); training FAR, MDR = "
        f"{100 * table.train_objectives[0]:.2f} %, {100 * table.train_objectives[1]:.2f} %",
        "",
        "| fault | online | MDR % (ours) | MDR % (paper) | FAR % (ours) | FAR % (paper) | accuracy % (ours) "
        f"| accuracy % (paper) | {_DETECTION_HEADER} |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for row in table.rows:
        s = row.summary()
        p_mdr, p_far = PAPER_TABLE4[row.fault]
        lines.append(f"| {FAULT_LABELS[row.fault]} | {_online(row)} | {_pct(s['mdr'])} | {p_mdr:g} | {_pct(s['far'])} "
                     f"| {p_far:g} | {_pct(s['accuracy'])} | {100 - p_mdr - p_far:g} | {_detection_cells(row)} |")
    return "\n".join(lines)


def _estimate_json(e: Estimate) -> dict[str, float]:
    return {"mean": e.mean, "half_width": e.half_width, "n": e.n}


def _row_json(row: Row) -> dict[str, Any]:
    s = row.summary()
    return {
        "method": row.method, "fault": row.fault, "params": row.params,
        "mdr": _estimate_json(s["mdr"]), "far": _estimate_json(s["far"]),
        "accuracy": _estimate_json(s["accuracy"]), "delay": _estimate_json(s["delay"]),
        "train_objectives": row.train_objectives, "seconds": row.seconds, "online": row.causal,
        **({"detection_rate": _estimate_json(s["detection_rate"])} if "detection_rate" in s else {}),
        "median_censored_delay": row.report.median_censored_delay(),
    }


# ------------------------------------------------------------------------------------
# files
# ------------------------------------------------------------------------------------
def _figure(width: float, height: float):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def write_table3(table: Table3, out: Path) -> list[Path]:
    out.mkdir(parents=True, exist_ok=True)
    md = out / "table3.md"
    md.write_text(format_table3(table) + "\n\n" + format_bars(table.bars) + "\n\n"
                  + format_self_referenced(table) + "\n\n" + format_anatomy(table) + "\n")
    written = [md]
    if table.causal:
        causal_md = out / "table3_causal.md"
        causal_md.write_text(format_causal(table) + "\n")
        written.append(causal_md)
    js = out / "table3.json"
    js.write_text(json.dumps({
        "settings": table.settings,
        "rows": [_row_json(r) for r in table.rows],
        "bars": [{"fault": b.fault, "bar": b.name, "estimate": _estimate_json(b.estimate),
                  "threshold": b.threshold, "met": b.met, "verdict": b.verdict} for b in table.bars],
        "archives": {f: {"X": o.X.tolist(), "F": o.F.tolist(), "chosen": o.index, "seconds": o.seconds}
                     for f, o in table.archives.items()},
        "timings": table.timings,
        "self_referenced": [_row_json(r) for r in table.self_referenced],
        "anatomy": table.anatomy,
        "causal": [_row_json(r) for r in table.causal],
        "causal_vs_literal": [{"fault": b.fault, "accuracy_difference": _estimate_json(b.estimate),
                               "verdict": b.verdict} for b in table.causal_bars],
    }, indent=1))
    return written + [js]


def write_table4(table: Table4, out: Path) -> list[Path]:
    out.mkdir(parents=True, exist_ok=True)
    md = out / "table4.md"
    md.write_text(format_table4(table) + "\n")
    js = out / "table4.json"
    js.write_text(json.dumps({"settings": table.settings, "params": table.params,
                              "train_objectives": table.train_objectives,
                              "rows": [_row_json(r) for r in table.rows]}, indent=1))
    return [md, js]


def write_fig1(scan: GridScan, out: Path) -> list[Path]:
    """CSV of the grid and the two 3-D surfaces (MDR, FAR) as one PNG."""
    out.mkdir(parents=True, exist_ok=True)
    path_csv = out / f"fig1_grid_{scan.fault}.csv"
    with path_csv.open("w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(["lam", "K", "far", "mdr"])
        for i, lam in enumerate(scan.lam):
            for j, K in enumerate(scan.K):
                writer.writerow([f"{lam:.6g}", f"{K:.6g}", f"{scan.far[i, j]:.6g}", f"{scan.mdr[i, j]:.6g}"])
    fig = _figure(11.0, 4.6)
    lam_mesh, k_mesh = np.meshgrid(scan.lam, scan.K, indexing="ij")
    for position, (label, values) in enumerate((("MDR %", scan.mdr), ("FAR %", scan.far)), start=1):
        ax = fig.add_subplot(1, 2, position, projection="3d")
        ax.plot_surface(lam_mesh, k_mesh, 100 * values, cmap="viridis", linewidth=0.2, edgecolor="k", alpha=0.9)
        ax.set_xlabel("λ")
        ax.set_ylabel("K_SD")
        ax.set_zlabel(label)
        ax.set_title(f"SS-DEWMA {label[:3]} ({FAULT_LABELS[scan.fault]}, training runs)", fontsize=9)
        ax.view_init(elev=25, azim=-130)
    path_png = out / f"fig1_surface_{scan.fault}.png"
    fig.savefig(path_png, dpi=90)
    return [path_csv, path_png]


def write_pareto(comparison: ParetoComparison, out: Path) -> list[Path]:
    """Both archives in the (FAR, MDR) plane, chosen designs starred, grid points behind."""
    out.mkdir(parents=True, exist_ok=True)
    fig = _figure(6.4, 4.6)
    ax = fig.add_subplot()
    if comparison.grid is not None:
        ax.scatter(100 * comparison.grid.far.ravel(), 100 * comparison.grid.mdr.ravel(), s=6, color="0.75",
                   label="20×20 grid (Fig. 1 axes)")
    styles = {"mopso": ("tab:blue", "o", "MOPSO"), "nsga2": ("tab:orange", "s", "NSGA-II")}
    for algo, front in comparison.fronts.items():
        color, marker, label = styles[algo]
        distinct = np.unique(front.F, axis=0)  # sorted by FAR; NSGA-II keeps duplicates
        # the attainment boundary: each point's MDR holds until the next point's FAR
        ax.plot(100 * distinct[:, 0], 100 * distinct[:, 1], marker=marker, ms=3.5, lw=0.8, color=color,
                drawstyle="steps-post",
                label=f"{label} ({len(distinct)} distinct points, HV {comparison.hypervolume[algo]:.5f})")
        ax.plot(100 * front.F[front.index, 0], 100 * front.F[front.index, 1], "*", ms=13, color=color,
                markeredgecolor="k")
    ax.set_xscale("symlog", linthresh=0.1)
    ax.set_yscale("symlog", linthresh=0.1)
    ax.set_xlabel("training FAR %")
    ax.set_ylabel("training MDR %")
    ax.set_title(f"Pareto fronts, {FAULT_LABELS[comparison.fault]} (★ = max-accuracy choice)", fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    path_png = out / f"pareto_{comparison.fault}.png"
    fig.savefig(path_png, dpi=110)
    path_csv = out / f"pareto_{comparison.fault}.csv"
    with path_csv.open("w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(["algorithm", "lam", "K", "far", "mdr", "chosen"])
        for algo, front in comparison.fronts.items():
            for k, (x, f) in enumerate(zip(front.X, front.F)):
                writer.writerow([algo, f"{x[0]:.6g}", f"{x[1]:.6g}", f"{f[0]:.6g}", f"{f[1]:.6g}", int(k == front.index)])
    return [path_png, path_csv]


# ------------------------------------------------------------------------------------
# command line
# ------------------------------------------------------------------------------------
COMMANDS = ("table3", "table4", "fig1", "pareto", "all")


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m mosd.paper", description=__doc__.split("\n\n")[0])
    parser.add_argument("command", choices=COMMANDS)
    parser.add_argument("--budget", choices=tuple(BUDGETS), default="paper")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--wavelet", choices=WAVELETS, default="paper",
                        help="denoiser of the SS/M-DEWMA statistic (default: the paper's literal MATLAB calls)")
    parser.add_argument("--n-jobs", type=int, default=2)
    parser.add_argument("--k-max", type=float, default=5.0,
                        help="upper end of the K_SD search box (Table 2: 5; Fig. 1 scans to 10)")
    parser.add_argument("--subgroups", choices=SUBGROUPS, default="window",
                        help="window: 5 consecutive x_p residuals (default); channels: the 3 residual channels "
                             "of one sample (the paper's literal reading)")
    parser.add_argument("--fault", choices=tuple(FAULTS), default=None,
                        help="fig1 (default offset) and pareto (default offset_var)")
    parser.add_argument("--out", default="outputs/paper", help="output directory")
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    try:
        settings = PaperSettings(budget=args.budget, seed=args.seed, wavelet=args.wavelet, n_jobs=args.n_jobs,
                                 k_max=args.k_max, subgroups=args.subgroups)
    except ConfigError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    out = Path(args.out)
    study = build_study(settings)
    written: list[Path] = []
    t0 = time.perf_counter()
    table3 = None
    if args.command in ("table3", "all"):
        table3 = run_table3(study)
        print("## Table 3\n\n" + format_table3(table3) + "\n\n### Bars\n\n" + format_bars(table3.bars)
              + "\n\n### Paper parameters, Phase-I vs self-referenced limit\n\n"
              + format_self_referenced(table3) + "\n\n### Where MO-SS-DEWMA's errors fall (subgroups per run)\n\n"
              + format_anatomy(table3) + "\n")
        if table3.causal:
            print("### The literal MO-SS-DEWMA (non-causal) beside its causal counterpart\n\n"
                  + format_causal(table3) + "\n")
        written += write_table3(table3, out)
    if args.command in ("table4", "all"):
        table4 = run_table4(study, None if table3 is None else table3.archives.get("offset_var"))
        print("## Table 4\n\n" + format_table4(table4) + "\n")
        written += write_table4(table4, out)
    grids: dict[str, GridScan] = {}
    if args.command in ("fig1", "all"):
        fault = args.fault or "offset"
        grids[fault] = scan = run_fig1(study, fault)
        region = scan.good_region(PAPER_GOOD_REGION["below"])
        print(f"## Fig. 1 ({FAULT_LABELS[fault]})\n\ngrid points with MDR and FAR < 1 %: {region['count']} of "
              f"{region['of']}, bounding box {region['box']} (paper: λ ∈ [0.25, 0.45], K ∈ [3.5, 5])\n")
        written += write_fig1(scan, out)
    if args.command in ("pareto", "all"):
        fault = args.fault or "offset_var"
        if fault not in grids:
            grids[fault] = run_fig1(study, fault)
            written += write_fig1(grids[fault], out)
        comparison = run_pareto(study, fault, grids[fault])
        print(f"## Pareto fronts ({FAULT_LABELS[fault]})\n")
        for algo, front in comparison.fronts.items():
            far, mdr = front.train_objectives
            print(f"- {algo}: {len(np.unique(front.F, axis=0))} distinct front points, hypervolume {comparison.hypervolume[algo]:.6f}, "
                  f"chosen λ = {front.params['lam']:.4f}, K = {front.params['K']:.4f} (training FAR {100 * far:.2f} %, "
                  f"MDR {100 * mdr:.2f} %), {front.seconds:.1f} s")
        print()
        written += write_pareto(comparison, out)
    print(f"settings: {json.dumps(settings.describe())}")
    print(f"timings: {json.dumps({k: round(v, 2) for k, v in study.timings.items()})}, "
          f"analysis {time.perf_counter() - t0:.1f} s")
    print("wrote: " + ", ".join(str(p) for p in written))
    return 0


if __name__ == "__main__":
    sys.exit(main())
