"""Paper 002's Tables 1–2 as ours: isolation delay and error amplitude vs. the missing-data rate.

Wen, Zhang and Pan (2013) report, for 5 / 10 / 20 % missing outputs, the delay
with which the entropy-optimal filter's error shows the fault (target: 1.112 s,
2.451 s, fails at 20 %; nuisance: 1.176 s, 2.578 s, fails at 20 %) and how its
amplitude grows. The computation here (docs/systems/paper002.md, a
reconstruction) runs the reconstructed plant with the target fault on half the
runs and the nuisance fault on the other half (a FaultSet), fills missing
outputs by EM, estimates with :class:`~mosd.estimators.entropy_filter.EntropyIsolationFilter`
and the fixed-gain baseline, and decides with a
:class:`~mosd.detectors.threshold.ThresholdDetector` on |x − x̂|. Everything
returned is plain dicts, lists and floats (the report command prints/plots them).
"""
from __future__ import annotations

import math

import numpy as np

from ..detectors.threshold import ThresholdDetector
from ..estimators.entropy_filter import EntropyIsolationFilter, FixedGainFilter
from ..faults.base import FaultSet
from ..faults.random_amplitude import RandomAmplitudeFault
from ..metrics import detection
from ..monitors.outputs import OutputMonitor
from ..noise.bounded import BoundedNoise
from ..plants.scalar_nonlinear import ScalarNonlinearPlant
from ..scenario import STREAMS, Scenario

MISSING_RATES = (0.0, 0.05, 0.10, 0.20)
PAPER = {  # Tables 1–2 of the paper (delays in s; "fails" at 20 %)
    "target_delay": {0.05: 1.112, 0.10: 2.451, 0.20: math.nan},
    "nuisance_delay": {0.05: 1.176, 0.10: 2.578, 0.20: math.nan},
}
DURATION = 10.0   # 100 steps of 0.1 s
ONSET = 5.0       # step 50
SETTLE = 10       # steps after the onset before the error's level is read


def mean_ci(values) -> dict:
    """Mean and 95 % normal confidence half-width over the finite values."""
    v = np.asarray(values, float)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return {"mean": math.nan, "ci95": math.nan, "n": 0}
    half = 1.96 * v.std(ddof=1) / math.sqrt(v.size) if v.size > 1 else math.nan
    return {"mean": float(v.mean()), "ci95": float(half), "n": int(v.size)}


def scenario(missing_rate: float, draw: str = "per_run") -> Scenario:
    """The reconstructed plant with target and nuisance runs alternating."""
    faults = FaultSet([RandomAmplitudeFault("sine", draw=draw, onset=ONSET, role="target"),
                       RandomAmplitudeFault("ramp", draw=draw, onset=ONSET, role="nuisance")])
    return Scenario(ScalarNonlinearPlant(missing_rate=missing_rate), BoundedNoise(), faults, duration=DURATION)


def design_entropy_filter(seed: int = 2013, n_particles: int = 500, draw: str = "per_run",
                          missing: str = "em", **options) -> EntropyIsolationFilter:
    """The entropy filter with its gain schedule designed on the estimator's seed stream."""
    sc = scenario(0.0, draw)
    target = RandomAmplitudeFault("sine", draw=draw, onset=ONSET, role="target")
    nuisance = RandomAmplitudeFault("ramp", draw=draw, onset=ONSET, role="nuisance")
    est = EntropyIsolationFilter(n_particles=n_particles, target=target, nuisance=nuisance, missing=missing, **options)
    template = sc.simulate(seed, 1, "estimator")
    return est.fit(template, sc.plant.model(sc.noise), np.random.default_rng([seed, STREAMS["estimator"], 10**6]))


def run_metrics(outputs, threshold: float, L: int, burn_in: int, dt: float) -> dict:
    """Per-run isolation numbers of one estimator's outputs (target and nuisance runs apart)."""
    points = OutputMonitor(("error",), burn_in=burn_in).transform(outputs)
    decisions = ThresholdDetector(threshold=threshold, L=L, threshold_max=max(10.0, threshold)).decide(
        points.z[:1], points.z).decision
    label = outputs.fault_label
    role_of_label = np.array(["none", *outputs.fault_roles])
    is_target = role_of_label[label.max(axis=1)] == "target"
    error = outputs.extra["error"]
    N = error.shape[1]
    onset = int(np.argmax(label.max(axis=0) > 0))
    steady = error[:, onset + SETTLE:]
    level = steady.mean(axis=1)
    # the paper's "delay": when the error shows the fault — first reaching half its run's steady level
    reached = (error[:, onset:] >= 0.5 * level[:, None]) & (level[:, None] > 0)
    response = np.where(reached.any(axis=1), np.argmax(reached, axis=1) * dt, (N - onset) * dt)
    delay = detection.detection_delay(decisions, points.fault_mask) * dt
    out = {}
    for role, rows in (("target", is_target), ("nuisance", ~is_target)):
        out[role] = {
            "detection_rate": mean_ci(detection.detection_rate(decisions[rows], points.fault_mask[rows])),
            "isolation_delay_s": mean_ci(delay[rows]),
            "false_alarm_run_rate": mean_ci(detection.false_alarm_run_rate(decisions[rows], points.fault_mask[rows])),
            "far": mean_ci(detection.false_alarm_rate(decisions[rows], points.fault_mask[rows])),
            "response_delay_s": mean_ci(response[rows]),
            "error_level": mean_ci(level[rows]),
            "error_fluctuation": mean_ci(steady[rows].std(axis=1, ddof=1)),
            "prefault_fluctuation": mean_ci(error[rows, burn_in:onset].std(axis=1, ddof=1)),
            "imputation_rmse": mean_ci(_imputation_rmse(outputs, rows)),
        }
    return out


