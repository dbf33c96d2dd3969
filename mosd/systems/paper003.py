"""Paper 003's Table 2 and Figs. 6–8 as ours: observer windows N against ramp rates (plain dicts and arrays).

Wang et al. 2020 (paper 003) §2.2: ramp faults of 0.1 … 1.0 m/s are injected
into the GPS altitude at step 500 (100 s at 5 Hz) and observers of windows
N = 1 … 15 are compared by their mean detection step and detection rate
(Table 2), per ramp rate (Fig. 8); Fig. 7 shows the residual and the adaptive
threshold of N = 1 and of a multi-step observer; Fig. 6 the training loss.

:class:`Study` runs all of it on simulated flights of
:class:`~mosd.plants.flapping_wing.FlappingWingMAV`: one set of fault-free
training flights (seed stream ``"estimator"``) trains one observer per N;
the same test flights (stream ``"test"``) are replayed with every ramp rate
(the fault is injected into the log only, so the flights themselves do not
depend on the rate) and decided on by the adaptive-χ² detector for both
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

from dataclasses import replace
from pathlib import Path

import numpy as np

from ..faults.ramp import RampFault
from ..faults.sensor import sensor_fault_signals
from ..scenario import training_rng
from ..validation import ConfigError, Interval, check_in, check_int
from . import base, cli
from .base import TUNED, decorate, design_params, figure, prefixed

SYSTEM = "paper003"
STATISTICS = ("observer_chi2", "chi2")


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


# ------------------------------------------------------------------------------------
# the study of the +experiment=paper003 preset, and its report command
# ------------------------------------------------------------------------------------
#: the study's default windows (six trainings: about 1.5 min cold on 2 cores); the report command's: 1 … 15
STUDY_WINDOWS = (1, 2, 4, 8, 12, 15)
FULL_WINDOWS = tuple(range(1, 16))
RATES = tuple(float(r) for r in np.round(np.arange(1, 11) / 10, 1))
#: the other reading's metric prefix, by the statistic the preset's monitor tests
READING_PREFIX = {"observer_chi2": "observer_", "chi2": "innovation_"}


def with_fault(trace, fault):
    """A fault-free flight log with ``fault`` added to its channel, as the plant injects a log fault.

    The flapping-wing plant adds a sensor fault to the log after the flight
    (:func:`mosd.faults.sensor_fault_signals`, called here too), so every ramp
    rate can replay the same flights (common random numbers) without simulating
    them again; ``tests/test_studies.py`` checks this equals simulating the
    plant with the fault. The replications' own generators are gone by now: a
    fault whose signal draws random numbers (a variance fault) would get fresh
    ones, so the ramp faults of this study (which draw nothing) are what it replays.
    """
    rngs = [np.random.default_rng([0, r]) for r in range(trace.y.shape[0])]
    g, mask = sensor_fault_signals(fault, trace.t, rngs, trace.y.shape[-1])
    return replace(trace, y=trace.y + g, fault_mask=mask)


class Study(base.Study):
    """Paper 003's Table 2 and Figs. 6–8 for a tuned adaptive-χ² design, windows N against ramp rates.

    One observer per window N is trained like the experiment's (the same
    fault-free flights of the ``estimator`` stream, the same generator: the
    experiment's own window is a cache hit). ``n_runs`` flights of the ``test``
    stream are replayed with every ramp rate (the fault is in the log only)
    and once fault-free. The tuned detector (``result.detector``) and the
    paper's (α = 0.01, a = b = 1; metrics prefixed ``paper_``) decide on both
    readings of the χ² statistic (docs/systems/paper003.md); the unprefixed
    metrics use the reading of the experiment's monitor, the other reading's
    carry its prefix (``innovation_`` for the filter's χ², ``observer_`` for
    the observer's standardised residual).

    Parameters
    ----------
    windows : sequence of int
        Observer windows N, distinct integers in [1, 100], including 1.
        Default (1, 2, 4, 8, 12, 15): six trainings, about 1.5 min cold on 2
        cores (seconds once cached); the report command runs 1 … 15.
    rates : sequence of float
        Ramp rates in m/s (the paper: 0.1 … 1.0), non-zero in [-100, 100].
    n_runs : int
        Test flights per rate (the paper's full scale: 20).
    trace_rate : float
        The rate whose first flight Fig. 7 shows (one of ``rates``).
    figures : bool
        Write the PNG figures into ``out_dir``.

    Notes
    -----
    ``detection_step_n1`` / ``detection_step_best``: steps from the onset to
    the first alarm at or after it, mean over the detecting flights, then over
    the rates (the paper's Table 2 counts absolute steps: 634 for N = 1 is 134
    after the onset at 500); ``best_window``: the N with the smallest;
    ``detection_rate_*``: share of post-onset points that alarm, mean over
    rates; the best window minimises the censored step (a flight that never
    alarms after the onset counts as the whole faulty horizon), not the step
    over detecting flights alone; ``far`` / ``far_n1``: share of the fault-free flights' points (after
    the first N) that alarm, for the best N and for N = 1.
    """

    system = SYSTEM

    def __init__(self, windows=STUDY_WINDOWS, rates=RATES, n_runs: int = 20, trace_rate: float = 0.1,
                 figures: bool = True):
        super().__init__(figures=figures)
        if isinstance(windows, (str, bytes)) or not hasattr(windows, "__len__") or not len(windows):
            raise ConfigError(f"study.windows={windows!r} is not allowed; allowed: a list of integers in [1, 100] "
                              f"including 1")
        self.windows = tuple(check_int("study.windows", w, 1, 100) for w in windows)
        if 1 not in self.windows or len(set(self.windows)) != len(self.windows):
            raise ConfigError(f"study.windows={list(windows)!r} is not allowed; allowed: distinct integers in "
                              f"[1, 100] including 1 (the classic observer)")
        if isinstance(rates, (str, bytes)) or not hasattr(rates, "__len__") or not len(rates):
            raise ConfigError(f"study.rates={rates!r} is not allowed; allowed: a list of ramp rates (m/s)")
        self.rates = tuple(float(check_in("study.rates", r, Interval(-100.0, 100.0))) for r in rates)
        if 0.0 in self.rates:
            raise ConfigError("study.rates contains 0; allowed: non-zero ramp rates in [-100, 100] m/s")
        self.n_runs = check_int("study.n_runs", n_runs, 1)
        self.trace_rate = float(trace_rate)
        if self.trace_rate not in self.rates:
            raise ConfigError(f"study.trace_rate={trace_rate!r} is not allowed; allowed: one of study.rates "
                              f"{list(self.rates)}")

    # -- computation --------------------------------------------------------------------
    def compute(self, experiment, designs: dict) -> dict:
        """Table 2 per design and reading, fault-free false alarms, Fig. 7 traces and the loss curves."""
        outputs_read = tuple(getattr(experiment.monitor, "outputs", ("observer_chi2",)))
        statistic = outputs_read[0] if outputs_read[0] in STATISTICS else "observer_chi2"
        dt = float(experiment.plant.dt)
        onset_step = int(round(experiment.fault.onset / dt))
        channel = int(getattr(experiment.fault, "channel", 0))
        training = experiment.simulate(None, experiment.budget.n_estimator, "estimator")
        clean = experiment.simulate(None, self.n_runs, "test")
        tests = {rate: with_fault(clean, RampFault(rate=rate, channel=channel, onset=experiment.fault.onset))
                 for rate in self.rates}
        shape = (len(self.windows), len(self.rates))
        keys = ("detection_step", "detection_rate", "run_detection_share", "censored_step")
        horizon = clean.y.shape[1] - onset_step  # a flight that never alarms counts as the whole faulty horizon
        table = {d: {s: {k: np.full(shape, np.nan) for k in keys} for s in STATISTICS} for d in designs}
        far = {d: {s: np.full(len(self.windows), np.nan) for s in STATISTICS} for d in designs}
        traces, loss, sigma = {}, {}, {}
        for i, window in enumerate(self.windows):
            estimator = experiment.estimator
            if getattr(estimator, "window", None) != window or not hasattr(estimator, "params_"):
                # an untrained observer like the experiment's (same network, training and filter settings)
                # of window N, trained with the experiment's generator: its own window is the same network
                estimator = experiment.estimator.with_params(window=window)
                estimator.fit(training, experiment.model, training_rng(experiment.seed))
            loss[window] = {k: np.asarray(v, float) for k, v in estimator.history_.items()}
            sigma[window] = float(estimator.residual_std_)
            free = estimator.estimate(clean, experiment.model)
            for j, rate in enumerate(self.rates):
                outputs = estimator.estimate(tests[rate], experiment.model)
                for name, detector in designs.items():
                    for s in STATISTICS:
                        z = np.stack([outputs.extra[s], outputs.extra["observer_residual"]], -1)
                        decided = detector.decide(z, z)
                        summary = detection_summary(decided.decision, onset_step, first_valid=window)
                        first = summary["first_alarm"]
                        summary["censored_step"] = float(np.mean(np.where(first >= 0, first, onset_step + horizon)))
                        for k in keys:
                            table[name][s][k][i, j] = summary[k] - (onset_step if k == "detection_step" else 0)
                        if rate == self.trace_rate:
                            traces[(name, s, window)] = {
                                "observer_residual": outputs.extra["observer_residual"][0],
                                "statistic": decided.statistic[0],
                                "threshold": np.broadcast_to(decided.threshold, decided.statistic.shape)[0],
                                "first_alarm": int(summary["first_alarm"][0])}
            for name, detector in designs.items():
                for s in STATISTICS:
                    z = np.stack([free.extra[s], free.extra["observer_residual"]], -1)
                    far[name][s][i] = float(np.mean(detector.decide(z, z).decision[:, window:] != 0))
        return {"windows": self.windows, "rates": self.rates, "n_runs": self.n_runs, "onset_step": onset_step,
                "dt": dt, "statistic": statistic, "table": table, "far": far, "traces": traces, "loss": loss,
                "sigma": sigma, "trace_rate": self.trace_rate,
                "params": {name: design_params(d) for name, d in designs.items()}}

    @staticmethod
    def _over_rates(values: np.ndarray) -> np.ndarray:
        """Mean over the rates (axis 1) of the finite entries (NaN where no rate detected anything)."""
        seen = np.isfinite(values)
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(seen.any(1), np.where(seen, values, 0.0).sum(1) / np.maximum(seen.sum(1), 1), np.nan)

    @classmethod
    def summary(cls, data: dict, design: str, statistic: str) -> dict[str, float]:
        """The headline numbers of one design and reading (class docstring)."""
        t = data["table"][design][statistic]
        step = cls._over_rates(t["detection_step"])
        rate = cls._over_rates(t["detection_rate"])
        far = data["far"][design][statistic]
        i1 = data["windows"].index(1)
        # the best window by the censored step, so that a window whose few detecting flights alarm early by
        # chance (a high threshold) does not win over one that detects every flight
        best = int(np.argmin(cls._over_rates(t["censored_step"])))
        return {"detection_step_n1": float(step[i1]), "detection_step_best": float(step[best]),
                "best_window": float(data["windows"][best]), "detection_rate_n1": float(rate[i1]),
                "detection_rate_best": float(rate[best]), "far": float(far[best]), "far_n1": float(far[i1])}

    def metrics(self, data: dict) -> dict[str, float]:
        """The study's metrics by name (class docstring)."""
        out = {}
        preset = data["statistic"]
        other = next(s for s in STATISTICS if s != preset)
        for design in data["table"]:
            prefix = prefixed(design)
            out.update({prefix + k: v for k, v in self.summary(data, design, preset).items()})
            out.update({prefix + READING_PREFIX[other] + k: v for k, v in self.summary(data, design, other).items()})
        return out

    # -- figures --------------------------------------------------------------------------
    def write_figures(self, data: dict, out_dir: Path) -> list[Path]:
        """Table 2 (step and rate against N), Fig. 8 (per rate), Fig. 7 (residual vs threshold), Fig. 6 (loss)."""
        out_dir.mkdir(parents=True, exist_ok=True)
        prefix = f"{self.system}_"
        files = []
        windows, rates, s0 = data["windows"], data["rates"], data["statistic"]
        names = {"observer_chi2": "observer's χ² (reading 2)", "chi2": "filter's innovation χ² (reading 1)"}

        fig = figure(9.0, 3.4)
        ax, bx = fig.subplots(1, 2)
        for design, ls in (("tuned", "-"), ("paper", "--")):
            for s, color in (("observer_chi2", "tab:blue"), ("chi2", "tab:orange")):
                if design not in data["table"]:
                    continue
                t = data["table"][design][s]
                label = f"{design}, {names[s]}"
                ax.plot(windows, self._over_rates(t["detection_step"]), ls=ls, color=color, marker="o", label=label)
                bx.plot(windows, 100 * self._over_rates(t["detection_rate"]), ls=ls, color=color, marker="o",
                        label=label)
        ax.set_xlabel("window N")
        ax.set_ylabel("detection step after the onset")
        ax.set_title(f"Table 2: mean over rates {rates[0]:g}…{rates[-1]:g} m/s", fontsize=10)
        bx.set_xlabel("window N")
        bx.set_ylabel("post-onset points alarmed (%)")
        bx.set_title("Table 2: detection rate", fontsize=10)
        for a in (ax, bx):
            a.grid(alpha=0.3)
        bx.legend(fontsize=7)
        files.append(out_dir / f"{prefix}table2.png")
        fig.savefig(files[-1], dpi=110)

        fig = figure(6.5, 3.6)
        ax = fig.add_subplot()
        steps = data["table"]["tuned"][s0]["detection_step"]
        colors = _colormap(len(rates))
        for j, rate in enumerate(rates):
            ax.plot(windows, data["onset_step"] + steps[:, j], marker=".", color=colors[j], label=f"{rate:g} m/s")
        ax.axhline(data["onset_step"], color="grey", ls=":", lw=0.8)
        ax.set_xlabel("window N")
        ax.set_ylabel("mean detection step")
        ax.set_title(f"Fig. 8: detection point per ramp rate (tuned design, {names[s0]})", fontsize=9)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, ncol=2)
        files.append(out_dir / f"{prefix}detection_point.png")
        fig.savefig(files[-1], dpi=110)

        best = int(self.summary(data, "tuned", s0)["best_window"])
        fig = figure(9.0, 5.0)
        axes = fig.subplots(2, 1, sharex=True)
        lo, hi = max(data["onset_step"] - 60, 0), data["onset_step"] + 120
        for ax, window in zip(axes, (1, best)):
            tr = data["traces"][("tuned", s0, window)]
            k = np.arange(tr["statistic"].size)
            ax.plot(k[lo:hi], tr["statistic"][lo:hi], lw=0.9, label=f"statistic ({names[s0]})")
            ax.plot(k[lo:hi], tr["threshold"][lo:hi], lw=0.9, color="r", label="adaptive threshold a·T_D + b·E_k")
            ax.axvline(data["onset_step"], color="grey", ls=":", lw=0.8)
            if tr["first_alarm"] >= 0:
                ax.axvline(tr["first_alarm"], color="k", ls="--", lw=0.8, label=f"first alarm, step {tr['first_alarm']}")
            ax.set_yscale("symlog", linthresh=1.0)
            ax.set_ylim(bottom=0.0)
            ax.set_title(f"Fig. 7: N = {window}, ramp {data['trace_rate']:g} m/s, one flight (tuned design)",
                         fontsize=9)
            ax.set_ylabel("χ² value")
            ax.grid(alpha=0.3)
            ax.legend(fontsize=7, loc="upper left")
        axes[-1].set_xlabel("log step")
        files.append(out_dir / f"{prefix}residual_threshold.png")
        fig.savefig(files[-1], dpi=110)

        fig = figure(6.5, 3.4)
        ax = fig.add_subplot()
        for window, color in zip(sorted({1, best, windows[-1]}), ("tab:blue", "tab:green", "tab:red")):
            curves = data["loss"][window]
            ax.plot(curves["train_loss"], color=color, label=f"N = {window}, training")
            ax.plot(curves["validation_loss"], color=color, ls="--", label=f"N = {window}, validation")
        ax.set_yscale("log")
        decorate(ax, "epoch", "weighted multi-step loss (standardised)",
                 "Fig. 6: training loss (early stopping, patience 10)", legend_size=7)
        files.append(out_dir / f"{prefix}training_loss.png")
        fig.savefig(files[-1], dpi=110)
        return files


