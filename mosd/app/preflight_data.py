"""Preflight's checks of a job's shapes and data: what one replication (or the recorded calibration split) allows.

Split from :mod:`mosd.app.preflight` by job: :func:`mosd.app.preflight.dry_run` calls these on its one-replication
copy of the pipeline. The checks of the run's shapes (burn-in, wavelet level, fault onset) and of the memory the
budget and the detector need, and the search box the calibration data allow the detector (:func:`data_box`,
:func:`narrow_to_data`, :func:`check_search_box`; :func:`fit_to_data` for a job built without preflight).
"""
from __future__ import annotations

import copy
import dataclasses
import inspect
import math
from typing import Any, Callable, Sequence

import numpy as np

from .build import Setup
from .config import ConfigError, one_line

def _run_length(setup: Setup) -> str:
    """``scenario.duration=5.2 s at plant.dt=0.001 s`` — the derivation behind a bound."""
    exp = setup.experiment
    if getattr(exp, "data", None) is not None:
        return f"recorded data {exp.data!r}"
    return f"scenario.duration={exp.duration:g} s at plant.dt={exp.plant.dt:g} s"


def _check_burn_in(setup: Setup, n_points: int) -> None:
    """The monitor's burn-in against the estimator's output length (``n_points`` per run)."""
    monitor = setup.experiment.monitor
    burn_in = getattr(monitor, "burn_in", None)
    if burn_in is None:
        return
    # a window subgroup is n samples after the burn-in, every other monitor's point one sample; a run needs
    # two: the detector's Phase-I spread (sd{l} of eq. 27) of one point per run is NaN in the one-replication
    # dry run, and a chart of one point per run decides nothing over time
    size = int(getattr(monitor, "n", 1)) if getattr(monitor, "subgroup", "") == "window" else 1
    need = 2 * size
    if burn_in > n_points - need:
        unit = "subgroups" if size > 1 else "points"
        raise ConfigError(f"monitor.burn_in={burn_in} leaves fewer than 2 {unit} of a "
                          f"{n_points}-point run ({_run_length(setup)}); "
                          f"allowed: 0 <= monitor.burn_in <= {max(n_points - need, 0)}, or a longer run")


def _check_denoiser(setup: Setup, n_chart_points: int) -> None:
    """A whole-series wavelet's level against the chart's length (PyWavelets' ``dwt_max_level``)."""
    denoiser = getattr(setup.experiment.detector, "denoiser", None)
    min_length = getattr(denoiser, "min_length", None)
    if not min_length or getattr(denoiser, "window", None) is not None or n_chart_points >= min_length:
        return
    level = int(denoiser.level)
    filter_span = min_length // 2 ** level  # dec_len - 1
    max_level = int(math.floor(math.log2(n_chart_points / filter_span))) if n_chart_points >= filter_span else 0
    allowed = f"denoise.level <= {max_level}" if max_level >= 1 else "a longer run, or denoise=none"
    monitor = setup.experiment.monitor
    source = ", ".join(f"monitor.{k}={getattr(monitor, k)}" for k in ("burn_in", "n") if hasattr(monitor, k))
    raise ConfigError(f"denoise.level={level} needs at least {min_length} chart points per run for "
                      f"{denoiser.wavelet}; the run has {n_chart_points} ({_run_length(setup)}"
                      f"{', ' + source if source else ''}); allowed: {allowed}")


def _check_onset(setup: Setup, train) -> None:
    """The fault's onset against the chart's time grid: a run needs fault-free and faulty chart points.

    A chart point's fault state is that of its last sample (``t >= onset``), so
    both exist exactly when ``t[0] < onset <= t[-1]`` on the chart's grid (the
    points after ``monitor.burn_in``). Without a fault-free point the false-alarm
    rate is 0/0 (NaN), without a faulty one the missed-detection rate is.
    """
    mask, t = np.asarray(train.fault_mask, bool), np.asarray(train.t, float)
    healthy, faulty = (~mask).any(axis=-1).all(), mask.any(axis=-1).all()
    if healthy and faulty:
        return
    fault, monitor = setup.experiment.fault, setup.experiment.monitor
    # a fault set (one fault per replication) has no onset key of its own
    key = "fault.onset" if (getattr(type(fault), "params", None) or {}).get("onset") is not None else "the fault's onset"
    value = f"={getattr(fault, 'onset', float('nan')):g}" if key == "fault.onset" else ""
    source = ", ".join(f"monitor.{k}={getattr(monitor, k)}" for k in ("burn_in", "n") if hasattr(monitor, k))
    what = ("leaves no fault-free chart point: the first is at" if not healthy
            else "leaves no faulty chart point: the last is at")
    raise ConfigError(f"{key}{value} {what} t={t[0] if not healthy else t[-1]:g} s ({source}; "
                      f"{_run_length(setup)}); allowed: {t[0]:g} < {key} <= {t[-1]:g}")


