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

The columns come in groups that ``--metrics`` picks from (by group or column
name): ``test`` (MDR, FAR, accuracy, detected, n_test), ``design`` (the chosen
design, online, run), ``setup`` (the differing choices) and ``study`` (every
study metric), also per system (``paper003``: that system's study metrics, as
``paper003:<metric>`` columns). The markdown table shows ``test``, ``design`` and
the set-up columns that differ among runs of the same preset (a column that only
differs between systems is the system's doing: ``--metrics setup`` shows them
all); the CSV holds every column of every group. Rows are grouped by system (the preset,
else the data source, else the plant: :func:`run_system`): the markdown has one table per
system, each with the set-up columns that differ among that system's runs and without the
columns empty on all of its rows; the CSV has a ``system`` column and leaves a missing value empty.
"""
from __future__ import annotations

import argparse
import csv
import io
import math
import sys
from typing import Sequence

COLUMNS = ("system", "preset", "fault", "detector", "optimizer", "mdr", "mdr_ci", "far", "far_ci", "accuracy", "accuracy_ci",
           "detection_rate", "params", "online", "n_test", "run_id", "experiment")


#: Config groups recorded as ``mosd.<group>`` tags (the option chosen on the command line).
CHOICE_GROUPS = ("experiment", "plant", "noise", "fault", "estimator", "monitor", "denoise", "detector", "optimizer",
                 "study")
#: Columns every row has anyway.
_FIXED = {"experiment": "preset", "fault": "fault", "detector": "detector", "optimizer": "optimizer"}
#: Params that do not change what a run measures (where it wrote, how many workers evaluated).
_IGNORED_PARAMS = ("tracking.", "outputs_root", "progress", "optimizer.n_jobs", "optimizer.backend",
                   "optimizer.dask_address", "hydra.")


#: The table's columns by group (``--metrics``); ``setup`` and ``study`` columns depend on the runs.
GROUPS = {"test": ("mdr", "far", "accuracy", "detected", "n_test"), "design": ("design", "online", "run")}
#: Other names of those columns (their CSV fields).
_ALIASES = {"detection_rate": "detected", "params": "design", "run_id": "run", "experiment": "run", "mdr_ci": "mdr",
            "far_ci": "far", "accuracy_ci": "accuracy"}
#: The columns always shown, first.
IDENTITY = ("preset", "fault", "detector", "optimizer")
#: CSV fields of the test and design columns.
_CSV_FIELDS = {"mdr": ("mdr", "mdr_ci"), "far": ("far", "far_ci"), "accuracy": ("accuracy", "accuracy_ci"),
               "detected": ("detection_rate",), "n_test": ("n_test",), "design": ("params",), "online": ("online",),
               "run": ("run_id", "experiment")}
#: Markdown headers of the test and design columns.
_HEADERS = {"mdr": "MDR %", "far": "FAR %", "accuracy": "accuracy %", "detected": "detected %", "design": "design",
            "online": "online", "n_test": "n_test", "run": "run"}
#: Tag naming a run's study metrics (continued in ``<tag>.2``, ``<tag>.3``, … beyond MLflow's tag length).
STUDY_METRICS_TAG = "mosd.study_metrics"
_TAG_CHUNK = 6000


class ReportError(Exception):
    """A problem with the command line or the store, reported as one line (exit 2)."""


def logged_study_name(name: str, test_metrics) -> str:
    """The MLflow key of study metric ``name``: ``study_<name>`` when a test metric has that name."""
    return f"study_{name}" if name in test_metrics else name


def study_metric_tags(names) -> dict[str, str]:
    """Tags naming a run's study metrics (comma-separated, split across tags beyond MLflow's tag length)."""
    chunks, current = [], ""
    for name in names:
        if current and len(current) + 1 + len(name) > _TAG_CHUNK:
            chunks.append(current)
            current = ""
        current = f"{current},{name}" if current else name
    if current:
        chunks.append(current)
    return {STUDY_METRICS_TAG + (f".{i + 1}" if i else ""): chunk for i, chunk in enumerate(chunks)}


def study_metric_names(tags) -> list[str]:
    """The study metric names :func:`study_metric_tags` recorded (none for runs logged before it)."""
    names, i = [], 1
    while (chunk := tags.get(STUDY_METRICS_TAG + (f".{i}" if i > 1 else ""))) is not None:
        names += [n for n in chunk.split(",") if n]
        i += 1
    return names


def _system(tags, params) -> str:
    """The name of a run's system (its study's group): the preset, else the study class's module."""
    target = params.get("study._target_", "")
    return tags.get("mosd.experiment") or (target.split(".")[-2] if target.count(".") >= 2 else "study")