def _colormap(n: int) -> list:
    from matplotlib import colormaps

    cmap = colormaps["viridis"]
    return [cmap(i / max(n - 1, 1)) for i in range(n)]


def format_report(data: dict) -> str:
    """Table 2 per design and reading as markdown (steps after the onset and absolute)."""
    lines = []
    onset = data["onset_step"]
    for design in data["table"]:
        p = data["params"][design]
        for s in (data["statistic"], *(x for x in STATISTICS if x != data["statistic"])):
            t = data["table"][design][s]
            step, rate = Study._over_rates(t["detection_step"]), Study._over_rates(t["detection_rate"])
            share = Study._over_rates(t["run_detection_share"])
            lines += [f"**{design} design** (α = {p['alpha']:.4g}, a = {p['a']:.4g}, b = {p['b']:.4g}), "
                      f"statistic `{s}`{' (the preset)' if s == data['statistic'] else ''}:", "",
                      "| N | detection step after onset | mean step | detection rate | runs detected "
                      "| FAR fault-free |", "|---|---|---|---|---|---|"]
            for i, window in enumerate(data["windows"]):
                lines.append(f"| {window} | {step[i]:.1f} | {onset + step[i]:.1f} | {100 * rate[i]:.1f} % "
                             f"| {100 * share[i]:.1f} % | {100 * data['far'][design][s][i]:.2f} % |")
            lines.append("")
    return "\n".join(lines)


