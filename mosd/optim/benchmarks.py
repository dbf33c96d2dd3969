"""How good is the MOPSO? Median hypervolume and IGD on ZDT1–3 against pymoo's algorithms.

Every algorithm gets the same budget of function evaluations (``("n_eval", n_eval)``
termination) and the same seeds. Hypervolume uses the reference point (1.1, 1.1); IGD is
measured against ``problem.pareto_front()``. The best published multi-objective PSO at
10,000 evaluations, SMPSO (Nebro et al. 2009), reaches HV ≈ 0.87 / 0.54 / 1.25 on
ZDT1/2/3 with that reference point; the true fronts have HV ≈ 0.877 / 0.543 / 1.328.

The ZDT optima lie on the lower bound of x2…xn, so the rule for particles that leave the
box (see :func:`mosd.optim.mopso.apply_bounds`) decides much of a PSO's score there.
``"zdt1_shifted"`` (:class:`ShiftedZDT1`) moves that optimum inside the box to tell
search ability from boundary effects.
"""
from __future__ import annotations

from typing import Callable
import time

import numpy as np
from joblib import Parallel, delayed
from pymoo.algorithms.moo.mopso_cd import MOPSO_CD
from pymoo.algorithms.moo.nsga2 import NSGA2
from pymoo.core.problem import Problem
from pymoo.indicators.hv import HV
from pymoo.indicators.igd import IGD
from pymoo.optimize import minimize
from pymoo.problems import get_problem

from ..validation import ConfigError, check_in, check_int, Interval
from .mopso import MOPSO


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

REFERENCE_POINT = (1.1, 1.1)
PROBLEMS = ("zdt1", "zdt2", "zdt3")

#: The comparison the issue asks for: name → factory of a fresh algorithm (population 100).
#: MOPSO_CD gets archive_size=100 like the others (its own default is 200).
VARIANTS: dict[str, Callable[[], object]] = {
    "MOPSO constriction (default)": lambda: MOPSO(),
    "MOPSO inertia (Coello 2004)": lambda: MOPSO(velocity="inertia"),
    "NSGA-II (pymoo)": lambda: NSGA2(pop_size=100),
    "MOPSO_CD (pymoo)": lambda: MOPSO_CD(pop_size=100, archive_size=100),
}

#: Options of :class:`~mosd.optim.MOPSO` that depart from paper 000 where it speaks
#: (boundary rule, inertia weight) or where it is silent (mutation, velocity clamp).
MOPSO_OPTIONS: dict[str, Callable[[], object]] = {
    "MOPSO constriction, no mutation": lambda: MOPSO(mutation_rate=None),
    "MOPSO constriction, max_velocity=0.5": lambda: MOPSO(max_velocity=0.5),
    "MOPSO constriction, max_velocity=0.2": lambda: MOPSO(max_velocity=0.2),
    "MOPSO constriction, w=0.4": lambda: MOPSO(w=0.4),
    "MOPSO constriction, boundary=absorb": lambda: MOPSO(boundary="absorb"),
    "MOPSO constriction, boundary=absorb, no mutation": lambda: MOPSO(boundary="absorb",
                                                                      mutation_rate=None),
    "MOPSO constriction, boundary=clip": lambda: MOPSO(boundary="clip"),
    "MOPSO constriction, boundary=clip, no mutation": lambda: MOPSO(boundary="clip",
                                                                    mutation_rate=None),
    "MOPSO inertia, boundary=absorb": lambda: MOPSO(velocity="inertia", boundary="absorb"),
}


def zdt_table(n_eval: int = 10000, seeds=(1, 2, 3, 4, 5), n_jobs: int = 1,
              variants=None, problems=PROBLEMS) -> list[dict]:
    """Median hypervolume and IGD of each algorithm on each ZDT problem.

    Parameters
    ----------
    n_eval : int
        Function evaluations per run.
    seeds : sequence of int
        One run per seed, algorithm and problem.
    n_jobs : int
        joblib workers; one task per run (a run lasts 0.3–10 s, far above joblib's
        per-task overhead).
    variants : None, sequence of str or dict
        Names from :data:`VARIANTS` / :data:`MOPSO_OPTIONS`, or a dict name → factory;
        None means :data:`VARIANTS`.
    problems : sequence of str
        pymoo problem names, or ``"zdt1_shifted"``.

    Returns
    -------
    list of dict
        One row per (problem, algorithm): ``problem``, ``algorithm``, ``hv_median``,
        ``igd_median``, ``hv`` and ``igd`` (per seed, in seed order), ``n_eval``,
        ``seconds_median``.
    """
    n_eval = check_int("benchmark.n_eval", n_eval, 1)
    n_jobs = check_int("benchmark.n_jobs", n_jobs, -1)
    factories = _resolve(variants)
    seeds = tuple(int(seed) for seed in seeds)
    tasks = [(problem, name, seed) for problem in problems for name in factories for seed in seeds]
    outcomes = Parallel(n_jobs=n_jobs)(
        delayed(_run)(problem, factories[name], seed, n_eval) for problem, name, seed in tasks)
    rows = []
    for problem in problems:
        for name in factories:
            runs = [out for (p, a, _), out in zip(tasks, outcomes) if p == problem and a == name]
            hv, igd, seconds = (np.array(values) for values in zip(*runs))
            rows.append({"problem": problem.upper(), "algorithm": name,
                         "hv_median": float(np.median(hv)), "igd_median": float(np.median(igd)),
                         "hv": hv.tolist(), "igd": igd.tolist(), "n_eval": n_eval,
                         "seconds_median": float(np.median(seconds))})
    return rows


def format_table(rows: list[dict]) -> str:
    """Markdown table: one line per algorithm, median HV and IGD per problem."""
    problems = list(dict.fromkeys(row["problem"] for row in rows))
    algorithms = list(dict.fromkeys(row["algorithm"] for row in rows))
    cell = {(row["problem"], row["algorithm"]): row for row in rows}
    header = "| algorithm | " + " | ".join(f"{p} HV | {p} IGD" for p in problems) + " |"
    lines = [header, "|---|" + "---:|---:|" * len(problems)]
    for name in algorithms:
        values = []
        for problem in problems:
            row = cell.get((problem, name))
            values += (["–", "–"] if row is None
                       else [f"{row['hv_median']:.4f}", f"{row['igd_median']:.4f}"])
        lines.append(f"| {name} | " + " | ".join(values) + " |")
    return "\n".join(lines)


def _resolve(variants) -> dict[str, Callable[[], object]]:
    if variants is None:
        return dict(VARIANTS)
    if isinstance(variants, dict):
        return dict(variants)
    known = {**VARIANTS, **MOPSO_OPTIONS}
    unknown = [name for name in variants if name not in known]
    if unknown:
        raise ConfigError(f"benchmark.variants={unknown!r} is not allowed; allowed: {', '.join(known)}")
    return {name: known[name] for name in variants}


def _run(problem_name: str, factory: Callable[[], object], seed: int, n_eval: int):
    problem = ShiftedZDT1() if problem_name == "zdt1_shifted" else get_problem(problem_name)
    start = time.perf_counter()
    result = minimize(problem, factory(), ("n_eval", n_eval), seed=seed)
    seconds = time.perf_counter() - start
    F = np.atleast_2d(result.F)
    hypervolume = HV(ref_point=np.array(REFERENCE_POINT))(F)
    igd = IGD(problem.pareto_front())(F)
    return float(hypervolume), float(igd), seconds
