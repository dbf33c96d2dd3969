"""Grid-archive multi-objective particle swarm optimiser (paper 000, §2.2.2).

The algorithm is the MOPSO of Coello Coello, Pulido & Lechuga, "Handling multiple
objectives with particle swarm optimization", IEEE Trans. Evol. Comput. 8(3),
256–279, 2004, as paper 000 uses it to minimise (FAR, MDR) over the chart parameters
(eq. 36): an external archive of non-dominated solutions on an adaptive hypercube
grid, truncated by eq. 37 when over capacity, leaders drawn from sparsely populated
cells, and a velocity/position update (eqs. 38–39).

One class, two presets:

* ``MOPSO()`` — the robust default, a swarm/recombination hybrid: each generation 30 % of
  the evaluations are particle moves and 70 % are children of archive members (crossover
  and mutation, ``recombination=0.7``), the share that made it robust (issues 21 and 33,
  ``docs/MOPSO.md``). It keeps the grid archive, eq. 37 and the
  density-based (roulette) leader choice, and changes what measurements on ZDT1–4,
  ZDT6, a ZDT1 with its optimum inside the box, and DTLZ2 (:mod:`mosd.optim.benchmarks`,
  ``docs/MOPSO.md``) showed to matter: inertia and social coefficients that decrease
  over the run, positions that stay on a bound they crossed (``boundary="clip"``),
  polynomial mutation of a share of the swarm, a personal best that follows the
  particle unless dominated, and, inside eq. 37, removal of the most crowded member
  of a cell rather than a random one — which in three or more objectives, where
  most cells hold one member, is what keeps the archive spread — with the archive's
  extremes kept; velocities are clamped to each variable's range. While the archive
  is less than half full, particles make SMPSO's constricted, partly repulsive move
  (``exploration``, :func:`smpso_velocity`): on multimodal landscapes (ZDT4, DTLZ1,
  DTLZ3) the attraction-only swarm collapsed onto a local front (issue 21). And 70 % of
  each generation's evaluations are archive offspring (``recombination``,
  :meth:`MOPSO._archive_offspring`: crossover and long-tailed mutation of two archive
  members), which combine what particles cannot (WFG4's separable multimodal distance
  variables, OSY's disconnected feasible regions) and re-spread an archive that has
  collapsed onto one point (ZDT2) (issue 21).
  While nothing feasible has been found, the archive holds a bounded set of the least
  infeasible points instead of the single least infeasible one (``infeasible="diverse"``,
  issue 33): leaders and parents stay diverse from an infeasible start (MW1). On a constrained
  problem, particles and offspring take NSGA-II's fine mutation steps (η = 20,
  ``constrained_fine_mutation``) from the first generation, and a share of the offspring gets one
  variable redrawn uniformly (``constrained_reset``: 30 % until the archive is feasible and full,
  10 % afterwards), which makes the long jumps instead (OSY's disconnected regions) and lets the
  archive leave a local front such as MW2's; once the archive is feasible and full, leaders and
  parents are drawn by crowding distance and truncation removes the most crowded members over the
  whole archive (``constrained``). From half the planned run on, a constrained run refines the front it
  found: 30 % of the offspring are an archive member (a third of them the ends of the front) with every
  variable moved by a small polynomial step, and the mutation takes η 50 (``constrained_late_phase``,
  ``constrained_refine``): the IGD gap to NSGA-II was convergence at the ends and kinks of the front, on
  constraint boundaries. That spread and converged the constrained fronts (MW2, MW3, MW7, CTP2, CTP3,
  issue 33). Unconstrained runs are unaffected.
* ``MOPSO(**PAPER_PRESET)`` (``MOPSO.paper()``, ``optimizer=mopso_paper``) — the paper's
  pure swarm, paper 000's Table 2 literally (every evaluation a particle move): constriction
  w = 0.7298, c1 = c2 = 1.4962, velocities reflected at the bounds, roulette-wheel leaders,
  Coello's mutation, random removal inside eq. 37, Coello's constraint handling; with the
  same seed it gives the same archive as this module did before the robust default.

The archive (grid, eq. 37, leader choice) and the constrained dominance live in
:mod:`mosd.optim.archive`; this module keeps the algorithm class and pymoo's lifecycle, and the rest of the
swarm lives in rooms by job (issue 50), whose names it re-exports: the operators on arrays in
:mod:`mosd.optim.variation`; the particles' move in :mod:`mosd.optim.particle_move`, the archive offspring in
:mod:`mosd.optim.offspring`, the compiled move's glue in :mod:`mosd.optim.compiled_move` and the run-length
planning in :mod:`mosd.optim.planning` (mixins of :class:`MOPSO`); the constants, the paper preset and the
option checks in :mod:`mosd.optim.mopso_settings`; pymoo's individuals in :mod:`mosd.optim.individuals`.
The swarm's state is arrays; pymoo's
individuals are built only where its API needs them: :meth:`MOPSO.next` runs a generation on arrays
and hands pymoo's ``advance`` an :class:`EvaluatedArrays`, whose individuals are built when the archive
keeps a candidate or something reads ``pop`` (``res.pop``, ``res.history``, callbacks); ``ask``/``tell``
and other evaluators get Populations (:func:`new_population`, evaluated by :class:`ArrayEvaluator`, which
hands X, F and CV back as arrays). Per-candidate ``Individual`` and ``Population`` bookkeeping, and
pymoo's operator functions' per-call overhead on a swarm of 100 (:func:`polynomial_steps`,
:func:`sbx_pairs` do their arithmetic and draws on arrays), were most of the optimiser's own time per
generation (issue 32): on the project's 2-core machine the main command's (swarm of 100) fell from 2.6–2.8 ms to
1.2–1.3 ms a generation, measured side by side with the code before at load average about 1.

Where the paper and Coello 2004 leave a detail open, the choice is documented at the
place that implements it:

* order of eqs. 38/39 — :meth:`MOPSO._infill`;
* how eq. 37 walks over the grid cells — :func:`~mosd.optim.archive.eq37_removal_counts`
  and :meth:`~mosd.optim.archive.GridArchive._truncate`;
* duplicates and constraints in the archive — :meth:`~mosd.optim.archive.GridArchive.update`;
* the run length that schedules and Coello's mutation refer to —
  :meth:`~mosd.optim.planning.GenerationPlan._planned_generations`.

Paper 000's step 4 also says to stop ("jump to step 7") once the archive is full; this
implementation does not: the run length is pymoo's termination criterion (the paper's
Table 2 uses M = 100 iterations), because an archive of 100 fills within a few
generations and stopping there would make M meaningless.

Integer variables: a problem may carry ``is_integer``, a boolean array of length
``n_var`` (absent: all real). Those coordinates are rounded to the nearest integer in
[⌈xl⌉, ⌊xu⌋] after sampling, every move and every mutation, so each evaluated X and
``res.X`` is integral there. Velocities stay real: rounding repairs the position and
leaves the swarm dynamics (eq. 39) as they are.
"""
from __future__ import annotations