def _check_memory(setup: Setup, bytes_per_run: int) -> None:
    """Each budget key against the machine's available memory (``psutil``), before any work.

    ``bytes_per_run`` is what one replication's simulated arrays take in the dry
    run; a budget of n replications holds at least n times that at once (the
    filter's internals and the chart come on top), so a key whose lower bound
    already exceeds the available memory can only end in a MemoryError.
    """
    available = available_memory()
    budget = setup.experiment.budget
    for key in ("n_test", "n_train", "n_calibration", "n_estimator"):
        n = int(getattr(budget, key, 0) or 0)
        if bytes_per_run and n * bytes_per_run > available:
            raise ConfigError(f"budget.{key}={n} needs at least {n * bytes_per_run / 2**30:.3g} GiB "
                              f"({bytes_per_run / 2**20:.3g} MiB per replication, {_run_length(setup)}); "
                              f"the machine has {available / 2**30:.3g} GiB available; "
                              f"allowed: budget.{key} <= {available // bytes_per_run}")


#: N x N arrays of 8 bytes that the kernel PCA's fit on N rows holds at once (scikit-learn's kernel matrix and the
#: eigensolver's copy, then the model's own kernel rows and their centred form): 4.0 times N^2 doubles, measured
#: with tracemalloc at N = 2000 and 4000 (mosd.detectors.kpca.KPCAModel)
KERNEL_FIT_ARRAYS = 4
#: N x p arrays of 8 bytes that scoring p rows against N fit rows holds at once (the kernel rows, their centred
#: form and a temporary): 3.0 measured at N = 1000, p = 8000
KERNEL_SCORE_ARRAYS = 3


def _kernel_bytes(n_fit: int, n_scored: int) -> int:
    return 8 * n_fit * max(KERNEL_FIT_ARRAYS * n_fit, KERNEL_SCORE_ARRAYS * n_scored)


