"""Tennessee Eastman: the classic per-fault PCA table, the literature's design beside the tuned one.

The literature's design (Yin et al. 2012, section 4.1): the 33 variables
XMEAS(1)-XMEAS(22) and XMV(1)-XMV(11), standardised with the mean and standard
deviation (ddof = 1) of ``d00.dat``, 9 principal components, theoretical
limits (F for T², Jackson–Mudholkar for SPE) at α = 0.01, a sample flagged
when T² or SPE is above its limit, no smoothing, no persistence. The tuned
design is the optimiser's (:mod:`mosd.detectors.pca`: components, α, EWMA λ
with recalibrated limits, persistence k).

Definitions (per sample, as in the literature):

* ``fdr`` of fault N — the share of the 800 post-onset samples of ``dNN_te.dat``
  (rows 160-959) that alarm: the fault detection rate, 1 − MDR;
* ``far`` — the share of rows 160-959 of ``d00_te.dat`` that alarm.

:class:`Study` computes both for every statistic (T², SPE, combined) and
design; ``python -m mosd.systems.tep`` prints the table without the optimiser,
with the recorded tuned design (``mosd/systems/designs/tep.json``) and the
published numbers beside ours. ``--table FILE`` monitors any CSV/Parquet
export instead: fit on its first half, the alarm rate on the rest and the tags
that drive the alarms.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping

import numpy as np

from ..data.tep import ALL_FAULTS, DEFAULT_FAULTS, DT, ONSET, TennesseeEastman, file_name
from ..detectors.pca import PCADetector
from ..validation import ConfigError, check_int
from . import base, cli
from .base import TUNED, figure
# the protocol's primitives and the family table live in their own modules (issue 49); their names stay importable
# from here, as before the split
from .tep_families import (FAMILIES, FAMILY_ABLATION, FLATLINE_ABLATION, FLATLINE_ROW,  # noqa: F401
                           FLATLINE_START, FLATLINE_WHY, LITERATURE_FAMILIES, _family_experiment, _family_scores,
                           ablation_report, ablation_study, at_operating_point, families_figure, families_report,
                           family_benchmark, family_metrics, family_study, flatline_value, format_ablation_rows,
                           format_families, format_literature_comparison, headline, literature_comparison,
                           literature_design)
from .tep_protocol import (DELAY_RUN, LITERATURE, MINUTES_PER_ROW, PROTOCOL_FAR, SYSTEM,  # noqa: F401
                           _study_source, _z, alpha_for_far, delays, design_text, episodes, far_interval, protocol,
                           whole_test_files)

STATISTICS = ("t2", "spe", "combined")
LIT = "lit"

#: Yin, Ding, Haghani, Hao & Zhang (2012), J. Process Control 22(9) 1567-1581, PCA with 9 components on the
#: 33 variables: Table 4 (FDR in %, a sample flagged when T² or SPE exceeds its limit; faults 1-15 only) and
#: Table 5 (FAR in %). Transcribed from the paper in the repository rajkhatri08/plant-health-rca-agent,
#: eval/published/yin2012.yaml (docs/systems/tep.md: how they were found and checked).
YIN2012_FDR_COMBINED = {1: 99.88, 2: 98.75, 3: 12.88, 4: 100.0, 5: 33.63, 6: 100.0, 7: 100.0, 8: 98.0, 9: 8.38,
                        10: 60.5, 11: 78.88, 12: 99.13, 13: 95.38, 14: 100.0, 15: 14.13}
YIN2012_FAR_COMBINED = 6.13


#: the ablation (issue 30): what component count, smoothing, persistence, the significance level and the
#: calibration data each buy. Each row is (base design, changes, calibration): the base is the literature's
#: design or the tuned one, ``"tuned"`` in a change stands for the tuned design's value, and the calibration
#: is ``"design"`` (the design's own: d00.dat alone for theoretical limits, d00.dat plus the held-back
#: lead-ins for empirical ones), ``"heldback"`` (empirical limits from the held-back lead-in rows) or
#: ``"d00"`` (empirical limits from d00.dat itself, in-sample: no lead-in row seen).
ABLATION = {
    "lit": (LIT, {}, "design"),
    "lit_tuned_components": (LIT, {"n_components": "tuned"}, "design"),
    "lit_tuned_alpha": (LIT, {"alpha": "tuned"}, "design"),
    "lit_heldback_limits": (LIT, {"limits": "empirical"}, "heldback"),
    "lit_tuned_smoothing": (LIT, {"lam": "tuned", "limits": "empirical"}, "heldback"),
    "lit_tuned_smoothing_d00_limits": (LIT, {"lam": "tuned", "limits": "empirical"}, "d00"),
    "lit_persistence3": (LIT, {"persistence": 3}, "design"),
    "tuned": (TUNED, {}, "heldback"),
    "tuned_lit_components": (TUNED, {"n_components": LITERATURE["n_components"]}, "heldback"),
    "tuned_no_smoothing": (TUNED, {"lam": 1.0, "limits": "empirical"}, "heldback"),
    "tuned_persistence3": (TUNED, {"persistence": 3}, "heldback"),
    "tuned_d00_limits": (TUNED, {"limits": "empirical"}, "d00"),
}


def alarm_rates(detector: PCADetector, calibration_z: np.ndarray, test_z: np.ndarray) -> dict[str, np.ndarray]:
    """Per test run, the share of points that alarm, for T², SPE and the combined rule (R,) each (the combined
    rule only for a family without T² and SPE)."""
    stats = STATISTICS if set(getattr(detector, "STATISTICS", ())) == {"t2", "spe"} else ("combined",)
    return {stat: detector.with_statistic(stat).decide(calibration_z, test_z).decision.astype(bool).mean(axis=-1)
            for stat in stats}


class Study(base.Study):
    """The TE per-fault table of the tuned design and of the literature's (module docstring).

    Metrics (``summary.json`` under ``"study"``), for design D in {``lit``, ``tuned``} (the issue's
    names: both designs are prefixed), statistic S in {``t2``, ``spe``, ``combined``} and fault N:

    * ``D_fdr_S_idvN`` — fault N's detection rate on its 800 post-onset test samples (all three
      statistics for ``lit``, the combined rule the design alarms on for ``tuned``);
    * ``D_far_S`` — the false-alarm rate on ``d00_te.dat`` rows 160-959;
    * unprefixed, the fair protocol's keys of the run's own design (:func:`protocol`; docs/systems/tep.md):
      ``fdr_idvN``, ``delay_first_idvN``, ``delay_run_idvN`` (k = ``delay_run_k``), ``far``, ``far_episodes``,
      ``far_ci_low``/``far_ci_high``, from each test file streamed whole (its lead-in is the past at the onset,
      :func:`whole_test_files`; ``tuned_fdr_combined_idvN`` starts every run at row 160 instead);
    * ``D_mdr_combined_mean`` — 1 − the mean combined detection rate over the training faults
      (``data.faults``, by default all but 3, 9 and 15): the MDR the optimiser minimised, on the test files.
    * ``lit_equal_far_alpha``, ``lit_equal_far_far_combined``, ``lit_equal_far_mdr_combined_mean`` — the
      literature's design given the tuned design's information (empirical limits from the same
      held-back lead-in rows) with the α that brings its FAR down to the tuned design's (chosen on
      the test file: the baseline's best case), and its mean MDR over the training faults;
      ``lit_d00_equal_far_*`` the same with the literature's theoretical limits from d00.dat alone
      (the comparison before issue 30, which gave the baseline less information than the tuned design).
    * ``D_delay_first_alarm_min_idvN`` and ``D_delay_run3_min_idvN`` for D in ``lit``, ``tuned``,
      ``lit_equal_far`` — minutes from the onset (row 160) to the first alarm and to the row completing
      the first run of :data:`DELAY_RUN` consecutive alarms (not reported for a fault without one);
      ``D_faults_detected_{first_alarm,run3}`` (training faults with one) and
      ``D_delay_{first_alarm,run3}_min_median`` (their median).
    * ``family_fdr_<family>_idvN``, ``family_far_<family>``, ``family_far_episodes_<family>`` and
      ``family_mean_mdr_<family>``: the same protocol keys named by the tuned design's family (``detector=``), as
      ``--families`` names them (:func:`family_metrics`), so a sweep's runs compare side by side; with
      ``detector.flatline`` on, named ``<family>_flatline`` (the labelled row, issue 49).
    * ``ablation_R_{far,mdr,equal_far_alpha,equal_far_far,equal_far_mdr}`` for each row R of
      :data:`ABLATION`: the FAR and mean MDR over the training faults, and the α, FAR and MDR at the tuned
      design's FAR (α chosen on the test file, :func:`alpha_for_far`).

    Parameters
    ----------
    fault : int
        The fault (IDV number) of the statistics and contribution figures.
    top : int
        Variables shown in the contribution figure.
    figures : bool
    """

    system = SYSTEM

    def __init__(self, fault: int = 10, top: int = 10, figures: bool = True):
        super().__init__(figures=figures)
        self.fault = check_int("study.fault", fault, 1, 21)
        self.top = check_int("study.top", top, 1, 52)

    def reference_designs(self, experiment, detector) -> dict[str, Any]:
        """The literature's design (module docstring), fitted on d00.dat alone."""
        return {LIT: PCADetector(**LITERATURE, statistic="combined", limits="theoretical", fit_runs=1)}

    def compute(self, experiment, designs: Mapping[str, Any]) -> dict:
        data = getattr(experiment, "data", None)
        if not isinstance(data, TennesseeEastman):
            raise ConfigError("study mosd.systems.tep.Study needs data=tep; allowed: +experiment=tep")
        out: dict = {"fdr": {}, "far": {}, "params": {}, "faults": list(ALL_FAULTS),
                     "train_faults": list(data.faults), "figure_fault": self.fault}
        for name, detector in designs.items():
            source = _study_source(data, literature=name == LIT)
            calibration = _z(experiment, source.trace("calibration"))
            test = source.trace("test")
            labels = test.fault_label.max(axis=1)
            z = _z(experiment, test)
            rates = alarm_rates(detector, calibration, z)
            out["fdr"][name] = {s: {int(n): float(r[labels == n][0]) for n in ALL_FAULTS} for s, r in rates.items()}
            out["far"][name] = {s: float(r[labels == 0][0]) for s, r in rates.items()}
            decision = detector.decide(calibration, z).decision
            out.setdefault("delays", {})[name] = self._delays(decision, labels)
            # the protocol streams each test file whole: its lead-in is the past at the onset (whole_test_files)
            whole, whole_labels = whole_test_files(experiment, source)
            out.setdefault("protocol", {})[name] = protocol(detector.decide(calibration, whole).decision[:, ONSET:],
                                                            whole_labels)
            out["params"][name] = {k: (int(v) if detector.tunable[k].integer else v)
                                   for k, v in base.design_params(detector).items()}
            if type(detector) is PCADetector:  # T², SPE and the contributions of a PCA of the tags
                out.setdefault("figure", {})[name] = self._figure_data(experiment, source, detector, calibration)
        out["variables"] = {name: list(_study_source(data, literature=name == LIT).output_names)
                            for name in designs}
        if TUNED in designs:  # the family's config name (detector=...): its module's
            family = type(designs[TUNED]).__module__.rsplit(".", 1)[-1]
            # with the frozen-tag statistic on, the keys are the labelled row's, never the headline family's
            flat = getattr(designs[TUNED], "flatline", None) is not None
            out["family"] = FLATLINE_ROW.format(family=family) if flat else family
        if LIT in designs and TUNED in designs and type(designs[TUNED]) is PCADetector:
            source = _study_source(data, literature=True)
            far = out["far"][TUNED]["combined"]
            # the literature's design at the tuned FAR with the tuned design's information: empirical limits
            # from the same held-back lead-in rows, α chosen on the test file (its best case)
            fair = designs[LIT].with_params(limits="empirical")
            out["equal_far"] = self._equal_far(experiment, source, fair, far)
            out["delays"]["lit_equal_far"] = out["equal_far"].pop("delays")
            # as before issue 30: theoretical limits from d00.dat alone, α chosen on the test file
            out["equal_far_d00"] = self._equal_far(experiment, source, designs[LIT], far)
            out["equal_far_d00"].pop("delays")
            out["ablation"] = self._ablation(experiment, source, designs, far, data.faults)
        return out

    @staticmethod
    def _delays(decision: np.ndarray, labels: np.ndarray) -> dict[str, dict[int, float]]:
        """Per fault, minutes from the onset to the first alarm and to the first run of DELAY_RUN (NaN: none)."""
        found = delays(np.asarray(decision, bool))
        return {key: {int(n): float(v[labels == n][0]) * MINUTES_PER_ROW for n in ALL_FAULTS if (labels == n).any()}
                for key, v in found.items()}

    @staticmethod
    def _ablation(experiment, source: TennesseeEastman, designs: Mapping[str, Any], far: float, train) -> dict:
        """Per row of :data:`ABLATION`: FAR and mean MDR over ``train``, and the MDR at the tuned FAR ``far``."""
        calibration = _z(experiment, source.trace("calibration"))
        test = source.trace("test")
        labels = test.fault_label.max(axis=1)
        z = _z(experiment, test)
        faulty = np.isin(labels, list(train))
        out = {}
        for row, (base_name, changes, data) in ABLATION.items():
            base_design = designs[base_name]
            params = {k: getattr(designs[TUNED], k) if v == "tuned" else v for k, v in changes.items()}
            if "n_components" in params:  # the literature's design declares a smaller range than the preset's
                params["max_components"] = max(int(base_design.max_components), int(params["n_components"]))
            detector = base_design.with_params(**params)
            # d00.dat alone: it fits the PCA and, held back from nothing, sets the empirical limits in-sample
            cal = calibration[:1] if data == "d00" else calibration
            rate = np.asarray(detector.decide(cal, z).decision, bool).mean(-1)
            alpha = alpha_for_far(detector, cal, z, labels == 0, far)
            at_far = np.asarray(detector.with_params(alpha=alpha).decide(cal, z).decision, bool).mean(-1)
            out[row] = {"far": float(rate[labels == 0][0]), "mdr": float(1.0 - rate[faulty].mean()),
                        "equal_far_alpha": alpha, "equal_far_far": float(at_far[labels == 0][0]),
                        "equal_far_mdr": float(1.0 - at_far[faulty].mean()),
                        "params": {k: float(getattr(detector, k)) for k in detector.tunable}, "calibration": data}
        return out

    @classmethod
    def _equal_far(cls, experiment, source: TennesseeEastman, detector: PCADetector, far: float) -> dict:
        """``detector`` with the largest α whose FAR on d00_te is at most ``far`` (the tuned FAR).

        α is chosen on the test file itself (:func:`alpha_for_far`): the comparison favours
        the baseline, which gets its best α for free.
        """
        calibration = _z(experiment, source.trace("calibration"))
        test = source.trace("test")
        labels = test.fault_label.max(axis=1)
        z = _z(experiment, test)
        alpha = alpha_for_far(detector, calibration, z, labels == 0, far)
        decision = np.asarray(detector.with_params(alpha=alpha).decide(calibration, z).decision, bool)
        r = decision.mean(axis=-1)
        return {"alpha": alpha, "far": float(r[labels == 0][0]), "limits": detector.limits,
                "fdr": {int(n): float(r[labels == n][0]) for n in np.unique(labels) if n},
                "delays": cls._delays(decision, labels)}

    def _figure_data(self, experiment, source: TennesseeEastman, detector: PCADetector, calibration: np.ndarray):
        """T², SPE and their limits over the whole test file of the figure's fault, and the contributions."""
        from dataclasses import replace

        from ..data.tep import file_name

        rows = source.values(file_name(self.fault, test=True))
        trace = source.trace("test")
        whole = replace(trace, y=rows[None], fault_mask=(np.arange(len(rows)) >= ONSET)[None],
                        fault_label=np.where(np.arange(len(rows)) >= ONSET, self.fault, 0)[None],
                        t=np.arange(len(rows)) * source.dt)
        z = _z(experiment, whole)
        stats = detector.statistics(calibration, z)
        decision = detector.decide(calibration, z).decision[0].astype(bool)
        model = detector.model(calibration)
        c_t2, c_spe = model.contributions(z[0], int(detector.n_components))
        alarmed = decision & (np.arange(len(rows)) >= ONSET)
        pick = alarmed if alarmed.any() else np.arange(len(rows)) >= ONSET
        return {"hours": np.arange(len(rows)) * source.dt / 3600.0, "t2": stats["t2"][0], "spe": stats["spe"][0],
                "t2_limit": stats["t2_limit"], "spe_limit": stats["spe_limit"], "alarm": decision,
                "contribution_t2": c_t2[pick].mean(axis=0), "contribution_spe": c_spe[pick].mean(axis=0),
                "n_alarmed": int(alarmed.sum())}

    def metrics(self, data: dict) -> dict[str, float]:
        metrics: dict[str, float] = {}
        train = [f for f in data["train_faults"] if f in data["faults"]]
        for name in data["fdr"]:
            prefix = f"{name}_"
            # the tuned design alarms on the combined rule: its T²/SPE rates are in the table and figure only
            for stat in STATISTICS if name == LIT else ("combined",):
                for fault, rate in data["fdr"][name][stat].items():
                    metrics[f"{prefix}fdr_{stat}_idv{fault}"] = rate
            for stat in data["far"][name]:
                metrics[f"{prefix}far_{stat}"] = data["far"][name][stat]
            combined = data["fdr"][name]["combined"]
            metrics[f"{prefix}mdr_combined_mean"] = float(1.0 - np.mean([combined[f] for f in train]))
        for key, prefix in (("equal_far", "lit_equal_far"), ("equal_far_d00", "lit_d00_equal_far")):
            if key in data:
                equal = data[key]
                metrics[f"{prefix}_alpha"] = equal["alpha"]
                metrics[f"{prefix}_far_combined"] = equal["far"]
                metrics[f"{prefix}_mdr_combined_mean"] = float(1.0 - np.mean([equal["fdr"][f] for f in train]))
        for name, by_kind in data.get("delays", {}).items():
            for kind, label in (("first_alarm", "first_alarm"), ("first_run", f"run{DELAY_RUN}")):
                values = by_kind[kind]
                # an undetected fault has no delay: left out, and counted
                for fault, minutes in values.items():
                    if np.isfinite(minutes):
                        metrics[f"{name}_delay_{label}_min_idv{fault}"] = minutes
                seen = [values[f] for f in train if np.isfinite(values.get(f, np.nan))]
                metrics[f"{name}_faults_detected_{label}"] = float(len(seen))
                if seen:
                    metrics[f"{name}_delay_{label}_min_median"] = float(np.median(seen))
        for row, scores in data.get("ablation", {}).items():
            for key in ("far", "mdr", "equal_far_alpha", "equal_far_far", "equal_far_mdr"):
                metrics[f"ablation_{row}_{key}"] = scores[key]
        # the fair protocol's keys of the run's own (tuned) design, unprefixed (docs/systems/tep.md)
        metrics.update(data.get("protocol", {}).get(TUNED, {}))
        if "family" in data and TUNED in data.get("protocol", {}):
            # and named by its family, so that the runs of a sweep over detector=... sit side by side in a report
            metrics.update(family_metrics({data["family"]: data["protocol"][TUNED]}))
        return metrics

    def write_figures(self, data: dict, out_dir: Path) -> list[Path]:
        return self.draw_figure_jobs(data, out_dir)

    def figure_jobs(self, data: dict, out_dir: Path) -> list[tuple[str, dict]]:
        """The detection rates, the statistics and the contributions (three figures, drawn side by side where
        the app has the cores), and the table as CSV."""
        out_dir = Path(out_dir)
        jobs = [("_rates_figure", {"data": data, "path": out_dir / "tep_detection_rates.png"})]
        if data.get("figure"):
            jobs += [("_statistics_figure", {"data": data, "path": out_dir / "tep_statistics.png"}),
                     ("_contributions_figure", {"data": data, "path": out_dir / "tep_contributions.png"})]
        return [*jobs, ("_write_table", {"data": data, "path": out_dir / "tep_table.csv"})]

    @staticmethod
    def _write_table(data: dict, path: Path) -> Path:
        path.write_text(format_table(data, csv=True))
        return path

    def _rates_figure(self, data: dict, path: Path) -> Path:
        designs = list(data["fdr"])
        fig = figure(10, 2.6 * len(designs))
        faults = data["faults"]
        x = np.arange(len(faults))
        for i, name in enumerate(designs):
            ax = fig.add_subplot(len(designs), 1, i + 1)
            for j, stat in enumerate(s for s in STATISTICS if s in data["fdr"][name]):
                ax.bar(x + (j - 1) * 0.27, [data["fdr"][name][stat][f] for f in faults], 0.27,
                       label={"t2": "T²", "spe": "SPE", "combined": "T² or SPE"}[stat])
            ax.set_xticks(x, [str(f) for f in faults])
            ax.set_ylim(0, 1.05)
            far = data["far"][name]["combined"]
            base.decorate(ax, ylabel="detection rate", legend_size=None,
                          title=f"{_label(name)} {_design_text(data['params'][name])}: FAR (combined) {far:.3f}")
        handles, labels = ax.get_legend_handles_labels()
        fig.legend(handles, labels, loc="outside upper center", ncols=3, fontsize=8)
        ax.set_xlabel("fault IDV(N), test files rows 160-959")
        fig.savefig(path, dpi=110)
        return path

    def _statistics_figure(self, data: dict, path: Path) -> Path:
        designs = list(data["figure"])
        fig = figure(10, 2.2 * 2 * len(designs))
        row = 0
        for name in designs:
            f = data["figure"][name]
            for stat, label in (("t2", "T²"), ("spe", "SPE")):
                row += 1
                ax = fig.add_subplot(2 * len(designs), 1, row)
                ax.semilogy(f["hours"], np.maximum(f[stat], 1e-6), lw=0.8, label=label)
                ax.axhline(f[f"{stat}_limit"], color="C3", lw=1.0, label=f"limit {f[f'{stat}_limit']:.3g}")
                ax.axvline(ONSET * 0.05, color="k", ls=":", lw=0.8)
                base.decorate(ax, ylabel=label, legend_loc="upper left", title_size=9,
                              title=f"{_label(name)} on d{data['figure_fault']:02d}_te.dat (fault from 8 h)")
        ax.set_xlabel("hours")
        fig.savefig(path, dpi=110)
        return path

    def _contributions_figure(self, data: dict, path: Path) -> Path:
        designs = list(data["figure"])
        fig = figure(10, 3.0 * len(designs))
        for i, name in enumerate(designs):
            f = data["figure"][name]
            names = data["variables"][name]
            for k, (stat, label) in enumerate((("contribution_t2", "T²"), ("contribution_spe", "SPE"))):
                ax = fig.add_subplot(len(designs), 2, 2 * i + 1 + k)
                values = np.asarray(f[stat])
                order = np.argsort(np.abs(values))[::-1][: self.top]
                ax.barh(np.arange(len(order))[::-1], values[order], color="C0" if k == 0 else "C1")
                ax.set_yticks(np.arange(len(order))[::-1], [names[j] for j in order], fontsize=7)
                base.decorate(ax, legend_size=None, title_size=8,
                              title=f"{_label(name)}: contributions to {label}, mean over {f['n_alarmed']} alarms "
                                    f"(IDV({data['figure_fault']}))")
        fig.savefig(path, dpi=110)
        return path


