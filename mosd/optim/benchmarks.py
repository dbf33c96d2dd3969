"""How good is the MOPSO? Normalised hypervolume on the ZDT, DTLZ, WFG, MW and CTP problems and OSY against its peers.

``python -m mosd.optim.benchmarks`` runs the suite of issue 21 and issue 33's constrained
problems against the peers in one invocation and prints the table with ratios and targets
(``--igd`` the IGD, ``--cpu`` the optimisers' own CPU per evaluation, ``--profile PROBLEM`` one
run's archive generation by generation); :func:`benchmark_table` returns the rows,
:func:`preset_table` does the same on the presets' own tuning problems, given their built
set-ups (``python -m mosd.app.tuning_benchmark`` composes them: Hydra lives above this layer).

Set-up (issue 21's protocol):

* problems (:data:`PROBLEMS`) — pymoo's ZDT1, ZDT2, ZDT3 (30 variables), ZDT4, ZDT6
  (10 variables); DTLZ1 (7 variables), DTLZ2, DTLZ3, DTLZ4 (12), DTLZ7 (22), all with
  3 objectives; WFG1, WFG2, WFG4 with 2 objectives, k = 4 position and l = 20 distance
  variables (Huband et al. 2006's set-up); OSY (6 variables, 6 constraints); MW1, MW2, MW3,
  MW7 (15 variables, 1–2 constraints) and CTP2, CTP3 (2 variables, 1 constraint), whose fronts
  are scanned through pymoo's evaluate (:func:`mw_front`, :func:`ctp_front`); optionally
  ``"zdt1_shifted"`` (:class:`ShiftedZDT1`, ZDT1 with its optimum moved into the box);
* budget — the same number of function evaluations for every algorithm: 50,000 on DTLZ1
  and DTLZ3, 10,000 elsewhere (:data:`N_EVAL`, as the issue's comparison);
  ``n_eval`` sets one budget for all; one run per seed, seeds 1–5, medians reported;
* quality — hypervolume of the final feasible non-dominated set after normalising each
  objective by the true front's ideal and nadir points, (f − ideal) / (nadir − ideal),
  with reference point 1.1 in every objective (:func:`mosd.metrics.hypervolume`). For ZDT1,
  ZDT2, ZDT4, ZDT6, DTLZ2–4 the front spans [0, 1] and this is the raw hypervolume with
  reference 1.1; ZDT3, DTLZ1, DTLZ7, WFG and OSY are rescaled. The fronts: pymoo's
  ``pareto_front()``, and for DTLZ7 and OSY (whose pymoo fronts are downloads) the
  analytical ones (:func:`dtlz7_front`, :func:`osy_front`), WFG4's too (:func:`wfg4_front`:
  pymoo's sample differs between processes). IGD against the same front is
  reported alongside;
* algorithms (:data:`ALGORITHMS`) — this package's :class:`~mosd.optim.mopso.MOPSO` with
  its defaults; the issue-14 default (:data:`ISSUE14_DEFAULT`, what ``MOPSO()`` was before
  issue 21) as the no-loss reference; when named, the first issue-21 default
  (:data:`EXPLORATION_DEFAULT`: the exploring move without archive offspring); pymoo's NSGA-II (100 individuals), NSGA-III (3
  objectives only: 91 Das–Dennis directions, 12 partitions, 92 individuals); jMetalPy's
  SMPSO (Nebro et al. 2009, swarm 100, crowding archive 100, polynomial mutation p = 1/n,
  η = 20) on the unconstrained problems. Paper 000's Table 2 preset and pymoo's MOPSO_CD
  run when named.

``docs/MOPSO.md`` has the measured tables.
"""
from __future__ import annotations

from __future__ import annotations

import argparse
import os
import sys
import time
import warnings
from typing import Callable

import numpy as np
from joblib import Parallel, delayed
from pymoo.core.problem import Problem
from pymoo.indicators.igd import IGD
from pymoo.optimize import minimize

from ..metrics import REFERENCE_VALUE
from ..validation import ConfigError, check_int
from .benchmark_algorithms import (ABLATIONS, ALGORITHMS, BEFORE_ISSUE33, BEFORE_ISSUE33_NAME, DEFAULT_NAME,
                                   EXPLORATION_DEFAULT, EXPLORATION_NAME, IGD_TARGETS, ISSUE14_DEFAULT, ISSUE14_NAME,
                                   MOPSO_CD_NAME, NSGA2_NAME, NSGA3_NAME, OPTIONAL, PAPER_NAME, PEERS, SMPSO_NAME,
                                   TARGETS, JMetalSMPSO, resolve_algorithms, runs_on, smpso_available)
