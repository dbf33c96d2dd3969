"""How good is the MOPSO? Median hypervolume on ZDT1–4, ZDT6 and DTLZ2 against other optimisers.

``python -m mosd.optim.benchmarks`` prints the table; :func:`benchmark_table` returns it.

Set-up (the issue's protocol):

* problems — pymoo's ZDT1, ZDT2, ZDT3 (30 variables), ZDT4, ZDT6 (10 variables) and
  DTLZ2 with 3 objectives and 12 variables; optionally ``"zdt1_shifted"``
  (:class:`ShiftedZDT1`, ZDT1 with its optimum moved from the bound into the box);
* budget — the same number of function evaluations for everyone, 10,000 by default
  (100 particles / individuals × 100 generations), DTLZ2 included; one run per seed,
  seeds 1–5, medians reported;
* quality — hypervolume of the final non-dominated set with reference point
  (1.1, 1.1) for ZDT and (1.1, 1.1, 1.1) for DTLZ2 (the true fronts score
  ZDT1/ZDT4 0.876, ZDT2 0.543, ZDT3 1.332, ZDT6 0.508, DTLZ2 1.331 − π/6 = 0.807);
  IGD against pymoo's ``pareto_front()`` is reported alongside;
* algorithms (:data:`ALGORITHMS`) — this package's :class:`~mosd.optim.mopso.MOPSO`
  with its defaults and with paper 000's Table 2 (:data:`~mosd.optim.mopso.PAPER_PRESET`),
  pymoo's NSGA-II and MOPSO_CD (archive 100, like the others), and jMetalPy's SMPSO
  (Nebro et al. 2009, swarm 100, crowding archive 100, polynomial mutation
  p = 1/n, η = 20: jMetalPy's standard set-up) when jMetalPy is installed.

The ZDT optima (and ZDT4's, ZDT6's) lie on the lower bound of x2…xn, so the rule for
particles that leave the box (:func:`mosd.optim.mopso.apply_bounds`) decides much of a
PSO's score there; ``"zdt1_shifted"`` and DTLZ2, whose optima lie inside the box, tell
search ability from boundary effects. ``docs/MOPSO.md`` has the measured tables.
"""
from __future__ import annotations

import argparse
import logging
import time
from typing import Callable

import numpy as np
from joblib import Parallel, delayed
from pymoo.algorithms.moo.mopso_cd import MOPSO_CD
from pymoo.algorithms.moo.nsga2 import NSGA2
from pymoo.core.problem import Problem
from pymoo.indicators.hv import HV
from pymoo.indicators.igd import IGD
from pymoo.optimize import minimize
from pymoo.problems import get_problem

from ..validation import ConfigError, Interval, check_in, check_int
from .mopso import MOPSO, PAPER_PRESET


class ShiftedZDT1(Problem):
    """ZDT1 with the optimum of x2…xn moved from the bound 0 to ``shift`` inside [0, 1].

    g = 1 + 9 · mean(|x_i − shift| / max(shift, 1 − shift)), i ≥ 2; f1 = x1,
    f2 = g (1 − √(f1 / g)). The Pareto front is ZDT1's (g = 1).
    """

    def __init__(self, n_var: int = 30, shift: float = 0.35):
        self.shift = check_in("benchmark.shift", shift, Interval(0.0, 1.0, open_low=True, open_high=True))
        super().__init__(n_var=check_int("benchmark.n_var", n_var, 2), n_obj=2, xl=0.0, xu=1.0)

    def _evaluate(self, X, out, *args, **kwargs):
        distance = np.abs(X[:, 1:] - self.shift) / max(self.shift, 1.0 - self.shift)
        g = 1.0 + 9.0 * distance.mean(axis=1)
        out["F"] = np.column_stack([X[:, 0], g * (1.0 - np.sqrt(X[:, 0] / g))])

    def _calc_pareto_front(self, n_points: int = 100):
        return get_problem("zdt1").pareto_front(n_points)


#: The issue's problems; ``"zdt1_shifted"`` may be added (:class:`ShiftedZDT1`).
PROBLEMS = ("zdt1", "zdt2", "zdt3", "zdt4", "zdt6", "dtlz2")
KNOWN_PROBLEMS = (*PROBLEMS, "zdt1_shifted")
#: Function evaluations per run, every problem (DTLZ2 included).
N_EVAL = 10_000
SEEDS = (1, 2, 3, 4, 5)
#: Hypervolume reference: 1.1 in every objective (ZDT: (1.1, 1.1); DTLZ2: (1.1, 1.1, 1.1)).
REFERENCE_VALUE = 1.1
#: Kept for callers of the two-objective table.
REFERENCE_POINT = (REFERENCE_VALUE, REFERENCE_VALUE)

