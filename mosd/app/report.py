"""``mosd report`` / ``python -m mosd.app.report``: the comparison table of finished runs.

Reads the runs of the app (tag ``mosd.role = job``) from an MLflow tracking store
and prints one row per set-up — the latest finished run of each, or every run
with ``--all`` — with the test MDR, FAR and accuracy (mean ± 95 % CI half-width,
in %), the chosen design, as a markdown table (paper 000, Table 3 layout) or as CSV.

A set-up is every choice a run was made with: its config groups (estimator,
denoiser, …) and every configuration value (budgets, seed, a detector's bounds),
except where the outputs go and where and on how many workers it evaluated
(``optimizer.n_jobs``, ``backend``, ``dask_address``: they change no result). Besides the
preset, fault, detector and optimizer, the table gets a column for each choice
that differs among the rows shown, so two runs are never merged into one row or
shown side by side without the difference that separates them.
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


#: Config groups recorded as ``mosd.<group>`` tags (the option chosen on the command line).
CHOICE_GROUPS = ("experiment", "plant", "noise", "fault", "estimator", "monitor", "denoise", "detector", "optimizer",
                 "study")
#: Columns every row has anyway.
_FIXED = {"experiment": "preset", "fault": "fault", "detector": "detector", "optimizer": "optimizer"}
#: Params that do not change what a run measures (where it wrote, how many workers evaluated).
_IGNORED_PARAMS = ("tracking.", "outputs_root", "progress", "optimizer.n_jobs", "optimizer.backend",
                   "optimizer.dask_address", "hydra.")


class ReportError(Exception):
    """A problem with the command line or the store, reported as one line (exit 2)."""


def collect(tracking_uri: str, experiment: str | None = None, latest_only: bool = True) -> list[dict]:
    """Rows of finished app runs: :data:`COLUMNS` plus one column per differing choice (:func:`differing_columns`)."""
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
        choices = {g: tags.get(f"mosd.{g}", "") for g in CHOICE_GROUPS}
        params = {k: v for k, v in run.data.params.items() if not k.startswith(_IGNORED_PARAMS)}
        key = (tuple(sorted(choices.items())), tuple(sorted(params.items())))
        if latest_only and key in seen:
            continue
        seen.add(key)
        names = [n for n in tags.get("mosd.params", "").split(",") if n]
        design = " ".join(f"{n}={metrics[n]:.4g}" for n in names if n in metrics)
        rows.append({
            # recorded data (data=tep, data=table) have no fault option: the data source fills the column
            "preset": choices["experiment"],
            "fault": tags.get("mosd.fault") or (f"data={tags['mosd.data']}" if tags.get("mosd.data") else "?"),
            "detector": tags.get("mosd.detector", "?"), "optimizer": tags.get("mosd.optimizer", "?"),
            **{m: metrics.get(m, math.nan) for m in ("mdr", "mdr_ci", "far", "far_ci", "accuracy", "accuracy_ci",
                                                      "detection_rate")},
            "params": design, "online": tags.get("mosd.online", "?"), "n_test": metrics.get("n_test", math.nan),
            "run_id": run.info.run_id, "experiment": ids.get(run.info.experiment_id, ""),
            "_choices": choices, "_config": params,
        })
    extra = differing_columns(rows)
    for row in rows:
        choices, config = row.pop("_choices"), row.pop("_config")
        for column in extra:
            row[column] = choices[column] if column in choices else config.get(column, "–")
    rows.sort(key=lambda r: (r["preset"], r["fault"], r["detector"], r["optimizer"], *(str(r[c]) for c in extra)))
    return rows


def differing_columns(rows: list[dict]) -> list[str]:
    """The choices (groups, then config values) that differ among ``rows``, beyond the fixed columns.

    A config value under a group whose option differs is left out: the option's
    column already says why it differs.
    """
    groups = [g for g in CHOICE_GROUPS if g not in _FIXED and len({r["_choices"][g] for r in rows}) > 1]
    varied = {g for g in CHOICE_GROUPS if len({r["_choices"][g] for r in rows}) > 1}
    keys = sorted({k for r in rows for k in r["_config"]})
    values = [k for k in keys if k.split(".")[0] not in varied
              and len({r["_config"].get(k) for r in rows}) > 1]
    return groups + values


def extra_columns(rows: list[dict]) -> list[str]:
    """The set-up columns :func:`collect` added to ``rows`` (beyond :data:`COLUMNS`)."""
    return [k for k in (rows[0] if rows else {}) if k not in COLUMNS]


def _percent(mean: float, half_width: float) -> str:
    if not math.isfinite(mean):
        return "–"
    if not math.isfinite(half_width):
        return f"{100 * mean:.2f}"
    return f"{100 * mean:.2f} ± {100 * half_width:.2f}"


def to_markdown(rows: list[dict]) -> str:
    """Markdown table: rates in % as mean ± 95 % CI half-width over the test replications."""
    extra = extra_columns(rows)
    header = ["preset", "fault", "detector", "optimizer", *extra, "MDR %", "FAR %", "accuracy %", "detected %",
              "design", "online", "n_test", "run"]
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    for r in rows:
        cells = [r["preset"] or "–", r["fault"], r["detector"], r["optimizer"], *(str(r[c] or "–") for c in extra),
                 _percent(r["mdr"], r["mdr_ci"]),
                 _percent(r["far"], r["far_ci"]), _percent(r["accuracy"], r["accuracy_ci"]),
                 _percent(r["detection_rate"], math.nan), r["params"] or "–", r["online"],
                 f"{r['n_test']:.0f}" if math.isfinite(r["n_test"]) else "–", r["run_id"][:8]]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def to_csv(rows: list[dict]) -> str:
    """CSV with :data:`COLUMNS` (rates as fractions, CIs as half-widths)."""
    out = io.StringIO()
    writer = csv.DictWriter(out, fieldnames=[*COLUMNS, *extra_columns(rows)], lineterminator="\n")
    writer.writeheader()
    for r in rows:
        writer.writerow({k: (repr(v) if isinstance(v, float) else v) for k, v in r.items()})
    return out.getvalue()


def _parser(default_uri: str) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="mosd report", description="Comparison table of finished mosd runs: one row per set-up, a column "
                                        "for every choice that differs among them.")
    parser.add_argument("--tracking-uri", default=default_uri,
                        help=f"MLflow tracking URI (default: {default_uri})")
    parser.add_argument("--experiment", default=None, help="only runs of this MLflow experiment (default: all)")
    parser.add_argument("--format", choices=("markdown", "csv"), default="markdown", help="output format")
    parser.add_argument("--all", action="store_true", help="every finished run, not only the latest per set-up")
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    from .settings import default_tracking_uri, redacted

    parser = _parser(default_tracking_uri())

    def error(message: str):  # one line instead of argparse's usage block
        raise ReportError(message)

    parser.error = error
    try:
        args = parser.parse_args(list(sys.argv[1:] if argv is None else argv))
        if args.tracking_uri.startswith("sqlite:///"):
            from .store import sqlite_path, sqlite_store_state

            db = sqlite_path(args.tracking_uri)
            if db is None or not db.is_file():
                raise ReportError(f"--tracking-uri={args.tracking_uri!r}: no such database (run mosd first)")
            state = sqlite_store_state(db)
            if state.state not in ("ok", "empty"):
                raise ReportError(f"--tracking-uri={args.tracking_uri!r}: the store {db} is damaged ({state.detail}); "
                                  f"allowed: a healthy MLflow store")
        rows = collect(args.tracking_uri, args.experiment, latest_only=not args.all)
    except ReportError as exc:
        print(f"mosd report: error: {redacted(str(exc))}", file=sys.stderr)
        return 2
    if not rows:
        print(f"mosd report: no finished mosd runs in {redacted(args.tracking_uri)}", file=sys.stderr)
        return 0
    sys.stdout.write((to_csv(rows) if args.format == "csv" else to_markdown(rows) + "\n"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
