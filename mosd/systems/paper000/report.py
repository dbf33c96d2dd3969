"""Paper 000's tables as markdown beside the paper's numbers, and their JSON, CSV and PNG files."""
from __future__ import annotations

import csv
import json
import math
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from ...metrics import Estimate, json_ready
from ..base import figure
from .numbers import FAULT_LABELS, PAPER_TABLE3, PAPER_TABLE4, PAPER_TABLE4_PARAMS
from .tables import BarCheck, GridScan, ParetoComparison, Row, Table3, Table4


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
    js.write_text(json.dumps(json_ready({
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
    }), indent=1, allow_nan=False))
    return written + [js]


def write_table4(table: Table4, out: Path) -> list[Path]:
    out.mkdir(parents=True, exist_ok=True)
    md = out / "table4.md"
    md.write_text(format_table4(table) + "\n")
    js = out / "table4.json"
    js.write_text(json.dumps(json_ready({"settings": table.settings, "params": table.params,
                                         "train_objectives": table.train_objectives,
                                         "rows": [_row_json(r) for r in table.rows]}), indent=1, allow_nan=False))
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
    fig = figure(11.0, 4.6)
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
    fig = figure(6.4, 4.6)
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


