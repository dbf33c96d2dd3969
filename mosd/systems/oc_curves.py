"""Operating-characteristic curves of paper 000's charts at matched in-control performance (issue 15).

SPC compares charts the way this module does: fix what they do in control, then ask how fast
each one finds faults of every size. For each fault kind and each chart:

* **on the plant** (the paper's pipeline: mould oscillator, dedicated-observer residual, windows
  of n = 5, 1,000 subgroups, fault from subgroup 501): every chart's limit is set on fault-free
  calibration runs so that its in-control point alarm rate is the same α (``--far``, the
  empirical (1 − α) quantile of its Phase-I statistic); then FAR, MDR, detection rate, mean
  delay over detected runs and the censored median delay on test runs of each fault size;
* **ARL** (causal charts only; zero-state, i.i.d. N(a, b²) subgroups of n = 5, the fault from the
  first subgroup, a drift as a ramp in the plant's time base): every chart's limit is set so that
  its in-control ARL0 is the same (``--arl0``), from the run lengths of the in-control runs
  themselves; then ARL1 per fault size on the same random numbers (paired across charts and sizes).

Charts (λ from paper 000's Table 3 for the fault kind; drift uses the offset presets; the width
is *not* the preset's, it is whatever gives the matched in-control performance):

* SS-DEWMA and M-DEWMA on the raw statistic (causal);
* SS-DEWMA with the paper's wavelet, causal sliding window (``window=128``) and whole series
  (non-causal, labelled, plant numbers only);
* MS-OEWMA with the paper's whole-series prefilter (non-causal, as paper 000 used it) and with a
  causal sliding-window prefilter (``window=128``), plant numbers only (its ARL would need the
  prefilter on every simulated residual);
* SS-DEWMA tuned: λ of the design MOPSO chooses for the kind's paper-size fault on training runs
  (raw statistic, Table 2's box, max accuracy — the main command's default set-up);
* the plain EWMA of the subgroup mean (λ = 0.2), the textbook reference.

Command::

    python -m mosd.systems.oc_curves [--budget paper|small|tiny] [--far 0.01] [--arl0 200]
                                     [--kinds offset,variance,drift] [--seed 0] [--out outputs/oc]

writes ``oc_<kind>.csv`` and ``oc_<kind>.png`` per fault kind and ``oc.md`` (the tables).
"""
from __future__ import annotations

import csv
import functools
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from ..denoisers import NoDenoiser
from ..detectors import EWMA, MDEWMA, MSOEWMA, SSDEWMA, Chart
from ..experiment import Experiment
from ..metrics import DetectionReport, Estimate
from ..validation import ConfigError, Interval, check_choice, check_in, check_int
from . import cli
from .base import figure
from .paper000 import PAPER_PRESETS, make_prefilter, make_solver

#: Fault sizes per kind: offset a and drift rate in σ (drift: σ per second), variance factor b.
SIZES: dict[str, tuple[float, ...]] = {
    "offset": (0.25, 0.5, 1.0, 2.0),
    "variance": (1.1, 1.25, 1.5, 2.0),
    "drift": (0.25, 0.5, 1.0, 2.0),
}
KINDS = tuple(SIZES)
#: paper 000's fault of each kind (the tuned design is tuned on it)
PAPER_SIZE = {"offset": 2.0, "variance": 2.0, "drift": 2.0}
#: Table 3's λ per kind (drift: the offset column); the widths are recalibrated, not taken
PAPER_LAMBDA = {method: {kind: PAPER_PRESETS[method]["offset" if kind == "drift" else kind]["lam"] for kind in SIZES}
                for method in ("SS-DEWMA", "M-DEWMA", "MS-OEWMA")}
EWMA_LAMBDA = 0.2
#: the experiment: paper 000's preset (docs/DECISIONS.md §2 layout) on the raw statistic, with the offset fault
PRESET, PRESET_OVERRIDES = "paper000", ("denoise=none", "fault=offset")
#: seed-stream id of the synthetic ARL runs, apart from mosd.scenario.STREAMS (0–3)
ARL_STREAM = 15