import math

import numpy as np
from pymoo.core.algorithm import Algorithm
from pymoo.core.individual import Individual
from pymoo.core.population import Population
from pymoo.core.sampling import Sampling
from pymoo.operators.sampling.rnd import FloatRandomSampling
from pymoo.util.display.multi import MultiObjectiveOutput

from ..validation import ConfigError, Interval, check_choice, check_in, check_int
from .archive import CONSTRAINED_RULES, INFEASIBLE_RULES, LEADER_RULES, REMOVAL_RULES, GridArchive, evaluated_arrays
from .compiled_move import CompiledMove
from .individuals import (ArrayEvaluator, EvaluatedArrays, SwarmPopulation, constraint_violation, new_population,
                          restart_pymoo_run)
from .mopso_settings import (COELLO_INERTIA, CONSTRAINED_LATE_PHASE, CONSTRAINED_REFINE, CONSTRAINED_RESET,
                             FINE_MUTATION_ETA, LATE_FINE_ETA, MUTATION_DECAY_EXPONENT, MUTATIONS, PAPER_MAX_ITERATIONS,
                             PAPER_PRESET, PERSONAL_BEST_RULES, REFINE_ENDS, REFINE_ETA, SCHEDULED, VELOCITIES,
                             coefficient, integer_mask, reset_shares)
