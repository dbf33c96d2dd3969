"""Paper 000's reproduction set-up: the ``--budget`` choices, the settings, the charts and the data cache.

The experiment is the ``+experiment=paper000`` preset (``conf/experiment/paper000.yaml``: mould
oscillator, dedicated-observer CESCKF residual, windows of n = 5, SS-DEWMA with the paper's
literal wavelet, Table 2's MOPSO and box) with the settings' overrides, composed by
:mod:`mosd.app.presets`; its calibration is shared by every fault (the calibration stream is
fault-free), and each fault's training and test runs are simulated once.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

from ...denoisers import NoDenoiser, WaveletDenoiser
from ...detectors import MDEWMA, MSOEWMA, SSDEWMA, Chart
from ...experiment import Budget, Experiment, PreparedData
from ...types import Subgroups
from ...validation import ConfigError, Interval, check_choice, check_in, check_int
from .. import cli
from .numbers import CAUSAL_OURS, FAULTS, METHODS, TUNED_MS_OEWMA


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

#: ``--subgroups`` choices and their preset overrides. Both give 1,000 subgroups per run after a
#: 200-sample burn-in, the fault on subgroups 501–1000: ``window`` is the preset (5.2 s runs, onset
#: 2.7 s); ``channels`` the three residual channels of one sample, 1.2 s runs, onset 0.7 s.
SUBGROUPS = {"window": (), "channels": ("monitor=channels", "scenario.duration=1.2", "fault.onset=0.7")}

#: ``--wavelet`` choices for the statistic of the SS/M-DEWMA charts, as overrides of the preset's
#: ``denoise=wavelet`` (``conf/denoise/wavelet.yaml``: MATLAB's literal calls of §3.2 — db3, level 3,
#: ``thselect(D, 'rigrsure')`` on the coarsest details without noise rescaling, one global soft
#: threshold; whole-series, so non-causal; docs/DECISIONS.md §4). ``sln``: SURE over all details
#: rescaled by σ̂ = median|cD₁|/0.6745 (MATLAB ``wden`` 'sln'). ``none``: the raw statistic (causal).
WAVELETS = {"paper": (), "sln": ("denoise.scaling=sln", "denoise.global_source=all"), "none": ("denoise=none",)}

#: conf/optimizer options of the optimisers the reproduction compares (MOPSO: Table 2 literally)
SOLVERS = {"mopso": "mopso_paper", "nsga2": "nsga2"}


def make_prefilter(window: int | None = None) -> WaveletDenoiser:
    """MS-OEWMA's residual prefilter, pinned: db3, level 3, rigrsure on all details rescaled by σ̂
    (``sln``) — noise removal at every scale, as :class:`mosd.detectors.MSOEWMA` documents it;
    whole series (``window=None``, as paper 000 used it) or a causal sliding window."""
    return WaveletDenoiser(scaling="sln", scope="global", global_source="all", window=window)


def make_solver(algorithm: str, pop_size: int):
    """A fresh optimiser: the paper's MOPSO (``conf/optimizer/mopso_paper.yaml``) or NSGA-II, of ``pop_size``."""
    option = SOLVERS[check_choice("algorithm", algorithm, tuple(SOLVERS))]
    return cli.component("optimizer", option, [f"pop_size={int(pop_size)}"])


def make_fault(name: str, onset: float = 2.7):
    """The fault ``conf/fault/<name>.yaml`` (one of :data:`FAULTS`) from ``onset`` (s)."""
    return cli.component("fault", check_choice("fault", name, FAULTS), [f"onset={float(onset)!r}"])


def make_chart(method: str, params: dict[str, float], chart: Chart) -> Chart:
    """A compared chart of ``method`` with ``params``, beside the preset's SS-DEWMA ``chart``.

    Every SS/M-DEWMA chart shares the preset chart's Phase-I limit (eq. 27) and denoiser
    (§3.2), so within that family only the parameters differ; the causal counterpart
    (:data:`CAUSAL_OURS`) is SS-DEWMA on the raw statistic, MS-OEWMA (:data:`TUNED_MS_OEWMA`
    too) filters the residual with :func:`make_prefilter`.
    """
    if method in ("SS-DEWMA", "MO-SS-DEWMA"):
        return chart.with_params(**params)
    if method == "M-DEWMA":
        return MDEWMA(limit=chart.limit, denoiser=getattr(chart, "denoiser", None), **params)
    if method == CAUSAL_OURS:
        return SSDEWMA(limit=chart.limit, denoiser=NoDenoiser(), **params)
    if method in ("MS-OEWMA", TUNED_MS_OEWMA):
        return MSOEWMA(limit=chart.limit, prefilter=make_prefilter(), **params)
    raise ConfigError(f"method={method!r} is not allowed; allowed: {', '.join(METHODS + (TUNED_MS_OEWMA, CAUSAL_OURS))}")