@dataclass(frozen=True)
class OCBudget:
    """Runs per stage: plant calibration and test runs (per size), ARL replications and horizon, tuning."""

    n_calibration: int
    n_test: int
    n_train: int
    arl_reps: int
    arl_horizon: int
    pop_size: int
    n_gen: int


BUDGETS = {
    "paper": OCBudget(n_calibration=40, n_test=60, n_train=10, arl_reps=500, arl_horizon=1500, pop_size=40,
                      n_gen=40),
    "small": OCBudget(n_calibration=12, n_test=20, n_train=4, arl_reps=200, arl_horizon=1000, pop_size=12, n_gen=8),
    "tiny": OCBudget(n_calibration=3, n_test=3, n_train=2, arl_reps=40, arl_horizon=400, pop_size=6, n_gen=2),
}


@dataclass(frozen=True)
class OCSettings:
    """What one OC study runs with (validated here, one-line errors naming the option)."""

    budget: str = "paper"
    far: float = 0.01
    arl0: float = 200.0
    kinds: tuple[str, ...] = KINDS
    seed: int = 0
    n_jobs: int = 2

    def __post_init__(self):
        check_choice("budget", self.budget, tuple(BUDGETS))
        check_in("far", self.far, Interval(0.0, 0.5, open_low=True))
        check_in("arl0", self.arl0, Interval(2.0, 1e4))
        if not self.kinds:
            raise ConfigError(f"kinds is empty; allowed: a comma-separated subset of {', '.join(KINDS)}")
        for kind in self.kinds:
            check_choice("kinds", kind, KINDS)
        check_int("seed", self.seed, 0, 2**63 - 1)
        check_int("n_jobs", self.n_jobs, 1, 64)
        horizon = BUDGETS[self.budget].arl_horizon
        # run lengths are censored at the horizon: keep it several ARL0 long
        if self.arl0 > horizon / 2:
            raise ConfigError(f"arl0={self.arl0:g} is too long for the {self.budget} budget's horizon of {horizon} "
                              f"subgroups; allowed: arl0 <= {horizon / 2:g}")

    @property
    def preset(self) -> OCBudget:
        return BUDGETS[self.budget]


# ------------------------------------------------------------------------------------------
# charts
# ------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class ChartSpec:
    """One compared chart: a name, its λ and a chart whose limit this module replaces by a matched one."""

    name: str
    lam: float
    chart: Chart

    @property
    def causal(self) -> bool:
        return bool(self.chart.is_causal)


def chart_specs(kind: str, tuned_lam: float | None) -> list[ChartSpec]:
    """The charts compared on one fault kind (module docstring).

    The wavelets are paper 000's literal call, ``conf/denoise/wavelet.yaml`` (whole series) and
    ``wavelet_causal.yaml`` (its sliding window); MS-OEWMA's prefilter is
    :func:`mosd.systems.paper000.make_prefilter`, whole series or on the same window.
    """
    ss, md, ms = (PAPER_LAMBDA[m][kind] for m in ("SS-DEWMA", "M-DEWMA", "MS-OEWMA"))
    whole, causal = (cli.component("denoise", option) for option in ("wavelet", "wavelet_causal"))
    specs = [
        ChartSpec("SS-DEWMA", ss, SSDEWMA(lam=ss, denoiser=NoDenoiser())),
        ChartSpec("SS-DEWMA + causal wavelet", ss, SSDEWMA(lam=ss, denoiser=causal)),
        ChartSpec("SS-DEWMA + wavelet (whole series)", ss, SSDEWMA(lam=ss, denoiser=whole)),
        ChartSpec("M-DEWMA", md, MDEWMA(lam=md, denoiser=NoDenoiser())),
        ChartSpec("MS-OEWMA (causal prefilter)", ms, MSOEWMA(lam=ms, prefilter=make_prefilter(causal.window))),
        ChartSpec("MS-OEWMA (whole-series prefilter)", ms, MSOEWMA(lam=ms, prefilter=make_prefilter())),
        ChartSpec("EWMA (mean only)", EWMA_LAMBDA, EWMA(lam=EWMA_LAMBDA, limit="phase1")),
    ]
    if tuned_lam is not None:
        specs.insert(1, ChartSpec("SS-DEWMA tuned", tuned_lam, SSDEWMA(lam=tuned_lam, denoiser=NoDenoiser())))
    return specs