from .offspring import ArchiveOffspring
from .particle_move import ParticleMove
from .planning import GenerationPlan
from .variation import (BOUNDARY_RULES, CONSTRICTION_PHI, CROSSOVER_ETA, CROSSOVER_PROBABILITY, SMPSO_C_RANGE,
                        SMPSO_INERTIA, SMPSO_MAX_VELOCITY, apply_bounds, constriction_coefficients, polynomial_mutation,
                        polynomial_steps, round_integers, sbx_children, sbx_pairs, smpso_velocity, to_bounds,
                        uniform_reset)

#: the names this module has always offered (kept importable from here; they live in the modules above)
__all__ = ["MOPSO", "ArrayEvaluator", "EvaluatedArrays", "SwarmPopulation", "new_population", "restart_pymoo_run",
           "BOUNDARY_RULES", "CONSTRICTION_PHI", "CROSSOVER_ETA", "CROSSOVER_PROBABILITY", "SMPSO_C_RANGE",
           "SMPSO_INERTIA", "SMPSO_MAX_VELOCITY", "apply_bounds", "constriction_coefficients", "polynomial_mutation",
           "polynomial_steps", "round_integers", "sbx_children", "sbx_pairs", "smpso_velocity", "to_bounds",
           "uniform_reset", "COELLO_INERTIA", "CONSTRAINED_LATE_PHASE", "CONSTRAINED_REFINE", "CONSTRAINED_RESET",
           "FINE_MUTATION_ETA", "LATE_FINE_ETA", "MUTATION_DECAY_EXPONENT", "MUTATIONS", "PAPER_MAX_ITERATIONS",
           "PAPER_PRESET", "PERSONAL_BEST_RULES", "REFINE_ENDS", "REFINE_ETA", "SCHEDULED", "VELOCITIES"]


