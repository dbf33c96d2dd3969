"""The ``scale`` section of ``python -m mosd.bench``: where a tuning's time goes as workers are added.

One generation-heavy tuning per kind of evaluation path, each built as the command builds it
(Hydra composes the configuration here, in the layer that may load it):

* ``threads`` — the main command's chart (``+fault=offset_var optimizer=mopso``): the compiled
  fused evaluation, extra workers are threads of the run's process;
* ``paper001``, ``paper002`` — the presets' evaluators (IMM mode probabilities, the entropy
  filter's threshold detector): extra workers are loky processes;
* ``tep`` — the Tennessee Eastman PCA preset on recorded data (``pip install ".[te]"``; without
  the files the row says so);
* ``threads_n200`` — the main command with 20 times its training runs (``budget.n_train=200
  budget.n_calibration=50``, issue 32's larger workload): the same optimiser step against an
  evaluation 20 times longer, so its serial share is what a study with statistical power sees;
* ``paper002_n4000``, ``paper001_n2000`` — the process path at ten times the presets' training
  runs (issue 32's larger workloads), by name only (their simulation takes minutes on 2 cores).

Each runs the optimiser of its set-up for a fixed number of generations at n_jobs = 1, 2, 4, …
up to the machine's CPUs, then on a local Dask cluster of the largest n (the fastest of two
tunings on the same pool or cluster each). Per generation it
reports the wall time, the optimiser's own serial time (everything outside the evaluation:
archive, operators, selection; pymoo's bookkeeping), dispatch and gather (the evaluation's wall
time less a perfect split of its compute time: pipes, pickling, waiting on the slowest chunk) and
the evaluation itself (the compute time over n), and the compute time at n against n_jobs=1's for
the same candidates (``compute x``: how much the parts computed at once slowed each other down).
``serial share`` is the optimiser's part of one n_jobs=1 generation: Amdahl's serial fraction, the
bound 1/share on any speed-up. Every n must give the archive of n_jobs=1 bit for bit (``identical``).
For a MOPSO set-up, the optimiser's serial time with the compiled move (:mod:`mosd.kernels.swarm`) and
with the NumPy move, tunings of each alternated in one process (``scale_serial_move_ratio_<workload>``,
NumPy over compiled; the archives must be the same).

Before the workloads, the machine's own ceiling (:func:`machine_ceiling`): n copies of a loop that shares
nothing, started at the same instant, against one alone. A borrowed machine's "cores" may share physical cores
and power with each other and with its neighbours, so n of them at once do less than n times one's work; no
n-worker tuning can beat this ratio by much (its evaluation, unlike the loop, also shares memory bandwidth).

Then a sweep of 2 × CPUs jobs of the main command, one after the other and with the joblib
launcher running CPUs jobs at once (each job's thread pools pinned to its share of the cores).
"""
from __future__ import annotations

import copy
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

from ..timing import best_of

#: workload name -> (how the command builds it, what kind of evaluation path it exercises)
WORKLOADS = {
    "threads": ((), "+fault=offset_var optimizer=mopso: fused chart, threads"),
    "paper001": (("paper001",), "+experiment=paper001: IMM mode probabilities, processes"),
    "paper002": (("paper002",), "+experiment=paper002: entropy filter, processes"),
    "tep": (("tep",), "+experiment=tep: recorded TE data, PCA, processes"),
    "threads_n200": ((), "the main command at budget.n_train=200 budget.n_calibration=50 (issue 32's 20x budget)"),
    "paper002_n4000": (("paper002",), "+experiment=paper002 budget.n_train=4000 (issue 32's 10x budget), processes"),
    "paper001_n2000": (("paper001",), "+experiment=paper001 budget.n_train=2000 (issue 32's 10x budget), processes"),
}
#: the workloads ``--only scale`` runs (the 10x paper budgets take minutes to simulate on 2 cores: by name only,
#: ``bench_workload("paper002_n4000")``, as the 16-core measurement in docs/SCALING.md does)
DEFAULT_WORKLOADS = ("threads", "paper001", "paper002", "tep", "threads_n200")
#: overrides of a workload built from the main command (``threads_n200``: the evaluation per generation grows with
#: the training runs, the optimiser's own step does not, so its serial share falls: docs/SCALING.md)
OVERRIDES = {"threads_n200": ("budget.n_train=200", "budget.n_calibration=50"),
             "paper002_n4000": ("budget.n_train=4000",), "paper001_n2000": ("budget.n_train=2000",)}
