"""Markdown of :mod:`mosd.optim.benchmarks`' rows: the hypervolume (and IGD) table, ratios, targets, CPU, profile."""
from __future__ import annotations

from .benchmark_algorithms import DEFAULT_NAME, IGD_TARGETS, NSGA2_NAME, PEERS, SMPSO_NAME, TARGETS


def format_profile(rows: list[dict], generations=(1, 2, 5, 10, 15, 20, 25, 30, 40, 50, 60, 70, 80, 90, 100)) -> str:
    """Markdown table of :func:`generation_profile` at ``generations`` and where the archive first turns feasible."""
    first = next((row["generation"] for row in rows if row["feasible"]), None)
    lines = ["| generation | archive members | feasible | least CV in archive | feasible evaluations "
             "| distinct leaders | distinct parents |", "|---:|---:|---|---:|---:|---:|---:|"]
    for row in rows:
        if row["generation"] in generations or row["generation"] == first:
            cells = [row["generation"], row["members"], "yes" if row["feasible"] else "no", f"{row['least_cv']:.4f}",
                     row["feasible_evaluations"], "–" if row["leaders"] is None else row["leaders"],
                     "–" if row["parents"] is None else row["parents"]]
            lines.append("| " + " | ".join(str(c) for c in cells) + " |")
    return "\n".join(lines)


def format_table(rows: list[dict], igd: bool = False) -> str:
    """Markdown table: one line per algorithm, median HV (and IGD) per problem."""
    problems = list(dict.fromkeys(row["problem"] for row in rows))
    algorithms = list(dict.fromkeys(row["algorithm"] for row in rows))
    cell = {(row["problem"], row["algorithm"]): row for row in rows}
    columns = [f"{p} HV" for p in problems] + ([f"{p} IGD" for p in problems] if igd else [])
    lines = ["| algorithm | " + " | ".join(columns) + " |", "|---|" + "---:|" * len(columns)]
    for name in algorithms:
        rows_of = [cell.get((problem, name)) for problem in problems]
        values = ["–" if row is None else f"{row['hv_median']:.4f}" for row in rows_of]
        if igd:
            values += ["–" if row is None else f"{row['igd_median']:.4f}" for row in rows_of]
        lines.append(f"| {name} | " + " | ".join(values) + " |")
    return "\n".join(lines)


def format_ratios(rows: list[dict], algorithm: str = DEFAULT_NAME,
                  references=(SMPSO_NAME, NSGA2_NAME)) -> str:
    """Markdown table of median-HV ratios ``algorithm`` / reference, per problem."""
    problems = list(dict.fromkeys(row["problem"] for row in rows))
    cell = {(row["problem"], row["algorithm"]): row["hv_median"] for row in rows}
    lines = ["| ratio | " + " | ".join(problems) + " |", "|---|" + "---:|" * len(problems)]
    for reference in references:
        values = []
        for problem in problems:
            mine, theirs = cell.get((problem, algorithm)), cell.get((problem, reference))
            values.append("–" if mine is None or not theirs else f"{mine / theirs:.3f}")
        lines.append(f"| {algorithm} / {reference} | " + " | ".join(values) + " |")
    return "\n".join(lines)


def best_peer(rows: list[dict], problem: str) -> tuple[str, float] | None:
    """The peer (:data:`PEERS`) with the highest median HV on ``problem``, and that HV."""
    peers = [(row["hv_median"], row["algorithm"]) for row in rows
             if row["problem"] == problem and row["algorithm"] in PEERS]
    if not peers:
        return None
    hv, name = max(peers)
    return name, hv


def target_rows(rows: list[dict], algorithm: str = DEFAULT_NAME) -> list[dict]:
    """The targets per problem (:data:`TARGETS` on the median HV, :data:`IGD_TARGETS` on the median IGD):
    ``problem``, ``metric`` ("HV" or "IGD"), ``hv`` (the algorithm's median of that metric), ``reference``
    (name), ``reference_hv``, ``ratio``, ``factor``, ``met`` (None when a needed row is missing)."""
    cells = {"HV": {(row["problem"], row["algorithm"]): row["hv_median"] for row in rows},
             "IGD": {(row["problem"], row["algorithm"]): row.get("igd_median") for row in rows}}
    out = []
    for problem in dict.fromkeys(row["problem"] for row in rows):
        for metric, targets in (("HV", TARGETS), ("IGD", IGD_TARGETS)):
            cell = cells[metric]
            if problem not in targets or cell.get((problem, algorithm)) is None:
                continue
            reference, factor = targets[problem]
            if reference == "best peer":
                found = best_peer(rows, problem)
                reference, theirs = found if found else (reference, None)
            else:
                theirs = cell.get((problem, reference))
            mine = cell[(problem, algorithm)]
            ratio = None if not theirs else mine / theirs
            met = None if ratio is None else (ratio >= factor if metric == "HV" else ratio <= factor)
            out.append({"problem": problem, "metric": metric, "hv": mine, "reference": reference,
                        "reference_hv": theirs, "ratio": ratio, "factor": factor, "met": met})
    return out


def format_targets(rows: list[dict], algorithm: str = DEFAULT_NAME) -> str:
    """Markdown table of :func:`target_rows` (HV: ratio ≥ target; IGD: ratio ≤ target)."""
    lines = [f"| problem | metric | {algorithm} | reference | reference value | ratio | target | met |",
             "|---|---|---:|---|---:|---:|---:|---|"]
    for t in target_rows(rows, algorithm):
        theirs = "–" if t["reference_hv"] is None else f"{t['reference_hv']:.4f}"
        ratio = "–" if t["ratio"] is None else f"{t['ratio']:.3f}"
        met = "–" if t["met"] is None else ("yes" if t["met"] else "**no**")
        bound = "≥" if t["metric"] == "HV" else "≤"
        lines.append(f"| {t['problem']} | {t['metric']} | {t['hv']:.4f} | {t['reference']} | {theirs} | {ratio} "
                     f"| {bound} {t['factor']:.2f} | {met} |")
    return "\n".join(lines)


def format_cpu(rows: list[dict]) -> str:
    """Markdown table of the optimisers' own CPU per evaluation (µs, median over seeds; :func:`_run`)."""
    problems = list(dict.fromkeys(row["problem"] for row in rows))
    algorithms = list(dict.fromkeys(row["algorithm"] for row in rows))
    cell = {(row["problem"], row["algorithm"]): row.get("cpu_us_median") for row in rows}
    lines = ["| algorithm | " + " | ".join(f"{p} µs/eval" for p in problems) + " |",
             "|---|" + "---:|" * len(problems)]
    for name in algorithms:
        values = ["–" if cell.get((p, name)) is None else f"{cell[(p, name)]:.1f}" for p in problems]
        lines.append(f"| {name} | " + " | ".join(values) + " |")
    return "\n".join(lines)
