"""The computations behind paper 003's results, on our reconstruction (plain dicts and arrays).

Wang et al. 2020 (paper 003) §2.2: ramp faults of 0.1 … 1.0 m/s are injected
into the GPS altitude at step 500 (100 s at 5 Hz) and observers of windows
N = 1 … 15 are compared by their mean detection step and detection rate
(Table 2), per ramp rate (Fig. 8); Fig. 7 shows the residual and the adaptive
threshold of N = 1 and of a multi-step observer; Fig. 6 the training loss.

:func:`table2` runs all of it on simulated flights of
:class:`~mosd.plants.flapping_wing.FlappingWingMAV`: one set of fault-free
training flights (seed stream ``"estimator"``) trains one observer per N;
the same test flights (stream ``"test"``) are replayed with every ramp rate
(the fault is injected into the log only, so the flights themselves do not
depend on the rate) and decided on by :class:`AdaptiveChi2Detector` for both
readings of the χ² statistic (``"observer_chi2"`` and the filter's ``"chi2"``).

Definitions (the paper does not define its two numbers):

* detection step — the first alarm at or after the onset step, among the runs
  that alarm there (a run that never alarms after the onset is a miss);
* detection rate — the share of post-onset points that alarm (the point-wise
  fault detection rate), averaged over runs;
* run detection share — the share of runs that alarm at all after the onset;
* false-alarm rate — the share of pre-onset points (after the first N) that alarm.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from ..detectors.adaptive_chi2 import AdaptiveChi2Detector
from ..estimators.neural_observer import MultiStepNeuralObserver
from ..faults.ramp import RampFault
from ..plants.flapping_wing import FlappingWingMAV
from ..scenario import replication_rngs

#: σ of the logged channels' white noise: GPS altitude (m), down velocity (m/s), pitch (rad), throttle, tail (rad)
LOG_NOISE_SIGMA = (0.05, 0.05, 0.005, 0.001, 0.001)
STATISTICS = ("observer_chi2", "chi2")


def default_noise():
    """The white log noise of :data:`LOG_NOISE_SIGMA`, no process noise (a Gaussian noise model)."""
    from ..noise.gaussian import GaussianNoise  # the lead's module; imported only when the default is used

    return GaussianNoise(process_cov=0.0, measurement_cov=np.square(LOG_NOISE_SIGMA), n_x=6, n_y=5)


def detection_summary(decision: np.ndarray, onset_step: int, first_valid: int = 0) -> dict[str, np.ndarray]:
    """Per-design numbers of decisions (P, R, K) or (R, K) (module docstring for the definitions).

    Returns arrays over the leading design axis (scalars for (R, K)):
    ``detection_step`` (mean over detecting runs, NaN if none), ``detection_rate``,
    ``run_detection_share``, ``false_alarm_rate`` and ``first_alarm`` (R,) per run
    (the step index, -1 for a miss).
    """
    alarm = np.asarray(decision) > 0
    post = alarm[..., onset_step:]
    detected = post.any(-1)
    first = np.where(detected, onset_step + post.argmax(-1), -1)
    count = detected.sum(-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean_step = np.where(count > 0, np.where(detected, first, 0).sum(-1) / count, np.nan)
    return {"detection_step": mean_step, "detection_rate": post.mean((-1, -2)),
            "run_detection_share": detected.mean(-1),
            "false_alarm_rate": alarm[..., first_valid:onset_step].mean((-1, -2)), "first_alarm": first}


def table2(windows: Sequence[int] = tuple(range(1, 16)), rates: Sequence[float] = tuple(np.round(np.arange(1, 11) / 10, 1)),
           n_test: int = 20, n_train: int = 10, n_samples: int = 1000, onset_step: int = 500, seed: int = 0,
           alpha: float = 0.01, a: float = 1.0, b: float = 1.0, plant: FlappingWingMAV | None = None, noise=None,
           observer: dict | None = None, trace_rate: float = 0.1) -> dict:
    """Table 2, Fig. 6, Fig. 7 and Fig. 8 of paper 003 on simulated flights (module docstring).

    Parameters
    ----------
    windows, rates : observer windows N and ramp rates (m/s) to compare.
    n_test : test flights per rate (the paper's full scale: >= 20).
    n_train : fault-free training flights.
    n_samples, onset_step : run length and fault onset in steps.
    alpha, a, b : the detector's design (paper: a = b = 1).
    plant, noise : default :class:`FlappingWingMAV` and :func:`default_noise`.
    observer : further :class:`MultiStepNeuralObserver` parameters (epochs, cache_dir, ...).
    trace_rate : ramp rate whose first run's traces are kept for Fig. 7.

    Returns
    -------
    dict with ``windows``, ``rates``, per statistic s in :data:`STATISTICS`:
    ``[s]["detection_step"]``, ``["detection_rate"]``, ``["run_detection_share"]``,
    ``["false_alarm_rate"]`` each (len(windows), len(rates)) and their means over
    rates ``["mean_detection_step"]`` etc. (len(windows),); ``loss`` (per N:
    train and validation curves); ``traces`` (per N: observer residual, χ²
    statistics and thresholds of one run at ``trace_rate``); ``observer_sigma``
    (per N, the held-out σ of the N-step prediction error).
    """
    plant = plant or FlappingWingMAV()
    noise = noise or default_noise()
    model = plant.model(noise)
    dt = plant.dt
    onset = onset_step * dt
    training = plant.simulate(n_samples, noise, None, replication_rngs(seed, "estimator", n_train))
    tests = {rate: plant.simulate(n_samples, noise, RampFault(rate=rate, onset=onset), replication_rngs(seed, "test", n_test))
             for rate in rates}
    detector = AdaptiveChi2Detector(alpha=alpha, a=a, b=b)
    shape = (len(windows), len(rates))
    results = {s: {key: np.full(shape, np.nan) for key in
                   ("detection_step", "detection_rate", "run_detection_share", "false_alarm_rate")} for s in STATISTICS}
    loss, traces, sigma = {}, {}, {}
    for i, window in enumerate(windows):
        estimator = MultiStepNeuralObserver(window=window, **(observer or {}))
        estimator.fit(training, model, np.random.default_rng([seed, 3, 10**6 + window]))
        loss[window] = estimator.history_
        sigma[window] = estimator.residual_std_
        for j, rate in enumerate(rates):
            outputs = estimator.estimate(tests[rate], model)
            for s in STATISTICS:
                z = np.stack([outputs.extra[s], outputs.extra["observer_residual"]], -1)
                decided = detector.decide(z, z)
                summary = detection_summary(decided.decision, onset_step, first_valid=window)
                for key in results[s]:
                    results[s][key][i, j] = summary[key]
                if rate == trace_rate:
                    traces.setdefault(window, {"observer_residual": outputs.extra["observer_residual"][0]})
                    traces[window][s] = {"statistic": decided.statistic[0], "threshold": decided.threshold[0],
                                         "first_alarm": int(summary["first_alarm"][0])}
    for s in STATISTICS:
        for key in list(results[s]):
            values = results[s][key]
            seen = np.isfinite(values)
            with np.errstate(invalid="ignore", divide="ignore"):
                results[s]["mean_" + key] = np.where(seen, values, 0.0).sum(1) / seen.sum(1)
    return {"windows": list(windows), "rates": list(rates), "n_test": n_test, "n_train": n_train,
            "n_samples": n_samples, "onset_step": onset_step, "seed": seed, **results, "loss": loss,
            "traces": traces, "observer_sigma": sigma}


def format_table2(result: dict, statistic: str = "observer_chi2") -> str:
    """Table 2 as text: N, mean detection step, detection rate, run share, false-alarm rate."""
    r = result[statistic]
    lines = [f"statistic={statistic}  (rates {result['rates'][0]}..{result['rates'][-1]} m/s, "
             f"{result['n_test']} runs each, onset step {result['onset_step']})",
             "  N  mean step  detection rate  runs detected  false alarms"]
    for i, window in enumerate(result["windows"]):
        lines.append(f"{window:3d}  {r['mean_detection_step'][i]:9.1f}  {100 * r['mean_detection_rate'][i]:13.1f}%"
                     f"  {100 * r['mean_run_detection_share'][i]:12.1f}%  {100 * r['mean_false_alarm_rate'][i]:11.2f}%")
    return "\n".join(lines)