#: generations timed per workload (the swarm is the set-up's own), and tunings per n_jobs of which the
#: fastest is reported (the one the rest of the machine disturbed least), on the same pool or cluster
N_GEN, N_GEN_QUICK = 10, 5
REPEATS, REPEATS_QUICK = 2, 1


def job_counts(cpus: int) -> list[int]:
    """1, 2, 4, … below ``cpus``, then ``cpus`` itself."""
    counts, n = [], 1
    while n < cpus:
        counts.append(n)
        n *= 2
    return counts + [max(1, cpus)]


#: the loop :func:`machine_ceiling` runs in each process: integer arithmetic in the interpreter, nothing shared but
#: the core; it sleeps until the wall-clock instant on its command line, so that every copy starts at once
_SPIN = ("import sys, time\n"
         "time.sleep(max(0.0, float(sys.argv[1]) - time.time()))\n"
         "t, s = time.perf_counter(), 0\n"
         "for i in range(int(sys.argv[2])):\n"
         "    s += i * i\n"
         "print(time.perf_counter() - t)\n")
#: iterations of that loop: 0.1-0.3 s alone on the machines measured so far
SPIN_LOOPS = 2_000_000


def _spin_at_once(n_processes: int, loops: int) -> list[float]:
    """Seconds each of ``n_processes`` copies of :data:`_SPIN` took, all started at one instant."""
    # (the interpreters start within this lead; -S: no site packages, a start of a few ms)
    start = time.time() + 0.15 + 0.01 * n_processes
    copies = [subprocess.Popen([sys.executable, "-S", "-c", _SPIN, repr(start), str(loops)],
                               stdout=subprocess.PIPE, text=True) for _ in range(n_processes)]
    return [float(copy_.communicate()[0]) for copy_ in copies]


def machine_ceiling(n_processes: int, repeats: int = 5, loops: int = SPIN_LOOPS) -> tuple[float, float, float]:
    """What ``n_processes`` workers can gain over one on this machine, whatever runs on them.

    ``n_processes`` copies of a loop that shares nothing (:data:`_SPIN`) start at one instant; a generation
    waits for its slowest part, so the ceiling is ``n_processes`` times one copy's time alone over the slowest
    copy's time among them. One copy alone and the copies at once are timed back to back, ``repeats`` times,
    and the median of those pairs' ratios is the ceiling: a shared machine's speed drifts by tens of percent
    within seconds, and a pair sees the same drift on both sides. Returns (ceiling, median seconds alone,
    median seconds of the slowest copy at once).
    """
    if n_processes < 1:
        raise ValueError(f"n_processes must be at least 1, got {n_processes}")
    alone, together = np.array([(_spin_at_once(1, loops)[0], max(_spin_at_once(n_processes, loops)))
                                for _ in range(max(1, repeats))]).T
    return float(np.median(n_processes * alone / together)), float(np.median(alone)), float(np.median(together))


def bench_machine(quick: bool = False, cpus: int | None = None) -> tuple[list, dict]:
    """Rows and ``scale_machine_ceiling_<n>`` for every n of :func:`job_counts` above 1."""
    cpus = cpus or os.cpu_count() or 1
    rows, figures = [], {}
    for n in job_counts(cpus)[1:]:
        ceiling, alone, together = machine_ceiling(n, repeats=3 if quick else 5)
        figures[f"scale_machine_ceiling_{n}"] = ceiling
        rows.append((f"the machine: {n} processes of a loop that shares nothing at once vs one", ceiling,
                     f"medians: one alone {1e3 * alone:.0f} ms, the slowest of {n} at once {1e3 * together:.0f} ms; "
                     f"about the most a tuning on {n} workers can gain here"))
    return rows, figures


