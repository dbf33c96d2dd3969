"""``mosd report`` / ``python -m mosd.app.report``: the comparison table of finished runs.

Reads the runs of the app (tag ``mosd.role = job``) from an MLflow tracking store
and prints one row per (preset, fault, detector, optimizer) — the latest finished run of each,
or every run with ``--all`` — with the test MDR, FAR and accuracy (mean ± 95 % CI
half-width, in %), the chosen λ and control width, as a markdown table (paper 000,
Table 3 layout) or as CSV.
"""
from __future__ import annotations

import argparse
import csv
import io
import math
import sys
from typing import Sequence

COLUMNS = ("preset", "fault", "detector", "optimizer", "mdr", "mdr_ci", "far", "far_ci", "accuracy", "accuracy_ci",
           "detection_rate", "params", "online", "n_test", "run_id", "experiment")


class ReportError(Exception):
    """A problem with the command line or the store, reported as one line (exit 2)."""


def collect(tracking_uri: str, experiment: str | None = None, latest_only: bool = True) -> list[dict]:
    """Rows (dicts with :data:`COLUMNS`) of finished app runs, sorted by preset, fault, detector, optimizer."""
    from mlflow.tracking import MlflowClient

    client = MlflowClient(tracking_uri=tracking_uri)
    experiments = client.search_experiments()
    if experiment is not None:
        chosen = [e for e in experiments if e.name == experiment]
        if not chosen:
            names = ", ".join(sorted(e.name for e in experiments)) or "none"
            raise ReportError(f"--experiment={experiment!r} is not in {tracking_uri}; allowed: {names}")
        experiments = chosen
    ids = {e.experiment_id: e.name for e in experiments}
    if not ids:
        return []
    runs, token = [], None
    while True:
        page = client.search_runs(list(ids), filter_string="tags.`mosd.role` = 'job' and attributes.status = 'FINISHED'",
                                  order_by=["attributes.start_time DESC"], max_results=1000, page_token=token)
        runs.extend(page)
        token = page.token
        if not token:
            break
    rows, seen = [], set()
    for run in runs:  # newest first
        tags, metrics = run.data.tags, run.data.metrics
        key = (tags.get("mosd.experiment", ""), tags.get("mosd.fault", "?"), tags.get("mosd.detector", "?"),
               tags.get("mosd.optimizer", "?"))
        if latest_only and key in seen:
            continue
        seen.add(key)
        names = [n for n in tags.get("mosd.params", "").split(",") if n]
        params = " ".join(f"{n}={metrics[n]:.4g}" for n in names if n in metrics)
        rows.append({
            "preset": key[0], "fault": key[1], "detector": key[2], "optimizer": key[3],
            **{m: metrics.get(m, math.nan) for m in ("mdr", "mdr_ci", "far", "far_ci", "accuracy", "accuracy_ci",
                                                      "detection_rate")},
            "params": params, "online": tags.get("mosd.online", "?"), "n_test": metrics.get("n_test", math.nan),
            "run_id": run.info.run_id, "experiment": ids.get(run.info.experiment_id, ""),
        })
    rows.sort(key=lambda r: (r["preset"], r["fault"], r["detector"], r["optimizer"]))
    return rows


def _percent(mean: float, half_width: float) -> str:
    if not math.isfinite(mean):
        return "–"
    if not math.isfinite(half_width):
        return f"{100 * mean:.2f}"
    return f"{100 * mean:.2f} ± {100 * half_width:.2f}"


def to_markdown(rows: list[dict]) -> str:
    """Markdown table: rates in % as mean ± 95 % CI half-width over the test replications."""
    header = ["preset", "fault", "detector", "optimizer", "MDR %", "FAR %", "accuracy %", "detected %", "design",
              "online", "n_test", "run"]
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    for r in rows:
        cells = [r["preset"] or "–", r["fault"], r["detector"], r["optimizer"], _percent(r["mdr"], r["mdr_ci"]),
                 _percent(r["far"], r["far_ci"]), _percent(r["accuracy"], r["accuracy_ci"]),
                 _percent(r["detection_rate"], math.nan), r["params"] or "–", r["online"],
                 f"{r['n_test']:.0f}" if math.isfinite(r["n_test"]) else "–", r["run_id"][:8]]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def to_csv(rows: list[dict]) -> str:
    """CSV with :data:`COLUMNS` (rates as fractions, CIs as half-widths)."""
    out = io.StringIO()
    writer = csv.DictWriter(out, fieldnames=COLUMNS, lineterminator="\n")
    writer.writeheader()
    for r in rows:
        writer.writerow({k: (repr(v) if isinstance(v, float) else v) for k, v in r.items()})
    return out.getvalue()


def _parser(default_uri: str) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="mosd report", description="Comparison table (preset × fault × detector × optimizer) of finished mosd runs.")
    parser.add_argument("--tracking-uri", default=default_uri,
                        help=f"MLflow tracking URI (default: {default_uri})")
    parser.add_argument("--experiment", default=None, help="only runs of this MLflow experiment (default: all)")
    parser.add_argument("--format", choices=("markdown", "csv"), default="markdown", help="output format")
    parser.add_argument("--all", action="store_true", help="every finished run, not only the latest per combination")
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    from .tracking import default_tracking_uri

    parser = _parser(default_tracking_uri())

    def error(message: str):  # one line instead of argparse's usage block
        raise ReportError(message)

    parser.error = error
    try:
        args = parser.parse_args(list(sys.argv[1:] if argv is None else argv))
        if args.tracking_uri.startswith("sqlite:///"):
            from pathlib import Path

            db = Path(args.tracking_uri.removeprefix("sqlite:///"))
            if not db.is_file():
                raise ReportError(f"--tracking-uri={args.tracking_uri!r}: no such database (run mosd first)")
        rows = collect(args.tracking_uri, args.experiment, latest_only=not args.all)
    except ReportError as exc:
        print(f"mosd report: error: {exc}", file=sys.stderr)
        return 2
    if not rows:
        print(f"mosd report: no finished mosd runs in {args.tracking_uri}", file=sys.stderr)
        return 0
    sys.stdout.write((to_csv(rows) if args.format == "csv" else to_markdown(rows) + "\n"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