# ------------------------------------------------------------------------------------------
# matched limits
# ------------------------------------------------------------------------------------------
def far_limit(phase1_statistic: np.ndarray, far: float) -> float:
    """The constant limit exceeded by a share ``far`` of the Phase-I points (their (1 − far) quantile)."""
    return float(np.quantile(np.asarray(phase1_statistic, float).ravel(), 1.0 - far))


def run_lengths(statistic: np.ndarray, limit: float) -> np.ndarray:
    """Zero-state run length of every run (R, T) against a constant limit: first k with l_k > limit (1-based).

    Runs without an alarm get T + 1 (censored at the horizon).
    """
    alarms = np.asarray(statistic) > limit
    return np.where(alarms.any(axis=-1), np.argmax(alarms, axis=-1) + 1, alarms.shape[-1] + 1)


def arl_limit(statistic: np.ndarray, arl0: float) -> float:
    """The constant limit whose mean run length over the in-control runs (R, T) is ``arl0``.

    The run length at limit h is 1 + #{k : max_{j<=k} l_j <= h}, a non-decreasing step
    function of h; the smallest h with mean run length >= arl0 is found by bisection
    on the sorted running maxima.
    """
    running = np.maximum.accumulate(np.asarray(statistic, float), axis=-1)
    horizon = running.shape[-1]
    if arl0 >= horizon:
        raise ConfigError(f"arl0={arl0:g} is not below the simulated horizon of {horizon} subgroups; "
                          f"allowed: arl0 < {horizon}")
    candidates = np.unique(running)
    low, high = 0, candidates.size - 1
    while low < high:
        mid = (low + high) // 2
        if (1.0 + (running <= candidates[mid]).sum(axis=-1)).mean() >= arl0:
            high = mid
        else:
            low = mid + 1
    return float(candidates[low])


# ------------------------------------------------------------------------------------------
# synthetic subgroups for the ARL
# ------------------------------------------------------------------------------------------
def faulty_subgroups(base: np.ndarray, kind: str, size: float, dt: float) -> np.ndarray:
    """Standardised subgroups (R, T, n) of a fault present from the first sample, from N(0, 1) ``base``.

    offset: a + e; variance: b·e; drift: e + size·dt·j at sample j = 1, 2, ... (σ per second,
    the plant's time base ``dt``): in the standardised units, the faults
    :func:`mosd.faults.sensor_fault_signals` injects on the plant. Not that function itself, on
    purpose: the variance fault scales the *same* draws e (the plant adds independent extra noise
    of variance b² − 1), so that every size and chart is scored on one set of random numbers
    (paired ARLs).
    """
    check_choice("kind", kind, KINDS)
    if kind == "offset":
        return base + size
    if kind == "variance":
        return base * size
    samples = np.arange(1, base.shape[-2] * base.shape[-1] + 1).reshape(base.shape[-2:])
    return base + size * dt * samples


def arl_curves(specs: Sequence[ChartSpec], kind: str, settings: OCSettings, dt: float,
               rng: np.random.Generator, subgroup_n: int = 5) -> dict[str, dict]:
    """ARL0-matched limits and ARL1 per size for the causal charts (module docstring), subgroups of ``subgroup_n``."""
    preset = settings.preset
    base = rng.standard_normal((preset.arl_reps, preset.arl_horizon, subgroup_n))
    out: dict[str, dict] = {}
    for spec in specs:
        if not spec.causal:
            continue
        if isinstance(spec.chart, MSOEWMA):
            continue  # prefilter on every simulated residual: too slow to be worth it (module docstring)
        in_control = spec.chart.statistic(base)
        limit = arl_limit(in_control, settings.arl0)
        rl0 = run_lengths(in_control, limit)
        sizes = {}
        for size in SIZES[kind]:
            rl = run_lengths(spec.chart.statistic(faulty_subgroups(base, kind, size, dt)), limit)
            sizes[size] = _arl(rl, preset.arl_horizon)
        out[spec.name] = {"limit": limit, "arl0": _arl(rl0, preset.arl_horizon), "arl1": sizes}
    return out


