"""Generation planning of :class:`mosd.optim.mopso.MOPSO`: the run length and what depends on it.

How long the run is planned to last (:meth:`GenerationPlan._planned_generations`), the coefficients scheduled over
it, the late phase of a constrained run, the share of the swarm that explores and the mutation's distribution
index per row. A mixin of :class:`~mosd.optim.mopso.MOPSO`: it reads the algorithm's options (``horizon``, ``w``,
``c1``, ``c2``, ``mutation*``, ``constrained*``, ``exploration``), its state (``n_iter``, ``planned_generations``,
``leader_archive``, ``constrained_problem``) and pymoo's ``termination``, and draws nothing.
"""
from __future__ import annotations

import math
import warnings

import numpy as np
from pymoo.termination.max_eval import MaximumFunctionCallTermination
from pymoo.termination.max_gen import MaximumGenerationTermination

from .mopso_settings import FINE_MUTATION_ETA, LATE_FINE_ETA, PAPER_MAX_ITERATIONS


class GenerationPlan:
    """The MOPSO's schedule over its planned generations (a mixin of :class:`~mosd.optim.mopso.MOPSO`)."""

    def _planned_generations(self) -> int:
        """Generations the run is planned to last (the initial swarm counts as one).

        ``horizon`` if given; else the limit of a termination that *is* a
        MaximumGenerationTermination (``n_gen``) or MaximumFunctionCallTermination
        (``n_eval`` E → ⌈E / pop_size⌉). The limits nested inside combined criteria such
        as pymoo's default termination (1,000 generations or 100,000 evaluations, but
        usually ended much earlier by its tolerances) are not a run length and are not
        read; then, if anything depends on the run length, paper 000's M = 100 is
        assumed with a warning.
        """
        if self.horizon is not None:
            return self.horizon
        criterion = self.termination
        limit = None
        if isinstance(criterion, MaximumGenerationTermination):
            limit = criterion.n_max_gen
        elif isinstance(criterion, MaximumFunctionCallTermination) and criterion.n_max_evals is not None:
            limit = math.ceil(criterion.n_max_evals / self.pop_size)
        if limit is not None and math.isfinite(limit):
            return max(1, int(limit))
        scheduled = any(isinstance(value, tuple) for value in (self.w, self.c1, self.c2))
        if scheduled or (self.mutation == "coello" and self.mutation_rate is not None):
            warnings.warn("MOPSO: the termination is not an n_gen/n_eval limit and optimizer.horizon is "
                          f"not set; schedules assume {PAPER_MAX_ITERATIONS} generations "
                          "(paper 000, Table 2)", stacklevel=2)
        return PAPER_MAX_ITERATIONS

    def _scheduled(self, value, move: int) -> float:
        """A coefficient at move ``move``: a constant, or a pair [start, end] linear from the
        first move (0) to the last planned one (planned generations − 2), then ``end``."""
        if not isinstance(value, tuple):
            return value
        start, end = value
        last = self.planned_generations - 2
        return end if last <= 0 else start + (end - start) * min(1.0, move / last)

    def _late_phase(self) -> bool:
        """Whether this generation is in a constrained run's late phase (``constrained_late_phase``): the
        generations done, the initial swarm's not counted, reach that share of the planned ones
        (:meth:`_planned_generations`)."""
        if self.constrained_late_phase is None or not self.constrained_problem:
            return False
        return (self.n_iter - 1) / max(1, self.planned_generations - 1) >= self.constrained_late_phase

    def _exploring_share(self) -> float:
        """Share of the swarm that makes SMPSO's move (:func:`smpso_velocity`) this move.

        max(0, 1 − |A| / (``exploration`` × Z_ar)): 1 while the archive is empty, 0 once
        it holds ``exploration`` × ``archive_size`` members. A small archive is what a
        swarm stalled on a multimodal landscape shows (one local optimum dominates
        everything found so far: under the attraction-only update ZDT4's archive held one
        or two members from generation 17 to 49, docs/MOPSO.md), while on a front the swarm
        has reached the archive fills within a few generations and the velocity variant
        contracts the swarm as before.
        """
        if not self.exploration:
            return 0.0
        return max(0.0, 1.0 - len(self.leader_archive) / (self.exploration * self.archive_size))

    def _mutation_etas(self, n: int):
        """The polynomial mutation's distribution index for n rows (particles or archive offspring).

        ``mutation_eta``, except on a problem with constraints, where the first
        round(``constrained_fine_mutation`` × n) rows take NSGA-II's :data:`FINE_MUTATION_ETA` from the
        first generation on (issue 33, docs/MOPSO.md: the fronts lie on constraint boundaries, where the
        long-tailed steps mostly leave the feasible region; the redraw of ``constrained_reset`` makes the long
        jumps instead); in a constrained run's late phase (``constrained_late_phase``) every row takes
        :data:`LATE_FINE_ETA`. A scalar when all rows share one, so that unconstrained runs are unchanged.
        """
        if self._late_phase():
            return np.full(n, LATE_FINE_ETA)
        if not (self.constrained_fine_mutation and self.constrained_problem):
            return self.mutation_eta
        etas = np.full(n, float(self.mutation_eta))
        etas[:int(round(self.constrained_fine_mutation * n))] = FINE_MUTATION_ETA
        return etas

    def _eta_rows(self, n: int) -> np.ndarray:
        """:meth:`_mutation_etas` as one index per row (what the compiled mutation takes)."""
        etas = self._mutation_etas(n)
        return np.full(n, float(etas)) if np.ndim(etas) == 0 else np.asarray(etas, dtype=float)