SMPSO_NAME = "SMPSO (jMetalPy)"
NSGA2_NAME = "NSGA-II (pymoo)"
DEFAULT_NAME = "MOPSO (default)"
PAPER_NAME = "MOPSO paper (Table 2)"


def make_problem(name: str) -> Problem:
    """A benchmark problem by name (:data:`KNOWN_PROBLEMS`)."""
    if name not in KNOWN_PROBLEMS:
        raise ConfigError(f"benchmark.problems={name!r} is not allowed; allowed: {', '.join(KNOWN_PROBLEMS)}")
    if name == "zdt1_shifted":
        return ShiftedZDT1()
    if name == "dtlz2":
        return get_problem("dtlz2", n_var=12, n_obj=3)
    return get_problem(name)


class JMetalSMPSO:
    """jMetalPy's SMPSO on a pymoo problem, with the budget and seed of the other runs.

    jMetalPy draws from Python's ``random`` and NumPy's global generator; both are
    seeded before each run (each run is one joblib task, so runs do not share them).
    The swarm is evaluated as one batch through the pymoo problem, so both libraries
    see the same objective function.
    """

    def __init__(self, swarm_size: int = 100, archive_size: int = 100):
        self.swarm_size = swarm_size
        self.archive_size = archive_size

    def solve(self, problem: Problem, n_eval: int, seed: int) -> np.ndarray:
        """Final archive's objective values, shape (n, n_obj)."""
        import random

        from jmetal.algorithm.multiobjective.smpso import SMPSO
        from jmetal.operator.mutation import PolynomialMutation
        from jmetal.util.archive import CrowdingDistanceArchive
        from jmetal.util.termination_criterion import StoppingByEvaluations

        logging.getLogger("jmetal").setLevel(logging.WARNING)
        random.seed(seed)
        np.random.seed(seed)
        wrapped = _jmetal_problem(problem)
        algorithm = SMPSO(problem=wrapped, swarm_size=self.swarm_size,
                          mutation=PolynomialMutation(probability=1.0 / problem.n_var, distribution_index=20.0),
                          leaders=CrowdingDistanceArchive(self.archive_size),
                          termination_criterion=StoppingByEvaluations(max_evaluations=n_eval),
                          swarm_evaluator=_BatchEvaluator(problem))
        algorithm.run()
        return np.array([solution.objectives for solution in algorithm.result()], dtype=float)


def smpso_available() -> bool:
    """Whether jMetalPy can be imported."""
    try:
        import jmetal.algorithm.multiobjective.smpso  # noqa: F401
    except ImportError:
        return False
    return True


#: The comparison of the issue: name → factory of a fresh algorithm (100 particles / individuals).
#: MOPSO_CD gets archive_size=100 like the others (its own default is 200).
ALGORITHMS: dict[str, Callable[[], object]] = {
    DEFAULT_NAME: lambda: MOPSO(),
    PAPER_NAME: lambda: MOPSO(**PAPER_PRESET),
    NSGA2_NAME: lambda: NSGA2(pop_size=100),
    SMPSO_NAME: lambda: JMetalSMPSO(),
    "MOPSO_CD (pymoo)": lambda: MOPSO_CD(pop_size=100, archive_size=100),
}

#: One change at a time from the default (or from the paper preset), for docs/MOPSO.md.
ABLATIONS: dict[str, Callable[[], object]] = {
    "default, boundary=reflect": lambda: MOPSO(boundary="reflect"),
    "default, boundary=absorb": lambda: MOPSO(boundary="absorb"),
    "default, velocity=constriction": lambda: MOPSO(velocity="constriction"),
    "default, velocity=inertia": lambda: MOPSO(velocity="inertia"),
    "default, constant w=0.4, c1=1, c2=1.5": lambda: MOPSO(w=0.4, c1=1.0, c2=1.5),
    "default, max_velocity=0.5": lambda: MOPSO(max_velocity=0.5),
    "default, max_velocity=None": lambda: MOPSO(max_velocity=None),
    "default, mutation=None": lambda: MOPSO(mutation=None),
    "default, mutation=coello (p_m 0.5)": lambda: MOPSO(mutation="coello", mutation_rate=0.5),
    "default, leader=tournament": lambda: MOPSO(leader="tournament"),
    "default, personal_best=coin": lambda: MOPSO(personal_best="coin"),
    "default, removal=random, keep_extremes=False": lambda: MOPSO(removal="random", keep_extremes=False),
    "default, n_divisions=30": lambda: MOPSO(n_divisions=30),
    "paper, boundary=clip": lambda: MOPSO(**{**PAPER_PRESET, "boundary": "clip"}),
}


