"""What a run prints and logs as numbers: the final metrics, the summary's lines, the design on the search box."""
from __future__ import annotations

import math
from typing import TYPE_CHECKING, Mapping

if TYPE_CHECKING:
    from .build import Setup


def on_bound(params: Mapping[str, float], setup: Setup) -> list[str]:
    """The chosen parameters that sit on the optimiser's search box (1e-6 of its width)."""
    names = []
    for name, value in params.items():
        interval = setup.experiment.detector.tunable[name]
        low, high = setup.bounds.get(name, (interval.low, interval.high))
        tol = 1e-6 * (high - low) + (1e-6 if interval.open_low or interval.open_high else 0.0)
        if value <= low + tol or value >= high - tol:
            names.append(f"{name} = {value:g} in [{low:g}, {high:g}]")
    return names


def bound_notes(params: Mapping[str, float], setup: Setup) -> list[str]:
    """The summary's notes on :func:`on_bound`'s parameters: widen the box only where the parameter may go further.

    A design on the edge of the box that is also the edge of the parameter's
    allowed range (``persistence = 1``, the smallest allowed) cannot be moved by
    widening ``detector.bounds``: it says so instead of advising it.
    """
    notes = []
    for name, value in params.items():
        interval = setup.experiment.detector.tunable[name]
        low, high = setup.bounds.get(name, (interval.low, interval.high))
        tol = 1e-6 * (high - low) + (1e-6 if interval.open_low or interval.open_high else 0.0)
        at_low, at_high = value <= low + tol, value >= high - tol
        if not (at_low or at_high):
            continue
        edge = float(interval.low if at_low else interval.high)
        text = f"{name} = {value:g} in [{low:g}, {high:g}]"
        if abs((low if at_low else high) - edge) <= tol:
            text += f" (the {'smallest' if at_low else 'largest'} value {name} allows)"
        else:
            text += f" (widen detector.bounds.{name}: the optimum may lie outside the box)"
        notes.append(text)
    return notes


#: a study of more metrics than this is one line on the screen: where its metrics are (issue 51: TE's 384 took 80)
SHOWN_STUDY_METRICS = 24


def study_lines(name: str, study: Mapping[str, float], width: int = 110,
                shown: int | None = SHOWN_STUDY_METRICS) -> list[str]:
    """The ``study`` lines of the summary: one line saying where a long study's metrics are, else grouped and wrapped.

    A study of more than ``shown`` metrics (None: no limit) is one line: their count and where they are
    (``summary.json``'s ``study``, the MLflow run, ``python -m mosd report --metrics study``). Otherwise metrics
    sharing a name up to their last ``_`` part (``lit_fdr_t2_idv1``, ``lit_fdr_t2_idv2``, …) form one family
    printed as ``lit_fdr_t2: idv1 0.9988, idv2 …``; the rest are listed together; every line is wrapped at
    ``width`` characters, between metrics.
    """
    if shown is not None and len(study) > shown:
        return [f"study     {name}: {len(study)} metrics, in summary.json (\"study\") and the MLflow run "
                "(python -m mosd report --metrics study)"]
    families: dict[str, list[tuple[str, str, float]]] = {}  # stem -> (full key, last part, value)
    for key, value in study.items():
        stem, _, tail = key.rpartition("_")
        families.setdefault(stem or key, []).append((key, tail, value))
    loose = [(key, value) for items in families.values() if len(items) < 3 for key, _, value in items]
    entries = [("", [f"{k} {v:.4g}" for k, v in loose])] if loose else []
    entries += [(f"{stem}: ", [f"{tail} {v:.4g}" for _, tail, v in items])
                for stem, items in families.items() if len(items) >= 3]
    lines = [f"study     {name}: {len(study)} metrics"]
    for head, items in entries:  # wrapped between metrics, never between a name and its value
        line = "  " + head
        for i, item in enumerate(items):
            piece = item + ("," if i < len(items) - 1 else "")
            if len(line) + 1 + len(piece) > width and line.strip() and not line.endswith(": "):
                lines.append(line)
                line = "      " + piece
            else:
                line += ("" if line.endswith(("  ", ": ")) else " ") + piece
        lines.append(line)
    return lines


def final_metrics(result, seconds_per_point: float) -> dict[str, float]:
    """The run's scalar metrics: test means and CI half-widths, chosen parameters, training objectives."""
    metrics: dict[str, float] = {}
    for key, estimate in result.summary().items():
        metrics[key] = estimate.mean
        metrics[f"{key}_ci"] = estimate.half_width
    if math.isnan(metrics.get("accuracy", 0.0)) and not math.isnan(metrics.get("far", math.nan) + metrics.get("mdr", math.nan)):
        # recorded data: every run is all fault-free or all faulty, so no run has its own 1 - FAR - MDR;
        # the accuracy is that of the mean rates (no CI: the two means come from different runs)
        from ..metrics.summary import accuracy

        metrics["accuracy"] = accuracy(metrics["far"], metrics["mdr"])
    for key in ("delay", "delay_censored"):
        if key in metrics:
            metrics[f"{key}_s"] = metrics[key] * seconds_per_point
            metrics[f"{key}_s_ci"] = metrics[f"{key}_ci"] * seconds_per_point
    metrics["delay_censored_median_s"] = result.test.median_censored_delay() * seconds_per_point
    metrics["n_test"] = float(result.test.n_runs)
    metrics.update({name: float(value) for name, value in result.params.items()})
    metrics.update({f"train_{name}": float(value) for name, value in result.train_objectives.items()})
    metrics["sigma"] = float(result.sigma)
    return metrics