from .benchmark_problems import (EXTRA_PROBLEMS, KNOWN_PROBLEMS, N_EVAL, PROBLEMS, REFERENCE_POINT, SEEDS, Benchmark,
                                 ShiftedZDT1, benchmark_of, ctp_front, dtlz7_front, make_problem, mw_front,
                                 normalisation, normalised_hypervolume, osy_front, scanned_front, wfg4_front)
from .benchmark_report import (best_peer, format_cpu, format_profile, format_ratios, format_table, format_targets,
                               target_rows)
from .mopso import MOPSO

#: the names this module has always offered (kept importable from here; most live in the modules above)
__all__ = ["ABLATIONS", "ALGORITHMS", "BEFORE_ISSUE33", "BEFORE_ISSUE33_NAME", "DEFAULT_NAME", "EXPLORATION_DEFAULT",
           "EXPLORATION_NAME", "IGD_TARGETS", "ISSUE14_DEFAULT", "ISSUE14_NAME", "MOPSO_CD_NAME", "NSGA2_NAME",
           "NSGA3_NAME", "OPTIONAL", "PAPER_NAME", "PEERS", "SMPSO_NAME", "TARGETS", "JMetalSMPSO", "runs_on",
           "smpso_available", "EXTRA_PROBLEMS", "KNOWN_PROBLEMS", "N_EVAL", "PROBLEMS", "REFERENCE_POINT", "SEEDS",
           "Benchmark", "ShiftedZDT1", "ctp_front", "dtlz7_front", "make_problem", "mw_front", "normalisation",
           "normalised_hypervolume", "osy_front", "scanned_front", "wfg4_front", "best_peer", "format_cpu",
           "format_profile", "format_ratios", "format_table", "format_targets", "target_rows", "TimedProblem",
           "benchmark_table", "preset_table", "generation_profile", "main"]


def benchmark_table(problems=tuple(PROBLEMS), algorithms=None, seeds=SEEDS, n_eval: int | None = None,
                    n_jobs: int = 2, progress: bool = False) -> list[dict]:
    """Median normalised hypervolume and IGD of each algorithm on each problem.

    Parameters
    ----------
    problems : sequence of str
        Names from :data:`KNOWN_PROBLEMS`.
    algorithms : None, sequence of str or dict
        Names from :data:`ALGORITHMS`, :data:`OPTIONAL` or :data:`ABLATIONS`, or a dict
        name → factory; None means :data:`ALGORITHMS` (SMPSO left out when jMetalPy is
        missing). An algorithm that does not run on a problem (:func:`runs_on`) has no row.
    seeds : sequence of int
        One run per seed, algorithm and problem.
    n_eval : int or None
        Function evaluations per run; None: each problem's own (:data:`PROBLEMS`).
    n_jobs : int
        joblib workers; one task per run.
    progress : bool
        A progress bar on stderr (tqdm).

    Returns
    -------
    list of dict
        One row per (problem, algorithm), problems outermost: ``problem`` (upper case),
        ``algorithm``, ``hv_median``, ``igd_median``, ``hv`` and ``igd`` (per seed, in
        seed order), ``n_eval``, ``reference_point`` (in normalised objectives),
        ``seconds_median`` (wall time), ``cpu_us`` and ``cpu_us_median`` (the optimiser's own
        process CPU per evaluation in µs: the run's CPU less the CPU spent in the problem's
        ``_evaluate``; jMetalPy's SMPSO includes its per-solution wrapper).
    """
    if n_eval is not None:
        n_eval = check_int("benchmark.n_eval", n_eval, 1)
    n_jobs = check_int("benchmark.n_jobs", n_jobs, -1)
    problems = tuple(problems)
    built = {name: make_problem(name) for name in problems}
    factories = resolve_algorithms(algorithms)
    seeds = tuple(int(seed) for seed in seeds)
    if not seeds:
        raise ConfigError("benchmark.seeds is empty; allowed: one or more integers")
    budget = {name: n_eval or benchmark_of(name).n_eval for name in problems}
    tasks = [(problem, name, seed) for problem in problems for name in factories for seed in seeds
             if runs_on(name, built[problem])]
    # the longest runs first, so that the workers finish together
    order = sorted(range(len(tasks)), key=lambda i: -budget[tasks[i][0]])
    jobs = (delayed(_run)(i, tasks[i][0], factories[tasks[i][1]], tasks[i][2], budget[tasks[i][0]]) for i in order)
    outcomes = [None] * len(tasks)
    stream = Parallel(n_jobs=n_jobs, return_as="generator_unordered")(jobs)
    for index, outcome in _progress(stream, len(tasks), progress):
        outcomes[index] = outcome
    rows = []
    for problem in problems:
        for name in factories:
            runs = [out for (p, a, _), out in zip(tasks, outcomes) if p == problem and a == name]
            if not runs:
                continue
            hv, igd, seconds, cpu_us = (np.array(values) for values in zip(*runs))
            rows.append({"problem": problem.upper(), "algorithm": name,
                         "hv_median": float(np.median(hv)), "igd_median": float(np.median(igd)),
                         "hv": hv.tolist(), "igd": igd.tolist(), "n_eval": budget[problem],
                         "reference_point": (REFERENCE_VALUE,) * built[problem].n_obj,
                         "seconds_median": float(np.median(seconds)), "cpu_us_median": float(np.median(cpu_us)),
                         "cpu_us": cpu_us.tolist()})
    return rows