def _largest_fit(available: int, n_scored: int) -> int:
    """The most fit rows whose kernel arrays (:func:`_kernel_bytes`) fit in ``available`` bytes."""
    by_fit = math.isqrt(max(available, 0) // (8 * KERNEL_FIT_ARRAYS))
    by_scoring = max(available, 0) // (8 * KERNEL_SCORE_ARRAYS * max(n_scored, 1))
    return int(min(by_fit, by_scoring))


def check_kernel_memory(setup: Setup, rows_per_fit_run: Sequence[int], n_scored: int) -> None:
    """A kernel-matrix detector's (``detector=kpca``) memory against the machine's, from the row counts, before any
    work.

    The kernel PCA fits on every complete row of its fit runs (N, ``sum(rows_per_fit_run)``) and holds
    :data:`KERNEL_FIT_ARRAYS` N x N arrays at once, and scores the largest set of runs (``n_scored`` rows) against
    them in one block (:data:`KERNEL_SCORE_ARRAYS` N x p arrays); 30,000 calibration rows need 27 GiB. Refused in
    one line naming the keys that lower N and the largest N that fits, instead of a MemoryError midway (the dry
    run's: "Unable to allocate 6.71 GiB", issue 53 item 8).
    """
    from ..detectors.kpca import KernelPCADetector

    detector = setup.experiment.detector
    if not isinstance(detector, KernelPCADetector):
        return
    n_fit = int(sum(rows_per_fit_run))
    need, available = _kernel_bytes(n_fit, n_scored), available_memory()
    if need <= available:
        return
    largest = _largest_fit(available, n_scored)
    ways = []
    cumulative = np.cumsum(np.asarray(rows_per_fit_run, int))
    runs_that_fit = int(np.searchsorted(cumulative, largest, side="right"))
    if len(rows_per_fit_run) > 1 and runs_that_fit >= 1:
        ways.append(f"detector.fit_runs={runs_that_fit} (the first calibration runs fit it, the rest set the limits)")
    data = getattr(setup.experiment, "data", None)
    if data is None and runs_that_fit >= 1:
        ways.append(f"budget.n_calibration <= {runs_that_fit}")
    elif data is None:
        ways.append("a shorter scenario.duration or a larger plant.dt")
    elif "splits" in inspect.signature(type(data)).parameters:  # a source with row ranges (data=table)
        ways.append(f"a data.splits.calibration of at most {largest} rows")
    ways.append("a detector without a kernel matrix (detector=pca)")
    raise ConfigError(f"detector=kpca fits its kernel matrix on {n_fit} calibration rows and scores {n_scored} rows "
                      f"against them ({_run_length(setup)}): about {need / 2**30:.3g} GiB at once, the machine has "
                      f"{available / 2**30:.3g} GiB available; allowed: at most {largest} fit rows: "
                      f"{', or '.join(ways)}")


def complete_rows(z: np.ndarray) -> np.ndarray:
    """Rows of each run of ``z`` (R, K, m) with every value finite: what a fit on them uses."""
    return np.all(np.isfinite(np.asarray(z, float)), axis=-1).sum(axis=-1)


def check_kernel_memory_of(setup: Setup, calibration_z: np.ndarray, scored_runs: Sequence[int],
                           n_fit_runs: int | None = None) -> None:
    """:func:`check_kernel_memory` from a calibration array (R, K, m) and the row counts of the sets scored at once.

    ``n_fit_runs``: calibration runs of the real run when ``calibration_z`` holds fewer (a simulated dry run's one
    replication stands for each of ``budget.n_calibration``, all of the same length).
    """
    detector = setup.experiment.detector
    fit = np.asarray(detector.fit_rows(calibration_z) if hasattr(detector, "fit_rows") else calibration_z, float)
    per_run = [int(n) for n in complete_rows(fit)]
    if n_fit_runs is not None and per_run:
        per_run = [per_run[0]] * int(n_fit_runs)
    check_kernel_memory(setup, per_run, max([int(n) for n in scored_runs] or [0]))


def available_memory() -> int:
    """Bytes of memory available to new work: ``MemAvailable`` of /proc/meminfo, else ``psutil``'s figure.

    The same number psutil reports on Linux, read without importing psutil (a tenth of a
    second of every run's startup on a loaded 2-core machine).
    """
    try:
        with open("/proc/meminfo", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    import psutil

    return int(psutil.virtual_memory().available)


def _nbytes(obj) -> int:
    """Bytes of the NumPy arrays an object (a Residuals, a Trace) holds as attributes."""
    fields = vars(obj) if hasattr(obj, "__dict__") else {f.name: getattr(obj, f.name) for f in dataclasses.fields(obj)}
    return sum(v.nbytes for v in fields.values() if isinstance(v, np.ndarray))


def _default_design(setup: Setup) -> np.ndarray:
    """One design inside the search box: the detector's own values where they fit, else the box middle."""
    detector = setup.experiment.detector
    row = []
    for name, interval in detector.tunable.items():
        low, high = setup.bounds.get(name, (interval.low, interval.high))
        value = getattr(detector, name, None)
        value = float(value) if isinstance(value, (int, float)) and low <= float(value) <= high else 0.5 * (low + high)
        row.append(float(interval.round(value)))
    return np.array([row], float)


def data_box(detector, calibration_z: np.ndarray) -> dict[str, tuple[float, float]]:
    """The search box the calibration points allow the detector (its ``data_bounds``), or {} for a detector without one.

    Each family states its own rules (:meth:`mosd.detectors.latent.LatentDetector.data_bounds`: λ's floor
    for the held-back runs, PCA/DPCA/ICA/KPCA/autoencoder components, CVA horizons and states, slow features).
    """
    declare = getattr(detector, "data_bounds", None)
    if declare is None:
        return {}
    return {name: (float(low), float(high)) for name, (low, high) in
            declare(np.asarray(detector.features(calibration_z), float)).items() if name in detector.tunable}


def narrow_to_data(setup: Setup, box: dict[str, tuple[float, float]] | None) -> None:
    """Narrow the optimiser's box to what the data allow (:func:`data_box`), except where ``detector.bounds`` names it.

    Where a parameter's declared range ends at another parameter (``n_components`` up to
    ``max_components``, ``lam`` above ``lam_min``), that parameter is moved, so that the detector's own
    ranges are the data's (the summary then calls the end "the largest value n_components allows", not
    a box to widen); any other end goes into ``setup.bounds``. The detector's own value of an integer
    parameter outside the box is moved to its nearest end (the table's 9 default components on 8 tags:
    7); a real one is refused. An explicit ``detector.bounds.X`` is the user's box and is not moved: where it
    leaves what the data allow it is refused here, naming the key (a family that would lower the value itself,
    SFA's slow features, would otherwise run another box than the user's); :func:`check_search_box` then
    evaluates its ends.
    """
    if not box:
        return
    from ..validation import Interval

    detector = setup.experiment.detector
    changes: dict = {}
    for name, (low, high) in box.items():
        if name not in detector.tunable:
            continue
        interval, declared = detector.tunable[name], type(detector).params[name].domain
        if interval.integer:
            low, high = math.ceil(low - 1e-9), math.floor(high + 1e-9)
        if name in setup.bounds:  # the user's box: refused where it leaves what the data allow
            allowed = Interval(max(low, interval.low), min(high, interval.high), interval.open_low and
                               low <= interval.low, interval.open_high and high >= interval.high, interval.integer)
            user_low, user_high = setup.bounds[name]
            outside = next((v for v in (user_low, user_high) if v not in allowed and not (
                v == allowed.low and allowed.open_low or v == allowed.high and allowed.open_high)), None)
            if outside is not None:
                raise ConfigError(f"detector.bounds.{name}=[{user_low:g}, {user_high:g}] reaches {name}={outside:g}, "
                                  f"which the calibration data cannot take; allowed: {allowed}")
            continue
        new_low, new_high = max(low, float(interval.low)), min(high, float(interval.high))
        if new_low > new_high or new_low == new_high and (interval.open_low or interval.open_high):
            allow = (f"at most {high:g}" if high < low or high < float(interval.low)
                     else f"only in [{low:g}, {high:g}]")
            raise ConfigError(f"the calibration data allow detector.{name} {allow}, outside its range {interval}; "
                              "allowed: more tags (a model with a residual space needs two or more), more (or "
                              "longer) calibration runs, fewer held back (detector.fit_runs), or a per-tag detector "
                              "(detector=tag_ewma, detector=tag_cusum)")
        if new_low == float(interval.low) and new_high == float(interval.high):
            continue
        for end, value, moved in (("low", new_low, new_low > interval.low),
                                  ("high", new_high, new_high < interval.high)):
            reference = getattr(declared, end)
            if moved and isinstance(reference, str):
                changes[reference] = int(value) if interval.integer else value
            elif moved:
                old = setup.bounds.get(name, (float(interval.low), float(interval.high)))
                setup.bounds[name] = (new_low, old[1]) if end == "low" else (old[0], new_high)
        value = getattr(detector, name)
        if not (new_low <= float(value) <= new_high) or interval.open_low and float(value) <= new_low:
            if not interval.integer:
                raise ConfigError(f"detector.{name}={value:g} is outside what the calibration data allow; allowed: "
                                  f"{'(' if interval.open_low else '['}{new_low:g}, {new_high:g}]")
            changes[name] = int(min(max(float(value), new_low), new_high))
    if changes:
        setup.experiment.detector = detector.with_params(**changes)


def search_box(setup: Setup) -> list[tuple[str, float, np.ndarray]]:
    """Designs that span the optimiser's box: each parameter at its low and its high end, the others at the default.

    Returns ``(parameter, value, design (1, d))``; the first is the default design
    (parameter ``""``). What :func:`check_search_box` evaluates: any design of the
    box takes each parameter's value somewhere between these.
    """
    detector = setup.experiment.detector
    base = _default_design(setup)
    designs = [("", math.nan, base)]
    for column, (name, interval) in enumerate(detector.tunable.items()):
        low, high = setup.bounds.get(name, (interval.low, interval.high))
        for end in (low, high):
            if not math.isfinite(end):
                continue
            value = float(interval.round(end)) if interval.integer else float(end)
            if interval.open_low and value <= interval.low or interval.open_high and value >= interval.high:
                continue  # an open end (alpha > 0) is approached, never evaluated
            design = base.copy()
            design[0, column] = value
            designs.append((name, value, design))
    return designs


def check_search_box(setup: Setup, evaluate: Callable[[np.ndarray], Any], source: str) -> None:
    """Evaluate every design of :func:`search_box`; the first the data or the plant cannot take is a ConfigError.

    One population first (one call); only when it fails, design by design to name
    the bound. ``source`` says what was run (``recorded data ...``, ``scenario...``).
    """
    designs = search_box(setup)
    try:
        evaluate(np.vstack([d for _, _, d in designs]))
        return
    except Exception:  # noqa: BLE001 - found again below, design by design, and named
        pass
    def fails(design) -> str | None:
        try:
            evaluate(design)
        except Exception as exc:  # noqa: BLE001 - any failure here would stop the optimisation midway
            return one_line(exc) if isinstance(exc, ConfigError) else f"{type(exc).__name__}: {one_line(exc)}"
        return None

    tunable = list(setup.experiment.detector.tunable)
    for name, value, design in designs:
        message = fails(design)
        if message is None:
            continue
        if not name:  # the default design: the parameter whose other end mends it is the one to blame
            culprit = next((n for n, _, d in designs[1:] if fails(d) is None), None)
            if culprit is None:
                raise ConfigError(f"the detector's design fails on a one-replication dry run ({source}): "
                                  f"{message}") from None
            name, value = culprit, float(design[0, tunable.index(culprit)])
        interval = setup.experiment.detector.tunable[name]
        low, high = setup.bounds.get(name, (interval.low, interval.high))
        box = (f"detector.bounds.{name}=[{low:g}, {high:g}]" if name in setup.bounds
               else f"detector.{name}'s range [{low:g}, {high:g}] (no detector.bounds.{name})")
        raise ConfigError(f"{box} reaches {name}={value:g}, which the optimiser would try and {source} cannot "
                          f"take: {message}") from None


def fit_to_data(setup: Setup) -> None:
    """:func:`narrow_to_data` for a job built without preflight (in a launcher's worker process, a system's script).

    Recorded data: their calibration split; a simulated system: one calibration replication, as the
    dry run's (a detector without ``data_bounds`` costs nothing).
    """
    exp = setup.experiment
    if not hasattr(exp.detector, "data_bounds"):
        return
    copied = copy.deepcopy(exp)
    if getattr(exp, "data", None) is not None:
        calibration = copied.prepare().phase1.z
    else:
        calibration = _simulated_calibration(copied)
        if calibration is None:
            return
    narrow_to_data(setup, data_box(copied.detector, calibration))


def _simulated_calibration(exp) -> np.ndarray | None:
    """The detector's calibration points of the dry run's simulated replications (:func:`_dry_calibration_runs`;
    None for an estimator trained first)."""
    from ..experiment import Budget, Experiment

    if getattr(exp.estimator, "requires_fit", False):
        return None
    mini = Experiment(exp.plant, exp.noise, exp.fault, exp.estimator, exp.monitor, exp.detector,
                      duration=exp.duration, budget=Budget(1, 1, 1, 1), seed=exp.seed, objectives=exp.objectives)
    calibration = mini.residuals(None, _dry_calibration_runs(exp), "calibration")
    mini.monitor.fit(calibration)
    return mini.prepare(calibration=calibration).phase1.z


def _dry_calibration_runs(exp) -> int:
    """Calibration replications a simulated dry run needs: one, or one past the detector's ``fit_runs``.

    A family that holds calibration runs back (``detector.fit_runs`` below ``budget.n_calibration``) bounds
    λ by the length of a held-back run (:meth:`mosd.detectors.latent.LatentDetector.lam_bounds`); with a
    single replication nothing is held back, so the dry run would miss the floor that the run then enforces
    midway, after its outputs exist. Simulated replications all have the same length, so one held-back
    replication gives the run's floor.
    """
    fit_runs = getattr(exp.detector, "fit_runs", None)
    if fit_runs is None or getattr(exp.detector, "data_bounds", None) is None:
        return 1
    return int(min(exp.budget.n_calibration, fit_runs + 1))
