"""The archive offspring of :class:`mosd.optim.mopso.MOPSO` (``recombination``, issues 21 and 33).

How many of the swarm's slots are children of archive members, and the children: SBX and polynomial mutation of
two members (compiled where :mod:`mosd.kernels.swarm` applies), refinement children in a constrained run's late
phase, and the uniform redraw of one variable on a constrained problem. A mixin of
:class:`~mosd.optim.mopso.MOPSO`; every draw comes from the algorithm's ``random_state``.
"""
from __future__ import annotations

import numpy as np

from .mopso_settings import REFINE_ENDS, REFINE_ETA
from .variation import (CROSSOVER_ETA, CROSSOVER_PROBABILITY, polynomial_mutation, polynomial_steps, sbx_children,
                        uniform_reset)


class ArchiveOffspring:
    """Children of archive members for the last slots of each generation (a mixin of
    :class:`~mosd.optim.mopso.MOPSO`)."""

    def _n_offspring(self) -> int:
        """Slots of the swarm filled by archive offspring each move: round(``recombination`` × N), at most N − 1."""
        if not self.recombination:
            return 0
        return min(self.pop_size - 1, int(round(self.recombination * self.pop_size)))

    def _archive_offspring(self, n: int) -> np.ndarray:
        """``n`` children of archive members: simulated binary crossover, then polynomial mutation.

        Each child has two parents drawn by the leader rule (:meth:`GridArchive.select_leaders`,
        so members of sparse cells are preferred, as for leaders), pymoo's SBX (probability
        :data:`CROSSOVER_PROBABILITY`, η = :data:`CROSSOVER_ETA`, one child per pair) and
        pymoo's polynomial mutation of every child (1/n_var per variable, η = ``mutation_eta``).

        Why (issue 21, docs/MOPSO.md): a particle moves all its variables along one line
        towards its attractors, so it cannot combine the good distance variables of two
        members (WFG4's separable 30-minimum shift), and a swarm whose archive has
        collapsed onto one point has every attractor on that point (ZDT2's f1 = 0 end):
        only a mutated copy of a converged member enters such an archive. Crossover of
        archive members does both, as NSGA-II's variation does; its children of a
        one-member archive are mutated copies of it. On a problem with constraints, the mutation takes
        η = 20 (``constrained_fine_mutation``, :meth:`_mutation_etas`) and a share ``constrained_reset``
        of the children then gets one variable redrawn uniformly (:func:`uniform_reset`, :meth:`_reset_share`);
        in a constrained run's late phase the last round(``constrained_refine`` × n) children are refinement
        children instead (:meth:`_refined_children`), which the redraw may hit as well.
        """
        refined = self._refined_count(n)
        children = self._varied_children(n - refined)
        if refined:
            children = np.vstack([children, self._refined_children(refined)])
        share = self._reset_share()
        if share:
            problem = self.problem
            children = uniform_reset(children, problem.xl, problem.xu, share, self.random_state)
        return children

    def _varied_children(self, n: int) -> np.ndarray:
        """Crossover and polynomial mutation of the archive offspring (:meth:`_archive_offspring`)."""
        archive, problem, rng = self.leader_archive, self.problem, self.random_state
        if n == 0:
            return np.empty((0, problem.n_var))
        pairs = archive.select_leaders(2 * n, rng, self.leader).reshape(n, 2)
        compiled = self._compiled_move()
        if compiled is not None:
            first, second = archive.X[pairs[:, 0]].astype(float), archive.X[pairs[:, 1]].astype(float)
            return compiled.offspring(first, second, np.asarray(problem.xl, dtype=float),
                                      np.asarray(problem.xu, dtype=float), CROSSOVER_PROBABILITY, CROSSOVER_ETA,
                                      self._eta_rows(n), self._bit_source(compiled))
        children = sbx_children(archive.X[pairs[:, 0]], archive.X[pairs[:, 1]], problem.xl, problem.xu, rng,
                                CROSSOVER_PROBABILITY, CROSSOVER_ETA)
        return polynomial_mutation(children, problem.xl, problem.xu, self._mutation_etas(n), 1.0, rng)

    def _refined_count(self, n: int) -> int:
        """How many of ``n`` archive offspring are refinement children: round(``constrained_refine`` × n) in a
        constrained run's late phase (``constrained_late_phase``) once the archive holds a feasible point, else 0
        (so the infeasible start, the search of the first half and unconstrained runs are unchanged)."""
        if not (self.constrained_refine and self._late_phase() and self.leader_archive.feasible):
            return 0
        return int(round(self.constrained_refine * n))

    def _refined_children(self, n: int) -> np.ndarray:
        """``n`` refinement children (``constrained_refine``): a local search around feasible archive members.

        Each child is an archive member with every variable moved by pymoo's polynomial mutation step of
        η = :data:`REFINE_ETA`, about 1 % of its range. A share :data:`REFINE_ENDS` of the members are the
        ends of the front (the minimum of each objective in turn), the others are drawn by the leader rule
        (on a full feasible archive NSGA-II's crowding tournament). Why (issue 33, fifth
        change, docs/MOPSO.md): on MW3, MW7, CTP2 and CTP3 the final archive was spread as evenly as
        NSGA-II's population but lay further from the front — near kinks and segment ends on constraint
        boundaries (MW7's lower branch after f1 ≈ 0.9, CTP2's first segment next to the f1 = 0 end, CTP3's
        isolated front points) — and a child of SBX between two distant members, or of a one-variable
        mutation, lands near such a member too rarely to move it closer.
        """
        archive, problem, rng = self.leader_archive, self.problem, self.random_state
        chosen = archive.select_leaders(n, rng, self.leader)
        # the first round(REFINE_ENDS n) refine the ends of the front instead, the objectives' minima in turn
        ends = int(round(REFINE_ENDS * n))
        chosen[:ends] = np.argmin(archive.F, axis=0)[np.arange(ends) % archive.F.shape[1]]
        return polynomial_steps(archive.X[chosen], problem.xl, problem.xu, np.full(n, REFINE_ETA), 1.0, rng)

    def _reset_share(self) -> float:
        """The share of this generation's archive offspring redrawn by :func:`uniform_reset` (``constrained_reset``):
        the first share until the archive is feasible and full, the second from then on; 0 without constraints."""
        if not (self.constrained_reset and self.constrained_problem):
            return 0.0
        archive = self.leader_archive
        return self.constrained_reset[1] if archive.feasible and archive.filled else self.constrained_reset[0]