def load_average() -> float:
    return os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")


def build_setup(preset: tuple[str, ...], overrides: tuple[str, ...] = ()):
    """The built set-up of ``python -m mosd +fault=offset_var optimizer=mopso [OVERRIDES]`` or of ``+experiment=NAME``."""
    from .presets import preset_setup

    if preset:
        return preset_setup(preset[0], overrides)
    from hydra import compose, initialize_config_dir

    from .build import build
    from .config import CONFIG_DIR, CONFIG_NAME

    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3", job_name="mosd"):
        cfg = compose(CONFIG_NAME, overrides=["+fault=offset_var", "optimizer=mopso", "tracking=none", *overrides])
    return build(cfg)


def time_tuning(setup, evaluator, n_jobs: int, n_gen: int, backend: str = "loky", repeats: int = 1) -> dict:
    """The fastest of ``repeats`` tunings of ``n_gen`` generations on ``n_jobs`` workers, its wall time split as
    the module says; ``start_s`` is the first population's (pools, clusters and compiled kernels start there)."""
    from pymoo.optimize import minimize

    from ..optim.problem import EvaluationClock, TuningProblem

    problem = TuningProblem(evaluator, bounds=setup.bounds, n_jobs=n_jobs, backend=backend)
    best = None
    try:
        rng = np.random.default_rng(0)
        warm = rng.uniform(problem.xl, problem.xu, size=(max(2, 2 * n_jobs), problem.n_var))
        t0 = time.perf_counter()
        problem.evaluate_population(problem.round(warm))
        start_s = time.perf_counter() - t0
        for _ in range(max(1, repeats)):
            problem.clock = EvaluationClock()
            algorithm = copy.deepcopy(setup.algorithm)
            t0 = time.perf_counter()
            result = minimize(problem, algorithm, ("n_gen", n_gen), seed=setup.experiment.seed)
            wall = time.perf_counter() - t0
            if best is None or wall < best[0]:
                best = (wall, problem.clock, result)
    finally:
        problem.close()
    wall, clock, result = best
    generations = max(1, clock.calls)
    evaluation = clock.compute_s / n_jobs
    return {"n_jobs": n_jobs, "backend": backend, "generations": generations, "wall_s": wall, "start_s": start_s,
            "wall_per_gen_s": wall / generations, "serial_per_gen_s": (wall - clock.wall_s) / generations,
            "dispatch_per_gen_s": max(0.0, clock.wall_s - evaluation) / generations,
            "evaluation_per_gen_s": evaluation / generations, "candidates": clock.candidates,
            "split": clock.split,
            "X": np.atleast_2d(result.X), "F": np.atleast_2d(result.F)}