@dataclass(frozen=True)
class PaperSettings:
    """What one reproduction runs with.

    Parameters
    ----------
    budget : {"paper", "small", "tiny"}
        See :data:`BUDGETS`.
    seed : int
        Root seed: simulation streams and the optimisers.
    wavelet : {"paper", "sln", "none"}
        Denoiser of the SS/M-DEWMA statistic (:data:`WAVELETS`).
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
        check_choice("wavelet", self.wavelet, tuple(WAVELETS))
        check_int("n_jobs", self.n_jobs, 1, 64)
        check_in("alpha", self.alpha, Interval(0.0, 1.0))
        check_in("k_max", self.k_max, Interval(0.0, 10.0, open_low=True))
        check_choice("subgroups", self.subgroups, tuple(SUBGROUPS))

    @property
    def preset(self) -> BudgetPreset:
        return BUDGETS[self.budget]

    @property
    def bounds(self) -> dict[str, tuple[float, float]]:
        """The optimiser's search box beyond λ's (0, 1): K_SD ∈ (0, k_max)."""
        return {"K": (0.0, float(self.k_max))}

    def overrides(self) -> list[str]:
        """The ``+experiment=paper000`` overrides of these settings (Hydra syntax)."""
        budget = self.preset.replications
        return [f"seed={self.seed}", f"budget.n_calibration={budget.n_calibration}",
                f"budget.n_train={budget.n_train}", f"budget.n_test={budget.n_test}",
                *WAVELETS[self.wavelet], *SUBGROUPS[self.subgroups]]

    def describe(self) -> dict[str, Any]:
        p = self.preset
        return {
            "budget": self.budget, "seed": self.seed, "wavelet": self.wavelet, "n_jobs": self.n_jobs,
            "n_calibration": p.replications.n_calibration, "n_train": p.replications.n_train,
            "n_test": p.replications.n_test, "pop_size": p.pop_size, "n_gen": p.n_gen,
            "ms_oewma_alpha": self.alpha, "k_max": self.k_max, "subgroups": self.subgroups,
        }


@dataclass
class FaultData:
    """One fault's cached data: Phase I and training (the optimiser's), test (reported)."""

    name: str
    fault: Any
    prepared: PreparedData
    test: tuple  # (Subgroups, Residuals) of Experiment.test_data

    @property
    def test_subgroups(self) -> Subgroups:
        return self.test[0]


@dataclass
class Reproduction:
    """The paper's experiment, its settings and the per-fault data cache of one reproduction.

    Build with :func:`build_study`; :func:`fault_data` fills ``faults`` on demand.
    Every stage is a verb of :class:`~mosd.experiment.Experiment`: this package only
    chooses the paper's set-ups and formats tables and figures.
    """

    settings: PaperSettings
    experiment: Experiment
    calibration: Any
    faults: dict[str, FaultData] = field(default_factory=dict)
    timings: dict[str, float] = field(default_factory=dict)

    def chart(self, method: str, params: dict[str, float]) -> Chart:
        """A compared chart (:func:`make_chart`) beside the preset's SS-DEWMA."""
        return make_chart(method, params, self.experiment.detector)

    def describe(self) -> dict[str, Any]:
        """The settings and the denoiser of the SS/M-DEWMA statistic (for the tables' JSON)."""
        return {**self.settings.describe(), "denoiser": repr(self.experiment.detector.denoiser)}


def build_study(settings: PaperSettings | None = None) -> Reproduction:
    """The preset's experiment with the settings' overrides and its Phase-I calibration (shared by all faults)."""
    settings = settings or PaperSettings()
    t0 = time.perf_counter()
    experiment = cli.preset("paper000", settings.overrides()).experiment
    study = Reproduction(settings, experiment, experiment.calibrate())
    study.timings["calibration_s"] = time.perf_counter() - t0
    return study


def fault_data(study: Reproduction, name: str) -> FaultData:
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