class UndefinedResult(RuntimeError):
    """A run's metrics are NaN: it ends FAILED rather than reporting them as a finished result."""


def undefined_metrics(metrics: Mapping[str, float]) -> list[str]:
    """The metrics a run must not report as finished: NaN means (no points to score, e.g. no fault-free point).

    Left out: CI half-widths (NaN from a single test replication) and the delays,
    which are means over the detected runs only (NaN when no run was detected).
    """
    return [key for key, value in metrics.items()
            if isinstance(value, float) and math.isnan(value)
            and not key.endswith("_ci") and not key.startswith("delay")]


def header_line(labels: Mapping[str, str], setup: Setup) -> str:
    """``mosd  fault=…  detector=…  optimizer=… (pop × gen)  estimator=…  denoise=…``: the summary's first line."""
    pop = getattr(setup.algorithm, "pop_size", "?")
    preset = f"experiment={labels['experiment']}  " if labels.get("experiment") else ""
    source = f"data={labels['data']}" if labels.get("data") else f"fault={labels.get('fault')}"
    return (f"mosd  {preset}{source}  detector={labels.get('detector')}  "
            f"optimizer={labels.get('optimizer', '')} ({pop} × {setup.n_gen})  estimator={labels.get('estimator')}  "
            f"denoise={labels.get('denoise')}")


def format_summary(labels, result, setup: Setup, metrics, timings, run_dir, tracking_line, study=None,
                   header: bool = True) -> str:
    """The summary printed at the end of a run; ``header=False`` leaves out the first line (printed at the start).

    :func:`result_lines`, then :func:`closing_lines`: a single run prints the first as soon as its test
    is scored and the second when its files and its MLflow run are done.
    """
    return "\n".join([*([header_line(labels, setup)] if header else []), result_lines(result, setup, metrics),
                      closing_lines(setup, timings, run_dir, tracking_line, study)])


def result_lines(result, setup: Setup, metrics) -> str:
    """The chosen design and its test results (``chosen`` … ``delay``)."""
    n_test = int(metrics["n_test"])
    params = "  ".join(f"{k} = {v}" if isinstance(v, int) else f"{k} = {v:.4f}" for k, v in result.params.items())

    def pm(key, digits=4):  # no "± nan": one run (or one detected run) has no interval
        half = metrics[key + "_ci"]
        return f"{metrics[key]:.{digits}f}" + (f" ± {half:.{digits}f}" if math.isfinite(half) else "")

    train = ", ".join(f"{k} {v:.4g}" for k, v in result.train_objectives.items())
    online = "online (causal detector)" if setup.experiment.detector.is_causal else \
        "NOT online: the detector uses future points (non-causal)"
    return "\n".join([
        f"chosen    {params}   (training: {train}; archive of {len(result.archive_F)})",
        *(f"          on the search bound: {note}" for note in bound_notes(result.params, setup)),
        f"test      {_test_runs(setup, n_test)}; {online}",
        f"  FAR       {pm('far')}",
        f"  MDR       {pm('mdr')}",
        f"  accuracy  {pm('accuracy')}",
        f"  detected  {pm('detection_rate')} of the runs",
        f"  delay     {pm('delay_s', 4)} s over detected runs; censored median "
        f"{metrics['delay_censored_median_s']:.4g} s (undetected runs beyond the horizon)",
    ])


def _test_runs(setup: Setup, n_test: int) -> str:
    """What the test scored: fresh simulated replications, or the recorded data's test runs."""
    recorded = getattr(setup.experiment, "data", None) is not None
    runs = (f"{n_test} run{'s' * (n_test != 1)} of the recorded data's test split" if recorded
            else f"{n_test} fresh replication{'s' * (n_test != 1)}")
    return runs + (", mean ± 95 % CI half-width" if n_test > 1 else " (one run: no interval)")


def closing_lines(setup: Setup, timings, run_dir, tracking_line, study=None) -> str:
    """Where the time went, the studies' lines, the run directory and the MLflow run (``wall time`` …)."""
    lines = [
        "wall time " + f"{timings['wall_s']:.1f} s  (" + ", ".join(
            f"{k.removesuffix('_s')} {v:.1f}" for k, v in timings.items() if k != "wall_s") + ")",
        *(study_lines(type(setup.study).__name__, study) if study else []),
        f"run dir   {run_dir}",
    ]
    if tracking_line:
        lines.append(tracking_line)
    return "\n".join(lines)