class MOPSO(ParticleMove, CompiledMove, ArchiveOffspring, GenerationPlan, Algorithm):
    """Grid-archive multi-objective PSO of Coello et al. 2004 as used by paper 000.

    The defaults are the robust variant, a swarm/recombination hybrid (70 % of each
    generation's evaluations are archive offspring, ``recombination``); ``MOPSO(**PAPER_PRESET)``
    (or :meth:`MOPSO.paper`, ``optimizer=mopso_paper``) is paper 000's Table 2, the paper's
    pure swarm. Each move (eqs. 38–39, velocity first):

        v ← w v + c1 r1 (pbest − x) + c2 r2 (leader − x),  v clamped to ±max_velocity Δ,
        (while the archive is small, SMPSO's move instead for some particles: ``exploration``)
        x ← x + v,  then the bound rule, mutation and integer rounding,

    with r1, r2 ~ U(0, 1) per particle and dimension, a leader per particle and move
    drawn from the archive, and Δ = xu − xl per variable. With ``recombination`` r, only
    the first N − round(r N) slots move so; the last round(r N) are filled each generation
    by children of archive members (:meth:`_archive_offspring`).

    Parameters
    ----------
    pop_size : int
        Number of particles N (Table 2: 100).
    archive_size : int
        Archive capacity Z_ar (Table 2: 100).
    n_divisions : int
        Grid intervals per objective (Coello 2004: 30; default 50, measured slightly
        better on ZDT2/ZDT3 and no worse elsewhere).
    velocity : {"scheduled", "constriction", "inertia"}
        Where unset coefficients (``w``, ``c1``, ``c2`` = None) come from.
        "scheduled" (the default): w 0.6 → 0.2, c1 = 1, c2 1.75 → 1.0 linearly over the
        run — a decreasing inertia as in Shi & Eberhart 1998; the social coefficient
        falls as well (unlike Ratnaweera et al.'s 2004 TVAC): early moves overshoot the
        leader (c2 r2 > 1), late ones contract onto it. Constant coefficients either
        converged on ZDT1 and stalled inside the box, or the reverse (docs/MOPSO.md).
        "constriction": paper 000 eq. 39 with Clerc's
        constriction factor, φ = 4.1 → w = 0.7298, c1 = c2 = 1.4962 (Table 2).
        "inertia": Coello 2004's W = 0.4, c1 = c2 = 1.
    w, c1, c2 : float, pair of float, or None
        Inertia weight and cognitive / social coefficients, >= 0. A pair [start, end]
        changes linearly from the first move to the last planned one (see ``horizon``)
        and stays at ``end`` afterwards.
    max_velocity : float or None
        Each velocity component is clamped to ±max_velocity × (xu − xl) before the move
        (SMPSO: 0.5). None: no clamp (paper 000 and Coello 2004). The default 1.0 (at
        most the variable's range per move) measured as good as no clamp and better than
        0.5 with the scheduled coefficients, and still stops a diverging swarm.
    boundary : {"clip", "reflect", "absorb"}
        What an out-of-range coordinate does to its velocity (:func:`apply_bounds`);
        "reflect" is paper 000's and Coello's rule.
    leader : {"roulette", "tournament"}
        Leader choice from the grid (:meth:`GridArchive.select_leaders`).
    personal_best : {"dominance", "coin"}
        pbest update (:meth:`_update_personal_best`); "coin" is Coello 2004's.
    removal : {"crowding", "random"}
        Which members of a crowded cell eq. 37 removes (:meth:`GridArchive._truncate`).
    keep_extremes : bool
        Truncation never removes the archive's best member in any objective.
    mutation : {"polynomial", "coello"} or None
        "polynomial": each move, a share ``mutation_rate`` of the particles (drawn at
        random) gets Deb's polynomial mutation with probability 1/n_var per variable and
        distribution index ``mutation_eta`` (pymoo's ``PolynomialMutation``; SMPSO: one
        particle in six, η = 20). "coello": Coello 2004's operator
        (:meth:`_coello_mutation`), active during the first ``mutation_rate`` of the run.
        None: no mutation (paper 000 does not mention one).
    mutation_rate : float or None
        In (0, 1]: the share of particles mutated per move ("polynomial"), or Coello's p_m,
        the share of the run during which mutation acts ("coello"). None: no mutation
        (the pre-existing key's meaning).
    mutation_eta : float
        Distribution index of the polynomial mutation (of particles and of archive
        offspring), >= 0. Default 3: long-tailed steps, chosen (issue 21) so that offspring
        jump between OSY's disconnected feasible regions (20, the issue-14 value: mostly steps
        of about 5 % of the range; docs/MOPSO.md). On a problem with constraints, OSY
        included, ``constrained_fine_mutation`` now replaces it by 20 and the redraw of
        ``constrained_reset`` makes those jumps (issue 33).
    exploration : float in (0, 1] or None
        While the archive holds fewer than ``exploration`` × ``archive_size`` members,
        the first ⌈s N⌉ particles, s = 1 − |A| / (``exploration`` × Z_ar)
        (:meth:`_exploring_share`), make SMPSO's constricted move (:func:`smpso_velocity`)
        instead of the velocity variant's. Default 0.5: what lets the swarm leave the local
        fronts of ZDT4, DTLZ1 and DTLZ3 (issue 21, docs/MOPSO.md). None: never (the
        issue-14 default and the paper preset).
    recombination : float in (0, 1) or None
        Share r of the swarm's N slots filled each move by archive offspring instead of
        particle moves: round(r N) children (at most N − 1) of two archive members each,
        drawn by the ``leader`` rule, through pymoo's SBX (η 15, probability 0.9) and
        polynomial mutation (``mutation_eta``, 1/n_var per variable)
        (:meth:`_archive_offspring`). Default 0.7 (issue 21, docs/MOPSO.md: 0.3–0.5 left
        WFG4 below 0.95 × NSGA-II). None: every slot is a particle (issue-14 default, paper
        preset).
    infeasible : {"diverse", "least"}
        What the archive holds while no feasible point has been found
        (:class:`~mosd.optim.archive.GridArchive`). "diverse" (default): the ⌈``archive_size`` / 2⌉
        least infeasible distinct points (constraint violation first, then crowding, as
        NSGA-II's constrained domination ranks its population), leaders and parents drawn from
        them by binary tournament on the violation; from the first feasible point on, the
        archive is the feasible non-dominated set as before. "least" (Coello 2004, the paper
        preset): the constrained dominance alone, which keeps only the least infeasible point,
        so that one point is every leader and both parents of every offspring until a feasible
        point is found (MW1: 60–100 generations, issue 33, docs/MOPSO.md).
    constrained : {"crowding", "grid"}
        How the feasible archive of a problem with constraints is kept spread. "crowding"
        (default): once the feasible archive is full (:data:`~mosd.optim.archive.SPREAD_FILL`),
        leaders and parents by NSGA-II's crowding-distance binary tournament, and truncation of
        the most crowded members over the whole archive rather than cell by cell
        (:class:`~mosd.optim.archive.GridArchive`); "grid" (paper preset): cells, eq. 37 and the
        ``leader`` rule, as on an unconstrained problem. With the grid rules the IGD of MW2, MW3,
        MW7, CTP2 and CTP3 was 1.3–1.7 × NSGA-II's (issue 33, docs/MOPSO.md). An unconstrained
        problem always uses the grid rules.
    constrained_fine_mutation : float in [0, 1] or None
        On a problem with constraints, this share of the archive offspring and of the mutated
        particles (the first round(share × n) rows) is mutated with NSGA-II's η = 20
        (:data:`FINE_MUTATION_ETA`) instead of ``mutation_eta``, from the first generation on: the
        optimum lies on a constraint boundary, where the long-tailed steps mostly leave the feasible
        region (issue 33, docs/MOPSO.md). Default 1 (all of them; the long jumps come from the uniform
        redraw of ``constrained_reset``); None or 0: none.
    constrained_reset : float in [0, 1], pair of them, or None
        On a problem with constraints, this share of each generation's archive offspring gets one
        variable, chosen at random, redrawn uniformly in its bounds after crossover and mutation
        (:func:`uniform_reset`); a pair [s1, s2]: s1 until the archive is feasible and full, s2 from
        then on. MW2's distance function has a second basin far from the optimum in each variable; on 2
        of 5 seeds the default settled there (a local front 0.04–0.1 above the true one), and the
        polynomial mutation's steps do not leave it; and with the fine mutation from the first generation
        the redraw is what still finds OSY's disconnected feasible regions while the archive fills
        (issue 33, docs/MOPSO.md). Default [0.3, 0.1] (21, then 7 of 70 offspring); None or 0: none.
    constrained_refine : float in [0, 1] or None
        On a problem with constraints, in the late phase (``constrained_late_phase``) and once the archive
        holds a feasible point, this share of each generation's archive offspring are refinement children
        instead of crossover children: an archive member (a third of them the ends of the front) with every
        variable moved by a polynomial step of η = :data:`REFINE_ETA` (:meth:`_refined_children`). The IGD
        gap to NSGA-II on MW3, MW7, CTP2 and CTP3 was convergence — archive points 0.01–0.04 off the front
        at its ends and kinks, which lie on constraint boundaries, and CTP3's isolated front points reached
        less closely — which crossover of distant members rarely refines (issue 33, fifth change,
        docs/MOPSO.md). Default 0.3 (21 of 70 offspring); None or 0: none.
    constrained_late_phase : float in [0, 1] or None
        On a problem with constraints, the share of the planned generations after which the run refines the
        front the first part found: the refinement children of ``constrained_refine``, and the mutated
        particles and all archive offspring with the polynomial mutation index :data:`LATE_FINE_ETA`
        instead of η 20 (the uniform redraw of ``constrained_reset`` goes on: stopping it left MW2 on its
        local front on 2 seeds of 10) (issue 33, fifth change, docs/MOPSO.md). Default 0.5; None: no late
        phase (and no refinement). Needs the run length (:meth:`_planned_generations`).
    horizon : int or None
        Run length in generations (the initial swarm included) that scheduled
        coefficients and Coello's mutation refer to. None: taken from the termination if
        it is a plain ``("n_gen", G)`` (G) or ``("n_eval", E)`` (⌈E / pop_size⌉)
        criterion; any other termination (time, tolerance, pymoo's default) does not say
        how long the run lasts, so paper 000's M = 100 is assumed, with a warning.
    sampling : pymoo Sampling, optional
        Initial positions; uniform in the bounds by default (paper 000 step 1).
    **kwargs
        Passed to :class:`pymoo.core.algorithm.Algorithm` (termination, callback,
        save_history, seed, …).

    Notes
    -----
    Median hypervolumes at 10,000 evaluations are in ``docs/MOPSO.md`` (and
    ``python -m mosd.optim.benchmarks``). ``res.X``/``res.F`` are the final archive. The
    archive lives in ``self.leader_archive`` because pymoo's base class reserves
    ``self.archive``. Every random draw uses ``self.random_state``, the Generator pymoo
    seeds in ``setup`` from ``seed``; ``setup`` also resets the swarm, so a second
    ``setup`` starts a new run.
    """

    def __init__(self, pop_size: int = 100, archive_size: int = 100, n_divisions: int = 50,
                 velocity: str = "scheduled", w=None, c1=None, c2=None,
                 max_velocity: float | None = 1.0, boundary: str = "clip",
                 leader: str = "roulette", personal_best: str = "dominance",
                 removal: str = "crowding", keep_extremes: bool = True,
                 mutation: str | None = "polynomial", mutation_rate: float | None = 0.15,
                 mutation_eta: float = 3.0, exploration: float | None = 0.5,
                 recombination: float | None = 0.7, infeasible: str = "diverse", constrained: str = "crowding",
                 constrained_fine_mutation: float | None = 1.0,
                 constrained_reset=CONSTRAINED_RESET, constrained_refine: float | None = CONSTRAINED_REFINE,
                 constrained_late_phase: float | None = CONSTRAINED_LATE_PHASE, horizon: int | None = None,
                 sampling: Sampling | None = None, output=None, **kwargs):
        # ArrayEvaluator unless the caller brings an evaluator (then the arrays are read back from the individuals)
        kwargs.setdefault("evaluator", ArrayEvaluator())
        super().__init__(output=MultiObjectiveOutput() if output is None else output, **kwargs)
        self.pop_size = check_int("optimizer.pop_size", pop_size, 1)
        self.archive_size = check_int("optimizer.archive_size", archive_size, 1)
        self.n_divisions = check_int("optimizer.n_divisions", n_divisions, 1)
        self.velocity = check_choice("optimizer.velocity", velocity, VELOCITIES)
        defaults = {"scheduled": SCHEDULED, "constriction": constriction_coefficients(),
                    "inertia": COELLO_INERTIA}[velocity]
        self.w, self.c1, self.c2 = (coefficient(f"optimizer.{name}", value, default)
                                    for name, value, default in zip(("w", "c1", "c2"), (w, c1, c2), defaults))
        self.max_velocity = (None if max_velocity is None else
                             check_in("optimizer.max_velocity", max_velocity,
                                      Interval(0.0, math.inf, open_low=True, open_high=True)))
        self.boundary = check_choice("optimizer.boundary", boundary, BOUNDARY_RULES)
        self.leader = check_choice("optimizer.leader", leader, LEADER_RULES)
        self.personal_best = check_choice("optimizer.personal_best", personal_best, PERSONAL_BEST_RULES)
        self.removal = check_choice("optimizer.removal", removal, REMOVAL_RULES)
        self.keep_extremes = check_choice("optimizer.keep_extremes", keep_extremes, (True, False))
        self.mutation = check_choice("optimizer.mutation", mutation, (*MUTATIONS, None))
        self.mutation_rate = (None if mutation_rate is None else
                              check_in("optimizer.mutation_rate", mutation_rate,
                                       Interval(0.0, 1.0, open_low=True)))
        self.mutation_eta = check_in("optimizer.mutation_eta", mutation_eta,
                                     Interval(0.0, math.inf, open_high=True))
        self.exploration = (None if exploration is None else
                            check_in("optimizer.exploration", exploration, Interval(0.0, 1.0, open_low=True)))
        self.recombination = (None if recombination is None else
                              check_in("optimizer.recombination", recombination,
                                       Interval(0.0, 1.0, open_low=True, open_high=True)))
        self.infeasible = check_choice("optimizer.infeasible", infeasible, INFEASIBLE_RULES)
        self.constrained = check_choice("optimizer.constrained", constrained, CONSTRAINED_RULES)
        self.constrained_fine_mutation = (None if constrained_fine_mutation is None else
                                          check_in("optimizer.constrained_fine_mutation", constrained_fine_mutation,
                                                   Interval(0.0, 1.0)))
        self.constrained_reset = reset_shares(constrained_reset)
        self.constrained_refine = (None if constrained_refine is None else
                                   check_in("optimizer.constrained_refine", constrained_refine, Interval(0.0, 1.0)))
        self.constrained_late_phase = (None if constrained_late_phase is None else
                                       check_in("optimizer.constrained_late_phase", constrained_late_phase,
                                                Interval(0.0, 1.0)))
        self.horizon = None if horizon is None else check_int("optimizer.horizon", horizon, 1)
        if sampling is not None and not isinstance(sampling, Sampling):
            raise ConfigError(f"optimizer.sampling={sampling!r} is not allowed; allowed: a pymoo Sampling")
        self.sampling = FloatRandomSampling() if sampling is None else sampling

        # swarm state, (re)built by _setup
        self.leader_archive: GridArchive | None = None
        self.particle_position: np.ndarray | None = None
        self.particle_velocity: np.ndarray | None = None
        self.pbest_X: np.ndarray | None = None
        self.pbest_F: np.ndarray | None = None
        self.pbest_CV: np.ndarray | None = None
        self.is_integer: np.ndarray | None = None
        self.constrained_problem = False
        self.planned_generations: int | None = None

    @classmethod
    def paper(cls, **overrides) -> "MOPSO":
        """Paper 000's Table 2 settings (:data:`PAPER_PRESET`), optionally overridden."""
        return cls(**{**PAPER_PRESET, **overrides})

    # -- pymoo lifecycle ------------------------------------------------------------------

    def _setup(self, problem, **kwargs):
        if not problem.has_bounds() or not (np.all(np.isfinite(problem.xl))
                                            and np.all(np.isfinite(problem.xu))):
            raise ConfigError("optimizer: the problem needs finite bounds xl, xu; allowed: finite bounds")
        self.is_integer = integer_mask(problem)
        # issue 33: the crowding rules, the fine mutation and the redraw act on constrained problems only, so that an
        # unconstrained run (the presets' tuning problems, issue 21's table) is the same bit for bit
        self.constrained_problem = bool(problem.has_constraints())
        self.leader_archive = GridArchive(self.archive_size, self.n_divisions, self.removal,
                                          self.keep_extremes, self.infeasible,
                                          self.constrained if self.constrained_problem else "grid")
        self.particle_position = self.particle_velocity = None
        self.pbest_X = self.pbest_F = self.pbest_CV = None
        self.planned_generations = self._planned_generations()
        restart_pymoo_run(self)

    # pymoo keeps the current and the last evaluated population in ``pop`` and ``off``; :meth:`next` stores the
    # generation's arrays there (EvaluatedArrays) and the individuals are built when one of them is read
    @property
    def pop(self) -> Population | None:
        pop = self.__dict__.get("_pop")
        return pop.population() if isinstance(pop, EvaluatedArrays) else pop

    @pop.setter
    def pop(self, value) -> None:
        self.__dict__["_pop"] = value

    @property
    def off(self) -> Population | None:
        off = self.__dict__.get("_off")
        return off.population() if isinstance(off, EvaluatedArrays) else off

    @off.setter
    def off(self, value) -> None:
        self.__dict__["_off"] = value

    def next(self) -> None:
        """pymoo's ``Algorithm.next`` (infill, evaluate, advance) on arrays, when MOPSO's own evaluator evaluates.

        The positions of the move (or the initial sampling), one ``problem.evaluate`` of them as
        :class:`ArrayEvaluator` makes it (counted in ``evaluator.n_eval``), then pymoo's ``advance`` with an
        :class:`EvaluatedArrays`: the same draws and arithmetic as the Population path, without building the
        individuals nothing reads (issue 32). Another evaluator, an evaluator callback or pymoo's ``archive``
        take pymoo's own ``next``, and so does a subclass that overrides a hook of the Population path
        (``infill``, ``_infill``, ``_initialize_infill``); ``ask``/``tell`` keep returning and taking Populations.
        The first generation (the initial swarm) takes pymoo's own ``next`` as well, whose ``infill`` starts the
        run (the one place it starts, so nothing here calls pymoo's private start-up): the same sampling and
        evaluation on a Population of :func:`new_population`, once per run.
        """
        evaluator, cls = self.evaluator, type(self)
        if (not self.is_initialized or type(evaluator) is not ArrayEvaluator or evaluator.callback is not None
                or self.archive is not None or cls.infill is not MOPSO.infill or cls._infill is not MOPSO._infill
                or cls._initialize_infill is not MOPSO._initialize_infill):
            return super().next()
        if self.problem is None:
            raise Exception("Please call `setup(problem)` before calling next().")
        self.advance(infills=self._evaluate_positions(self._moved_positions()))

    def _evaluate_positions(self, X: np.ndarray) -> EvaluatedArrays:
        """``X`` evaluated as :meth:`ArrayEvaluator.eval` evaluates :func:`new_population`'s individuals."""
        evaluator, problem = self.evaluator, self.problem
        config = Individual.default_config()
        owned = np.array(X, dtype=float)  # the individuals' rows: not the array the problem gets
        X = owned.copy()
        out = problem.evaluate(X, return_values_of=evaluator.evaluate_values_of, return_as_dictionary=True,
                               algorithm=self)
        CV = None
        if problem.has_constraints() and len(X):
            CV = constraint_violation(out, len(X), config)
        evaluator.n_eval += len(X)
        return EvaluatedArrays(owned, out, CV, self.n_iter, config, evaluated_X=X)

    def _initial_positions(self) -> np.ndarray:
        """The initial swarm (paper 000 step 1): the sampling's positions, integer variables rounded."""
        # Sampling.do wraps its samples in Population.new("X", ·), whose .get("X") gives them back as one array
        X = self.sampling.do(self.problem, self.pop_size, algorithm=self, random_state=self.random_state).get("X")
        return round_integers(X, self.is_integer, self.problem.xl, self.problem.xu)

    def _initialize_infill(self):
        return new_population(self._initial_positions(), self.n_iter)

    def infill(self) -> Population | None:
        """pymoo's ``Algorithm.infill`` (initialise on the first call, then ``_infill``), tagging the infills'
        ``n_gen`` and ``n_iter`` (data of the individuals) without ``Population.set``'s per-individual lookups."""
        if self.problem is None or not self.is_initialized:
            # pymoo's start of a run (its hook before the initial infill), then _initialize_infill and the tags
            return super().infill()
        infills = self._infill()
        if infills is not None and not (isinstance(infills, SwarmPopulation) and infills.tags == self.n_iter):
            # not tagged by new_population (an override of _infill may return any population)
            for individual in infills:
                individual.data["n_gen"] = individual.data["n_iter"] = self.n_iter
        return infills

    def _evaluated(self, infills) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """X, F, CV of the evaluated infills: :class:`EvaluatedArrays`' or :class:`ArrayEvaluator`'s arrays, else
        read from the individuals."""
        if isinstance(infills, EvaluatedArrays):
            return infills.swarm
        last = getattr(self.evaluator, "last", None)
        if last is not None and last[0] is infills:
            # read once: res.history's copies of the algorithm need not carry them
            self.evaluator.last = None
            return last[1:]
        return evaluated_arrays(infills, self.problem.has_constraints())

    def _initialize_advance(self, infills=None, **kwargs):
        # paper 000 step 1: v_0 = 0 and Pbest_0 = Pop_0
        X, F, CV = evaluated = self._evaluated(infills)
        self.particle_position = X
        self.particle_velocity = np.zeros_like(X, dtype=float)
        self.pbest_X, self.pbest_F, self.pbest_CV = X.copy(), F.copy(), CV.reshape(-1).copy()
        self.leader_archive.update(infills, self.random_state, evaluated)

    def _infill(self):
        """One move of the swarm (:meth:`_moved_positions`) as a Population."""
        return new_population(self._moved_positions(), self.n_iter)

    def _advance(self, infills=None, **kwargs):
        self.pop = infills
        evaluated = self._evaluated(infills)
        self.leader_archive.update(infills, self.random_state, evaluated)
        self._update_personal_best(*evaluated)

    def _set_optimum(self):
        self.opt = self.leader_archive.members.copy()
