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

import argparse
import logging
import os
import sys
import time
import warnings
from dataclasses import dataclass
from functools import lru_cache
from typing import Callable

import numpy as np
from joblib import Parallel, delayed
from pymoo.algorithms.moo.mopso_cd import MOPSO_CD
from pymoo.algorithms.moo.nsga2 import NSGA2
from pymoo.algorithms.moo.nsga3 import NSGA3
from pymoo.core.problem import Problem
from pymoo.indicators.igd import IGD
from pymoo.optimize import minimize
from pymoo.problems import get_problem
from pymoo.util.nds.non_dominated_sorting import NonDominatedSorting
from pymoo.util.ref_dirs import get_reference_directions

from ..metrics import REFERENCE_VALUE, hypervolume
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


def dtlz7_front(n_grid: int = 301) -> np.ndarray:
    """DTLZ7's 3-objective Pareto front: g = 1, f3 = 2 (3 − Σ f_i / 2 (1 + sin 3π f_i)), non-dominated part."""
    axis = np.linspace(0.0, 1.0, n_grid)
    f1, f2 = (v.ravel() for v in np.meshgrid(axis, axis))
    h = 3.0 - (f1 / 2.0 * (1.0 + np.sin(3.0 * np.pi * f1)) + f2 / 2.0 * (1.0 + np.sin(3.0 * np.pi * f2)))
    F = np.column_stack([f1, f2, 2.0 * h])
    return F[NonDominatedSorting().do(F, only_non_dominated_front=True)]


def osy_front(n_points: int = 200) -> np.ndarray:
    """OSY's Pareto front from its five analytical regions (Deb 2001, §10.3), evaluated and filtered.

    x4 = x6 = 0 throughout: (5, 1, x3, 0, 5, 0) and (5, 1, x3, 0, 1, 0) with x3 ∈ [1, 5];
    (x1, (x1 − 2)/3, 1, 0, 1, 0) with x1 ∈ [4.056, 5]; (0, 2, x3, 0, 1, 0) with
    x3 ∈ [1, 3.732]; (x1, 2 − x1, 1, 0, 1, 0) with x1 ∈ [0, 1]. Ideal (−274, 4),
    nadir (−42, 76).
    """
    t = np.linspace(0.0, 1.0, n_points)
    one, zero = np.ones_like(t), np.zeros_like(t)
    x3 = 1.0 + 4.0 * t
    x1_cd, x3_de, x1_ef = 4.056 + 0.944 * t, 1.0 + 2.732 * t, t
    X = np.vstack([np.column_stack([5 * one, one, x3, zero, 5 * one, zero]),
                   np.column_stack([5 * one, one, x3, zero, one, zero]),
                   np.column_stack([x1_cd, (x1_cd - 2.0) / 3.0, one, zero, one, zero]),
                   np.column_stack([zero, 2 * one, x3_de, zero, one, zero]),
                   np.column_stack([x1_ef, 2.0 - x1_ef, one, zero, one, zero])])
    F, G = get_problem("osy").evaluate(X, return_values_of=["F", "G"])
    F = F[np.all(G <= 1e-9, axis=1)]
    return F[NonDominatedSorting().do(F, only_non_dominated_front=True)]


def wfg4_front(n_points: int = 1000) -> np.ndarray:
    """WFG4's 2-objective Pareto front, the quarter ellipse (2 sin φ, 4 cos φ), φ ∈ [0, π/2].

    pymoo builds it from reference directions whose sample differs between processes (its
    smallest f1 came out 0.068 in one and 0.095 in another), which moved the normalisation.
    """
    phi = np.linspace(0.0, np.pi / 2.0, n_points)
    return np.column_stack([2.0 * np.sin(phi), 4.0 * np.cos(phi)])