def _arl(rl: np.ndarray, horizon: int) -> dict[str, float]:
    return {"mean": float(rl.mean()), "se": float(rl.std(ddof=1) / math.sqrt(rl.size)),
            "censored": float((rl > horizon).mean())}


# ------------------------------------------------------------------------------------------
# the plant
# ------------------------------------------------------------------------------------------
def make_fault(kind: str, size: float, onset: float):
    """The sensor fault ``conf/fault/<kind>.yaml`` of one size (a, or b for variance) from ``onset`` (s)."""
    size_key = "b" if check_choice("kind", kind, KINDS) == "variance" else "a"
    return cli.component("fault", kind, [f"{size_key}={float(size)!r}", f"onset={float(onset)!r}"])


def make_setup(settings: OCSettings):
    """Paper 000's preset on the raw statistic (:data:`PRESET_OVERRIDES`) with this study's budget and seed."""
    preset = settings.preset
    return cli.preset(PRESET, [*PRESET_OVERRIDES, f"seed={settings.seed}",
                               f"budget.n_calibration={preset.n_calibration}", f"budget.n_train={preset.n_train}",
                               f"budget.n_test={preset.n_test}"])


def tune_lambda(experiment: Experiment, prepared, settings: OCSettings, bounds: dict) -> dict[str, float]:
    """MOPSO (Table 2, literal) on the training runs of the paper-size fault: the main command's choice."""
    from ..optim.selection import choose

    preset = settings.preset
    tuned = experiment.tune(prepared, make_solver("mopso", preset.pop_size), ("n_gen", preset.n_gen),
                            n_jobs=settings.n_jobs, bounds=bounds,
                            choose=functools.partial(choose, rule="max_accuracy"))
    return dict(tuned.params)


def plant_curves(specs: Sequence[ChartSpec], phase1_z: np.ndarray, tests: dict[float, object],
                 settings: OCSettings) -> dict[str, dict]:
    """FAR-matched limits and (FAR, MDR, detection rate, delays) per size on the plant's test runs."""
    out: dict[str, dict] = {}
    for spec in specs:
        phase1 = spec.chart.statistic(phase1_z)
        limit = far_limit(phase1, settings.far)
        width = (limit - phase1.mean()) / phase1.std(ddof=1)
        sizes = {}
        for size, subgroups in tests.items():
            report = DetectionReport.of(spec.chart.statistic(subgroups.z) > limit, subgroups)
            summary = report.summary()
            sizes[size] = {"far": summary["far"], "mdr": summary["mdr"], "detection_rate": summary["detection_rate"],
                           "delay": summary["delay"], "median_censored_delay": report.median_censored_delay()}
        out[spec.name] = {"limit": limit, "width": float(width), "phase1_far": float((phase1 > limit).mean()),
                          "sizes": sizes}
    return out


@dataclass
class KindResult:
    kind: str
    specs: list[ChartSpec]
    tuned: dict[str, float]
    plant: dict[str, dict]
    arl: dict[str, dict]
    seconds: float


def run_kind(setup, calibration, kind: str, settings: OCSettings) -> KindResult:
    """Tune, simulate the test runs of every size (same seeds: paired), score every chart."""
    t0 = time.perf_counter()
    experiment = setup.experiment
    onset = experiment.fault.onset
    prepared = experiment.prepare(calibration=calibration, fault=make_fault(kind, PAPER_SIZE[kind], onset))
    tuned = tune_lambda(experiment, prepared, settings, setup.bounds)
    specs = chart_specs(kind, tuned["lam"])
    tests = {size: experiment.test_data(prepared, fault=make_fault(kind, size, onset))[0] for size in SIZES[kind]}
    plant = plant_curves(specs, prepared.phase1.z, tests, settings)
    rng = np.random.default_rng([settings.seed, ARL_STREAM, KINDS.index(kind)])
    arl = arl_curves(specs, kind, settings, experiment.plant.dt, rng, experiment.monitor.n)
    return KindResult(kind, specs, tuned, plant, arl, time.perf_counter() - t0)


def run(settings: OCSettings) -> list[KindResult]:
    """Calibrate once (the calibration stream is fault-free), then every fault kind."""
    setup = make_setup(settings)
    calibration = setup.experiment.calibrate()
    return [run_kind(setup, calibration, kind, settings) for kind in settings.kinds]


