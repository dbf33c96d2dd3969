"""The algorithms of :mod:`mosd.optim.benchmarks`: this package's MOPSO variants and the peers, by name.

The names the tables use, the MOPSO defaults of earlier issues as constructor arguments, issue 21's and issue 33's
targets, jMetalPy's SMPSO run on a pymoo problem, and the factories (:data:`ALGORITHMS`, :data:`OPTIONAL`,
:data:`ABLATIONS`) that :func:`resolve_algorithms` picks from.
"""
from __future__ import annotations

import logging
from typing import Callable

import numpy as np
from pymoo.algorithms.moo.mopso_cd import MOPSO_CD
from pymoo.algorithms.moo.nsga2 import NSGA2
from pymoo.algorithms.moo.nsga3 import NSGA3
from pymoo.core.problem import Problem
from pymoo.util.ref_dirs import get_reference_directions

from ..validation import ConfigError
from .mopso import MOPSO, PAPER_PRESET

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


def resolve_algorithms(algorithms) -> dict[str, Callable[[], object]]:
    """Name → factory of ``algorithms``: None (:data:`ALGORITHMS`, SMPSO only where jMetalPy is installed), a dict
    (as it is) or names out of :data:`ALGORITHMS`, :data:`OPTIONAL` and :data:`ABLATIONS` (others: one-line error)."""
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
