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
    """The summary printed at the end of a run; ``header=False`` leaves out the first line (printed at the start)."""
    n_test = int(metrics["n_test"])
    params = "  ".join(f"{k} = {v}" if isinstance(v, int) else f"{k} = {v:.4f}" for k, v in result.params.items())

    def pm(key, digits=4):
        return f"{metrics[key]:.{digits}f} ± {metrics[key + '_ci']:.{digits}f}"

    train = ", ".join(f"{k} {v:.4g}" for k, v in result.train_objectives.items())
    online = "online (causal detector)" if setup.experiment.detector.is_causal else \
        "NOT online: the detector uses future points (non-causal)"
    lines = [
        *([header_line(labels, setup)] if header else []),
        f"chosen    {params}   (training: {train}; archive of {len(result.archive_F)})",
        *([f"          on the search bound: {', '.join(on_bound(result.params, setup))} "
           "(widen detector.bounds: the optimum may lie outside the box)"] if on_bound(result.params, setup) else []),
        f"test      {n_test} fresh replications, mean ± 95 % CI half-width; {online}",
        f"  FAR       {pm('far')}",
        f"  MDR       {pm('mdr')}",
        f"  accuracy  {pm('accuracy')}",
        f"  detected  {pm('detection_rate')} of the runs",
        f"  delay     {pm('delay_s', 4)} s over detected runs; censored median "
        f"{metrics['delay_censored_median_s']:.4g} s (undetected runs beyond the horizon)",
        "wall time " + f"{timings['wall_s']:.1f} s  (" + ", ".join(
            f"{k.removesuffix('_s')} {v:.1f}" for k, v in timings.items() if k != "wall_s") + ")",
        *([f"study     {type(setup.study).__name__}: " + ", ".join(f"{k} {v:.4g}" for k, v in study.items())]
          if study else []),
        f"run dir   {run_dir}",
    ]
    if tracking_line:
        lines.append(tracking_line)
    return "\n".join(lines)