def preset_table(setups, algorithms=(DEFAULT_NAME, ISSUE14_NAME), seeds=(1, 2, 3),
                 budget_scale: float = 1.0, n_jobs: int = 1, progress: bool = False) -> list[dict]:
    """Median normalised hypervolume of MOPSO variants on the presets' own tuning problems.

    ``setups`` maps a preset's name to its built set-up (what ``python -m mosd +experiment=NAME``
    builds: ``.experiment``, ``.bounds``, ``.n_gen``, ``.algorithm.pop_size``); the command that
    composes them is ``python -m mosd.app.tuning_benchmark`` (Hydra lives above this layer).
    For each, the training data are prepared once, and each algorithm minimises the objectives
    over the detector's parameters with the preset's swarm size and the preset's number of
    generations × ``budget_scale``, one run per seed. The objectives are normalised by the
    ideal and nadir points of all final archives of that preset (every algorithm and seed
    together), reference 1.1.

    Returns
    -------
    list of dict
        Rows as :func:`benchmark_table`'s, ``problem`` the preset's name in upper case,
        ``n_eval`` the evaluations per run; no IGD (the true fronts are unknown).
    """
    from pymoo.termination.max_gen import MaximumGenerationTermination

    from .problem import TuningProblem

    factories = resolve_algorithms(list(algorithms))
    rows = []
    for name, setup in setups.items():
        pop_size = int(getattr(setup.algorithm, "pop_size", 100))
        n_gen = max(2, int(round(setup.n_gen * budget_scale)))
        data = setup.experiment.prepare()
        problem = TuningProblem(setup.experiment.evaluator(data), bounds=setup.bounds, n_jobs=n_jobs)
        fronts = {}
        try:
            tasks = [(algorithm, seed) for algorithm in factories for seed in seeds]
            for algorithm, seed in _progress(iter(tasks), len(tasks), progress):
                instance = factories[algorithm]()
                instance.pop_size = pop_size
                start = time.perf_counter()
                result = minimize(problem, instance, MaximumGenerationTermination(n_gen), seed=seed)
                fronts[algorithm, seed] = (np.atleast_2d(result.F), time.perf_counter() - start)
        finally:
            problem.close()
        union = np.vstack([F for F, _ in fronts.values()])
        ideal, nadir = union.min(axis=0), union.max(axis=0)
        nadir = np.where(nadir > ideal, nadir, ideal + 1.0)
        for algorithm in factories:
            hv = np.array([normalised_hypervolume(fronts[algorithm, seed][0], ideal, nadir) for seed in seeds])
            seconds = [fronts[algorithm, seed][1] for seed in seeds]
            rows.append({"problem": name.upper(), "algorithm": algorithm, "hv_median": float(np.median(hv)),
                         "igd_median": float("nan"), "hv": hv.tolist(), "igd": [], "n_eval": pop_size * n_gen,
                         "reference_point": (REFERENCE_VALUE,) * union.shape[1],
                         "seconds_median": float(np.median(seconds))})
    return rows