def thread_ceiling(setup, evaluator, n_threads: int, repeats: int = 15) -> float | None:
    """The speed-up of the bare evaluation on ``n_threads`` threads: what the machine gives, before any optimiser.

    One population of the set-up's size (uniform in the box, seed 0) is evaluated whole on one
    thread, then cut into at most ``n_threads`` parts, none shorter than the kernel's lanes (as the tuning
    cuts it), evaluated at once, one per thread (this one and the tuning's own pool threads, already started),
    with nothing between them: no optimiser step. Fastest of ``repeats`` each. The ratio is
    the most a threaded tuning of this workload can reach on this machine (cores shared with
    another hardware thread, memory bandwidth and clock boost all enter it); None when the
    workload does not evaluate on threads.
    """
    from ..optim.problem import TuningProblem, _thread_pool, dealt, thread_slices

    problem = TuningProblem(evaluator, bounds=setup.bounds, n_jobs=max(2, n_threads))
    try:
        if not problem.in_threads:
            return None
        fused = evaluator.fused()
        pop = int(getattr(setup.algorithm, "pop_size", 100) or 100)
        X = problem.round(np.random.default_rng(0).uniform(problem.xl, problem.xu, size=(pop, problem.n_var)))
        # cut as the tuning cuts a population (TuningProblem._evaluate_in_threads): dealt, then sliced
        edges = thread_slices(fused, X.shape[0], n_threads)
        dealt_X = X[dealt(X.shape[0], len(edges) - 1)]
        parts = [dealt_X[start:stop] for start, stop in zip(edges[:-1], edges[1:])]
        fused(X)  # compiled kernels loaded

        pool = _thread_pool(n_threads - 1)

        def together():
            helpers = [pool.submit(fused, part) for part in parts[1:]]
            fused(parts[0])
            for helper in helpers:
                helper.result()

        return best_of(lambda: fused(X), repeats) / best_of(together, repeats)
    finally:
        problem.close()


