"""Paper 001's Figs. 2–5 as ours: mode probabilities, amplitude, and RMSE fused vs. each sensor.

Hu, Jin, Xue and Sun (2017) show, over 500 Monte Carlo runs of the turning
target with an actuator-2 fault f = 2 from 16.5 s: the normal model dominant
before the fault and the actuator-2 model above 0.5 soon after (Fig. 2), the
amplitude estimate (Fig. 3), and the state and amplitude RMSE of the fused
filter below those of sensor 1 < sensor 2 < sensor 3 (Figs. 4–5). The
computation here (docs/systems/paper001.md, a reconstruction) runs
:class:`~mosd.plants.networked_target.NetworkedTarget`, estimates with
:class:`~mosd.estimators.async_imm.AsyncIMMFusion` on all sensors and on each
one alone, and decides with
:class:`~mosd.detectors.mode_probability.ModeProbabilityDetector`. Everything
returned is plain dicts, lists and floats.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Sequence

import numpy as np

from ..faults.actuator import ActuatorFault
from ..metrics.estimation import rmse_over_runs
from ..metrics.registry import per_run
from ..metrics.summary import Estimate
from ..scenario import Scenario, replication_rngs
from ..validation import ConfigError, Interval, check_in, check_int
from . import base, cli
from .base import TUNED, decorate, design_params, figure, prefixed

SYSTEM = "paper001"
SENSOR_FILTERS = ("s1", "s2", "s3")
#: the calibration runs' replications of the ``test`` stream start here (disjoint from the study's runs)
CALIBRATION_FIRST = 10**6
#: the reliability curve's bins of μ₂ and the least share of all fusion steps a bin needs to enter the largest
#: gap (a share, not a count: the gap then does not depend on the number of runs, issue 30)
CALIBRATION_BINS, CALIBRATION_MIN_SHARE = 10, 0.01
#: Λ's prior, as the mean number of fusion intervals to a fault 1/h (docs/systems/paper001.md, "Λ is a prior"):
#: the preset's 40 (one fault per run, the onset uniform over the run's 40 intervals), half and double it, and
#: 16.5, the hazard whose mean time to a fault is the paper's fixed onset at 16.5 s
PRIOR_INTERVALS = (20.0, 40.0, 80.0, 16.5)
#: the pairs of filters whose RMSE order the paper claims (sensor 1 < 2 < 3, fused below each)
RMSE_PAIRS = (("sensor1", "sensor2"), ("sensor2", "sensor3"), ("fused", "sensor1"))


def hazard_transition(n_intervals: float, n_faults: int) -> np.ndarray:
    """Λ from the scenario's fault hazard (a reconstruction; docs/systems/paper001.md, "Choosing Λ").

    The paper's scenario puts one fault in every run, at an instant the filter
    does not know; with no other knowledge the onset is equally likely in each of
    the run's ``n_intervals`` fusion intervals, so the chance that a fault starts
    within one fusion interval is h = 1/n_intervals, split equally over the
    ``n_faults`` fault directions. The paper's faults are constant and one at a
    time, so a fault neither ends nor changes direction: the fault rows are
    absorbing. Row i holds P(mode i → mode m) (§3.1, rows summing to 1)::

        Λ = [[1 − h, h/d_f, …, h/d_f],
             [0,     1,     …, 0    ],
             …
             [0,     0,     …, 1    ]]

    Parameters
    ----------
    n_intervals : float
        Fusion intervals of a run (the paper's example: 40, t = 0 … 40 s at 1 s), >= 1;
        a prior's mean time to a fault in intervals in general (:data:`PRIOR_INTERVALS`).
    n_faults : int
        Fault models d_f (the example: 2 actuators).
    """
    n_intervals = check_in("n_intervals", n_intervals, Interval(1.0, 1e9))
    n_faults = check_int("n_faults", n_faults, 1)
    hazard = 1.0 / n_intervals
    trans = np.eye(n_faults + 1)
    trans[0, 0] = 1.0 - hazard
    trans[0, 1:] = hazard / n_faults
    return trans


def reliability(probability: np.ndarray, outcome: np.ndarray, bins: int = CALIBRATION_BINS,
                min_share: float = CALIBRATION_MIN_SHARE) -> dict:
    """A reliability curve: per equal bin of [0, 1], the mean probability and the share of outcomes that occurred.

    Returns ``mean_probability``, ``active_share`` and ``steps`` (per bin; NaN where
    a bin is empty), ``ece``, the expected calibration error Σ_b (n_b/n) |share_b −
    mean_b| (the step-weighted mean gap), ``ece_middle``, the same over the bins other
    than the first and the last (where the forecaster is unsure; NaN if they are empty),
    and ``max_gap``, the largest |share − mean
    probability| over the bins holding at least ``min_share`` of all values. All three are
    estimates of fixed quantities of the forecaster, whatever the number of runs (the
    bins kept are chosen by share, not by count); a calibrated forecaster's gaps shrink
    like the binomial error √(p(1 − p)/n_b).
    """
    probability = np.asarray(probability, float).ravel()
    outcome = np.asarray(outcome, bool).ravel()
    index = np.clip((probability * bins).astype(int), 0, bins - 1)
    steps = np.bincount(index, minlength=bins)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.bincount(index, probability, bins) / steps
        share = np.bincount(index, outcome.astype(float), bins) / steps
    gap = np.where(steps > 0, np.abs(share - mean), 0.0)
    kept = steps >= min_share * max(steps.sum(), 1)
    middle = np.arange(bins)[1:-1]  # the bins between the first and the last: where the filter is unsure
    return {"mean_probability": mean, "active_share": share, "steps": steps,
            "ece": float(np.sum(gap * steps) / max(steps.sum(), 1)),
            "ece_middle": float(np.sum(gap[middle] * steps[middle]) / steps[middle].sum()) if steps[middle].any()
            else math.nan,
            "max_gap": float(np.max(gap[kept])) if kept.any() else math.nan}


def mode_calibration(experiment, n_runs: int, actuator: int = 2, bins: int = CALIBRATION_BINS,
                     min_share: float = CALIBRATION_MIN_SHARE, estimator=None) -> dict:
    """Are the fused filter's mode probabilities probabilities? A reliability curve of μ_actuator.

    ``n_runs`` runs whose faults follow the estimator's own Λ: in each fusion
    interval a fault-free run turns faulty with probability 1 − λ_00, on
    actuator m with probability λ_0m / (1 − λ_00), at the interval's midpoint
    (like the paper's 16.5 s), with the scenario's amplitude, and stays so (a run
    may end fault-free). The fusion steps t_1 … t_K of all runs are binned by
    μ_actuator into ``bins`` equal bins of [0, 1]; in each bin the share of steps
    at which that actuator's fault is active should equal the bin's mean μ.
    Draws: the onsets from ``default_rng([seed, 2, 2**30])``, the runs from the
    ``test`` stream's replications :data:`CALIBRATION_FIRST` … (disjoint from the
    study's).

    Returns
    -------
    dict
        ``mean_probability``, ``active_share``, ``steps`` (per bin; NaN where
        empty), ``ece`` and ``max_gap`` (:func:`reliability`), ``hazard`` (1 − λ_00),
        ``faulty_runs``. ``estimator``: another Λ's filter (default the experiment's).
    """
    model, estimator = experiment.model, estimator or experiment.estimator
    n_models = len(estimator.model_set(model))
    trans, _ = estimator._probabilities(n_models)  # the estimator's own Λ (a float expands to a matrix)
    hazard = 1.0 - float(trans[0, 0])
    if hazard <= 0.0:
        raise ConfigError("estimator.transition keeps the normal model forever (lambda_00 = 1); allowed for the "
                          "calibration check: lambda_00 < 1")
    fault = experiment.fault
    period, duration = float(experiment.plant.dt), float(experiment.duration)
    n_intervals = int(round(duration / period)) - 1
    rng = np.random.default_rng([int(experiment.seed), 2, 2**30])
    start = rng.geometric(hazard, size=n_runs)  # the interval (t_{k-1}, t_k] in which the fault starts
    which = 1 + rng.choice(n_models - 1, size=n_runs, p=trans[0, 1:] / hazard)
    # the runs in order of (interval, actuator), the fault-free ones first: replication CALIBRATION_FIRST + i is
    # the i-th, as when each (interval, actuator) group was simulated and estimated on its own
    keys = sorted((int(k), int(m)) if k <= n_intervals else (0, 0) for k, m in zip(start, which))
    members = {key: None if key[0] == 0 else ActuatorFault(actuator=key[1], amplitude=fault.amplitude,
                                                           onset=(key[0] - 0.5) * period) for key in set(keys)}
    # all runs in one batch (one simulation, one filter call; the plant checks each fault): the groups one at a
    # time cost 0.7-1.0 s per 500 runs, in calls of one or two runs each (issue 32)
    n_samples = Scenario(experiment.plant, experiment.noise, None, duration).n_samples
    trace = experiment.plant.simulate(n_samples, experiment.noise, [members[key] for key in keys],
                                      replication_rngs(experiment.seed, "test", n_runs, first=CALIBRATION_FIRST))
    mu = estimator.estimate(trace, model).extra["mode_probabilities"][:, 1:, actuator]
    active = trace.x[:, 1:, model.n_x + actuator - 1] != 0
    curve = reliability(mu.ravel(), active.ravel(), bins, min_share)
    return {**curve, "hazard": hazard, "faulty_runs": int(sum(key != (0, 0) for key in keys))}


def prior_tag(intervals: float) -> str:
    """The metric infix of a prior 1/h: ``20`` for 20 intervals, ``16p5`` for 16.5."""
    return f"{intervals:g}".replace(".", "p")


def _run_mse(estimate: np.ndarray, truth: np.ndarray, first: int) -> np.ndarray:
    """Each run's mean over the steps from ``first`` of the squared error summed over components (R,)."""
    err = np.asarray(estimate, float) - np.asarray(truth, float)
    err = err[..., None] if err.ndim == 2 else err
    return np.nanmean(np.sum(err[:, first:] ** 2, axis=-1), axis=-1)


class Study(base.Study):
    """Paper 001's Monte Carlo comparison (Figs. 2–5 and the decision rule) for a tuned design.

    Runs ``n_runs`` faulty and ``n_runs`` fault-free replications of the
    experiment's scenario on the ``test`` seed stream (the fault-free runs share
    the faulty runs' seeds: common random numbers), estimates with the
    experiment's fusion filter on all sensors and on each sensor alone, and
    decides with the tuned detector and with the paper's design (μ_T = 0.5,
    L = 1, ``mosd/systems/designs/paper001.json``; metrics prefixed ``paper_``).

    Parameters
    ----------
    n_runs : int
        Monte Carlo runs of each kind (the paper: 500).
    figures : bool
        Write the PNG figures into ``out_dir``.
    prior_intervals : sequence of float
        Λ's priors to compare, each as the mean fusion intervals to a fault 1/h >= 1
        (default :data:`PRIOR_INTERVALS`; empty: no comparison).

    Notes
    -----
    Metric definitions (``run`` returns them under these names):

    * ``rmse_state_<f>`` / ``rmse_amplitude_<f>`` for f in fused, sensor1..3: the
      Monte Carlo RMSE curve (:func:`~mosd.metrics.estimation.rmse_over_runs`)
      averaged over the fusion instants at or after the onset. The amplitude
      error is that of the fused fault-input estimate Σ_m μ_m f̂_m e_m against
      the true fault input (docs/systems/paper001.md).
    * ``isolation_rate``: faulty runs whose first alarm at or after the onset
      names actuator 2; ``false_isolation_rate``: faulty runs that declare
      actuator 1 at any point at or after the onset.
    * ``far``, ``mdr``, ``detection_rate`` (faulty runs detected): the metric
      registry's, on the faulty runs; ``delay_s``: mean over detected runs of
      (first alarm − first faulty fusion instant) in seconds.
    * ``no_fault_declared_rate``: fault-free runs without any declaration
      (``paper_no_fault_declared_rate``: the same at the paper's μ_T = 0.5, L = 1).
    * ``mode_calibration_ece``, ``mode_calibration_ece_middle`` and ``mode_calibration_max_gap``: the
      step-weighted mean gap over all bins and over the bins between 0.1 and 0.9, and the largest
      gap, of the reliability curve of μ₂ (:func:`reliability`,
      :func:`mode_calibration`, ``n_runs`` runs whose faults start as Λ says).
    * ``mse_<q>_<a>_minus_<b>`` and ``..._ci95`` for q in state, amplitude and the
      pairs :data:`RMSE_PAIRS`: the mean over runs of the paired difference of each
      run's mean squared error after the onset, and its 95 % Student-t half-width. A
      claimed order whose difference has a CI containing 0 is not resolved by the runs.
    * Λ as a prior (``prior_intervals``; the fused filter with
      :func:`hazard_transition` of each 1/h on the same runs): ``prior_<tag>_<key>``
      for key in ``isolation_rate``, ``delay_s``, ``far``, ``no_fault_declared_rate``
      (the tuned design), ``paper_no_fault_declared_rate``, ``rmse_state_fused``,
      ``rmse_amplitude_fused`` and ``mode_calibration_ece`` (runs whose faults start as
      that Λ says), tag = 1/h with ``p`` for a decimal point (``20``, ``16p5``).
    """

    system = SYSTEM

    def __init__(self, n_runs: int = 500, figures: bool = True, prior_intervals=PRIOR_INTERVALS):
        super().__init__(figures=figures)
        self.n_runs = check_int("study.n_runs", n_runs, 2)
        if isinstance(prior_intervals, (str, bytes)) or not hasattr(prior_intervals, "__iter__"):
            raise ConfigError(f"study.prior_intervals={prior_intervals!r} is not allowed; allowed: a list of mean "
                              f"intervals to a fault >= 1, e.g. [20, 40, 80, 16.5]")
        self.prior_intervals = tuple(check_in("study.prior_intervals", v, Interval(1.0, 1e9))
                                     for v in prior_intervals)

    # -- computation --------------------------------------------------------------------
    def compute(self, experiment, designs: dict) -> dict:
        """Estimates, RMSE curves and decisions of each named detector design (plain dict)."""
        faulty = experiment.simulate(experiment.fault, self.n_runs, "test")
        clean = experiment.simulate(None, self.n_runs, "test")
        onset_index = int(np.argmax(faulty.fault_mask.any(axis=0)))
        filters = {"fused": experiment.estimator}
        for i, name in enumerate(SENSOR_FILTERS, start=1):
            # the same filter on one sensor's packets
            filters[f"sensor{i}"] = experiment.estimator.with_params(sensors=(name,))
        curves, errors = {}, {}
        fused = None
        for name, est in filters.items():
            res = est.estimate(faulty, experiment.model)
            fused = res if name == "fused" else fused
            curves[name] = {
                "state": rmse_over_runs(res.extra["x_filt"], faulty.x[..., :2]),
                "amplitude": rmse_over_runs(res.extra["fault_estimate"], faulty.x[..., 2:]),
                # the declared (actuator-2) model's conditional amplitude, averaged over runs (Fig. 3)
                "amplitude_mean": res.extra["fault_amplitudes"][..., 1].mean(axis=0),
            }
            errors[name] = {"state": _run_mse(res.extra["x_filt"], faulty.x[..., :2], onset_index),
                            "amplitude": _run_mse(res.extra["fault_estimate"], faulty.x[..., 2:], onset_index)}
        decisions = self._decide(experiment, designs, fused, experiment.estimator.estimate(clean, experiment.model))
        priors = {}
        n_faults = len(experiment.estimator.model_set(experiment.model)) - 1
        for intervals in self.prior_intervals:
            estimator = experiment.estimator.with_params(transition=hazard_transition(intervals, n_faults))
            res = estimator.estimate(faulty, experiment.model)
            scored = self._decide(experiment, designs, res, estimator.estimate(clean, experiment.model))
            priors[intervals] = {
                **{k: scored[TUNED][k] for k in ("isolation_rate", "delay_s", "far", "no_fault_declared_rate")
                   if TUNED in scored and k in scored[TUNED]},
                **({"paper_no_fault_declared_rate": scored["paper"]["no_fault_declared_rate"]}
                   if "paper" in scored else {}),
                "rmse_state_fused": float(rmse_over_runs(res.extra["x_filt"], faulty.x[..., :2])[onset_index:].mean()),
                "rmse_amplitude_fused": float(rmse_over_runs(res.extra["fault_estimate"],
                                                             faulty.x[..., 2:])[onset_index:].mean()),
                "mode_calibration_ece": mode_calibration(experiment, self.n_runs, estimator=estimator)["ece"]}
        return {"t": faulty.t, "onset_index": onset_index, "onset_s": float(experiment.fault.onset),
                "errors": errors, "priors": priors,
                "true_amplitude": faulty.x[0, :, 2:], "curves": curves,
                "calibration": mode_calibration(experiment, self.n_runs),
                "mode_probabilities_mean": fused.extra["mode_probabilities"].mean(axis=0),
                "decisions": decisions, "params": {name: design_params(d) for name, d in designs.items()},
                "n_runs": self.n_runs}

    def _decide(self, experiment, designs: dict, faulty_outputs, clean_outputs) -> dict[str, dict]:
        """Every design's scores on the fused filter's outputs of the faulty and the fault-free runs."""
        points = experiment.monitor.transform(faulty_outputs)
        clean_points = experiment.monitor.transform(clean_outputs)
        period = float(np.median(np.diff(faulty_outputs.t)))
        decisions = {}
        for name, detector in designs.items():
            d = detector.decide(clean_points.z, points.z).decision
            d0 = detector.decide(clean_points.z, clean_points.z).decision
            decisions[name] = self._score(detector, d, d0, points, clean_points, period)
        return decisions

    @staticmethod
    def _score(detector, d, d0, points, clean_points, period: float) -> dict:
        after = np.broadcast_to(points.fault_mask.any(axis=0), d.shape)
        # the decision value that names actuator 1 (the model set's fault 1)
        actuator1 = detector.labels[0] if getattr(detector, "labels", None) else 1
        delay = per_run("delay", d, points)
        scores = {
            "isolation_rate": float(np.nanmean(per_run("isolation_rate", d, points))),
            "false_isolation_rate": float(np.mean(((d == actuator1) & after).any(axis=-1))),
            "far": float(np.nanmean(per_run("far", d, points))),
            "mdr": float(np.nanmean(per_run("mdr", d, points))),

            "detection_rate": float(np.nanmean(per_run("detection_rate", d, points))),
            "no_fault_declared_rate": float(np.mean(~(d0 != 0).any(axis=-1))),
            "far_fault_free": float(np.mean(d0 != 0)),
        }
        if np.isfinite(delay).any():  # no detected run: no delay to report
            scores["delay_s"] = float(np.nanmean(delay) * period)
        return scores

    def metrics(self, data: dict) -> dict[str, float]:
        """The study's metrics by name (class docstring): the tuned design's, then the others' prefixed."""
        k0 = data["onset_index"]
        out = {}
        for name, curve in data["curves"].items():
            out[f"rmse_state_{name}"] = float(curve["state"][k0:].mean())
        for name, curve in data["curves"].items():
            out[f"rmse_amplitude_{name}"] = float(curve["amplitude"][k0:].mean())
        for design, scores in data["decisions"].items():
            out.update({prefixed(design) + k: float(v) for k, v in scores.items()})
        out["mode_calibration_ece"] = data["calibration"]["ece"]
        if math.isfinite(data["calibration"]["ece_middle"]):
            out["mode_calibration_ece_middle"] = data["calibration"]["ece_middle"]
        if math.isfinite(data["calibration"]["max_gap"]):
            out["mode_calibration_max_gap"] = data["calibration"]["max_gap"]
        for quantity in ("state", "amplitude"):
            for a, b in RMSE_PAIRS:
                diff = Estimate.of(data["errors"][a][quantity] - data["errors"][b][quantity])
                out[f"mse_{quantity}_{a}_minus_{b}"] = diff.mean
                out[f"mse_{quantity}_{a}_minus_{b}_ci95"] = diff.half_width
        for intervals, scores in data["priors"].items():
            out.update({f"prior_{prior_tag(intervals)}_{k}": float(v) for k, v in scores.items()})
        return out

    # -- figures --------------------------------------------------------------------------
    def write_figures(self, data: dict, out_dir: Path) -> list[Path]:
        """Figs. 2–5 as PNG files: mode probabilities, amplitude, state RMSE, amplitude RMSE; and the calibration."""
        return self.draw_figure_jobs(data, out_dir)

    def figure_jobs(self, data: dict, out_dir: Path) -> list[tuple[str, dict]]:
        """The five figures of :meth:`write_figures`, each a job of its own (drawn side by side where the app has
        the cores)."""
        path = Path(out_dir) / f"{self.system}_"
        return [("_mode_probabilities_figure", {"data": data, "path": Path(f"{path}mode_probabilities.png")}),
                ("_amplitude_figure", {"data": data, "path": Path(f"{path}amplitude.png")}),
                ("_rmse_figure", {"data": data, "key": "state", "title": "Fig. 4: RMSE of the state",
                                  "path": Path(f"{path}rmse_state.png")}),
                ("_rmse_figure", {"data": data, "key": "amplitude", "title": "Fig. 5: RMSE of the fault input",
                                  "path": Path(f"{path}rmse_amplitude.png")}),
                ("_calibration_figure", {"data": data, "path": Path(f"{path}calibration.png")})]

    @staticmethod
    def _finish(ax, onset: float, ylabel: str, title: str) -> None:
        ax.axvline(onset, color="grey", lw=0.8, ls=":")
        decorate(ax, "t (s)", ylabel, title)

    def _mode_probabilities_figure(self, data: dict, path: Path) -> Path:
        fig = figure(6.0, 3.4)
        ax = fig.add_subplot()
        mu = data["mode_probabilities_mean"]
        for m, label in enumerate(("normal model", "actuator-1 fault model", "actuator-2 fault model")):
            ax.plot(data["t"], mu[:, m], marker="o", ms=2.5, label=label)
        ax.axhline(0.5, color="r", lw=0.8, ls="--", label="μ_T = 0.5")
        self._finish(ax, data["onset_s"], "mean mode probability", f"Fig. 2: fused IMM, mean over {data['n_runs']} runs")
        fig.savefig(path, dpi=110)
        return path

    def _amplitude_figure(self, data: dict, path: Path) -> Path:
        fig = figure(6.0, 3.4)
        ax = fig.add_subplot()
        t = data["t"]
        ax.plot(t, data["true_amplitude"][:, 1], color="r", lw=1.0, label="true f (actuator 2)")
        for name, curve in data["curves"].items():
            color, ls = FIGURE_STYLES[name]
            ax.plot(t, curve["amplitude_mean"], color=color, ls=ls, label=name)
        self._finish(ax, data["onset_s"], "mean f̂ of the actuator-2 model",
                     "Fig. 3: amplitude estimate, fused vs single sensors")
        fig.savefig(path, dpi=110)
        return path

    def _rmse_figure(self, data: dict, key: str, title: str, path: Path) -> Path:
        fig = figure(6.0, 3.4)
        ax = fig.add_subplot()
        for name, curve in data["curves"].items():
            color, ls = FIGURE_STYLES[name]
            ax.plot(data["t"], curve[key], color=color, ls=ls, label=name)
        self._finish(ax, data["onset_s"], "RMSE over runs", f"{title}, {data['n_runs']} runs")
        fig.savefig(path, dpi=110)
        return path

    @staticmethod
    def _calibration_figure(data: dict, path: Path) -> Path:
        cal = data["calibration"]
        fig = figure(4.2, 4.0)
        ax = fig.add_subplot()
        ax.plot([0, 1], [0, 1], color="grey", lw=0.8, ls=":", label="calibrated")
        kept = cal["steps"] >= CALIBRATION_MIN_SHARE * cal["steps"].sum()
        ax.plot(cal["mean_probability"][kept], cal["active_share"][kept], marker="o", color="k",
                label=f"ECE {cal['ece']:.3f}, largest gap {cal['max_gap']:.3f}")
        ax.set_xlabel("mean μ₂ in the bin")
        ax.set_ylabel("share of steps with the actuator-2 fault active")
        ax.set_title(f"Mode-probability calibration, onsets as Λ says ({cal['faulty_runs']} faulty runs)",
                     fontsize=8)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
        fig.savefig(path, dpi=110)
        return path


#: line colour and style of each filter in the study's figures
FIGURE_STYLES = {"fused": ("k", "-"), "sensor1": ("tab:blue", "--"), "sensor2": ("tab:orange", "-."),
                 "sensor3": ("tab:green", ":")}


def format_report(metrics: dict[str, float], designs: dict[str, dict]) -> str:
    """The study's numbers as markdown tables (filters, then detector designs against the paper)."""
    lines = ["| filter | state RMSE after the onset | fault-input RMSE after the onset |", "|---|---|---|"]
    for name in ("fused", "sensor1", "sensor2", "sensor3"):
        lines.append(f"| {name} | {metrics[f'rmse_state_{name}']:.4f} | {metrics[f'rmse_amplitude_{name}']:.4f} |")
    lines += ["", "| design | μ_T | L | isolation | false isolation (act. 1) | detected | delay (s) | FAR | MDR "
              "| fault-free runs declaring no fault |", "|---|---|---|---|---|---|---|---|---|---|"]
    for design, p in designs.items():
        prefix = prefixed(design)
        lines.append(f"| {design} | {p['mu_T']:.4g} | {int(p['persistence'])} | {metrics[prefix + 'isolation_rate']:.3f} "
                     f"| {metrics[prefix + 'false_isolation_rate']:.3f} | {metrics[prefix + 'detection_rate']:.3f} "
                     f"| {metrics.get(prefix + 'delay_s', math.nan):.3f} | {metrics[prefix + 'far']:.4f} "
                     f"| {metrics[prefix + 'mdr']:.4f} | {metrics[prefix + 'no_fault_declared_rate']:.3f} |")
    return "\n".join(lines)


def format_orders(metrics: dict[str, float]) -> str:
    """The claimed RMSE orders with the paired difference's CI: resolved only when the CI excludes 0."""
    lines = ["| claim | quantity | mean paired MSE difference | 95 % CI | verdict |", "|---|---|---|---|---|"]
    for quantity in ("state", "amplitude"):
        for a, b in RMSE_PAIRS:
            mean, half = metrics[f"mse_{quantity}_{a}_minus_{b}"], metrics[f"mse_{quantity}_{a}_minus_{b}_ci95"]
            verdict = ("not resolved" if abs(mean) <= half else
                       "holds" if mean < 0 else "**reversed**")
            lines.append(f"| {a} < {b} | {quantity} | {mean:+.5f} | ± {half:.5f} | {verdict} |")
    return "\n".join(lines)


def format_priors(metrics: dict[str, float], intervals=PRIOR_INTERVALS) -> str:
    """Λ's prior against what the study measures (the tuned design; the paper's quiet fault-free runs)."""
    lines = ["| prior 1/h (intervals) | h | isolation | delay (s) | FAR | fault-free runs quiet (tuned) "
             "| fault-free runs quiet (μ_T = 0.5) | fused state / amplitude RMSE | calibration ECE |",
             "|---|---|---|---|---|---|---|---|---|"]
    for n in intervals:
        p = f"prior_{prior_tag(n)}_"
        if p + "rmse_state_fused" not in metrics:
            continue
        lines.append(f"| {n:g} | {1 / n:.4f} | {metrics.get(p + 'isolation_rate', math.nan):.3f} "
                     f"| {metrics.get(p + 'delay_s', math.nan):.3f} | {metrics.get(p + 'far', math.nan):.4f} "
                     f"| {metrics.get(p + 'no_fault_declared_rate', math.nan):.3f} "
                     f"| {metrics.get(p + 'paper_no_fault_declared_rate', math.nan):.3f} "
                     f"| {metrics[p + 'rmse_state_fused']:.4f} / {metrics[p + 'rmse_amplitude_fused']:.4f} "
                     f"| {metrics[p + 'mode_calibration_ece']:.3f} |")
    return "\n".join(lines)


def format_calibration(cal: dict) -> str:
    """The reliability curve of μ₂ (:func:`mode_calibration`) as a markdown table."""
    lines = [f"Mode-probability calibration: faults start as Λ says (hazard {cal['hazard']:.4g} per fusion interval, "
             f"{cal['faulty_runs']} faulty runs); expected calibration error (step-weighted mean gap) "
             f"{cal['ece']:.3f}, {cal['ece_middle']:.3f} between 0.1 and 0.9; largest gap {cal['max_gap']:.3f} "
             f"over bins with >= {100 * CALIBRATION_MIN_SHARE:g} % of the steps", "",
             "| μ₂ bin | steps | mean μ₂ | share with the fault active |",
             "|---|---|---|---|"]
    n = len(cal["steps"])
    for i in range(n):
        if cal["steps"][i]:
            lines.append(f"| {i / n:.1f}–{(i + 1) / n:.1f} | {int(cal['steps'][i])} | {cal['mean_probability'][i]:.3f} "
                         f"| {cal['active_share'][i]:.3f} |")
    return "\n".join(lines)


def _order(metrics: dict[str, float], quantity: str) -> bool | None:
    """Sensor 1 < 2 < 3 on ``quantity``: True or False where every paired difference's CI excludes 0, else None."""
    signs = []
    for a, b in (("sensor1", "sensor2"), ("sensor2", "sensor3")):
        mean, half = metrics[f"mse_{quantity}_{a}_minus_{b}"], metrics[f"mse_{quantity}_{a}_minus_{b}_ci95"]
        if not abs(mean) > half:
            return None  # the runs do not resolve this pair: the claim is neither met nor failed
        signs.append(mean < 0)
    return all(signs)


def bars(metrics: dict[str, float], prefix: str = "") -> list[tuple[str, bool | None, str]]:
    """The issue's scientific bars: (bar, met, the numbers); met is None where the runs do not resolve it.

    The orders of the sensors are read off the paired per-run differences (``mse_*_minus_*``)
    and their 95 % CI: a difference whose CI contains 0 leaves the order not resolved.
    """
    fused_s, fused_a = metrics["rmse_state_fused"], metrics["rmse_amplitude_fused"]
    singles_s = [metrics[f"rmse_state_sensor{i}"] for i in (1, 2, 3)]
    singles_a = [metrics[f"rmse_amplitude_sensor{i}"] for i in (1, 2, 3)]
    return [
        ("fused RMSE of the state below every single sensor's", fused_s < min(singles_s),
         f"{fused_s:.4f} vs {', '.join(f'{v:.4f}' for v in singles_s)}"),
        ("fused RMSE of the amplitude below every single sensor's", fused_a < min(singles_a),
         f"{fused_a:.4f} vs {', '.join(f'{v:.4f}' for v in singles_a)}"),
        ("state RMSE: sensor 1 < 2 < 3", _order(metrics, "state"), " < ".join(f"{v:.4f}" for v in singles_s)),
        ("amplitude RMSE: sensor 1 < 2 < 3", _order(metrics, "amplitude"),
         " < ".join(f"{v:.4f}" for v in singles_a)),
        ("actuator-2 fault isolated in >= 95 % of runs", metrics[prefix + "isolation_rate"] >= 0.95,
         f"{metrics[prefix + 'isolation_rate']:.3f}"),
        ("false isolation of actuator 1 <= 5 %", metrics[prefix + "false_isolation_rate"] <= 0.05,
         f"{metrics[prefix + 'false_isolation_rate']:.3f}"),
        ("fault-free runs declare no fault in >= 95 %", metrics[prefix + "no_fault_declared_rate"] >= 0.95,
         f"{metrics[prefix + 'no_fault_declared_rate']:.3f}"),
    ]


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m mosd.systems.paper001 [--n-runs 500] [--seed 0] [--mu-T M] [--persistence L] [--out DIR]``."""
    parser = cli.report_parser("python -m mosd.systems.paper001", "Paper 001's Monte Carlo study (Figs. 2-5, "
                               "decision rule) without the optimiser: the tuned design beside the paper's.",
                               out="outputs/systems/paper001")
    parser.add_argument("--n-runs", type=int, default=500, help="faulty and fault-free runs each (default 500)")
    cli.design_options(parser, SYSTEM)  # --mu-T, --persistence

    def body(args):
        study = Study(n_runs=args.n_runs)
        experiment = cli.preset(SYSTEM, [f"seed={args.seed}", f"budget.n_test={args.n_runs}"]).experiment
        designs = {TUNED: experiment.detector.with_params(**cli.tuned_design(args, SYSTEM)),
                   **study.reference_designs(experiment, experiment.detector)}
        data, metrics, files = cli.score(study, experiment, designs, Path(args.out), n_runs=args.n_runs,
                                         seed=args.seed)
        params = data["params"]
        print(f"## Paper 001: {args.n_runs} faulty + {args.n_runs} fault-free runs, seed {args.seed} (test stream)\n")
        print(format_report(metrics, params) + "\n")
        print(format_calibration(data["calibration"]) + "\n")
        print("### The RMSE orders, paired over the runs\n\n" + format_orders(metrics) + "\n")
        print("### Λ is a prior: the study under other hazards\n\n" + format_priors(metrics, study.prior_intervals)
              + "\n")
        for design in params:
            rows = [(name, "not resolved" if met is None else "met" if met else "**not met**", numbers)
                    for name, met, numbers in bars(metrics, prefixed(design))]
            print(f"### Scientific bars, {design} design\n\n" + cli.markdown_table(("bar", "met", "numbers"), rows)
                  + "\n")
        return files

    return cli.run_report(parser, argv, body)


if __name__ == "__main__":
    raise SystemExit(main())