def generation_profile(problem_name: str, algorithm: str = DEFAULT_NAME, seed: int = 1,
                       n_eval: int | None = None) -> list[dict]:
    """Per generation of one MOPSO run: what the archive holds and how many leaders and parents it gives.

    Rows: ``generation``, ``members`` (archive size), ``feasible`` (whether they are feasible),
    ``least_cv`` (the smallest constraint violation in the archive), ``feasible_evaluations``
    (of the generation), ``leaders`` and ``parents`` (distinct archive members among the
    particles' leaders and among the offspring's parents drawn for the generation). The table of
    docs/MOPSO.md's issue-33 section (MW1 before and after the infeasible-start rule).
    """
    from .archive import GridArchive

    factory = resolve_algorithms([algorithm])[algorithm]
    instance = factory()
    if not isinstance(instance, MOPSO):
        raise ConfigError(f"benchmark.profile algorithm={algorithm!r} is not allowed; allowed: a MOPSO variant")
    draws, rows = [], []

    class Recording(GridArchive):
        def select_leaders(self, n, random_state, rule="roulette"):
            chosen = super().select_leaders(n, random_state, rule)
            draws.append(len(np.unique(chosen)))
            return chosen

    def record(run):
        archive, CV = run.leader_archive, run.pop.get("CV").reshape(-1)
        leaders, parents = (draws + [None, None])[:2] if run.n_iter > 1 else (None, None)
        rows.append({"generation": run.n_iter, "members": len(archive), "feasible": archive.feasible,
                     "least_cv": float(archive.CV.min()), "feasible_evaluations": int((CV <= 0.0).sum()),
                     "leaders": leaders, "parents": parents if run._n_offspring() else None})
        draws.clear()

    instance.setup(make_problem(problem_name), termination=("n_eval", n_eval or benchmark_of(problem_name).n_eval),
                   seed=seed, callback=record)
    instance.leader_archive.__class__ = Recording  # the same archive, its leader draws counted
    instance.run()
    return rows


def _progress(stream, total: int, show: bool):
    if not show:
        yield from stream
        return
    from tqdm import tqdm

    with tqdm(total=total, unit="run", file=sys.stderr, dynamic_ncols=True) as bar:
        for item in stream:
            bar.update()
            yield item


def main(argv=None) -> int:
    """``python -m mosd.optim.benchmarks``: print the table, the ratios and issue 21's targets as Markdown."""
    parser = argparse.ArgumentParser(prog="python -m mosd.optim.benchmarks", description=__doc__.splitlines()[0])
    parser.add_argument("--problems", nargs="+", default=list(PROBLEMS), choices=KNOWN_PROBLEMS)
    parser.add_argument("--algorithms", nargs="+", default=None, metavar="NAME",
                        help=f"default: {', '.join(ALGORITHMS)}; also {', '.join(OPTIONAL)}")
    parser.add_argument("--seeds", type=int, default=len(SEEDS), help="seeds 1..N (default 5)")
    parser.add_argument("--n-eval", type=int, default=None,
                        help="evaluations per run for every problem (default: 50,000 on DTLZ1/DTLZ3, else 10,000)")
    parser.add_argument("--n-jobs", type=int, default=2, help="joblib workers (default 2)")
    parser.add_argument("--ablations", action="store_true", help="also the one-change variants of the default")
    parser.add_argument("--igd", action="store_true", help="also print median IGD")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")
    parser.add_argument("--cpu", action="store_true",
                        help="also print the optimisers' own CPU per evaluation (µs, beyond the problem's)")
    parser.add_argument("--profile", default=None, choices=KNOWN_PROBLEMS, metavar="PROBLEM",
                        help="instead: the per-generation archive profile of one run (seed 1) of each algorithm "
                             "(default: the default and the default before issue 33)")
    args = parser.parse_args(argv)
    if args.profile is not None:
        try:
            for name in args.algorithms or (DEFAULT_NAME, BEFORE_ISSUE33_NAME):
                print(f"{name}, {args.profile.upper()}, seed 1:\n")
                print(format_profile(generation_profile(args.profile, name, 1, args.n_eval)) + "\n")
        except ConfigError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
        return 0
    try:
        algorithms = dict(resolve_algorithms(args.algorithms))
        if args.ablations:
            algorithms.update(ABLATIONS)
        start = time.perf_counter()
        rows = benchmark_table(args.problems, algorithms, tuple(range(1, args.seeds + 1)), args.n_eval,
                               args.n_jobs, progress=not args.no_progress)
    except ConfigError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    seconds = time.perf_counter() - start
    budget = (f"{args.n_eval:,} evaluations per run" if args.n_eval else
              "10,000 evaluations per run (DTLZ1, DTLZ3: 50,000)")
    print(f"Median normalised hypervolume over seeds 1-{args.seeds}, {budget}, reference point 1.1 "
          f"in every normalised objective\n")
    print(format_table(rows, igd=args.igd))
    print()
    print(format_ratios(rows, references=[name for name in (*PEERS, ISSUE14_NAME) if name in algorithms]))
    if args.cpu:
        print()
        print(format_cpu(rows))
    if DEFAULT_NAME in algorithms:
        print()
        print(format_targets(rows))
    if args.algorithms is None and SMPSO_NAME not in algorithms:
        print("\nSMPSO left out: jMetalPy is not installed (pip install jmetalpy)")
    n_runs = sum(len(row["hv"]) for row in rows)
    load = " ".join(f"{value:.2f}" for value in os.getloadavg())
    print(f"\n{n_runs} runs in {seconds:.0f} s with n_jobs={args.n_jobs}; load average at the end {load}")
    return 0