def bench_workload(name: str, quick: bool = False, cpus: int | None = None) -> tuple[list, dict]:
    """Rows and JSON figures of one workload at every n_jobs and on Dask at the largest."""
    import importlib.util

    preset, what = WORKLOADS[name]
    if name == "tep":
        from ..data.tep import bibmon_directory

        if bibmon_directory() is None:
            return [(f"{name}: skipped, the TE files need pip install \".[te]\"", float("nan"), what)], {}
    cpus = cpus or os.cpu_count() or 1
    n_gen = N_GEN_QUICK if quick else N_GEN
    repeats = REPEATS_QUICK if quick else REPEATS
    load_before = load_average()
    setup = build_setup(preset, OVERRIDES.get(name, ()))
    prepare_s = {}
    # the training runs simulated on every CPU (the same data for any n_jobs); for the presets' budgets, which
    # cost seconds, first once on every CPU unreported (the first simulation loads the compiled kernels and
    # warms the caches), then on one and on every CPU (the 10x budgets by name would cost minutes on one)
    if name in DEFAULT_WORKLOADS and cpus > 1:
        setup.experiment.prepare(n_jobs=cpus)
    for n_jobs in ([1] if name in DEFAULT_WORKLOADS and cpus > 1 else []) + [cpus]:
        t0 = time.perf_counter()
        data = setup.experiment.prepare(n_jobs=n_jobs)
        prepare_s[n_jobs] = time.perf_counter() - t0
    evaluator = setup.experiment.evaluator(data)
    _load_the_move(setup.algorithm)
    runs = [time_tuning(setup, evaluator, n, n_gen, repeats=repeats) for n in job_counts(cpus)]
    if importlib.util.find_spec("distributed") is not None:
        runs.append(time_tuning(setup, evaluator, runs[-1]["n_jobs"], n_gen, backend="dask", repeats=repeats))
    one = runs[0]
    pop = getattr(setup.algorithm, "pop_size", "?")
    rows = [(f"{name}: prepare (simulate/estimate the training runs) on n_jobs={n_jobs}, s", seconds,
             f"{what}; {pop} x {n_gen} generations timed, fastest of {repeats}" if n_jobs == cpus else "")
            for n_jobs, seconds in sorted(prepare_s.items())]
    if len(prepare_s) > 1:
        rows.append((f"{name}: prepare speed-up n_jobs={cpus} vs 1", prepare_s[1] / prepare_s[cpus], ""))
    figures: dict = {f"scale_prepare_s_{name}_{n}": seconds for n, seconds in prepare_s.items()}
    serial_share = one["serial_per_gen_s"] / one["wall_per_gen_s"]
    for run in runs:
        speedup = one["wall_s"] / run["wall_s"]
        identical = bool(np.array_equal(run["X"], one["X"]) and np.array_equal(run["F"], one["F"]))
        label = f"{name}: n_jobs={run['n_jobs']}" + (" dask" if run["backend"] == "dask" else "")
        share = run["serial_per_gen_s"] / run["wall_per_gen_s"]
        # the same candidates (identical archives) computed in parts at once against in one process: above 1, the
        # parts slowed each other down (shared cores, caches, memory bandwidth), which no dispatch can remove
        inflation = run["evaluation_per_gen_s"] * run["n_jobs"] / max(one["evaluation_per_gen_s"], 1e-12)
        note = (f"wall/gen {1e3 * run['wall_per_gen_s']:.2f} ms = serial {1e3 * run['serial_per_gen_s']:.2f} "
                f"+ dispatch/gather {1e3 * run['dispatch_per_gen_s']:.2f} + evaluation "
                f"{1e3 * run['evaluation_per_gen_s']:.2f} ms; compute x{inflation:.2f} of one worker's; "
                f"serial share {share:.1%}; efficiency "
                f"{speedup / run['n_jobs']:.0%}; identical {int(identical)}; start {run['start_s']:.2f} s; "
                f"split {run['split']} of {run['generations']} populations")
        rows.append((f"{label} speed-up vs n_jobs=1", speedup, note))
        if run["backend"] == "dask":
            loky = next(r for r in runs if r["n_jobs"] == run["n_jobs"] and r["backend"] == "loky")
            figures[f"scale_dask_vs_loky_{name}"] = loky["wall_s"] / run["wall_s"]
            figures[f"scale_dask_speedup_{name}_{run['n_jobs']}"] = speedup
            figures[f"scale_dask_start_s_{name}"] = run["start_s"]
        else:
            figures[f"scale_speedup_{name}_{run['n_jobs']}"] = speedup
            if run["n_jobs"] > 1:
                figures[f"scale_compute_inflation_{name}_{run['n_jobs']}"] = inflation
        figures[f"scale_identical_{name}"] = int(identical and figures.get(f"scale_identical_{name}", 1))
    figures[f"scale_serial_share_{name}"] = serial_share
    for n_threads in (sorted({2, cpus}) if cpus > 1 else []):
        ceiling = thread_ceiling(setup, evaluator, n_threads, repeats=5 if quick else 15)
        if ceiling is None:
            break
        figures[f"scale_thread_ceiling_{name}_{n_threads}"] = ceiling
        rows.append((f"{name}: the bare evaluation on {n_threads} threads vs 1 (the machine's ceiling)", ceiling,
                     f"one population in {n_threads} parts at once, no optimiser: the most a "
                     f"{n_threads}-worker tuning of this workload can reach here"))
    move = compiled_move_side_by_side(setup, evaluator, n_gen, rounds=2 if quick else 4)
    if move is not None:
        compiled, numpy_move, compared = move
        figures[f"scale_serial_move_ratio_{name}"] = numpy_move / compiled
        rows.append((f"{name}: optimiser's serial time per generation, NumPy move vs compiled move",
                     numpy_move / compiled,
                     f"n_jobs=1, medians of alternated tunings: {1e3 * numpy_move:.2f} ms with the NumPy move, "
                     f"{1e3 * compiled:.2f} ms with mosd.kernels.swarm "
                     + ("(same archives)" if compared else "(archives not compared: NumPy's power is not the C "
                                                           "library's pow here)")))
    figures[f"scale_wall_per_gen_ms_{name}_1"] = 1e3 * one["wall_per_gen_s"]
    rows.append((f"{name}: serial share of an n_jobs=1 generation", serial_share,
                 f"first {n_gen} generations; Amdahl's bound on the speed-up 1/share = "
                 f"{1 / max(serial_share, 1e-12):.0f}; load average {load_before:.2f} -> {load_average():.2f}"))
    budget = int(getattr(setup, "n_gen", 0) or 0)
    if not quick and budget > n_gen:
        # the set-up's own run length: the archive fills and its truncation starts after the first generations, and
        # minimize's set-up is shared by more of them
        whole = time_tuning(setup, evaluator, 1, budget)
        share = whole["serial_per_gen_s"] / whole["wall_per_gen_s"]
        figures[f"scale_serial_share_budget_{name}"] = share
        rows.append((f"{name}: serial share of an n_jobs=1 generation over the set-up's {budget} generations", share,
                     f"wall/gen {1e3 * whole['wall_per_gen_s']:.2f} ms = serial {1e3 * whole['serial_per_gen_s']:.2f}"
                     f" ms + evaluation; one tuning; load average {load_average():.2f}"))
    return rows, figures