def _label(name: str) -> str:
    return {LIT: "literature design", TUNED: "tuned design"}.get(name, name)


_design_text = design_text  # the name before the split (issue 49)


def format_table(data: dict, csv: bool = False) -> str:
    """The classic table: per fault, T²/SPE/combined detection rates per design, the published rate, FAR last."""
    designs = list(data["fdr"])
    equal = data.get("equal_far")
    # a family without T² and SPE has the combined column only
    columns = [(n, s) for n in designs for s in STATISTICS if s in data["fdr"][n]]
    head = (["fault"] + [f"{n} {s}" for n, s in columns]
            + ([f"lit combined at the tuned FAR (α {equal['alpha']:.2g})"] if equal else [])
            + ["Yin 2012 combined (%)"])
    rows = []
    for f in data["faults"]:
        cells = [f"IDV({f})"] + [f"{100 * data['fdr'][n][s][f]:.2f}" for n, s in columns]
        cells += [f"{100 * equal['fdr'][f]:.2f}"] if equal else []
        cells.append(f"{YIN2012_FDR_COMBINED[f]:.2f}" if f in YIN2012_FDR_COMBINED else "")
        rows.append(cells)
    rows.append(["FAR d00_te"] + [f"{100 * data['far'][n][s]:.2f}" for n, s in columns]
                + ([f"{100 * equal['far']:.2f}"] if equal else []) + [f"{YIN2012_FAR_COMBINED:.2f}"])
    if csv:
        return "\n".join(",".join(r) for r in [head, *rows]) + "\n"
    return cli.markdown_table(head, rows)


