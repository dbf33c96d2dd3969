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

import copy
import math
from pathlib import Path
from typing import Sequence

import numpy as np

from ..detectors.mode_probability import ModeProbabilityDetector
from ..estimators.async_imm import AsyncIMMFusion
from ..faults.actuator import ActuatorFault
from ..metrics.estimation import rmse_over_runs
from ..metrics.registry import per_run
from ..monitors.outputs import OutputMonitor
from ..noise.continuous import ContinuousWhiteNoise
from ..plants.networked_target import NetworkedTarget
from ..scenario import Scenario
from ..validation import ConfigError, check_int
from . import run_designs

DURATION = 41.0  # fusion instants t = 0, 1, ..., 40 s
FILTERS = {"fused": None, "s1": ("s1",), "s2": ("s2",), "s3": ("s3",)}
#: the scenario's only fault (label 1) is the model set's fault 2 (actuator 2)
LABELS = (2, 1)
DESIGNS = ((0.5, 1), (0.5, 2), (0.5, 3), (0.7, 1), (0.7, 2), (0.9, 1))


def scenario(faulty: bool = True) -> Scenario:
    """The paper's example: actuator 2 fails with f = 2 at 16.5 s (or no fault)."""
    return Scenario(NetworkedTarget(), ContinuousWhiteNoise(), ActuatorFault() if faulty else None, duration=DURATION)


def rmse_study(seed: int = 2017, n_reps: int = 500) -> dict:
    """Figs. 2–5: per filter, RMSE curves of the state and of the fault input, and their means over t = 1..40.

    Also the fused filter's mean mode probabilities (Fig. 2) and the mean
    amplitude estimate of the actuator-2 model per filter (Fig. 3).
    """
    sc = scenario()
    trace = sc.simulate(seed, n_reps, "test")
    model = sc.plant.model(sc.noise)
    out = {"t": trace.t.tolist(), "filters": {}}
    for name, sensors in FILTERS.items():
        res = AsyncIMMFusion(sensors=sensors).estimate(trace, model)
        state = rmse_over_runs(res.extra["x_filt"], trace.x[..., :2])
        fault = rmse_over_runs(res.extra["fault_estimate"], trace.x[..., 2:])
        out["filters"][name] = {
            "state_rmse": state.tolist(), "fault_rmse": fault.tolist(),
            "state_rmse_mean": float(state[1:].mean()), "fault_rmse_mean": float(fault[1:].mean()),
            "amplitude_mean": res.extra["fault_amplitudes"][..., 1].mean(axis=0).tolist(),
            "mode_probabilities_mean": res.extra["mode_probabilities"].mean(axis=0).tolist(),
        }
    return out


def detection_table(seed: int = 2017, n_reps: int = 500,
                    designs: Sequence[tuple[float, int]] = DESIGNS) -> list[dict]:
    """The decision rule (§4) for designs (μ_T, L): false alarms on faulty and fault-free runs, delay, isolation."""
    sc = scenario()
    model = sc.plant.model(sc.noise)
    estimator, monitor = AsyncIMMFusion(), OutputMonitor(outputs=["mode_probabilities"])
    faulty = monitor.transform(estimator.estimate(sc.simulate(seed, n_reps, "test"), model))
    clean = monitor.transform(estimator.estimate(scenario(False).simulate(seed, n_reps, "calibration"), model))
    detector = ModeProbabilityDetector(labels=LABELS)
    X = np.asarray(designs, float)
    on_faulty = detector.population(None, faulty.z, X).decision
    on_clean = detector.population(None, clean.z, X).decision
    rows = []
    for (mu_T, L), d, d0 in zip(designs, on_faulty, on_clean):
        rows.append({
            "mu_T": float(mu_T), "L": int(L),
            "far": float(per_run("far", d, faulty).mean()),
            "far_fault_free": float(per_run("far", d0, clean).mean()),
            "alarmed_fault_free_runs": float(np.mean((d0 != 0).any(axis=-1))),
            "delay": float(np.nanmean(per_run("delay", d, faulty))),
            "detection_rate": float(np.nanmean(per_run("detection_rate", d, faulty))),
            "isolation_rate": float(np.nanmean(per_run("isolation_rate", d, faulty))),
        })
    return rows


# ------------------------------------------------------------------------------------
# the study of the +experiment=paper001 preset, and its report command
# ------------------------------------------------------------------------------------
#: the paper's own decision rule (§5: μ_T = 0.5; L = 1, it gives no persistence value)
PAPER_DESIGN = {"mu_T": 0.5, "L": 1}
#: the design MOPSO chose in ``python -m mosd +experiment=paper001`` (seed 0; far/mdr on 200 training runs):
#: the report command scores it without re-running the optimiser
TUNED_DESIGN = {"mu_T": 0.7822769303275614, "L": 1}
SENSOR_FILTERS = ("s1", "s2", "s3")