def _load_the_move(algorithm) -> None:
    """Load a MOPSO's compiled move before the timed tunings (as their first population loads the evaluation's
    kernels untimed): otherwise the first tuning's serial time holds its 17-27 ms load, all of it with --quick."""
    from .. import kernels
    from ..optim.mopso import MOPSO

    if isinstance(algorithm, MOPSO) and kernels.enabled():
        from ..kernels import swarm

        swarm.warm_up()


def compiled_move_side_by_side(setup, evaluator, n_gen: int, rounds: int = 4) -> tuple[float, float, bool] | None:
    """The optimiser's serial seconds per n_jobs=1 generation with the compiled MOPSO move and with the NumPy
    move (:meth:`mosd.optim.mopso.MOPSO._compiled_move` declined), medians of ``rounds`` tunings of each,
    alternated in this process, and whether their archives were compared (and found the same): only where
    NumPy's ``power`` is the C library's (:func:`mosd.kernels.swarm.matches_numpy`; with AVX-512 NumPy may round
    some powers to the neighbouring float, and the two moves' archives part). None when the set-up's algorithm
    does not use the compiled move."""
    from unittest import mock

    from .. import kernels
    from ..optim.mopso import MOPSO

    algorithm = setup.algorithm
    if not (isinstance(algorithm, MOPSO) and kernels.enabled()):
        return None
    times: dict = {True: [], False: []}
    results = {}
    for _ in range(rounds):
        for compiled in (True, False):
            if compiled:
                run = time_tuning(setup, evaluator, 1, n_gen)
            else:
                with mock.patch.object(MOPSO, "_compiled_move", lambda self: None):
                    run = time_tuning(setup, evaluator, 1, n_gen)
            times[compiled].append(run["serial_per_gen_s"])
            results[compiled] = (run["X"], run["F"])
    from ..kernels import swarm

    compared = swarm.matches_numpy()
    if compared and not all(np.array_equal(a, b) for a, b in zip(results[True], results[False])):
        raise RuntimeError("the compiled MOPSO move gave another archive than the NumPy move")
    return float(np.median(times[True])), float(np.median(times[False])), compared