def benchmark_table(problems=PROBLEMS, algorithms=None, seeds=SEEDS, n_eval: int = N_EVAL,
                    n_jobs: int = 2) -> list[dict]:
    """Median hypervolume and IGD of each algorithm on each problem.

    Parameters
    ----------
    problems : sequence of str
        Names from :data:`KNOWN_PROBLEMS`.
    algorithms : None, sequence of str or dict
        Names from :data:`ALGORITHMS` / :data:`ABLATIONS`, or a dict name → factory;
        None means :data:`ALGORITHMS` (SMPSO left out when jMetalPy is missing).
    seeds : sequence of int
        One run per seed, algorithm and problem.
    n_eval : int
        Function evaluations per run.
    n_jobs : int
        joblib workers; one task per run (a run lasts 0.3–5 s, far above joblib's
        per-task overhead).

    Returns
    -------
    list of dict
        One row per (problem, algorithm), problems outermost: ``problem`` (upper case),
        ``algorithm``, ``hv_median``, ``igd_median``, ``hv`` and ``igd`` (per seed, in
        seed order), ``n_eval``, ``reference_point``, ``seconds_median`` (wall time).
    """
    n_eval = check_int("benchmark.n_eval", n_eval, 1)
    n_jobs = check_int("benchmark.n_jobs", n_jobs, -1)
    problems = tuple(problems)
    for name in problems:
        make_problem(name)
    factories = _resolve(algorithms)
    seeds = tuple(int(seed) for seed in seeds)
    if not seeds:
        raise ConfigError("benchmark.seeds is empty; allowed: one or more integers")
    tasks = [(problem, name, seed) for problem in problems for name in factories for seed in seeds]
    outcomes = Parallel(n_jobs=n_jobs)(
        delayed(_run)(problem, factories[name], seed, n_eval) for problem, name, seed in tasks)
    rows = []
    for problem in problems:
        n_obj = make_problem(problem).n_obj
        for name in factories:
            runs = [out for (p, a, _), out in zip(tasks, outcomes) if p == problem and a == name]
            hv, igd, seconds = (np.array(values) for values in zip(*runs))
            rows.append({"problem": problem.upper(), "algorithm": name,
                         "hv_median": float(np.median(hv)), "igd_median": float(np.median(igd)),
                         "hv": hv.tolist(), "igd": igd.tolist(), "n_eval": n_eval,
                         "reference_point": (REFERENCE_VALUE,) * n_obj,
                         "seconds_median": float(np.median(seconds))})
    return rows


def format_table(rows: list[dict], igd: bool = False) -> str:
    """Markdown table: one line per algorithm, median HV (and IGD) per problem."""
    problems = list(dict.fromkeys(row["problem"] for row in rows))
    algorithms = list(dict.fromkeys(row["algorithm"] for row in rows))
    cell = {(row["problem"], row["algorithm"]): row for row in rows}
    columns = [f"{p} HV" for p in problems] + ([f"{p} IGD" for p in problems] if igd else [])
    lines = ["| algorithm | " + " | ".join(columns) + " |", "|---|" + "---:|" * len(columns)]
    for name in algorithms:
        rows_of = [cell.get((problem, name)) for problem in problems]
        values = ["–" if row is None else f"{row['hv_median']:.4f}" for row in rows_of]
        if igd:
            values += ["–" if row is None else f"{row['igd_median']:.4f}" for row in rows_of]
        lines.append(f"| {name} | " + " | ".join(values) + " |")
    return "\n".join(lines)


def format_ratios(rows: list[dict], algorithm: str = DEFAULT_NAME,
                  references=(SMPSO_NAME, NSGA2_NAME)) -> str:
    """Markdown table of median-HV ratios ``algorithm`` / reference, per problem."""
    problems = list(dict.fromkeys(row["problem"] for row in rows))
    cell = {(row["problem"], row["algorithm"]): row["hv_median"] for row in rows}
    lines = ["| ratio | " + " | ".join(problems) + " |", "|---|" + "---:|" * len(problems)]
    for reference in references:
        values = []
        for problem in problems:
            mine, theirs = cell.get((problem, algorithm)), cell.get((problem, reference))
            values.append("–" if mine is None or not theirs else f"{mine / theirs:.3f}")
        lines.append(f"| {algorithm} / {reference} | " + " | ".join(values) + " |")
    return "\n".join(lines)