def parse_windows(text: str) -> tuple[int, ...]:
    """``--windows``: ``'A-B'`` (a range) or a comma list of integers."""
    try:
        if "-" in text:
            low, high = (int(v) for v in text.split("-"))
            return tuple(range(low, high + 1))
        return tuple(int(v) for v in text.split(","))
    except ValueError:
        raise ConfigError(f"--windows={text!r} is not allowed; allowed: 'A-B' or a comma list of integers, "
                          f"e.g. 1-15 or 1,4,12") from None


def main(argv=None) -> int:
    """``python -m mosd.systems.paper003 [--n-runs 20] [--windows 1-15] [--seed 0] [--out DIR]``."""
    parser = cli.report_parser("python -m mosd.systems.paper003", "Paper 003's Table 2 and Figs. 6-8 at full scale "
                               "without the optimiser: the tuned design beside the paper's (alpha 0.01, a = b = 1).",
                               out="outputs/systems/paper003")
    parser.add_argument("--n-runs", type=int, default=20, help="test flights per ramp rate (default 20)")
    parser.add_argument("--windows", default="1-15",
                        help="observer windows: 'A-B' or a comma list including 1 (default 1-15; trains one each)")
    cli.design_options(parser, SYSTEM)  # --alpha, --a, --b

    def body(args):
        windows = parse_windows(args.windows)
        study = Study(windows=windows, n_runs=args.n_runs)
        experiment = cli.preset(SYSTEM, [f"seed={args.seed}"]).experiment
        designs = {TUNED: experiment.detector.with_params(**cli.tuned_design(args, SYSTEM)),
                   **study.reference_designs(experiment, experiment.detector)}
        data, metrics, files = cli.score(study, experiment, designs, Path(args.out), windows=list(windows),
                                         rates=list(study.rates), n_runs=args.n_runs, seed=args.seed,
                                         observer_sigma=lambda d: d["sigma"], table=lambda d: {
                                             design: {s: {k: v.tolist() for k, v in t.items()} for s, t in by_s.items()}
                                             for design, by_s in d["table"].items()},
                                         far=lambda d: {design: {s: v.tolist() for s, v in by_s.items()}
                                                        for design, by_s in d["far"].items()})
        print(f"## Paper 003: windows {windows[0]}..{windows[-1]}, rates {study.rates[0]:g}..{study.rates[-1]:g} m/s, "
              f"{args.n_runs} flights each, seed {args.seed}\n")
        print(format_report(data))
        print(cli.markdown_table(("metric", "value"), ((k, f"{v:.4g}") for k, v in metrics.items())) + "\n")
        return files

    return cli.run_report(parser, argv, body)


if __name__ == "__main__":
    raise SystemExit(main())