def format_delays(data: dict) -> str:
    """Per fault and design: minutes to the first alarm and to the first run of DELAY_RUN alarms."""
    designs = [n for n in (LIT, "lit_equal_far", TUNED) if n in data.get("delays", {})]
    head = ["fault"] + [f"{_label(n)}: first alarm / run of {DELAY_RUN} (min)" for n in designs]

    def cell(name, fault):
        d = data["delays"][name]
        return " / ".join("–" if not np.isfinite(d[k].get(fault, np.nan)) else f"{d[k][fault]:.0f}"
                          for k in ("first_alarm", "first_run"))

    return cli.markdown_table(head, [[f"IDV({f})"] + [cell(n, f) for n in designs] for f in data["faults"]])


def format_ablation(data: dict) -> str:
    """The ablation (:data:`ABLATION`): each row's FAR and MDR, and its MDR at the tuned FAR."""
    rows = []
    for row, scores in data.get("ablation", {}).items():
        p = scores["params"]
        rows.append([row, f"{int(p['n_components'])}", f"{p['alpha']:.3g}", f"{p['lam']:.3f}",
                     f"{int(p['persistence'])}", scores["calibration"], f"{100 * scores['far']:.3f}",
                     f"{100 * scores['mdr']:.2f}", f"{scores['equal_far_alpha']:.3g}",
                     f"{100 * scores['equal_far_far']:.3f}", f"{100 * scores['equal_far_mdr']:.2f}"])
    return cli.markdown_table(["row", "a", "α", "λ", "k", "limits from", "FAR (%)", "MDR (%)",
                               "α at the tuned FAR", "FAR (%)", "MDR at the tuned FAR (%)"], rows)


