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

from ..metrics.estimation import rmse_over_runs
from ..metrics.registry import per_run
from ..validation import check_int
from . import base, cli
from .base import TUNED, decorate, design_params, figure, prefixed

SYSTEM = "paper001"
SENSOR_FILTERS = ("s1", "s2", "s3")


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
    * ``no_fault_declared_rate``: fault-free runs without any declaration.
    """

    system = SYSTEM

    def __init__(self, n_runs: int = 500, figures: bool = True):
        super().__init__(figures=figures)
        self.n_runs = check_int("study.n_runs", n_runs, 2)

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
        return {"t": faulty.t, "onset_index": onset_index, "onset_s": float(experiment.fault.onset),
                "true_amplitude": faulty.x[0, :, 2:], "curves": curves,
                "mode_probabilities_mean": fused.extra["mode_probabilities"].mean(axis=0),
                "decisions": decisions, "params": {name: design_params(d) for name, d in designs.items()},
                "n_runs": self.n_runs}

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
            "detection_rate": float(np.nanmean(per_run("detection_rate", d, points))),
            "no_fault_declared_rate": float(np.mean(~(d0 != 0).any(axis=-1))),
            "far_fault_free": float(np.mean(d0 != 0)),
        }

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
        return out

    # -- figures --------------------------------------------------------------------------
    def write_figures(self, data: dict, out_dir: Path) -> list[Path]:
        """Figs. 2–5 as PNG files: mode probabilities, amplitude, state RMSE, amplitude RMSE."""
        out_dir.mkdir(parents=True, exist_ok=True)
        prefix = f"{self.system}_"
        t, onset = data["t"], data["onset_s"]
        styles = {"fused": ("k", "-"), "sensor1": ("tab:blue", "--"), "sensor2": ("tab:orange", "-."),
                  "sensor3": ("tab:green", ":")}
        files = []

        def finish(ax, ylabel, title):
            ax.axvline(onset, color="grey", lw=0.8, ls=":")
            decorate(ax, "t (s)", ylabel, title)

        fig = figure(6.0, 3.4)
        ax = fig.add_subplot()
        mu = data["mode_probabilities_mean"]
        for m, label in enumerate(("normal model", "actuator-1 fault model", "actuator-2 fault model")):
            ax.plot(t, mu[:, m], marker="o", ms=2.5, label=label)
        ax.axhline(0.5, color="r", lw=0.8, ls="--", label="μ_T = 0.5")
        finish(ax, "mean mode probability", f"Fig. 2: fused IMM, mean over {data['n_runs']} runs")
        files.append(out_dir / f"{prefix}mode_probabilities.png")
        fig.savefig(files[-1], dpi=110)

        fig = figure(6.0, 3.4)
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
            fig = figure(6.0, 3.4)
            ax = fig.add_subplot()
            for name, curve in data["curves"].items():
                color, ls = styles[name]
                ax.plot(t, curve[key], color=color, ls=ls, label=name)
            finish(ax, "RMSE over runs", f"{title}, {data['n_runs']} runs")
            files.append(out_dir / f"{prefix}{fname}.png")
            fig.savefig(files[-1], dpi=110)
        return files


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
        for design in params:
            rows = [(name, "met" if met else "**not met**", numbers)
                    for name, met, numbers in bars(metrics, prefixed(design))]
            print(f"### Scientific bars, {design} design\n\n" + cli.markdown_table(("bar", "met", "numbers"), rows)
                  + "\n")
        return files

    return cli.run_report(parser, argv, body)


if __name__ == "__main__":
    raise SystemExit(main())
