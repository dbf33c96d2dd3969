"""Paper 000's comparison on our simulation: Table 3, Table 4, Fig. 1 and the Pareto fronts (issue 5).

Commands (``python -m mosd.paper`` is the same command as ``python -m mosd.systems.paper000``)::

    python -m mosd.paper table3 [--budget paper|small|tiny] [--seed S]
    python -m mosd.paper table4 [--budget ...] [--seed S]
    python -m mosd.paper fig1   [--fault offset] [--budget ...]
    python -m mosd.paper pareto [--fault offset_var] [--budget ...]
    python -m mosd.paper all    [--budget ...]

Each prints a markdown table beside the paper's numbers and writes CSV/JSON/PNG
files under ``outputs/paper/`` (``--out`` to change). Sensitivity options:
``--k-max`` (K_SD search box, Table 2: 5), ``--wavelet paper|sln|none`` (denoiser
of the SS/M-DEWMA statistic), ``--subgroups window|channels`` (docs/DECISIONS.md §2),
``--n-jobs``. docs/RESULTS.md shows what these commands produce. No MLflow; the
experiment is the ``+experiment=paper000`` preset composed by Hydra
(:mod:`mosd.app.presets`) with the options as overrides.

The set-up (docs/DECISIONS.md §1–7), from ``conf/experiment/paper000.yaml``:

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

Modules by job: :mod:`.numbers` (the paper's numbers), :mod:`.setup` (settings, charts,
the data cache), :mod:`.tables` (the computations), :mod:`.report` (markdown and files),
:mod:`.study` (the preset's :class:`Study`), :mod:`.command` (the command line).
"""
from .command import COMMANDS, main
from .numbers import (BASELINES, CAUSAL_OURS, FAULT_LABELS, FAULTS, METHODS, PAPER_GOOD_REGION, PAPER_PRESETS,
                      PAPER_TABLE3, PAPER_TABLE4, PAPER_TABLE4_PARAMS, TUNED_MS_OEWMA, paper_error_bound)
from .report import (format_anatomy, format_bars, format_causal, format_self_referenced, format_table3,
                     format_table4, write_fig1, write_pareto, write_table3, write_table4)
from .setup import (BUDGETS, SOLVERS, SUBGROUPS, WAVELETS, BudgetPreset, FaultData, PaperSettings, Reproduction,
                    build_study, fault_data, make_chart, make_fault, make_prefilter, make_solver)
from .study import Study
from .tables import (BarCheck, GridScan, ParetoComparison, Row, Table3, Table4, compare_accuracy,
                     compare_with_paper, error_anatomy, evaluate_design, fig1_axes, make_evaluator, ms_oewma_grid,
                     optimise, run_fig1, run_pareto, run_table3, run_table4, self_referenced_report, tune_causal,
                     tune_ms_oewma)

__all__ = [
    "BASELINES", "BUDGETS", "CAUSAL_OURS", "COMMANDS", "FAULTS", "FAULT_LABELS", "METHODS", "PAPER_GOOD_REGION",
    "PAPER_PRESETS", "PAPER_TABLE3", "PAPER_TABLE4", "PAPER_TABLE4_PARAMS", "SOLVERS", "SUBGROUPS",
    "TUNED_MS_OEWMA", "WAVELETS", "BarCheck", "BudgetPreset", "FaultData", "GridScan", "PaperSettings",
    "ParetoComparison", "Reproduction", "Row", "Study", "Table3", "Table4", "build_study", "compare_accuracy",
    "compare_with_paper", "error_anatomy", "evaluate_design", "fault_data", "fig1_axes", "format_anatomy",
    "format_bars", "format_causal", "format_self_referenced", "format_table3", "format_table4", "main",
    "make_chart", "make_evaluator", "make_fault", "make_prefilter", "make_solver", "ms_oewma_grid", "optimise",
    "paper_error_bound", "run_fig1", "run_pareto", "run_table3", "run_table4", "self_referenced_report",
    "tune_causal", "tune_ms_oewma", "write_fig1", "write_pareto", "write_table3", "write_table4",
]