def run_system(tags) -> str:
    """The system a run belongs to, what ``mosd report`` groups by: the preset, else the data source, else the plant."""
    return (tags.get("mosd.experiment") or (f"data={tags['mosd.data']}" if tags.get("mosd.data") else "")
            or tags.get("mosd.plant") or "?")


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
            "system": run_system(tags),
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
        system = _system(tags, run.data.params)
        for name in study_metric_names(tags):
            logged = f"study_{name}" if f"study_{name}" in metrics else name
            rows[-1][f"{system}:{name}"] = metrics.get(logged, math.nan)
    extra = differing_columns(rows)
    studies = sorted({k for r in rows for k in r if ":" in k})
    for row in rows:
        choices, config = row.pop("_choices"), row.pop("_config")
        study = {k: row.pop(k) for k in [k for k in row if ":" in k]}
        for column in extra:
            row[column] = choices[column] if column in choices else config.get(column, "–")
        # every row has every column (a system's study metrics are "–" on another system's row)
        row.update({column: study.get(column, "–") for column in studies})
    rows.sort(key=lambda r: (r["system"], r["preset"], r["fault"], r["detector"], r["optimizer"], *(str(r[c]) for c in extra)))
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
    """The set-up columns :func:`collect` added to ``rows`` (beyond :data:`COLUMNS`; no study metric)."""
    return [k for k in (rows[0] if rows else {}) if k not in COLUMNS and ":" not in k]


def study_columns(rows: list[dict]) -> list[str]:
    """The study metric columns of ``rows`` (``<system>:<metric>``)."""
    return [k for k in (rows[0] if rows else {}) if ":" in k]


def by_system(rows: list[dict]) -> dict[str, list[dict]]:
    """``rows`` grouped by their system (:func:`run_system`), in the rows' order."""
    found: dict[str, list[dict]] = {}
    for r in rows:
        found.setdefault(r.get("system", r["preset"]), []).append(r)
    return found


def default_setup_columns(rows: list[dict]) -> list[str]:
    """The set-up columns that differ among runs of one system (the others only differ between systems)."""
    return [c for c in extra_columns(rows)
            if any(len({str(r[c]) for r in same}) > 1 for same in by_system(rows).values())]


def groups(rows: list[dict]) -> dict[str, list[str]]:
    """Every group of ``--metrics`` with its columns: test, design, setup, study and one per system."""
    found = {name: list(columns) for name, columns in GROUPS.items()}
    found["setup"] = extra_columns(rows)
    found["study"] = study_columns(rows)
    for column in found["study"]:
        found.setdefault(column.split(":")[0], []).append(column)
    return found


def select_columns(rows: list[dict], metrics: str | None) -> list[str]:
    """The columns ``--metrics`` names (groups or columns, comma-separated), in its order; None: the default.

    A study metric's bare name (``detection_step_best``) stands for that metric of
    every system that has it. An unknown name is a :class:`ReportError` naming what is allowed.
    """
    every = groups(rows)
    if metrics is None:
        return [*default_setup_columns(rows), *every["test"], *every["design"]]
    chosen: list[str] = []
    for name in (n.strip() for n in metrics.split(",")):
        name = _ALIASES.get(name, name)
        if name in every:
            chosen += every[name]
        elif name in every["test"] + every["design"] + every["setup"] + every["study"]:
            chosen.append(name)
        elif any(column.split(":", 1)[1] == name for column in every["study"]):
            chosen += [column for column in every["study"] if column.split(":", 1)[1] == name]
        else:
            shown = ", ".join(every["setup"]) or "none differ"
            raise ReportError(f"--metrics={name!r} is not a group or column of this report; allowed: the groups "
                              f"{', '.join(every)}; the columns {', '.join(every['test'] + every['design'])}; a set-up "
                              f"column ({shown}); a study metric, bare or as system:metric (the CSV lists them all)")
    return list(dict.fromkeys(chosen))


def _percent(mean: float, half_width: float) -> str:
    if not math.isfinite(mean):
        return "–"
    if not math.isfinite(half_width):
        return f"{100 * mean:.2f}"
    return f"{100 * mean:.2f} ± {100 * half_width:.2f}"