def _figure(width: float, height: float):
    """A matplotlib figure without pyplot (no global state, no display)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), layout="constrained")
    FigureCanvasAgg(fig)
    return fig


class Study:
    """Paper 001's Monte Carlo comparison (Figs. 2–5 and the decision rule) for a tuned design.

    Runs ``n_reps`` faulty and ``n_reps`` fault-free replications of the
    experiment's scenario on the ``test`` seed stream (the fault-free runs share
    the faulty runs' seeds: common random numbers), estimates with the
    experiment's fusion filter on all sensors and on each sensor alone, and
    decides with the tuned detector and with the paper's design (μ_T = 0.5,
    L = 1; metrics prefixed ``paper_``).

    Parameters
    ----------
    n_reps : int
        Monte Carlo runs of each kind (the paper: 500).
    figures : bool
        Write the PNG figures into ``out_dir``.

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
    * ``far``, ``mdr``: point rates of the metric registry on the faulty runs;
      ``delay_s``: mean over detected runs of (first alarm − first faulty
      fusion instant) in seconds; ``detected_rate``: faulty runs detected.
    * ``no_fault_declared_rate``: fault-free runs without any declaration.
    """

    def __init__(self, n_reps: int = 500, figures: bool = True):
        self.n_reps = check_int("study.n_reps", n_reps, 2)
        if not isinstance(figures, bool):
            raise ConfigError(f"study.figures={figures!r} is not allowed; allowed: true, false")
        self.figures = figures

    def run(self, experiment, result, out_dir) -> tuple[dict[str, float], list[Path]]:
        """The study for ``result.detector`` (the tuned design) beside the paper's design."""
        paper = result.detector.with_params(**PAPER_DESIGN)
        data = self.compute(experiment, {"tuned": result.detector, "paper": paper})
        files = self.write_figures(data, Path(out_dir)) if self.figures else []
        return self.metrics(data), files

    # -- computation --------------------------------------------------------------------
    def compute(self, experiment, designs: dict) -> dict:
        """Estimates, RMSE curves and decisions of each named detector design (plain dict)."""
        faulty = experiment.simulate(experiment.fault, self.n_reps, "test")
        clean = experiment.simulate(None, self.n_reps, "test")
        onset_index = int(np.argmax(faulty.fault_mask.any(axis=0)))
        filters = {"fused": experiment.estimator}
        for i, name in enumerate(SENSOR_FILTERS, start=1):
            single = copy.copy(experiment.estimator)
            single.sensors = (name,)  # the same filter on one sensor's packets (validated at estimate)
            filters[f"sensor{i}"] = single
        curves = {}
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
        points = experiment.monitor.transform(fused)
        clean_points = experiment.monitor.transform(experiment.estimator.estimate(clean, experiment.model))
        decisions = {}
        for name, detector in designs.items():
            d = detector.decide(clean_points.z, points.z).decision
            d0 = detector.decide(clean_points.z, clean_points.z).decision
            decisions[name] = self._score(detector, d, d0, points, clean_points, float(np.median(np.diff(fused.t))))
            decisions[name]["params"] = {k: float(getattr(detector, k)) for k in detector.tunable}
        return {"t": faulty.t, "onset_index": onset_index, "onset_s": float(experiment.fault.onset),
                "true_amplitude": faulty.x[0, :, 2:], "curves": curves,
                "mode_probabilities_mean": fused.extra["mode_probabilities"].mean(axis=0),
                "decisions": decisions, "n_reps": self.n_reps}

    @staticmethod
    def _score(detector, d, d0, points, clean_points, period: float) -> dict:
        after = np.broadcast_to(points.fault_mask.any(axis=0), d.shape)
        # the decision value that names actuator 1 (the model set's fault 1)
        actuator1 = detector.labels[0] if getattr(detector, "labels", None) else 1
        delay = per_run("delay", d, points)
        return {
            "isolation_rate": float(np.nanmean(per_run("isolation_rate", d, points))),
            "false_isolation_rate": float(np.mean(((d == actuator1) & after).any(axis=-1))),
            "far": float(np.nanmean(per_run("far", d, points))),
            "mdr": float(np.nanmean(per_run("mdr", d, points))),
            "delay_s": float(np.nanmean(delay) * period) if np.isfinite(delay).any() else math.nan,
            "detected_rate": float(np.nanmean(per_run("detection_rate", d, points))),
            "no_fault_declared_rate": float(np.mean(~(d0 != 0).any(axis=-1))),
            "far_fault_free": float(np.mean(d0 != 0)),
        }

    @staticmethod
    def metrics(data: dict) -> dict[str, float]:
        """The study's metrics by name (class docstring): the tuned design's, then ``paper_``-prefixed."""
        k0 = data["onset_index"]
        out = {}
        for name, curve in data["curves"].items():
            out[f"rmse_state_{name}"] = float(curve["state"][k0:].mean())
        for name, curve in data["curves"].items():
            out[f"rmse_amplitude_{name}"] = float(curve["amplitude"][k0:].mean())
        for design, prefix in (("tuned", ""), ("paper", "paper_")):
            if design in data["decisions"]:
                out.update({prefix + k: float(v) for k, v in data["decisions"][design].items() if k != "params"})
        return out

    # -- figures --------------------------------------------------------------------------
    @staticmethod
    def write_figures(data: dict, out_dir: Path, prefix: str = "paper001_") -> list[Path]:
        """Figs. 2–5 as PNG files: mode probabilities, amplitude, state RMSE, amplitude RMSE."""
        out_dir.mkdir(parents=True, exist_ok=True)
        t, onset = data["t"], data["onset_s"]
        styles = {"fused": ("k", "-"), "sensor1": ("tab:blue", "--"), "sensor2": ("tab:orange", "-."),
                  "sensor3": ("tab:green", ":")}
        files = []

        def finish(ax, ylabel, title):
            ax.axvline(onset, color="grey", lw=0.8, ls=":")
            ax.set_xlabel("t (s)")
            ax.set_ylabel(ylabel)
            ax.set_title(title, fontsize=10)
            ax.grid(alpha=0.3)
            ax.legend(fontsize=8)

        fig = _figure(6.0, 3.4)
        ax = fig.add_subplot()
        mu = data["mode_probabilities_mean"]
        for m, label in enumerate(("normal model", "actuator-1 fault model", "actuator-2 fault model")):
            ax.plot(t, mu[:, m], marker="o", ms=2.5, label=label)
        ax.axhline(0.5, color="r", lw=0.8, ls="--", label="μ_T = 0.5")
        finish(ax, "mean mode probability", f"Fig. 2: fused IMM, mean over {data['n_reps']} runs")
        files.append(out_dir / f"{prefix}mode_probabilities.png")
        fig.savefig(files[-1], dpi=110)

        fig = _figure(6.0, 3.4)
        ax = fig.add_subplot()
        ax.plot(t, data["true_amplitude"][:, 1], color="r", lw=1.0, label="true f (actuator 2)")
        for name, curve in data["curves"].items():
            color, ls = styles[name]
            ax.plot(t, curve["amplitude_mean"], color=color, ls=ls, label=name)
        finish(ax, "mean f̂ of the actuator-2 model", "Fig. 3: amplitude estimate, fused vs single sensors")
        files.append(out_dir / f"{prefix}amplitude.png")
        fig.savefig(files[-1], dpi=110)

        for key, title, fname in (("state", "Fig. 4: RMSE of the state", "rmse_state"),
                                  ("amplitude", "Fig. 5: RMSE of the fault input", "rmse_amplitude")):
            fig = _figure(6.0, 3.4)
            ax = fig.add_subplot()
            for name, curve in data["curves"].items():
                color, ls = styles[name]
                ax.plot(t, curve[key], color=color, ls=ls, label=name)
            finish(ax, "RMSE over runs", f"{title}, {data['n_reps']} runs")
            files.append(out_dir / f"{prefix}{fname}.png")
            fig.savefig(files[-1], dpi=110)
        return files


