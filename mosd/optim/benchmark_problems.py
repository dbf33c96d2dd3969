"""The benchmark problems of :mod:`mosd.optim.benchmarks`: what is built, its budget, its true front, its normalisation.

Issue 21's problems and issue 33's constrained ones (:data:`PROBLEMS`), ZDT1 with its optimum inside the box
(:class:`ShiftedZDT1`), the analytical or scanned fronts where pymoo's are downloads or coarse, and the normalised
hypervolume every table reports (the set-up is in :mod:`mosd.optim.benchmarks`' docstring).
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Callable

import numpy as np
from pymoo.core.problem import Problem
from pymoo.problems import get_problem
from pymoo.util.nds.non_dominated_sorting import NonDominatedSorting

from ..metrics import REFERENCE_VALUE, hypervolume
from ..validation import ConfigError, Interval, check_in, check_int


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


def make_problem(name: str) -> Problem:
    """A benchmark problem by name (:data:`KNOWN_PROBLEMS`)."""
    return benchmark_of(name).make()


def benchmark_of(name: str) -> Benchmark:
    """The :class:`Benchmark` of problem ``name`` (:data:`KNOWN_PROBLEMS`); a one-line error names the allowed ones."""
    known = {**PROBLEMS, **EXTRA_PROBLEMS}
    if name not in known:
        raise ConfigError(f"benchmark.problems={name!r} is not allowed; allowed: {', '.join(KNOWN_PROBLEMS)}")
    return known[name]


@lru_cache(maxsize=None)
def normalisation(name: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Ideal point, nadir point and the true front of problem ``name`` (computed once per process)."""
    benchmark = benchmark_of(name)
    front = np.asarray(benchmark.front(benchmark.make()), dtype=float)
    return front.min(axis=0), front.max(axis=0), front


def normalised_hypervolume(F: np.ndarray, ideal: np.ndarray, nadir: np.ndarray) -> float:
    """Hypervolume of (F − ideal) / (nadir − ideal) with reference 1.1 in every objective (module docstring)."""
    F = np.atleast_2d(np.asarray(F, dtype=float))
    if F.size == 0:
        return 0.0
    return hypervolume((F - ideal) / (nadir - ideal))