def scanned_front(problem: Problem, X0: np.ndarray, column: int, values: np.ndarray,
                  chunk: int = 200_000) -> np.ndarray:
    """The feasible non-dominated points of ``problem`` over rows ``X0`` with ``X0[:, column]`` swept over ``values``.

    For the constrained 2-objective problems whose pymoo fronts are downloads (MW7, CTP2, CTP3)
    or coarse (MW1: 46 of 100 points on g = 1 survive its constraint): each row of ``X0`` is a
    point of the unconstrained optimum (position variable on a grid, distance variables at their
    optimum), and sweeping one distance variable raises g until the constraints admit the point.
    Every point goes through pymoo's own ``evaluate``, so no objective or constraint is written
    twice; the front is the non-dominated feasible set of the sweep.
    """
    per_row, fronts = max(1, chunk // len(values)), [np.empty((0, problem.n_obj))]
    for start in range(0, len(X0), per_row):
        rows = X0[start:start + per_row]
        X = np.repeat(rows, len(values), axis=0)
        X[:, column] = np.tile(values, len(rows))
        with np.errstate(all="ignore"):  # CTP's constraint divides 0 by 0 at f1 = 0, g = 1 (NaN: infeasible)
            F, G = problem.evaluate(X, return_values_of=["F", "G"])
        F = np.vstack([fronts[-1], F[np.all(G <= 0.0, axis=1)]])
        fronts.append(F[NonDominatedSorting().do(F, only_non_dominated_front=True)])
    return fronts[-1]


def mw_front(problem: Problem, n_points: int = 801) -> np.ndarray:
    """Front of a 2-objective MW problem (Ma & Wang 2019) by :func:`scanned_front`.

    x1 on a grid of ``n_points`` in [0, 1]; the other variables at the optimum of the problem's
    distance function — g1 (MW1): x_i^(n−2) = 1/2 + i/(2n); g2 (MW2): x_i = i/n; g3 (MW3, MW7):
    x_i = 1 − (x_{i−1} − 1/2)², i = 2…n — and x_n swept over [0, 1] (801 values).
    """
    n, name = problem.n_var, type(problem).__name__
    X0 = np.zeros((n_points, n))
    X0[:, 0] = np.linspace(0.0, 1.0, n_points)
    i = np.arange(1, n)
    if name == "MW1":
        X0[:, 1:] = (0.5 + i / (2.0 * n)) ** (1.0 / (n - problem.n_obj))
    elif name == "MW2":
        X0[:, 1:] = i / n
    else:
        for k in i:
            X0[:, k] = 1.0 - (X0[:, k - 1] - 0.5) ** 2
    return scanned_front(problem, X0, n - 1, np.linspace(0.0, 1.0, 801))


def ctp_front(problem: Problem, n_points: int = 2001) -> np.ndarray:
    """Front of pymoo's 2-variable CTP2/CTP3 (Deb et al. 2001) by :func:`scanned_front`.

    x1 on a grid of ``n_points`` in [0, 1], x2 (g = 1 + x2) swept over [0, 0.6] in steps of
    0.0002. The unconstrained front g = 1 is infeasible there; the constrained front lies on
    the line (f2 − 1) cos θ = f1 sin θ, θ = −0.2π: disconnected pieces (CTP2), points (CTP3).
    """
    X0 = np.column_stack([np.linspace(0.0, 1.0, n_points), np.zeros(n_points)])
    return scanned_front(problem, X0, 1, np.linspace(0.0, 0.6, 3001))


@dataclass(frozen=True)
class Benchmark:
    """A benchmark problem: how to build it, its default budget and its true front."""

    make: Callable[[], Problem]
    n_eval: int
    front: Callable[[Problem], np.ndarray] = lambda problem: problem.pareto_front()


def _wfg(name: str) -> Callable[[], Problem]:
    return lambda: get_problem(name, n_var=24, n_obj=2, k=4, l=20)


def _dtlz(name: str, n_var: int) -> Callable[[], Problem]:
    return lambda: get_problem(name, n_var=n_var, n_obj=3)


#: Issue 21's problems (name → :class:`Benchmark`); ``"zdt1_shifted"`` is extra (:data:`KNOWN_PROBLEMS`).
PROBLEMS: dict[str, Benchmark] = {
    "zdt1": Benchmark(lambda: get_problem("zdt1"), 10_000),
    "zdt2": Benchmark(lambda: get_problem("zdt2"), 10_000),
    "zdt3": Benchmark(lambda: get_problem("zdt3"), 10_000),
    "zdt4": Benchmark(lambda: get_problem("zdt4"), 10_000),
    "zdt6": Benchmark(lambda: get_problem("zdt6"), 10_000),
    "dtlz1": Benchmark(_dtlz("dtlz1", 7), 50_000),
    "dtlz2": Benchmark(_dtlz("dtlz2", 12), 10_000),
    "dtlz3": Benchmark(_dtlz("dtlz3", 12), 50_000),
    "dtlz4": Benchmark(_dtlz("dtlz4", 12), 10_000),
    "dtlz7": Benchmark(_dtlz("dtlz7", 22), 10_000, lambda problem: dtlz7_front()),
    "wfg1": Benchmark(_wfg("wfg1"), 10_000),
    "wfg2": Benchmark(_wfg("wfg2"), 10_000),
    "wfg4": Benchmark(_wfg("wfg4"), 10_000, lambda problem: wfg4_front()),
    "osy": Benchmark(lambda: get_problem("osy"), 10_000, lambda problem: osy_front()),
    "mw1": Benchmark(lambda: get_problem("mw1"), 10_000, mw_front),
    "mw2": Benchmark(lambda: get_problem("mw2"), 10_000, mw_front),
    "mw3": Benchmark(lambda: get_problem("mw3"), 10_000, mw_front),
    "mw7": Benchmark(lambda: get_problem("mw7"), 10_000, mw_front),
    "ctp2": Benchmark(lambda: get_problem("ctp2"), 10_000, ctp_front),
    "ctp3": Benchmark(lambda: get_problem("ctp3"), 10_000, ctp_front),
}
EXTRA_PROBLEMS: dict[str, Benchmark] = {"zdt1_shifted": Benchmark(ShiftedZDT1, 10_000)}
KNOWN_PROBLEMS = (*PROBLEMS, *EXTRA_PROBLEMS)
#: Default budget per run where a problem sets none (``Benchmark.n_eval`` does for all).
N_EVAL = 10_000
SEEDS = (1, 2, 3, 4, 5)
#: Kept for callers of the two-objective table: the normalised reference point of a 2-objective problem.
REFERENCE_POINT = (REFERENCE_VALUE, REFERENCE_VALUE)

DEFAULT_NAME = "MOPSO (default)"
ISSUE14_NAME = "MOPSO (issue-14 default)"
PAPER_NAME = "MOPSO paper (Table 2)"
NSGA2_NAME = "NSGA-II (pymoo)"
NSGA3_NAME = "NSGA-III (pymoo)"
SMPSO_NAME = "SMPSO (jMetalPy)"
MOPSO_CD_NAME = "MOPSO_CD (pymoo)"
EXPLORATION_NAME = "MOPSO (exploration only)"
BEFORE_ISSUE33_NAME = "MOPSO (before issue 33)"
#: ``MOPSO()`` before issue 21 (the no-loss reference), and after its first change (SMPSO's
#: exploring move, no archive offspring), as constructor arguments.
ISSUE14_DEFAULT = dict(exploration=None, recombination=None, mutation_eta=20.0)
EXPLORATION_DEFAULT = dict(recombination=None, mutation_eta=20.0)
#: ``MOPSO()`` before issue 33 (Coello's infeasible rule, the grid rules on constrained fronts).
BEFORE_ISSUE33 = dict(infeasible="least", constrained="grid", constrained_fine_mutation=None,
                      constrained_reset=None, constrained_refine=None, constrained_late_phase=None)
#: The peers of issue 21 (the "best peer" of a problem is the best of these that ran on it).
PEERS = (NSGA2_NAME, NSGA3_NAME, SMPSO_NAME)

#: Issue 21's targets: problem → (reference: a peer name, "best peer" or the issue-14 default, factor);
#: issue 33's constrained problems against NSGA-II. Median HV of the default ≥ factor × the reference's.
TARGETS: dict[str, tuple[str, float]] = {
    "ZDT4": ("best peer", 0.95), "DTLZ1": ("best peer", 0.95), "DTLZ3": ("best peer", 0.95),
    "WFG4": (NSGA2_NAME, 0.95), "OSY": (NSGA2_NAME, 0.97),
    **{name: (ISSUE14_NAME, 0.98) for name in ("ZDT1", "ZDT2", "ZDT3", "ZDT6", "DTLZ2", "DTLZ4", "DTLZ7",
                                                 "WFG1", "WFG2")},
    "MW1": (NSGA2_NAME, 0.9),
    **{name: (NSGA2_NAME, 0.98) for name in ("MW2", "MW3", "MW7", "CTP2", "CTP3")},
}
#: Issue 33's spread targets: problem → (reference, factor); median IGD of the default ≤ factor × the reference's.
IGD_TARGETS: dict[str, tuple[str, float]] = {name: (NSGA2_NAME, 1.1) for name in ("MW2", "MW3", "MW7", "CTP2", "CTP3")}


def make_problem(name: str) -> Problem:
    """A benchmark problem by name (:data:`KNOWN_PROBLEMS`)."""
    return _benchmark(name).make()


def _benchmark(name: str) -> Benchmark:
    known = {**PROBLEMS, **EXTRA_PROBLEMS}
    if name not in known:
        raise ConfigError(f"benchmark.problems={name!r} is not allowed; allowed: {', '.join(KNOWN_PROBLEMS)}")
    return known[name]


@lru_cache(maxsize=None)
def normalisation(name: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Ideal point, nadir point and the true front of problem ``name`` (computed once per process)."""
    benchmark = _benchmark(name)
    front = np.asarray(benchmark.front(benchmark.make()), dtype=float)
    return front.min(axis=0), front.max(axis=0), front


def normalised_hypervolume(F: np.ndarray, ideal: np.ndarray, nadir: np.ndarray) -> float:
    """Hypervolume of (F − ideal) / (nadir − ideal) with reference 1.1 in every objective (module docstring)."""
    F = np.atleast_2d(np.asarray(F, dtype=float))
    if F.size == 0:
        return 0.0
    return hypervolume((F - ideal) / (nadir - ideal))


class JMetalSMPSO:
    """jMetalPy's SMPSO on a pymoo problem, with the budget and seed of the other runs.

    jMetalPy draws from Python's ``random`` and NumPy's global generator; both are
    seeded before each run (each run is one joblib task, so runs do not share them).
    The swarm is evaluated as one batch through the pymoo problem, so both libraries
    see the same objective function. Constraints are not passed (it runs on the
    unconstrained problems only).
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


def _nsga3() -> NSGA3:
    return NSGA3(get_reference_directions("das-dennis", 3, n_partitions=12), pop_size=92)


#: name → factory of a fresh algorithm (100 particles / individuals; NSGA-III 92).
ALGORITHMS: dict[str, Callable[[], object]] = {
    DEFAULT_NAME: lambda: MOPSO(),
    ISSUE14_NAME: lambda: MOPSO(**ISSUE14_DEFAULT),
    NSGA2_NAME: lambda: NSGA2(pop_size=100),
    NSGA3_NAME: _nsga3,
    SMPSO_NAME: lambda: JMetalSMPSO(),
}
#: Run only when named (MOPSO_CD gets archive_size=100 like the others; its own default is 200).
OPTIONAL: dict[str, Callable[[], object]] = {
    EXPLORATION_NAME: lambda: MOPSO(**EXPLORATION_DEFAULT),
    PAPER_NAME: lambda: MOPSO(**PAPER_PRESET),
    BEFORE_ISSUE33_NAME: lambda: MOPSO(**BEFORE_ISSUE33),
    MOPSO_CD_NAME: lambda: MOPSO_CD(pop_size=100, archive_size=100),
}

#: One change at a time from the default, for docs/MOPSO.md.
ABLATIONS: dict[str, Callable[[], object]] = {
    "default, recombination=None": lambda: MOPSO(recombination=None),
    "default, recombination=0.5": lambda: MOPSO(recombination=0.5),
    "default, recombination=0.5, mutation_eta=2": lambda: MOPSO(recombination=0.5, mutation_eta=2.0),
    "default, mutation_eta=20": lambda: MOPSO(mutation_eta=20.0),
    "default, exploration=None": lambda: MOPSO(exploration=None),
    "default, leader=tournament": lambda: MOPSO(leader="tournament"),
    "default, infeasible=least": lambda: MOPSO(infeasible="least"),
    "default, constrained=grid": lambda: MOPSO(constrained="grid"),
    "default, constrained_fine_mutation=None": lambda: MOPSO(constrained_fine_mutation=None),
    "default, constrained=grid, constrained_fine_mutation=None":
        lambda: MOPSO(constrained="grid", constrained_fine_mutation=None),
    "default, constrained_reset=None": lambda: MOPSO(constrained_reset=None),
    "default, constrained_fine_mutation=0.5": lambda: MOPSO(constrained_fine_mutation=0.5),
    "default, constrained_reset=0.1": lambda: MOPSO(constrained_reset=0.1),
    "default, constrained_refine=None": lambda: MOPSO(constrained_refine=None),
    "default, constrained_late_phase=None": lambda: MOPSO(constrained_late_phase=None),
    "default, constrained_refine=None, constrained_late_phase=None":
        lambda: MOPSO(constrained_refine=None, constrained_late_phase=None),
}


def runs_on(algorithm: str, problem: Problem) -> bool:
    """Whether ``algorithm`` runs on ``problem`` (NSGA-III: 3 objectives; SMPSO: unconstrained)."""
    if algorithm == NSGA3_NAME:
        return problem.n_obj == 3
    if algorithm == SMPSO_NAME:
        return not problem.has_constraints()
    return True


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
    factories = _resolve(algorithms)
    seeds = tuple(int(seed) for seed in seeds)
    if not seeds:
        raise ConfigError("benchmark.seeds is empty; allowed: one or more integers")
    budget = {name: n_eval or _benchmark(name).n_eval for name in problems}
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

    factories = _resolve(list(algorithms))
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

    factory = _resolve([algorithm])[algorithm]
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

    instance.setup(make_problem(problem_name), termination=("n_eval", n_eval or _benchmark(problem_name).n_eval),
                   seed=seed, callback=record)
    instance.leader_archive.__class__ = Recording  # the same archive, its leader draws counted
    instance.run()
    return rows


def format_profile(rows: list[dict], generations=(1, 2, 5, 10, 15, 20, 25, 30, 40, 50, 60, 70, 80, 90, 100)) -> str:
    """Markdown table of :func:`generation_profile` at ``generations`` and where the archive first turns feasible."""
    first = next((row["generation"] for row in rows if row["feasible"]), None)
    lines = ["| generation | archive members | feasible | least CV in archive | feasible evaluations "
             "| distinct leaders | distinct parents |", "|---:|---:|---|---:|---:|---:|---:|"]
    for row in rows:
        if row["generation"] in generations or row["generation"] == first:
            cells = [row["generation"], row["members"], "yes" if row["feasible"] else "no", f"{row['least_cv']:.4f}",
                     row["feasible_evaluations"], "–" if row["leaders"] is None else row["leaders"],
                     "–" if row["parents"] is None else row["parents"]]
            lines.append("| " + " | ".join(str(c) for c in cells) + " |")
    return "\n".join(lines)


def _progress(stream, total: int, show: bool):
    if not show:
        yield from stream
        return
    from tqdm import tqdm

    with tqdm(total=total, unit="run", file=sys.stderr, dynamic_ncols=True) as bar:
        for item in stream:
            bar.update()
            yield item


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


def best_peer(rows: list[dict], problem: str) -> tuple[str, float] | None:
    """The peer (:data:`PEERS`) with the highest median HV on ``problem``, and that HV."""
    peers = [(row["hv_median"], row["algorithm"]) for row in rows
             if row["problem"] == problem and row["algorithm"] in PEERS]
    if not peers:
        return None
    hv, name = max(peers)
    return name, hv


def target_rows(rows: list[dict], algorithm: str = DEFAULT_NAME) -> list[dict]:
    """The targets per problem (:data:`TARGETS` on the median HV, :data:`IGD_TARGETS` on the median IGD):
    ``problem``, ``metric`` ("HV" or "IGD"), ``hv`` (the algorithm's median of that metric), ``reference``
    (name), ``reference_hv``, ``ratio``, ``factor``, ``met`` (None when a needed row is missing)."""
    cells = {"HV": {(row["problem"], row["algorithm"]): row["hv_median"] for row in rows},
             "IGD": {(row["problem"], row["algorithm"]): row.get("igd_median") for row in rows}}
    out = []
    for problem in dict.fromkeys(row["problem"] for row in rows):
        for metric, targets in (("HV", TARGETS), ("IGD", IGD_TARGETS)):
            cell = cells[metric]
            if problem not in targets or cell.get((problem, algorithm)) is None:
                continue
            reference, factor = targets[problem]
            if reference == "best peer":
                found = best_peer(rows, problem)
                reference, theirs = found if found else (reference, None)
            else:
                theirs = cell.get((problem, reference))
            mine = cell[(problem, algorithm)]
            ratio = None if not theirs else mine / theirs
            met = None if ratio is None else (ratio >= factor if metric == "HV" else ratio <= factor)
            out.append({"problem": problem, "metric": metric, "hv": mine, "reference": reference,
                        "reference_hv": theirs, "ratio": ratio, "factor": factor, "met": met})
    return out


def format_targets(rows: list[dict], algorithm: str = DEFAULT_NAME) -> str:
    """Markdown table of :func:`target_rows` (HV: ratio ≥ target; IGD: ratio ≤ target)."""
    lines = [f"| problem | metric | {algorithm} | reference | reference value | ratio | target | met |",
             "|---|---|---:|---|---:|---:|---:|---|"]
    for t in target_rows(rows, algorithm):
        theirs = "–" if t["reference_hv"] is None else f"{t['reference_hv']:.4f}"
        ratio = "–" if t["ratio"] is None else f"{t['ratio']:.3f}"
        met = "–" if t["met"] is None else ("yes" if t["met"] else "**no**")
        bound = "≥" if t["metric"] == "HV" else "≤"
        lines.append(f"| {t['problem']} | {t['metric']} | {t['hv']:.4f} | {t['reference']} | {theirs} | {ratio} "
                     f"| {bound} {t['factor']:.2f} | {met} |")
    return "\n".join(lines)


def format_cpu(rows: list[dict]) -> str:
    """Markdown table of the optimisers' own CPU per evaluation (µs, median over seeds; :func:`_run`)."""
    problems = list(dict.fromkeys(row["problem"] for row in rows))
    algorithms = list(dict.fromkeys(row["algorithm"] for row in rows))
    cell = {(row["problem"], row["algorithm"]): row.get("cpu_us_median") for row in rows}
    lines = ["| algorithm | " + " | ".join(f"{p} µs/eval" for p in problems) + " |",
             "|---|" + "---:|" * len(problems)]
    for name in algorithms:
        values = ["–" if cell.get((p, name)) is None else f"{cell[(p, name)]:.1f}" for p in problems]
        lines.append(f"| {name} | " + " | ".join(values) + " |")
    return "\n".join(lines)


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
        algorithms = dict(_resolve(args.algorithms))
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


def _resolve(algorithms) -> dict[str, Callable[[], object]]:
    if algorithms is None:
        return {name: make for name, make in ALGORITHMS.items()
                if name != SMPSO_NAME or smpso_available()}
    if isinstance(algorithms, dict):
        return dict(algorithms)
    known = {**ALGORITHMS, **OPTIONAL, **ABLATIONS}
    unknown = [name for name in algorithms if name not in known]
    if unknown:
        raise ConfigError(f"benchmark.algorithms={unknown!r} is not allowed; allowed: {', '.join(known)}")
    return {name: known[name] for name in algorithms}


def _run(index: int, problem_name: str, factory: Callable[[], object], seed: int, n_eval: int):
    problem = make_problem(problem_name)
    ideal, nadir, front = normalisation(problem_name)
    evaluation_cpu = _time_evaluations(problem)
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
    own_cpu_us = 1e6 * (cpu - evaluation_cpu[0]) / n_eval
    igd = float(IGD(front)(F)) if len(F) else float("inf")
    return index, (normalised_hypervolume(F, ideal, nadir), igd, seconds, own_cpu_us)


def _time_evaluations(problem: Problem) -> list[float]:
    """Wrap ``problem._evaluate`` so that the process CPU seconds spent inside it add up in the returned list.

    The optimiser's own CPU per evaluation is the run's process CPU minus this, divided by the
    evaluations: what the algorithm costs beyond the objective function (``--cpu``).
    """
    spent = [0.0]
    evaluate = problem._evaluate

    def timed(*args, **kwargs):
        start = time.process_time()
        try:
            return evaluate(*args, **kwargs)
        finally:
            spent[0] += time.process_time() - start

    problem._evaluate = timed
    return spent


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
    # run the importable module's main, so that the joblib workers find its functions by name
    from mosd.optim.benchmarks import main as _main

    raise SystemExit(_main())
