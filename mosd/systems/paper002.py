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

import copy
import math
from pathlib import Path

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
from ..validation import ConfigError, Interval, check_in, check_int

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


# ------------------------------------------------------------------------------------
# the study of the +experiment=paper002 preset, and its report command
# ------------------------------------------------------------------------------------
#: the design MOPSO chose in ``python -m mosd +experiment=paper002`` (seed 0; far/mdr on 100 training runs):
#: the report command scores it without re-running the optimiser
TUNED_DESIGN = {"threshold": 0.6696173191876901, "L": 1}
#: the reconstruction's fixed design of docs/systems/paper002.md (the paper's threshold is lost): L = 3 and the
#: threshold midway between the mean steady error levels of target and nuisance calibration runs
RECONSTRUCTION_L = 3
FILTER_PREFIXES = {"entropy": "", "baseline": "baseline_"}
THRESHOLD_GRID = np.round(np.arange(0.05, 3.0001, 0.01), 2)  # the threshold sweep of the ROC curves


def _figure(width: float, height: float):
    """A matplotlib figure without pyplot (no global state, no display)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def rate_tag(rate: float) -> str:
    """``r5`` for 5 %: the suffix of the study's per-rate metrics."""
    return f"r{int(round(100 * rate))}"


class Study:
    """Paper 002's comparison over missing-data rates (Tables 1–2, Figs. 3–10) for a tuned design.

    For each missing rate, ``n_runs`` target-fault and ``n_runs`` nuisance-fault
    runs of the experiment's scenario (its ``FaultSet``; the plant's
    ``missing_rate`` replaced) are drawn from the ``test`` seed stream, the
    same seeds at every rate (nested missing sets). The experiment's trained
    entropy-optimal filter and the fixed-gain baseline estimate them; the tuned
    detector (``result.detector``: threshold and L) decides on both.

    Parameters
    ----------
    n_runs : int
        Runs per fault role and rate (>= 2; the paper's figures: one run each).
    missing_rates : sequence of float
        MCAR rates of the outputs in [0, 0.9] (the paper: 0, 5, 10, 20 %).
    baseline_gain : float
        U of the fixed-gain baseline, in [-2, 2] (docs/systems/paper002.md: 0.27).
    figures : bool
        Write the PNG figures into ``out_dir``.

    Notes
    -----
    Metrics per rate r (suffix ``r0``, ``r5``, ``r10``, ``r20``), for the
    entropy filter and with the prefix ``baseline_`` for the fixed gain:

    * ``delay_target_s_r{r}``: mean over detected target runs of the time from
      the onset to the first alarm at or after it (s);
    * ``detection_rate_target_r{r}``: share of target runs detected at or after
      the onset;
    * ``false_alarm_nuisance_r{r}``: share of the nuisance runs' points after the
      onset that alarm (an alarm on the nuisance fault is a false isolation);
    * ``error_level_target_r{r}``, ``error_level_nuisance_r{r}``: mean steady
      error x − x̂ (10 steps after the onset to the end), whose meeting is the
      paper's failure at 20 %.

    Separation (complete data, the tuned L, thresholds swept over
    :data:`THRESHOLD_GRID`): ``roc_auc`` and ``baseline_roc_auc`` (area under
    target point-detection against nuisance point false alarms), and
    ``equal_fa_target_detection`` / ``baseline_equal_fa_target_detection``: the
    share of target points detected at the nuisance false-alarm rate of the
    tuned design on the entropy filter (interpolated on the sweep).
    """

    def __init__(self, n_runs: int = 200, missing_rates=MISSING_RATES, baseline_gain: float = 0.27,
                 figures: bool = True):
        self.n_runs = check_int("study.n_runs", n_runs, 2)
        if isinstance(missing_rates, (str, bytes)) or not hasattr(missing_rates, "__len__") or not len(missing_rates):
            raise ConfigError(f"study.missing_rates={missing_rates!r} is not allowed; allowed: a list of rates in "
                              f"[0, 0.9], e.g. [0.0, 0.05, 0.1, 0.2]")
        self.missing_rates = tuple(check_in("study.missing_rates", r, Interval(0.0, 0.9)) for r in missing_rates)
        if len(set(map(rate_tag, self.missing_rates))) != len(self.missing_rates):
            raise ConfigError(f"study.missing_rates={list(missing_rates)!r} repeats a rate (in whole per cent); "
                              f"allowed: distinct rates")
        self.baseline_gain = check_in("study.baseline_gain", baseline_gain, Interval(-2.0, 2.0))
        if not isinstance(figures, bool):
            raise ConfigError(f"study.figures={figures!r} is not allowed; allowed: true, false")
        self.figures = figures

    def run(self, experiment, result, out_dir) -> tuple[dict[str, float], list[Path]]:
        """The study for ``result.detector`` (the tuned threshold and L)."""
        data = self.compute(experiment, result.detector)
        files = self.write_figures(data, Path(out_dir)) if self.figures else []
        return self.metrics(data), files

    # -- computation --------------------------------------------------------------------
    def baseline(self, estimator) -> FixedGainFilter:
        """The fixed-gain filter with the entropy filter's handling of missing outputs."""
        return FixedGainFilter(gain=self.baseline_gain, missing=getattr(estimator, "missing", "em"),
                               em_half_width=getattr(estimator, "em_half_width", 1))

    def compute(self, experiment, detector) -> dict:
        """Per rate and filter: decisions, per-run numbers, mean error curves; the ROC on complete data."""
        filters = {"entropy": experiment.estimator, "baseline": self.baseline(experiment.estimator)}
        dt = float(experiment.plant.dt)
        out = {"rates": self.missing_rates, "dt": dt, "n_runs": self.n_runs, "params":
               {k: float(getattr(detector, k)) for k in detector.tunable}, "results": {}, "curves": {}, "roc": {},
               "gain": np.asarray(getattr(experiment.estimator, "gain_", np.full(1, np.nan))),
               "baseline_gain": self.baseline_gain}
        for rate in self.missing_rates:
            plant = copy.copy(experiment.plant)
            plant.missing_rate = check_in("study.missing_rates", rate, Interval(0.0, 0.9))
            trace = Scenario(plant, experiment.noise, experiment.fault, experiment.duration).simulate(
                experiment.seed, 2 * self.n_runs, "test")
            for name, est in filters.items():
                outputs = est.estimate(trace, experiment.model)
                points = experiment.monitor.transform(outputs)
                out["results"][(name, rate)] = self._score(detector, outputs, points, dt)
                out["curves"][(name, rate)] = self._curves(outputs)
                if rate == self.missing_rates[0]:
                    out["roc"][name] = self._roc(detector, points)
                    out["onset_s"] = float(outputs.t[int(np.argmax(outputs.fault_label.max(axis=0) > 0))])
                    out["t"] = np.asarray(outputs.t, float)
        return out

    @staticmethod
    def _roles(labels: np.ndarray, roles) -> np.ndarray:
        role_of_label = np.array(["none", *roles])
        return role_of_label[labels.max(axis=1)] == "target"

    def _score(self, detector, outputs, points, dt: float) -> dict:
        d = detector.decide(points.z[:1], points.z).decision
        is_target = self._roles(points.fault_label, points.fault_roles)
        active = points.fault_label > 0
        error = outputs.extra["error"]
        onset = int(np.argmax(outputs.fault_label.max(axis=0) > 0))
        level = error[:, onset + SETTLE:].mean(axis=1)
        delay = detection.detection_delay(d[is_target], points.fault_mask[is_target]) * dt
        nuisance = (d[~is_target] != 0) & active[~is_target]
        return {
            "delay_target_s": float(np.nanmean(delay)) if np.isfinite(delay).any() else math.nan,
            "delay_target_ci95": mean_ci(delay)["ci95"],
            "detection_rate_target": float(np.mean(detection.detection_rate(d[is_target], points.fault_mask[is_target]))),
            "false_alarm_nuisance": float(nuisance.sum() / max(active[~is_target].sum(), 1)),
            "error_level_target": float(level[is_target].mean()),
            "error_level_nuisance": float(level[~is_target].mean()),
            "nuisance_level_p95": float(np.percentile(level[~is_target], 95)),
        }

    def _curves(self, outputs) -> dict:
        """Error curves of target and nuisance runs: mean, 5 and 95 % quantiles, and the first run of each."""
        error = np.asarray(outputs.extra["error"], float)
        is_target = self._roles(outputs.fault_label, outputs.fault_roles)
        curves = {}
        for role, rows in (("target", is_target), ("nuisance", ~is_target)):
            e = error[rows]
            curves[role] = {"mean": e.mean(0), "low": np.percentile(e, 5, axis=0),
                            "high": np.percentile(e, 95, axis=0), "example": e[0]}
        return curves

    def _roc(self, detector, points) -> dict:
        """Target point detection against nuisance point false alarms over the threshold sweep (tuned L)."""
        X = np.column_stack([THRESHOLD_GRID, np.full(THRESHOLD_GRID.size, float(getattr(detector, "L", 1)))])
        d = detector.population(None, detector.features(points.z), X).decision != 0   # (P, R, K)
        is_target = self._roles(points.fault_label, points.fault_roles)
        active = points.fault_label > 0
        hit = (d[:, is_target] & active[is_target]).sum((1, 2)) / active[is_target].sum()
        fa = (d[:, ~is_target] & active[~is_target]).sum((1, 2)) / active[~is_target].sum()
        return {"threshold": THRESHOLD_GRID, "detection": hit, "false_alarm": fa}

    @staticmethod
    def _at_false_alarm(roc: dict, level: float) -> float:
        fa, hit = roc["false_alarm"][::-1], roc["detection"][::-1]  # increasing false alarms
        return float(np.interp(level, fa, hit))

    @staticmethod
    def _auc(roc: dict) -> float:
        fa = np.concatenate([[0.0], roc["false_alarm"][::-1], [1.0]])
        hit = np.concatenate([[0.0], roc["detection"][::-1], [1.0]])
        return float(np.sum(np.diff(fa) * (hit[1:] + hit[:-1]) / 2))

    def metrics(self, data: dict) -> dict[str, float]:
        """The study's metrics by name (class docstring)."""
        out = {}
        for name, prefix in FILTER_PREFIXES.items():
            for rate in data["rates"]:
                tag = rate_tag(rate)
                for key, value in data["results"][(name, rate)].items():
                    if key in ("delay_target_ci95", "nuisance_level_p95"):
                        continue
                    out[f"{prefix}{key}_{tag}"] = float(value)
        tuned_fa = data["results"][("entropy", data["rates"][0])]["false_alarm_nuisance"]
        for name, prefix in FILTER_PREFIXES.items():
            roc = data["roc"][name]
            out[f"{prefix}roc_auc"] = self._auc(roc)
            out[f"{prefix}equal_fa_target_detection"] = self._at_false_alarm(roc, tuned_fa)
        return out

    # -- figures --------------------------------------------------------------------------
    @staticmethod
    def write_figures(data: dict, out_dir: Path, prefix: str = "paper002_") -> list[Path]:
        """Figs. 3–10 (error responses per rate and role), the gain, the ROC and the delay over the rate."""
        out_dir.mkdir(parents=True, exist_ok=True)
        files = []
        t, onset, rates = data["t"], data["onset_s"], data["rates"]
        threshold = data["params"].get("threshold", math.nan)
        fig = _figure(9.0, 2.2 * len(rates))
        axes = fig.subplots(len(rates), 2, sharex=True, sharey=True, squeeze=False)
        for i, rate in enumerate(rates):
            for j, role in enumerate(("target", "nuisance")):
                ax = axes[i, j]
                for name, color in (("entropy", "tab:blue"), ("baseline", "tab:orange")):
                    c = data["curves"][(name, rate)][role]
                    label = "entropy gain" if name == "entropy" else f"fixed gain {data['baseline_gain']:g}"
                    ax.fill_between(t, c["low"], c["high"], color=color, alpha=0.15, lw=0)
                    ax.plot(t, c["mean"], color=color, lw=1.2, label=f"{label}: mean, 5-95 %")
                    if name == "entropy":
                        ax.plot(t, c["example"], color=color, lw=0.6, alpha=0.7, label="entropy gain: one run")
                ax.axhline(threshold, color="r", ls="--", lw=0.8, label=f"tuned threshold {threshold:.3g}")
                ax.axhline(-threshold, color="r", ls="--", lw=0.8)
                ax.axvline(onset, color="grey", ls=":", lw=0.8)
                ax.set_title(f"Fig. {3 + 2 * i + j}: {role} fault only, {100 * rate:g} % missing", fontsize=9)
                ax.grid(alpha=0.3)
                if j == 0:
                    ax.set_ylabel("error x − x̂")
                if i == len(rates) - 1:
                    ax.set_xlabel("t (s)")
        axes[0, 0].legend(fontsize=7, loc="upper left")
        files.append(out_dir / f"{prefix}errors.png")
        fig.savefig(files[-1], dpi=100)

        fig = _figure(6.0, 3.2)
        ax = fig.add_subplot()
        gain = data["gain"]
        ax.step(t[: gain.size], gain, where="post", label="entropy-optimal U_k (R1 = 1, R2 = 20)")
        ax.axhline(data["baseline_gain"], color="tab:orange", ls="--", label=f"fixed gain {data['baseline_gain']:g}")
        ax.axvline(onset, color="grey", ls=":", lw=0.8)
        ax.set_xlabel("t (s)")
        ax.set_ylabel("gain U")
        ax.set_title("Gain schedule: entropy-optimal vs fixed", fontsize=10)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
        files.append(out_dir / f"{prefix}gain.png")
        fig.savefig(files[-1], dpi=110)

        fig = _figure(9.0, 3.4)
        ax, bx = fig.subplots(1, 2)
        for name, color in (("entropy", "tab:blue"), ("baseline", "tab:orange")):
            roc = data["roc"][name]
            label = "entropy gain" if name == "entropy" else f"fixed gain {data['baseline_gain']:g}"
            ax.plot(roc["false_alarm"], roc["detection"], color=color, label=label)
            delays = [data["results"][(name, r)]["delay_target_s"] for r in rates]
            cis = [data["results"][(name, r)]["delay_target_ci95"] for r in rates]
            bx.errorbar([100 * r for r in rates], delays, yerr=cis, color=color, marker="o", capsize=3, label=label)
        tuned = data["results"][("entropy", rates[0])]
        ax.axvline(tuned["false_alarm_nuisance"], color="r", ls="--", lw=0.8, label="tuned design's nuisance FA")
        ax.set_xscale("symlog", linthresh=1e-3)
        ax.set_xlim(0.0, 1.0)
        ax.set_xlabel("nuisance points alarmed")
        ax.set_ylabel("target points detected")
        ax.set_title(f"Separation, complete data, L = {int(data['params'].get('L', 1))}", fontsize=10)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
        paper = [(100 * r, PAPER["target_delay"][r]) for r in rates if r in PAPER["target_delay"]]
        bx.plot([p[0] for p in paper], [p[1] for p in paper], "k^", label="paper (target; fails at 20 %)")
        bx.set_xlabel("missing outputs (%)")
        bx.set_ylabel("target isolation delay (s)")
        bx.set_title("Delay over the missing rate (tuned design)", fontsize=10)
        bx.grid(alpha=0.3)
        bx.legend(fontsize=8)
        files.append(out_dir / f"{prefix}separation_delay.png")
        fig.savefig(files[-1], dpi=110)
        return files