def preset_experiment(seed: int = 0, n_test: int = 500):
    """The ``+experiment=paper001`` set-up built without Hydra (the report command's experiment)."""
    from ..experiment import Budget, Experiment

    return Experiment(NetworkedTarget(), ContinuousWhiteNoise(), ActuatorFault(), AsyncIMMFusion(),
                      OutputMonitor(outputs=["mode_probabilities"]), ModeProbabilityDetector(labels=LABELS),
                      duration=DURATION, budget=Budget(n_calibration=100, n_train=200, n_test=n_test), seed=seed)


def format_report(metrics: dict[str, float], designs: dict[str, dict]) -> str:
    """The study's numbers as markdown tables (filters, then detector designs against the paper)."""
    lines = ["| filter | state RMSE after the onset | fault-input RMSE after the onset |", "|---|---|---|"]
    for name in ("fused", "sensor1", "sensor2", "sensor3"):
        lines.append(f"| {name} | {metrics[f'rmse_state_{name}']:.4f} | {metrics[f'rmse_amplitude_{name}']:.4f} |")
    lines += ["", "| design | μ_T | L | isolation | false isolation (act. 1) | detected | delay (s) | FAR | MDR "
              "| fault-free runs declaring no fault |", "|---|---|---|---|---|---|---|---|---|---|"]
    for design, prefix in (("tuned", ""), ("paper", "paper_")):
        p = designs[design]
        lines.append(f"| {design} | {p['mu_T']:.4g} | {int(p['L'])} | {metrics[prefix + 'isolation_rate']:.3f} "
                     f"| {metrics[prefix + 'false_isolation_rate']:.3f} | {metrics[prefix + 'detected_rate']:.3f} "
                     f"| {metrics[prefix + 'delay_s']:.3f} | {metrics[prefix + 'far']:.4f} "
                     f"| {metrics[prefix + 'mdr']:.4f} | {metrics[prefix + 'no_fault_declared_rate']:.3f} |")
    return "\n".join(lines)


