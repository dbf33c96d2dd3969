"""``python -m mosd.paper`` (also ``python -m mosd.systems.paper000``): Table 3, Table 4, Fig. 1, Pareto fronts."""
from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Sequence

import numpy as np

from .. import cli
from .numbers import FAULT_LABELS, FAULTS, PAPER_GOOD_REGION
from .report import (format_anatomy, format_bars, format_causal, format_self_referenced, format_table3,
                     format_table4, write_fig1, write_pareto, write_table3, write_table4)
from .setup import BUDGETS, SUBGROUPS, WAVELETS, PaperSettings, build_study
from .tables import GridScan, run_fig1, run_pareto, run_table3, run_table4

COMMANDS = ("table3", "table4", "fig1", "pareto", "all")
PROG = "python -m mosd.paper"
DESCRIPTION = "Paper 000's comparison on our simulation: Table 3, Table 4, Fig. 1 and the Pareto fronts."


def _parser() -> cli.ReportParser:
    parser = cli.report_parser(PROG, DESCRIPTION, out="outputs/paper")
    parser.add_argument("command", choices=COMMANDS)
    parser.add_argument("--budget", choices=tuple(BUDGETS), default="paper")
    parser.add_argument("--wavelet", choices=tuple(WAVELETS), default="paper",
                        help="denoiser of the SS/M-DEWMA statistic (default: the paper's literal MATLAB calls)")
    parser.add_argument("--n-jobs", type=int, default=2)
    parser.add_argument("--k-max", type=float, default=5.0,
                        help="upper end of the K_SD search box (Table 2: 5; Fig. 1 scans to 10)")
    parser.add_argument("--subgroups", choices=tuple(SUBGROUPS), default="window",
                        help="window: 5 consecutive x_p residuals (default); channels: the 3 residual channels "
                             "of one sample (the paper's literal reading)")
    parser.add_argument("--fault", choices=FAULTS, default=None,
                        help="fig1 (default offset) and pareto (default offset_var)")
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the chosen tables on the ``+experiment=paper000`` preset; print markdown, write files."""
    return cli.run_report(_parser(), argv, _run)


def _run(args) -> list[Path]:
    settings = PaperSettings(budget=args.budget, seed=args.seed, wavelet=args.wavelet, n_jobs=args.n_jobs,
                             k_max=args.k_max, subgroups=args.subgroups)
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
            far, mdr = (front.train_objectives[k] for k in ("far", "mdr"))
            print(f"- {algo}: {len(np.unique(front.F, axis=0))} distinct front points, hypervolume "
                  f"{comparison.hypervolume[algo]:.6f}, chosen λ = {front.params['lam']:.4f}, K = "
                  f"{front.params['K']:.4f} (training FAR {100 * far:.2f} %, MDR {100 * mdr:.2f} %), "
                  f"{front.seconds:.1f} s")
        print()
        written += write_pareto(comparison, out)
    print(f"settings: {json.dumps(study.describe())}")
    print(f"timings: {json.dumps({k: round(v, 2) for k, v in study.timings.items()})}, "
          f"analysis {time.perf_counter() - t0:.1f} s")
    return written