def _imputation_rmse(outputs, rows) -> np.ndarray:
    """RMS of ỹ − x over the filled samples of each run (NaN where nothing was missing)."""
    y = outputs.extra["y_filled"][rows]
    x = outputs.extra["x_hat"][rows] + outputs.extra["error"][rows]
    missing = np.isnan(outputs.r[rows, :, 0])
    with np.errstate(invalid="ignore"):
        sq = np.where(missing, (y - x) ** 2, 0.0).sum(axis=1) / missing.sum(axis=1)
    return np.sqrt(sq)


def isolation_table(missing_rates=MISSING_RATES, n_runs: int = 200, seed: int = 2013, n_particles: int = 500,
                    fixed_gain: float = 0.27, L: int = 3, burn_in: int = 10, threshold: float | None = None,
                    draw: str = "per_run", missing: str = "em") -> dict:
    """Tables 1–2 as ours: every metric as {mean, ci95, n} per estimator, missing rate and fault role.

    Parameters
    ----------
    missing_rates : sequence of float
        MCAR rates of the outputs (paper: 0, 5, 10, 20 %).
    n_runs : int
        Monte Carlo runs per fault (target and nuisance each); the same seeds at
        every rate (nested missing sets: common random numbers).
    seed : int
    n_particles : int
        Particles per design ensemble of the entropy filter.
    fixed_gain : float
        U of the fixed-gain baseline.
    L : int
        Persistence of the threshold detector.
    burn_in : int
        Points dropped before deciding (the x̂_0 = 0 vs x_0 ~ U[0, 1] transient).
    threshold : float, optional
        Threshold on |x − x̂|; default per estimator: midway between the mean
        steady error levels of target and nuisance runs of the complete-data
        calibration stream (never the test runs).
    draw : {"per_run", "per_step"}
        How the fault amplitudes vary (plant and filter design alike).
    missing : {"em", "skip"}

    Returns
    -------
    dict
        ``rates``, ``gain`` (the entropy schedule, list), ``thresholds``
        (per estimator), ``results[estimator][rate][role][metric]`` and
        ``paper`` (the paper's delays).
    """
    entropy = design_entropy_filter(seed, n_particles, draw, missing)
    estimators = {"entropy": entropy, "fixed": FixedGainFilter(gain=fixed_gain, missing=missing)}
    dt = scenario(0.0, draw).plant.dt
    thresholds = {}
    for name, est in estimators.items():
        if threshold is not None:
            thresholds[name] = float(threshold)
            continue
        sc = scenario(0.0, draw)
        cal = est.estimate(sc.simulate(seed, 2 * n_runs, "calibration"), sc.plant.model(sc.noise))
        calib = run_metrics(cal, 1.0, L, burn_in, dt)
        thresholds[name] = 0.5 * (calib["target"]["error_level"]["mean"] + calib["nuisance"]["error_level"]["mean"])
    results = {name: {} for name in estimators}
    for rate in missing_rates:
        sc = scenario(float(rate), draw)
        trace = sc.simulate(seed, 2 * n_runs, "test")
        model = sc.plant.model(sc.noise)
        for name, est in estimators.items():
            results[name][float(rate)] = run_metrics(est.estimate(trace, model), thresholds[name], L, burn_in, dt)
    return {"rates": [float(r) for r in missing_rates], "gain": entropy.gain_.tolist(), "thresholds": thresholds,
            "results": results, "paper": PAPER, "n_runs": int(n_runs), "draw": draw, "missing": missing}


def summary_lines(table: dict) -> list[str]:
    """One printable line per estimator, rate and role (for a quick look; the report command formats its own)."""
    lines = []
    for name, by_rate in table["results"].items():
        for rate, by_role in by_rate.items():
            for role, m in by_role.items():
                lines.append(
                    f"{name:8s} {rate:5.2f} {role:8s} det={m['detection_rate']['mean']:.3f} "
                    f"delay={m['isolation_delay_s']['mean']:.3f}±{m['isolation_delay_s']['ci95']:.3f}s "
                    f"FA-run={m['false_alarm_run_rate']['mean']:.3f} "
                    f"resp={m['response_delay_s']['mean']:.3f}±{m['response_delay_s']['ci95']:.3f}s "
                    f"level={m['error_level']['mean']:.3f}±{m['error_level']['ci95']:.3f} "
                    f"fluct={m['error_fluctuation']['mean']:.3f} pre={m['prefault_fluctuation']['mean']:.3f} "
                    f"imp={m['imputation_rmse']['mean']:.3f}")
    return lines