def _run(index: int, problem_name: str, factory: Callable[[], object], seed: int, n_eval: int):
    problem = TimedProblem(make_problem(problem_name))
    ideal, nadir, front = normalisation(problem_name)
    algorithm = factory()
    start, start_cpu = time.perf_counter(), time.process_time()
    if hasattr(algorithm, "solve"):
        F = np.atleast_2d(algorithm.solve(problem, n_eval, seed))
    else:
        with warnings.catch_warnings():
            # pymoo's CTP constraint divides 0 by 0 at f1 = 0, g = 1 (NaN: infeasible, as intended)
            warnings.filterwarnings("ignore", "invalid value encountered in divide", RuntimeWarning)
            result = minimize(problem, algorithm, ("n_eval", n_eval), seed=seed)
        F = np.empty((0, problem.n_obj)) if result.F is None else np.atleast_2d(result.F)
        if problem.has_constraints() and len(F):
            F = F[np.atleast_2d(result.CV).reshape(-1) <= 0.0]
    seconds, cpu = time.perf_counter() - start, time.process_time() - start_cpu
    own_cpu_us = 1e6 * (cpu - problem.cpu_s) / n_eval
    igd = float(IGD(front)(F)) if len(F) else float("inf")
    return index, (normalised_hypervolume(F, ideal, nadir), igd, seconds, own_cpu_us)


class TimedProblem(Problem):
    """A benchmark problem whose evaluations are timed: the process CPU seconds inside it add up in :attr:`cpu_s`.

    The optimiser's own CPU per evaluation (``--cpu``) is a run's process CPU less :attr:`cpu_s`, divided by the
    evaluations: what the algorithm costs beyond the objective function. pymoo's ``evaluate`` of this problem
    (the same checks and conversions as the wrapped problem's, from the same settings) calls its public ``do``,
    which calls the wrapped problem's ``do`` — the objective function and pymoo's formatting of its output, the
    part timed — so the values, and every run, are the wrapped problem's.

    Parameters
    ----------
    problem : pymoo Problem
        Bounded and with a fixed number of variables, as every benchmark problem is.
    """

    def __init__(self, problem: Problem):
        super().__init__(n_var=problem.n_var, n_obj=problem.n_obj, n_ieq_constr=problem.n_ieq_constr,
                         n_eq_constr=problem.n_eq_constr, xl=problem.xl, xu=problem.xu, vtype=problem.vtype,
                         requires_kwargs=problem.requires_kwargs, replace_nan_values_by=problem.replace_nan_values_by,
                         strict=problem.strict)
        self.problem = problem
        self.cpu_s = 0.0

    def do(self, X, return_values_of, *args, **kwargs):
        start = time.process_time()
        try:
            return self.problem.do(X, return_values_of, *args, **kwargs)
        finally:
            self.cpu_s += time.process_time() - start


if __name__ == "__main__":
    # run the importable module's main, so that the joblib workers find its functions by name
    from mosd.optim.benchmarks import main as _main

    raise SystemExit(_main())