# ------------------------------------------------------------------------------------------
# output
# ------------------------------------------------------------------------------------------
CSV_COLUMNS = ("kind", "chart", "causal", "lam", "size", "limit", "width_equivalent", "far", "far_ci", "mdr",
               "mdr_ci", "detection_rate", "delay_detected", "delay_detected_ci", "median_censored_delay",
               "arl_limit", "arl0", "arl1", "arl1_se")


def rows(result: KindResult) -> list[dict]:
    """One row per (chart, size): plant metrics and, for ARL-charts, the ARL at the same size."""
    out = []
    for spec in result.specs:
        plant, arl = result.plant[spec.name], result.arl.get(spec.name)
        for size, m in plant["sizes"].items():
            out.append({
                "kind": result.kind, "chart": spec.name, "causal": int(spec.causal), "lam": spec.lam, "size": size,
                "limit": plant["limit"], "width_equivalent": plant["width"],
                "far": m["far"].mean, "far_ci": m["far"].half_width, "mdr": m["mdr"].mean,
                "mdr_ci": m["mdr"].half_width, "detection_rate": m["detection_rate"].mean,
                "delay_detected": m["delay"].mean, "delay_detected_ci": m["delay"].half_width,
                "median_censored_delay": m["median_censored_delay"],
                "arl_limit": arl["limit"] if arl else math.nan, "arl0": arl["arl0"]["mean"] if arl else math.nan,
                "arl1": arl["arl1"][size]["mean"] if arl else math.nan,
                "arl1_se": arl["arl1"][size]["se"] if arl else math.nan,
            })
    return out


def write_csv(result: KindResult, out: Path) -> Path:
    path = out / f"oc_{result.kind}.csv"
    with path.open("w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=CSV_COLUMNS)
        writer.writeheader()
        for row in rows(result):
            writer.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in row.items()})
    return path


_SIZE_LABEL = {"offset": "offset a (σ)", "variance": "variance factor b", "drift": "drift rate (σ/s)"}


def write_plot(result: KindResult, settings: OCSettings, out: Path) -> Path:
    """MDR, mean delay over detected runs, FAR and ARL1 against the fault size, one line per chart."""
    fig = figure(11.0, 7.2)
    axes = fig.subplots(2, 2)
    sizes = SIZES[result.kind]
    for index, spec in enumerate(result.specs):
        plant = result.plant[spec.name]["sizes"]
        # one colour per chart in every panel (the ARL panel skips some charts)
        style = {"linestyle": "-" if spec.causal else ":", "marker": "o", "ms": 3, "color": f"C{index}",
                 "label": spec.name + ("" if spec.causal else " [non-causal]")}
        axes[0, 0].plot(sizes, [100 * plant[s]["mdr"].mean for s in sizes], **style)
        axes[0, 1].plot(sizes, [plant[s]["delay"].mean for s in sizes], **style)
        axes[1, 0].plot(sizes, [100 * plant[s]["far"].mean for s in sizes], **style)
        if spec.name in result.arl:
            arl1 = result.arl[spec.name]["arl1"]
            axes[1, 1].plot(sizes, [arl1[s]["mean"] for s in sizes], **style)
    titles = [("MDR % (plant, matched FAR)", None), ("delay, subgroups (detected runs)", None),
              (f"FAR % (plant; target {100 * settings.far:g} %)", None),
              (f"ARL1, subgroups (i.i.d., ARL0 = {settings.arl0:g})", "log")]
    for ax, (title, scale) in zip(axes.ravel(), titles):
        ax.set_title(title, fontsize=9)
        ax.set_xlabel(_SIZE_LABEL[result.kind])
        ax.grid(alpha=0.3)
        if scale:
            ax.set_yscale(scale)
    axes[0, 0].legend(fontsize=7)
    fig.suptitle(f"Operating characteristics, {result.kind} fault (tuned λ = {result.tuned['lam']:.3f})", fontsize=10)
    path = out / f"oc_{result.kind}.png"
    fig.savefig(path, dpi=100)
    return path