def monitor_table(table, detector: PCADetector, top: int = 10) -> dict:
    """Monitor a recorded table: fit on its calibration split, alarm rate and top tags on the other rows.

    Returns ``alarm_rate`` (share of the training and test rows that alarm), ``n_rows``, and
    ``top_t2``/``top_spe``: the tags with the largest mean share of T² and of SPE over the
    alarms (each alarm's contributions divided by its statistic), as (tag, share) pairs.
    """
    calibration = table.trace("calibration").y
    rest = np.concatenate([table.trace("training").y, table.trace("test").y], axis=1)
    decision = detector.decide(calibration, rest).decision[0].astype(bool)
    model = detector.model(calibration, table.output_names)
    c_t2, c_spe = model.contributions(rest[0], int(detector.n_components))
    finite = np.all(np.isfinite(rest[0]), axis=-1)
    pick = decision & finite
    result = {"alarm_rate": float(decision.mean()), "n_rows": int(decision.size), "n_alarms": int(decision.sum())}
    for name, c in (("top_t2", c_t2), ("top_spe", c_spe)):
        # each alarm's contributions as shares of its statistic, then averaged: a few huge spikes of one tag
        # must not outweigh what drives the other alarms
        rows = c[pick]
        total = rows.sum(axis=-1, keepdims=True)
        share = np.mean(rows / np.where(total > 0, total, 1.0), axis=0) if pick.any() else np.zeros(c.shape[-1])
        order = np.argsort(share)[::-1][:top]
        result[name] = [(table.output_names[j], float(share[j])) for j in order]
    return result


