"""Multi-objective tuning of the chart parameters (paper 000, §2.2.2).

:class:`MOPSO` is the grid-archive particle swarm optimiser (a pymoo algorithm), its archive
and dominance are in :mod:`mosd.optim.archive`;
:mod:`mosd.optim.selection` picks one design from its archive; :mod:`mosd.optim.benchmarks`
checks the optimiser on the ZDT, DTLZ, WFG problems and OSY against NSGA-II, NSGA-III and SMPSO.
"""
from .archive import GridArchive
from .mopso import MOPSO
from .selection import (RULES, Selection, SelectionWarning, choose, knee, max_accuracy,
                        min_mdr_far_le, select)

from .grid import constrained_grid_search, grid_objectives
from .problem import CandidateEvaluator, TuningProblem

__all__ = [
    "CandidateEvaluator",
    "constrained_grid_search",
    "grid_objectives",
    "MOPSO",
    "GridArchive",
    "RULES",
    "Selection",
    "SelectionWarning",
    "choose",
    "knee",
    "max_accuracy",
    "min_mdr_far_le",
    "select",
    "TuningProblem",
]