def preset_experiment(seed: int = 0):
    """The ``+experiment=paper002`` set-up built without Hydra (the report command's experiment)."""
    from ..experiment import Budget, Experiment

    faults = FaultSet([RandomAmplitudeFault("sine", onset=ONSET, role="target"),
                       RandomAmplitudeFault("ramp", onset=ONSET, role="nuisance")])
    return Experiment(ScalarNonlinearPlant(), BoundedNoise(), faults, EntropyIsolationFilter(),
                      OutputMonitor(outputs=["error"], burn_in=10), ThresholdDetector(threshold=0.8, L=3, threshold_max=3.0),
                      duration=DURATION, budget=Budget(n_calibration=40, n_train=100, n_test=200, n_estimator=1),
                      seed=seed)


def midway_threshold(experiment, n_runs: int) -> float:
    """The reconstruction's fixed threshold: midway between the steady error levels of calibration-stream runs.

    Drawn from the ``calibration`` stream with both faults (never the test runs).
    """
    sc = Scenario(experiment.plant, experiment.noise, experiment.fault, experiment.duration)
    outputs = experiment.estimator.estimate(sc.simulate(experiment.seed, 2 * n_runs, "calibration"), experiment.model)
    error = outputs.extra["error"]
    onset = int(np.argmax(outputs.fault_label.max(axis=0) > 0))
    level = error[:, onset + SETTLE:].mean(axis=1)
    is_target = Study._roles(outputs.fault_label, outputs.fault_roles)
    return float(0.5 * (level[is_target].mean() + level[~is_target].mean()))