def sweep_wall(n_jobs: int, launcher_jobs: int | None, quick: bool = False) -> tuple[float, float]:
    """Wall seconds of a sweep of ``n_jobs`` main-command jobs (``launcher_jobs`` None: one after the other), and
    the seconds from the command's start to its first job's (the first line of the earliest job's ``mosd.log``):
    the checks, Hydra's launch and the workers' start, which no job overlaps."""
    import datetime
    from pathlib import Path

    seeds = ",".join(str(s) for s in range(1, max(1, n_jobs // 2) + 1))
    args = ["-m", "+fault=offset,variance", f"seed={seeds}", "optimizer=mopso", "tracking=none", "progress=false"]
    if quick:
        args += ["optimizer.n_gen=10", "budget.n_test=10"]
    if launcher_jobs is not None:
        args += ["hydra/launcher=joblib", f"hydra.launcher.n_jobs={launcher_jobs}"]
    with tempfile.TemporaryDirectory(prefix="mosd-scale-") as outputs:
        env = dict(os.environ, MOSD_OUTPUTS=outputs)
        started = datetime.datetime.now()
        t0 = time.perf_counter()
        done = subprocess.run([sys.executable, "-m", "mosd", *args], env=env, capture_output=True, text=True)
        wall = time.perf_counter() - t0
        starts = []
        for log in Path(outputs).rglob("mosd.log"):
            first = log.read_text().split("]", 1)[0].lstrip("[")  # Hydra's "[2026-11-27 13:37:04,167][..."
            try:
                starts.append(datetime.datetime.strptime(first, "%Y-%m-%d %H:%M:%S,%f"))
            except ValueError:
                pass
    if done.returncode != 0:
        raise RuntimeError(f"python -m mosd {' '.join(args)} failed: {done.stderr.strip()[-500:]}")
    first_job = (min(starts) - started).total_seconds() if starts else float("nan")
    return wall, first_job


def bench_sweep(quick: bool = False, cpus: int | None = None) -> tuple[list, dict]:
    cpus = cpus or os.cpu_count() or 1
    n_jobs = 2 * cpus
    load_before = load_average()
    one_by_one, _ = sweep_wall(n_jobs, None, quick)
    parallel, first_job = sweep_wall(n_jobs, cpus, quick)
    note = f"load average {load_before:.2f} -> {load_average():.2f}"
    rows = [(f"sweep of {n_jobs} main-command jobs one after the other, s", one_by_one,
             "+fault=offset,variance seed=1.." + str(max(1, n_jobs // 2))),
            (f"the same sweep, hydra/launcher=joblib hydra.launcher.n_jobs={cpus}, s", parallel,
             "each job pinned to its share of the cores"),
            ("  of which before its first job started, s", first_job,
             "preflight's checks of every job, Hydra's launch, the workers' start"),
            ("sweep speed-up joblib launcher vs one after the other", one_by_one / parallel, note)]
    # no job log found: first_job is NaN, which the row shows and --json leaves out (mosd.bench.json_metrics)
    return rows, {"scale_sweep_speedup": one_by_one / parallel, "scale_sweep_serial_s": one_by_one,
                  "scale_sweep_parallel_s": parallel, "scale_sweep_first_job_s": first_job}


def workload_in_own_process(name: str, quick: bool = False) -> tuple[list, dict]:
    """:func:`bench_workload` in a fresh interpreter, as a run of that workload has it.

    One process for every workload made the later ones' figures depend on the earlier ones: glibc's malloc
    raises its thresholds for returning memory to the kernel after large frees, so after the main command's
    workload paper 001's evaluation took 8 ms a population in this process against 18-19 ms in a fresh one
    (its temporaries, tens of MB, were then no longer mapped and unmapped at each call), and its 2-worker
    speed-up compared a fresh worker with that faster process (docs/SCALING.md, "Each workload of the scale
    section in its own process; the allocator").
    """
    import json

    code = ("import json, sys; from mosd.app.scale_bench import bench_workload; "
            "rows, figures = bench_workload(sys.argv[1], quick=sys.argv[2] == '1'); "
            "print(json.dumps({'rows': rows, 'figures': figures}))")
    done = subprocess.run([sys.executable, "-c", code, name, "1" if quick else "0"], capture_output=True, text=True)
    if done.returncode != 0:
        raise RuntimeError(f"the scale workload {name} failed: {done.stderr.strip()[-500:]}")
    found = json.loads(done.stdout.strip().splitlines()[-1])
    return [tuple(row) for row in found["rows"]], found["figures"]


def bench_scale(quick: bool = False) -> tuple[list, dict]:
    """Every workload of :data:`WORKLOADS`, each in its own process, then the sweep; the load average beside them."""
    rows: list = [("load average (1 min) at the start", load_average(), f"{os.cpu_count()} CPUs")]
    more, figures = bench_machine(quick)
    rows += more
    for name in DEFAULT_WORKLOADS:
        more, found = workload_in_own_process(name, quick)
        rows += more
        figures.update(found)
    more, found = bench_sweep(quick)
    rows += more
    figures.update(found)
    figures["scale_load_average_1min"] = load_average()
    rows.append(("load average (1 min) at the end", figures["scale_load_average_1min"], ""))
    return rows, figures
