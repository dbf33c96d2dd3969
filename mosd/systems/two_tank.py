"""The two-tank level loop as a system: the worked example of docs/ADD_A_SYSTEM.md.

Its study scores every design on fresh test runs of the preset's fault
(``+experiment=two_tank``: a 2σ bias on the lower tank's level sensor) and on
as many fault-free runs; its report command does the same for the recorded
tuned design without the optimiser, and says in one line that there is none
before the preset has been run and its design recorded.
"""
from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np

from ..metrics import DetectionReport
from ..validation import check_int
from . import base, cli
from .base import TUNED, design_params, prefixed

SYSTEM = "two_tank"
#: the registry metrics the study reports per design (mosd.metrics.registry)
NAMES = ("far", "mdr", "accuracy", "detection_rate", "delay")


class Study(base.Study):
    """Every design on the same faulty and fault-free test runs.

    Parameters
    ----------
    n_runs : int
        Faulty and fault-free test runs each (>= 2).
    figures : bool
        Unused: the study draws no figure (the run's own chart.png shows the CUSUM).

    Notes
    -----
    Metrics, per design (unprefixed for the tuned one, ``<design>_`` otherwise): ``far``, ``mdr``,
    ``accuracy``, ``detection_rate``, ``delay`` (the registry's, means over the faulty runs) and
    ``far_fault_free`` (the share of points that alarm on the fault-free runs).
    """

    system = SYSTEM

    def __init__(self, n_runs: int = 100, figures: bool = True):
        super().__init__(figures=figures)
        self.n_runs = check_int("study.n_runs", n_runs, 2)

    def compute(self, experiment, designs: dict) -> dict:
        """Phase-I on the calibration runs, then every design on the same test runs (faulty and fault-free)."""
        phase1 = experiment.monitor.transform(experiment.calibrate())
        # the test stream only; the experiment scales the relative fault to σ of the fault-free residual
        faulty = experiment.monitor.transform(experiment.residuals(experiment.fault, self.n_runs, "test"))
        clean = experiment.monitor.transform(experiment.residuals(None, self.n_runs, "test"))
        reports, fault_free = {}, {}
        for name, detector in designs.items():
            reports[name] = DetectionReport.of(detector.decide(phase1.z, faulty.z).decision, faulty, NAMES)
            fault_free[name] = float(np.mean(detector.decide(phase1.z, clean.z).decision > 0))
        return {"reports": reports, "fault_free": fault_free,
                "params": {name: design_params(d) for name, d in designs.items()}}

    def metrics(self, data: dict) -> dict[str, float]:
        """The study's numbers by name (class docstring)."""
        out = {}
        for name, report in data["reports"].items():
            values = {k: report.values[k] for k in NAMES}
            out.update({prefixed(name) + k: float(np.nanmean(v)) if np.isfinite(v).any() else float("nan")
                        for k, v in values.items()})
            out[prefixed(name) + "far_fault_free"] = data["fault_free"][name]
        return out


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m mosd.systems.two_tank [--n-runs 100] [--seed 0] [--k K --h H --persistence L] [--out DIR]``."""
    parser = cli.report_parser("python -m mosd.systems.two_tank", "The two-tank study without the optimiser: "
                               "the recorded tuned design on fresh faulty and fault-free runs.",
                               out="outputs/systems/two_tank")
    parser.add_argument("--n-runs", type=int, default=100, help="faulty and fault-free runs each (default 100)")
    cli.design_options(parser, SYSTEM)  # --k, --h, --persistence once a design is recorded

    def body(args):
        tuned = cli.tuned_design(args, SYSTEM)  # "no recorded design yet ..." (one line, exit 2) before that
        study = Study(n_runs=args.n_runs)
        experiment = cli.preset(SYSTEM, [f"seed={args.seed}"]).experiment
        designs = {TUNED: experiment.detector.with_params(**tuned),
                   **study.reference_designs(experiment, experiment.detector)}
        _, metrics, files = cli.score(study, experiment, designs, Path(args.out), n_runs=args.n_runs, seed=args.seed)
        rows = [(k, f"{metrics[k]:.4g}") for k in (*NAMES, "far_fault_free")]
        print(f"## Two tanks: {args.n_runs} faulty + {args.n_runs} fault-free runs, seed {args.seed}\n")
        print(cli.markdown_table(("metric", "tuned"), rows) + "\n")
        return files

    return cli.run_report(parser, argv, body)


if __name__ == "__main__":
    raise SystemExit(main())