def bars(metrics: dict[str, float], prefix: str = "") -> list[tuple[str, bool, str]]:
    """The issue's scientific bars: (bar, met, the numbers)."""
    fused_s, fused_a = metrics["rmse_state_fused"], metrics["rmse_amplitude_fused"]
    singles_s = [metrics[f"rmse_state_sensor{i}"] for i in (1, 2, 3)]
    singles_a = [metrics[f"rmse_amplitude_sensor{i}"] for i in (1, 2, 3)]
    return [
        ("fused RMSE of the state below every single sensor's", fused_s < min(singles_s),
         f"{fused_s:.4f} vs {', '.join(f'{v:.4f}' for v in singles_s)}"),
        ("fused RMSE of the amplitude below every single sensor's", fused_a < min(singles_a),
         f"{fused_a:.4f} vs {', '.join(f'{v:.4f}' for v in singles_a)}"),
        ("state RMSE: sensor 1 < 2 < 3", singles_s[0] < singles_s[1] < singles_s[2],
         " < ".join(f"{v:.4f}" for v in singles_s)),
        ("amplitude RMSE: sensor 1 < 2 < 3", singles_a[0] < singles_a[1] < singles_a[2],
         " < ".join(f"{v:.4f}" for v in singles_a)),
        ("actuator-2 fault isolated in >= 95 % of runs", metrics[prefix + "isolation_rate"] >= 0.95,
         f"{metrics[prefix + 'isolation_rate']:.3f}"),
        ("false isolation of actuator 1 <= 5 %", metrics[prefix + "false_isolation_rate"] <= 0.05,
         f"{metrics[prefix + 'false_isolation_rate']:.3f}"),
        ("fault-free runs declare no fault in >= 95 %", metrics[prefix + "no_fault_declared_rate"] >= 0.95,
         f"{metrics[prefix + 'no_fault_declared_rate']:.3f}"),
    ]


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m mosd.systems.paper001 [--n-reps 500] [--seed 0] [--mu-T 0.7823] [--L 1] [--out DIR]``."""
    import argparse
    import json
    import sys
    import time

    parser = argparse.ArgumentParser(prog="python -m mosd.systems.paper001",
                                     description="Paper 001's Monte Carlo study (Figs. 2-5, decision rule) "
                                                 "without the optimiser: the tuned design beside the paper's.")
    parser.add_argument("--n-reps", type=int, default=500, help="faulty and fault-free runs each (default 500)")
    parser.add_argument("--seed", type=int, default=0, help="root seed; the test stream is used (default 0)")
    parser.add_argument("--mu-T", type=float, default=TUNED_DESIGN["mu_T"], help="tuned μ_T (default: seed 0's MOPSO)")
    parser.add_argument("--L", type=int, default=TUNED_DESIGN["L"], help="tuned persistence L")
    parser.add_argument("--out", default="outputs/systems/paper001", help="directory of the figures and JSON")
    args = parser.parse_args(argv)
    t0 = time.perf_counter()
    try:
        study = Study(n_reps=args.n_reps)
        experiment = preset_experiment(seed=args.seed, n_test=args.n_reps)
        tuned = experiment.detector.with_params(mu_T=args.mu_T, L=args.L)
        paper = experiment.detector.with_params(**PAPER_DESIGN)
    except ConfigError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    out = Path(args.out)
    data, metrics, files = run_designs(study, experiment, {"tuned": tuned, "paper": paper}, out)
    designs = {k: v["params"] for k, v in data["decisions"].items()}
    (out / "paper001_study.json").write_text(json.dumps({"metrics": metrics, "designs": designs,
                                                         "n_reps": args.n_reps, "seed": args.seed}, indent=1))
    print(f"## Paper 001: {args.n_reps} faulty + {args.n_reps} fault-free runs, seed {args.seed} (test stream)\n")
    print(format_report(metrics, designs) + "\n")
    for design, prefix in (("tuned", ""), ("paper", "paper_")):
        print(f"### Scientific bars, {design} design\n\n| bar | met | numbers |\n|---|---|---|")
        for name, met, numbers in bars(metrics, prefix):
            print(f"| {name} | {'met' if met else '**not met**'} | {numbers} |")
        print()
    print(f"wrote: {', '.join(str(p) for p in [*files, out / 'paper001_study.json'])}  ({time.perf_counter() - t0:.1f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