def _cell(r: dict, column: str) -> str:
    if column in ("mdr", "far", "accuracy"):
        return _percent(r[column], r[f"{column}_ci"])
    if column == "detected":
        return _percent(r["detection_rate"], math.nan)
    if column == "n_test":
        return f"{r['n_test']:.0f}" if math.isfinite(r["n_test"]) else "–"
    if column == "design":
        return r["params"] or "–"
    if column == "run":
        return r["run_id"][:8]
    value = r[column]
    if isinstance(value, float):
        return f"{value:.4g}" if math.isfinite(value) else "–"
    value = str(value or "–")
    # a configuration value that reads as a missing number (data.errors=nan, the option's name) is quoted
    return f"'{value}'" if value.lower() in ("nan", "none", "null") else value


def _table(rows: list[dict], columns: list[str]) -> str:
    """One markdown table; a column whose every cell is empty ("–") is left out, except the identity."""
    header = [*IDENTITY, *columns]
    cells = [[r["preset"] or "–", r["fault"], r["detector"], r["optimizer"], *(_cell(r, c) for c in columns)]
             for r in rows]
    keep = [i for i in range(len(header)) if i < len(IDENTITY) or any(row[i] != "–" for row in cells)]
    lines = ["| " + " | ".join(_HEADERS.get(header[i], header[i]) for i in keep) + " |",
             "|" + "|".join("---" for _ in keep) + "|"]
    lines += ["| " + " | ".join(row[i] for i in keep) + " |" for row in cells]
    return "\n".join(lines)


def to_markdown(rows: list[dict], columns: list[str] | None = None) -> str:
    """Markdown: rates in % as mean ± 95 % CI half-width over the test replications, one table per system.

    ``columns`` (:func:`select_columns`) after the identity columns; None: the
    default, chosen per system (the set-up columns that differ among its runs).
    Runs of several systems get one table each under a ``### system`` line;
    a column empty ("–") on every row of a table is left out of it (the identity columns stay).
    """
    systems = by_system(rows)
    if len(systems) == 1:
        return _table(rows, select_columns(rows, None) if columns is None else columns)
    parts = []
    for system, same in systems.items():
        shown = [c for c in (select_columns(rows, None) if columns is None else columns)
                 if c not in extra_columns(rows) or columns is not None or len({str(r[c]) for r in same}) > 1]
        parts.append(f"### {system} ({len(same)} run{'s' if len(same) > 1 else ''})\n\n" + _table(same, shown))
    return "\n\n".join(parts)


def to_csv(rows: list[dict], columns: list[str] | None = None) -> str:
    """CSV (rates as fractions, CIs as half-widths): ``columns`` after the identity, or every column (None)."""
    if columns is None:
        fields = [*COLUMNS, *extra_columns(rows), *study_columns(rows)]
    else:
        fields = [*IDENTITY, *(f for c in columns for f in _CSV_FIELDS.get(c, (c,)))]
    out = io.StringIO()
    writer = csv.DictWriter(out, fieldnames=list(dict.fromkeys(fields)), lineterminator="\n", extrasaction="ignore")
    writer.writeheader()
    for r in rows:
        # a missing value is an empty field, as spreadsheets and pandas read it (not "nan" or an en dash)
        writer.writerow({k: ("" if v == "–" or (isinstance(v, float) and math.isnan(v))
                             else repr(v) if isinstance(v, float) else v) for k, v in r.items()})
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
    parser.add_argument("--metrics", default=None,
                        help="columns to show, comma-separated group or column names: test, design, setup, study, "
                             "a system (paper003: its study metrics), or a column such as far, budget.n_test, "
                             "detection_step_best (default: test, design and the set-up columns that differ among "
                             "runs of one preset; the CSV's default is every column)")
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
            from .store import refusal, sqlite_path, sqlite_store_state

            db = sqlite_path(args.tracking_uri)
            if db is None or not db.is_file():
                raise ReportError(f"--tracking-uri={args.tracking_uri!r}: no such database (run mosd first)")
            state = sqlite_store_state(db)
            if state.state not in ("ok", "empty"):  # a locked store is said to be locked, never damaged (issue 53)
                raise ReportError(f"--tracking-uri={args.tracking_uri!r}: {refusal(db, state)}")
        rows = collect(args.tracking_uri, args.experiment, latest_only=not args.all)
        columns = select_columns(rows, args.metrics) if rows and args.metrics is not None else None
    except ReportError as exc:
        print(f"mosd report: error: {redacted(str(exc))}", file=sys.stderr)
        return 2
    if not rows:
        print(f"mosd report: no finished mosd runs in {redacted(args.tracking_uri)}", file=sys.stderr)
        return 0
    sys.stdout.write((to_csv(rows, columns) if args.format == "csv" else to_markdown(rows, columns) + "\n"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