#: Columns an exported file has besides its tags (:func:`export_csv`).
EXPORT_TIME, EXPORT_LABEL = "time", "fault"
#: The one table of the export that ``+experiment=table`` runs as it is (:func:`export_table`).
EXPORT_TABLE = "te_table.csv"


def export_table(tables: Mapping[str, np.ndarray], names: tuple[str, ...], out: Path) -> tuple[Path, dict]:
    """The ``tep`` preset's splits as one CSV a ``data=table`` run reads unchanged, and its row splits.

    Rows in order: ``d00.dat`` (calibration: fault-free), then ``d00_te.dat`` and the training files of the
    preset's 18 faults (training: fault-free and faulty rows), then their ``_te`` files (test: 160
    fault-free rows, then the fault). One clock, 180 s a row. A table is one run per split, so the EWMA
    and the persistence run across the files' boundaries inside a split, which the preset's runs do not.
    """
    import csv

    parts = {"calibration": [file_name(0)],
             "training": [file_name(0, test=True), *(file_name(f) for f in DEFAULT_FAULTS)],
             "test": [file_name(f, test=True) for f in DEFAULT_FAULTS]}
    path, splits, row = out / EXPORT_TABLE, {}, 0
    with path.open("w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow([EXPORT_TIME, EXPORT_LABEL, *names])
        for split, files in parts.items():
            start = row
            for name in files:
                fault, onset = int(name[1:3]), (ONSET if name.endswith("_te.dat") else 0)
                for k, sample in enumerate(tables[name]):
                    writer.writerow([f"{row * DT:g}", fault if k >= onset else 0, *(repr(float(v)) for v in sample)])
                    row += 1
            splits[split] = [start, row]
    return path, splits


def export_csv(out_dir: str | Path, directory: str | None = None, variables: str = "literature"):
    """Write every Braatz file as ``dNN.csv`` / ``dNN_te.csv``: time, fault label and the tags by name; and the
    preset's splits as one table (:func:`export_table`). Returns (the files written, that table's row splits).

    Each file keeps its rows in order: ``time`` in seconds from the file's first
    row (180 s per sample), ``fault`` the IDV number acting on the row (0 before
    row 160 of a test file and everywhere in ``d00``), then the tags
    (``XMEAS(1)`` ...) of ``variables`` (``literature``: the 33 the ``tep`` preset
    and its logged model use; ``all``: 52). What ``mosd monitor --keep time --keep
    fault`` scores with a TE run's model, and what ``data=table`` reads
    (``data.time_column=time data.label_column=fault``).
    """
    import csv

    source = TennesseeEastman(directory=directory, variables=variables)
    out = Path(out_dir)
    names = [file_name(0), *(file_name(f) for f in ALL_FAULTS),
             *(file_name(f, test=True) for f in (0, *ALL_FAULTS))]
    tables = [(name, source.values(name)) for name in names]  # every file read (and checked) before one is written
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for name, values in tables:
        fault = int(name[1:3])
        onset = ONSET if name.endswith("_te.dat") else 0
        path = out / name.replace(".dat", ".csv")
        with path.open("w", newline="") as handle:
            writer = csv.writer(handle)
            writer.writerow([EXPORT_TIME, EXPORT_LABEL, *source.output_names])
            for row, sample in enumerate(values):
                writer.writerow([f"{row * DT:g}", fault if row >= onset else 0, *(repr(float(v)) for v in sample)])
        written.append(path)
    table, splits = export_table(dict(tables), source.output_names, out)
    return [*written, table], splits


def table_command(path: Path, splits: Mapping[str, list]) -> str:
    """The ``+experiment=table`` command that runs :func:`export_table`'s file with its splits."""
    ranges = " ".join(f"'data.splits.{k}=[{a},{b}]'" for k, (a, b) in splits.items())
    return (f"python -m mosd +experiment=table data.path={path} data.time_column={EXPORT_TIME} "
            f"data.label_column={EXPORT_LABEL} {ranges}")


def main(argv=None) -> int:
    """``python -m mosd.systems.tep [--directory DIR] [--out DIR] | --table FILE [--time-column C] | --export DIR``."""
    parser = cli.report_parser("python -m mosd.systems.tep", "Tennessee Eastman: the per-fault PCA table (T², SPE, "
                               "combined) of the literature's design and of the tuned one, without the optimiser.",
                               out="outputs/systems/tep", seed=False)
    parser.add_argument("--directory", default=None, help="folder with d00.dat ... d21_te.dat (default: bibmon's)")
    parser.add_argument("--fault", type=int, default=10, help="fault of the statistics/contribution figures")
    parser.add_argument("--table", default=None, help="monitor a CSV/Parquet table instead (fit on its first half)")
    parser.add_argument("--time-column", default=None, help="--table: the time column (a name or a 0-based position)")
    parser.add_argument("--label-column", default=None, help="--table: the fault-label column")
    parser.add_argument("--export", default=None, metavar="DIR",
                        help="write the TE files as CSV (time, fault, the tags by name) into DIR and stop")
    parser.add_argument("--variables", default="literature", choices=("literature", "all"),
                        help="--export: the 33 variables of the tep preset (default) or all 52")
    parser.add_argument("--families", action="store_true",
                        help="tune every monitor family and print the per-fault table of the fair protocol")
    parser.add_argument("--family", action="append", default=None, choices=tuple(FAMILIES),
                        help="--families: only these families (repeat; default all)")
    parser.add_argument("--ablation", action="store_true",
                        help="the ablation: the literature's PCA design with one decision switched on at a time, the "
                             "tuned one with one switched off, each at the protocol's operating point")
    parser.add_argument("--pop-size", type=int, default=20, help="--families: the optimiser's population")
    parser.add_argument("--n-gen", type=int, default=5, help="--families: the optimiser's generations")
    parser.add_argument("--seed", type=int, default=0, help="--families: the optimiser's seed (default 0)")
    parser.add_argument("--no-flatline-rows", action="store_true",
                        help="--families: skip the labelled rows <family>_flatline (each family tuned again with "
                             "the frozen-tag statistic; the headline designs never have it)")
    parser.add_argument("--flatline", action="append", default=None, metavar="LAM|off",
                        help="--families, ablation only (repeat): also score each <family>_flatline design with the "
                             "flat statistic's smoothing replaced by LAM, or off, alpha re-chosen on the training "
                             "split (rows <family>_flatline_<LAM>; the labelled row's own is chosen in the box)")
    cli.design_options(parser, SYSTEM)

    def export_body(args):
        files, splits = export_csv(args.export, args.directory, args.variables)
        print(f"{len(files) - 1} TE files as CSV in {args.export} (columns {EXPORT_TIME}, {EXPORT_LABEL} and "
              f"{len(TennesseeEastman(args.directory, args.variables).output_names)} tags), and the tep preset's "
              f"splits as one table; run it with:")
        print(f"  {table_command(files[-1], splits)}")
        return [Path(args.export)]

    def table_body(args):
        from ..data.table import Table

        # a number is a column position (the unnamed index column of an export is position 0)
        time_column = int(args.time_column) if args.time_column and args.time_column.isdigit() else args.time_column
        table = Table(args.table, time_column=time_column, label_column=args.label_column,
                      splits={"calibration": [0.0, 0.5], "training": [0.5, 0.75], "test": [0.75, 1.0]})
        a = min(LITERATURE["n_components"], len(table.output_names) - 1)
        if a < 1:  # a PCA of one tag has no residual space (issue 53: 'detector.n_components=0 is out of range')
            raise ConfigError(f"--table {args.table}: {len(table.output_names)} tag(s) ({', '.join(table.output_names)}"
                              "); allowed: a table of two or more tags (PCA's T² and SPE need a residual space), or "
                              "a per-tag detector: python -m mosd +experiment=table detector=tag_ewma")
        detector = PCADetector(**{**LITERATURE, "n_components": a})
        result = monitor_table(table, detector)
        print(f"{table!r}: fitted on rows {table.file_rows('calibration')[0]}-{table.file_rows('calibration')[1]} "
              f"({a} components, alpha 0.01); alarm rate {result['alarm_rate']:.4f} on the other "
              f"{result['n_rows']} rows ({result['n_alarms']} alarms)")
        for name in ("top_t2", "top_spe"):
            print(f"  {name[4:].upper():4s} " + ", ".join(f"{t} {s:.2f}" for t, s in result[name][:5]))
        return [cli.write_json(Path(args.out) / "tep_table_monitor.json", result)]

    def body(args):
        if args.ablation:
            return ablation_report(args) + (families_report(args) if args.families else [])
        if args.families:
            return families_report(args)
        if args.export:
            return export_body(args)
        if args.table:
            return table_body(args)
        overrides = [f"data.directory={args.directory}"] if args.directory else []
        experiment = cli.preset(SYSTEM, overrides).experiment
        study = Study(fault=args.fault)
        designs = {TUNED: experiment.detector.with_params(**cli.tuned_design(args, SYSTEM)),
                   **study.reference_designs(experiment, experiment.detector)}
        experiment.monitor.fit(experiment.estimator.estimate(experiment.data.trace("calibration"), None))
        data, metrics, files = cli.score(study, experiment, designs, Path(args.out))
        print(f"## Tennessee Eastman, PCA: detection rates in % on the test files (rows 160-959), "
              f"FAR on d00_te.dat rows 160-959\n")
        for name in data["params"]:
            print(f"- {_label(name)}: {_design_text(data['params'][name])}, {len(data['variables'][name])} variables")
        print()
        print(format_table(data))
        print(f"\nmean MDR (combined) over the training faults {data['train_faults']}: "
              + ", ".join(f"{_label(n)} {metrics[f'{n}_mdr_combined_mean']:.4f}" for n in data["params"])
              + f"; literature design at the tuned FAR, same held-back rows "
              f"{metrics['lit_equal_far_mdr_combined_mean']:.4f} (α {metrics['lit_equal_far_alpha']:.3g}), "
              f"theoretical limits from d00.dat {metrics['lit_d00_equal_far_mdr_combined_mean']:.4f}\n")
        print(f"### Delays per fault (minutes from the onset; – none)\n\n{format_delays(data)}\n")
        print(f"### Ablation (limits from: design = d00.dat for theoretical limits, heldback = the lead-in rows of "
              f"the even _te files, d00 = d00.dat in-sample)\n\n{format_ablation(data)}\n")
        return files

    return cli.run_report(parser, argv, body)


def benchmark(quick: bool = False, seed: int = 0) -> dict:
    """Speed of the TE pipeline (``python -m mosd.bench --only tep``), best of a few repeats.

    ``candidates_per_s``: PCA designs (a, α, λ, k drawn in the preset's box) evaluated per second on
    the training split in-process (FAR and MDR: what one optimiser worker does);
    ``fit_score_s``: fitting the literature design on d00.dat and scoring all 22 test files.
    """
    from ..estimators.measured import MeasuredSignals
    from ..monitors.outputs import OutputMonitor
    from ..recorded import RecordedExperiment
    from ..timing import best_of

    te = TennesseeEastman()
    experiment = RecordedExperiment(te, MeasuredSignals(), OutputMonitor(), PCADetector(fit_runs=1, max_components=25))
    evaluator = experiment.evaluator(experiment.prepare())
    rng = np.random.default_rng(seed)
    n = 50 if quick else 200
    # λ above the floor the held-back runs allow (the detector's data_bounds, as a run's box)
    lam_low, _ = experiment.detector.data_bounds(evaluator.calibration_features)["lam"]
    X = np.column_stack([rng.integers(1, 26, n), rng.uniform(1e-4, 0.1, n), rng.uniform(lam_low, 1.0, n),
                         rng.integers(1, 11, n)]).astype(float)
    evaluator(X[:2])  # imports (scipy.signal) and the cached projections
    repeats = 2 if quick else 3

    def best(fn):
        return best_of(fn, repeats)

    calibration, test = te.trace("calibration").y, te.trace("test").y
    fit_score = best(lambda: PCADetector(**LITERATURE, fit_runs=1).decide(calibration, test))
    return {"candidates_per_s": n / best(lambda: evaluator(X)), "fit_score_s": fit_score, "n_candidates": n,
            "training_points": int(np.prod(evaluator.features.shape[:2])), "test_points": int(np.prod(test.shape[:2])),
            "families": family_benchmark(te, quick, seed)}


if __name__ == "__main__":
    raise SystemExit(main())