def main(argv=None) -> int:
    """``python -m mosd.optim.benchmarks``: print the table (and the ratios) as Markdown."""
    parser = argparse.ArgumentParser(prog="python -m mosd.optim.benchmarks", description=__doc__.splitlines()[0])
    parser.add_argument("--problems", nargs="+", default=list(PROBLEMS), choices=KNOWN_PROBLEMS)
    parser.add_argument("--seeds", type=int, default=len(SEEDS), help="seeds 1..N (default 5)")
    parser.add_argument("--n-eval", type=int, default=N_EVAL, help="evaluations per run (default 10,000)")
    parser.add_argument("--n-jobs", type=int, default=2, help="joblib workers (default 2)")
    parser.add_argument("--ablations", action="store_true", help="also the one-change variants of the default")
    parser.add_argument("--igd", action="store_true", help="also print median IGD")
    args = parser.parse_args(argv)
    algorithms = dict(_resolve(None))
    if args.ablations:
        algorithms.update(ABLATIONS)
    start = time.perf_counter()
    rows = benchmark_table(args.problems, algorithms, tuple(range(1, args.seeds + 1)), args.n_eval, args.n_jobs)
    seconds = time.perf_counter() - start
    print(f"Median hypervolume over seeds 1-{args.seeds}, {args.n_eval:,} evaluations per run, "
          f"reference point 1.1 in every objective\n")
    print(format_table(rows, igd=args.igd))
    print()
    print(format_ratios(rows))
    if SMPSO_NAME not in algorithms:
        print("\nSMPSO left out: jMetalPy is not installed (pip install jmetalpy)")
    print(f"\n{len(rows) * args.seeds} runs in {seconds:.0f} s with n_jobs={args.n_jobs}")
    return 0


def _resolve(algorithms) -> dict[str, Callable[[], object]]:
    if algorithms is None:
        return {name: make for name, make in ALGORITHMS.items()
                if name != SMPSO_NAME or smpso_available()}
    if isinstance(algorithms, dict):
        return dict(algorithms)
    known = {**ALGORITHMS, **ABLATIONS}
    unknown = [name for name in algorithms if name not in known]
    if unknown:
        raise ConfigError(f"benchmark.algorithms={unknown!r} is not allowed; allowed: {', '.join(known)}")
    return {name: known[name] for name in algorithms}


def _run(problem_name: str, factory: Callable[[], object], seed: int, n_eval: int):
    problem = make_problem(problem_name)
    algorithm = factory()
    start = time.perf_counter()
    if hasattr(algorithm, "solve"):
        F = algorithm.solve(problem, n_eval, seed)
    else:
        F = minimize(problem, algorithm, ("n_eval", n_eval), seed=seed).F
    seconds = time.perf_counter() - start
    F = np.atleast_2d(F)
    hypervolume = HV(ref_point=np.full(problem.n_obj, REFERENCE_VALUE))(F)
    igd = IGD(problem.pareto_front())(F)
    return float(hypervolume), float(igd), seconds


def _jmetal_problem(problem: Problem):
    from jmetal.core.problem import FloatProblem

    class Wrapped(FloatProblem):
        def __init__(self):
            super().__init__()
            self.lower_bound = [float(v) for v in problem.xl]
            self.upper_bound = [float(v) for v in problem.xu]

        def number_of_objectives(self) -> int:
            return problem.n_obj

        def number_of_constraints(self) -> int:
            return 0

        def evaluate(self, solution):
            solution.objectives = list(problem.evaluate(np.array([solution.variables]))[0])
            return solution

        def name(self) -> str:
            return type(problem).__name__

    return Wrapped()


class _BatchEvaluator:
    """jMetalPy Evaluator protocol: evaluate a list of solutions with one pymoo call."""

    def __init__(self, problem: Problem):
        self.problem = problem

    def evaluate(self, solution_list, problem):
        F = self.problem.evaluate(np.array([solution.variables for solution in solution_list]))
        for solution, objectives in zip(solution_list, np.atleast_2d(F)):
            solution.objectives = [float(v) for v in objectives]
        return solution_list


if __name__ == "__main__":
    raise SystemExit(main())