def _fmt(e: Estimate, scale: float = 100.0, digits: int = 2) -> str:
    if not math.isfinite(e.mean):
        return "—"
    if not math.isfinite(e.half_width):
        return f"{scale * e.mean:.{digits}f}"
    return f"{scale * e.mean:.{digits}f} ± {scale * e.half_width:.{digits}f}"


def format_kind(result: KindResult, settings: OCSettings) -> str:
    """Markdown: per chart and size, MDR % / detection rate / delay (plant) and ARL1 (i.i.d.)."""
    sizes = SIZES[result.kind]
    lines = [f"### {result.kind}: tuned design λ = {result.tuned['lam']:.4f}, K = {result.tuned['K']:.4f}; "
             f"limits matched to FAR = {100 * settings.far:g} % (plant) and ARL0 = {settings.arl0:g} (i.i.d.)", "",
             "| chart | causal | λ | K equiv. | FAR % (test, before onset) | "
             + " | ".join(f"MDR % @ {s:g}" for s in sizes) + " | "
             + " | ".join(f"delay @ {s:g} (det. %)" for s in sizes) + " | "
             + " | ".join(f"ARL1 @ {s:g}" for s in sizes) + " |",
             "|" + "---|" * (5 + 3 * len(sizes))]
    for spec in result.specs:
        plant, arl = result.plant[spec.name], result.arl.get(spec.name)
        far = plant["sizes"][sizes[0]]["far"]
        mdr = " | ".join(_fmt(plant["sizes"][s]["mdr"]) for s in sizes)
        delay = " | ".join(f"{_fmt(plant['sizes'][s]['delay'], 1.0, 1)} ({100 * plant['sizes'][s]['detection_rate'].mean:.0f})"
                           for s in sizes)
        arl1 = " | ".join(f"{arl['arl1'][s]['mean']:.1f} ± {arl['arl1'][s]['se']:.1f}" if arl else "—" for s in sizes)
        lines.append(f"| {spec.name} | {'yes' if spec.causal else '**no**'} | {spec.lam:.4g} | {plant['width']:.2f} "
                     f"| {_fmt(far)} | {mdr} | {delay} | {arl1} |")
    arl0 = {name: a["arl0"] for name, a in result.arl.items()}
    lines += ["", "In-control ARL0 reached by the matched limits (i.i.d. runs, mean ± se): "
              + "; ".join(f"{n} {a['mean']:.1f} ± {a['se']:.1f}" for n, a in arl0.items())]
    return "\n".join(lines)


def _parser():
    parser = cli.report_parser("python -m mosd.systems.oc_curves", __doc__.split("\n\n")[0], out="outputs/oc")
    parser.add_argument("--budget", default="paper", help=f"one of {', '.join(BUDGETS)} (default paper)")
    parser.add_argument("--far", type=float, default=0.01, help="matched in-control point alarm rate on the plant")
    parser.add_argument("--arl0", type=float, default=200.0, help="matched in-control ARL0 (i.i.d. subgroups)")
    parser.add_argument("--kinds", default=",".join(KINDS), help="comma-separated fault kinds")
    parser.add_argument("--n-jobs", type=int, default=2)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m mosd.systems.oc_curves [options]`` (module docstring)."""
    return cli.run_report(_parser(), argv, _run)


def _run(args) -> list[Path]:
    settings = OCSettings(budget=args.budget, far=args.far, arl0=args.arl0, seed=args.seed, n_jobs=args.n_jobs,
                          kinds=tuple(k.strip() for k in args.kinds.split(",") if k.strip()))
    t0 = time.perf_counter()
    results = run(settings)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    written, sections = [], []
    for result in results:
        written += [write_csv(result, out), write_plot(result, settings, out)]
        sections.append(format_kind(result, settings))
    text = "\n\n".join(sections) + "\n"
    (out / "oc.md").write_text(text)
    written.append(out / "oc.md")
    print(text)
    print(f"settings: budget={settings.budget} far={settings.far:g} arl0={settings.arl0:g} seed={settings.seed}; "
          f"{time.perf_counter() - t0:.1f} s ({', '.join(f'{r.kind} {r.seconds:.1f} s' for r in results)})")
    return written


if __name__ == "__main__":
    raise SystemExit(main())