def format_report(designs: dict[str, dict], by_design: dict[str, dict]) -> str:
    """Markdown: per design, filter and rate, the study's numbers beside the paper's delays."""
    lines = ["| design | filter | missing | target detected | target delay (s) | paper delay (s) "
             "| nuisance points alarmed | error level target / nuisance |", "|---|---|---|---|---|---|---|---|"]
    for design, metrics in by_design.items():
        p = designs[design]
        for name, prefix in FILTER_PREFIXES.items():
            for tag, rate in ((rate_tag(r), r) for r in MISSING_RATES):
                if f"{prefix}delay_target_s_{tag}" not in metrics:
                    continue
                paper = PAPER["target_delay"].get(rate, "–")
                paper = "fails" if isinstance(paper, float) and math.isnan(paper) else paper
                lines.append(
                    f"| {design} (threshold {p['threshold']:.3g}, L {int(p['L'])}) | {name} | {100 * rate:g} % "
                    f"| {metrics[f'{prefix}detection_rate_target_{tag}']:.3f} "
                    f"| {metrics[f'{prefix}delay_target_s_{tag}']:.3f} | {paper} "
                    f"| {metrics[f'{prefix}false_alarm_nuisance_{tag}']:.4f} "
                    f"| {metrics[f'{prefix}error_level_target_{tag}']:.3f} / "
                    f"{metrics[f'{prefix}error_level_nuisance_{tag}']:.3f} |")
    lines += ["", "| design | filter | ROC AUC (complete data) | target points detected at the tuned entropy design's "
              "nuisance false-alarm rate |", "|---|---|---|---|"]
    for design, metrics in by_design.items():
        for name, prefix in FILTER_PREFIXES.items():
            lines.append(f"| {design} | {name} | {metrics[prefix + 'roc_auc']:.4f} "
                         f"| {metrics[prefix + 'equal_fa_target_detection']:.4f} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    """``python -m mosd.systems.paper002 [--n-runs 200] [--seed 0] [--threshold T] [--L L] [--out DIR]``."""
    import argparse
    import json
    import sys
    import time

    parser = argparse.ArgumentParser(prog="python -m mosd.systems.paper002",
                                     description="Paper 002's study over missing rates (Tables 1-2, Figs. 3-10) "
                                                 "without the optimiser: the tuned design beside the "
                                                 "reconstruction's fixed one (midway threshold, L = 3).")
    parser.add_argument("--n-runs", type=int, default=200, help="target and nuisance runs each, per rate (default 200)")
    parser.add_argument("--seed", type=int, default=0, help="root seed; the test stream is used (default 0)")
    parser.add_argument("--threshold", type=float, default=TUNED_DESIGN["threshold"],
                        help="tuned threshold (default: seed 0's MOPSO)")
    parser.add_argument("--L", type=int, default=TUNED_DESIGN["L"], help="tuned persistence L")
    parser.add_argument("--out", default="outputs/systems/paper002", help="directory of the figures and JSON")
    args = parser.parse_args(argv)
    t0 = time.perf_counter()
    try:
        study = Study(n_runs=args.n_runs)
        experiment = preset_experiment(seed=args.seed)
        tuned = experiment.detector.with_params(threshold=args.threshold, L=args.L)
    except ConfigError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    experiment.fit_estimator()
    fixed = experiment.detector.with_params(threshold=midway_threshold(experiment, args.n_runs), L=RECONSTRUCTION_L)
    out = Path(args.out)
    by_design, designs, files = {}, {}, []
    for design, detector in (("tuned", tuned), ("midway", fixed)):
        data = study.compute(experiment, detector)
        by_design[design], designs[design] = study.metrics(data), data["params"]
        if design == "tuned":
            files = study.write_figures(data, out)
    (out / "paper002_study.json").write_text(json.dumps({"metrics": by_design, "designs": designs,
                                                         "n_runs": args.n_runs, "seed": args.seed}, indent=1))
    print(f"## Paper 002: {args.n_runs} target + {args.n_runs} nuisance runs per missing rate, seed {args.seed} "
          f"(test stream)\n")
    print(format_report(designs, by_design) + "\n")
    print(f"wrote: {', '.join(str(p) for p in [*files, out / 'paper002_study.json'])}  ({time.perf_counter() - t0:.1f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
