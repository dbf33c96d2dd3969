"""Paper 000's study of the ``+experiment=paper000`` preset: the tuned design beside Table 3's charts."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ...metrics import DetectionReport, Estimate
from ...validation import check_int
from .. import base
from ..base import TUNED, figure, prefixed
from .numbers import BASELINES, FAULTS, PAPER_PRESETS, PAPER_TABLE3
from .setup import make_chart

#: the study's metrics per design: the metric registry's names (means over the test runs)
NAMES = ("far", "mdr", "accuracy", "detection_rate", "delay")


def design_name(method: str) -> str:
    """``"M-DEWMA"`` → ``"m_dewma"``: a Table 3 method as a design name (its metrics' prefix)."""
    return method.lower().replace("-", "_")


def table3_fault(fault) -> str:
    """The Table 3 column of the experiment's fault: its kind, or ``offset`` for a drift (as paper 000 tunes it)."""
    kind = getattr(fault, "kind", "offset")
    return kind if kind in FAULTS else "offset"


class Study(base.Study):
    """Paper 000's Table 3 for a tuned SS-DEWMA: beside the paper-parameter charts, on the same test runs.

    ``n_runs`` fresh runs of the experiment's fault are drawn from the ``test`` seed stream
    (with the default ``n_runs`` equal to ``budget.n_test``, the same runs as the experiment's
    own test metrics), the Phase-I limits are fitted on the experiment's calibration runs, and
    the tuned design and Table 3's fixed designs of the fault's column (M-DEWMA, MS-OEWMA and
    SS-DEWMA with the paper's λ and K_SD, ``mosd/systems/designs/paper000.json``; the SS/M-DEWMA
    statistic denoised like the tuned one) decide on them. Every comparison is paired.

    Parameters
    ----------
    n_runs : int
        Test runs (>= 2).
    figures : bool
        Write ``paper000_table3.png`` into ``out_dir``.

    Notes
    -----
    Metrics: ``far``, ``mdr``, ``accuracy`` (1 − FAR − MDR), ``detection_rate`` (runs detected)
    and ``delay`` (subgroups from the onset to the first alarm over detected runs), the metric
    registry's, as means over the test runs: unprefixed for the tuned design, prefixed
    ``m_dewma_``, ``ms_oewma_``, ``ss_dewma_`` for the paper's charts; ``accuracy_vs_<design>``
    and ``accuracy_vs_<design>_ci95``: the tuned design's accuracy minus the chart's, mean over
    the runs and its 95 % Student-t half-width (positive: the tuned design is better).
    """

    system = "paper000"

    def __init__(self, n_runs: int = 100, figures: bool = True):
        super().__init__(figures=figures)
        self.n_runs = check_int("study.n_runs", n_runs, 2)

    def reference_designs(self, experiment, detector) -> dict:
        """Table 3's fixed charts of the experiment's fault (its column), beside the tuned ``detector``."""
        column = table3_fault(experiment.fault)
        return {design_name(m): make_chart(m, PAPER_PRESETS[m][column], detector) for m in BASELINES}

    def compute(self, experiment, designs: dict) -> dict:
        """Phase-I limits on the calibration runs, then every design's per-run metrics on the same test runs."""
        calibration = experiment.calibrate()
        fault = experiment.fault
        phase1 = experiment.monitor.transform(calibration)
        # a relative fault in σ of the calibration residual: the experiment scales it
        test = experiment.monitor.transform(experiment.residuals(fault, self.n_runs, "test"))
        reports, params, causal = {}, {}, {}
        for name, detector in designs.items():
            decided = detector.decide(phase1.z, test.z)
            reports[name] = DetectionReport.of(decided.decision, test, NAMES)
            params[name] = {k: float(v) for k, v in detector.tunable_params().items()}
            causal[name] = bool(detector.is_causal)
        return {"fault": table3_fault(fault), "n_runs": self.n_runs, "reports": reports, "params": params,
                "causal": causal}

    def metrics(self, data: dict) -> dict[str, float]:
        """The study's metrics by name (class docstring)."""
        out = {}
        reports = data["reports"]
        for name, report in reports.items():
            out.update({prefixed(name) + k: float(np.nanmean(report.values[k]))
                        if np.isfinite(report.values[k]).any() else math.nan for k in NAMES})
        if TUNED in reports:
            for name, report in reports.items():
                if name != TUNED:
                    gain = Estimate.of(reports[TUNED].values["accuracy"] - report.values["accuracy"])
                    out[f"accuracy_vs_{name}"], out[f"accuracy_vs_{name}_ci95"] = gain.mean, gain.half_width
        return out

    def write_figures(self, data: dict, out_dir: Path) -> list[Path]:
        """FAR and MDR (%) of every design with 95 % intervals, the paper's Table 3 values beside them."""
        out_dir.mkdir(parents=True, exist_ok=True)
        fig = figure(8.0, 3.4)
        axes = fig.subplots(1, 2)
        names = list(data["reports"])
        paper_of = {design_name(m): m for m in (*BASELINES, "MO-SS-DEWMA")}
        for ax, key, column in zip(axes, ("far", "mdr"), (1, 0)):
            estimates = [Estimate.of(data["reports"][n].values[key]) for n in names]
            x = np.arange(len(names))
            ax.bar(x, [100 * e.mean for e in estimates], yerr=[100 * np.nan_to_num(e.half_width) for e in estimates],
                   color=["tab:blue" if data["causal"][n] else "tab:grey" for n in names], capsize=3,
                   label="ours (grey: not online)")
            paper = [PAPER_TABLE3[paper_of.get(n, "MO-SS-DEWMA")][data["fault"]][column] for n in names]
            ax.plot(x, paper, "k^", label="paper (Table 3)")
            ax.set_xticks(x, names, fontsize=8)
            ax.set_ylabel(f"{key.upper()} %")
            ax.set_title(f"{key.upper()} on {data['n_runs']} test runs, {data['fault']} fault", fontsize=10)
            ax.grid(alpha=0.3, axis="y")
        axes[0].legend(fontsize=8)
        path = out_dir / f"{self.system}_table3.png"
        fig.savefig(path, dpi=110)
        return [path]
