"""Grid-archive multi-objective particle swarm optimiser (paper 000, §2.2.2).

The algorithm is the MOPSO of Coello Coello, Pulido & Lechuga, "Handling multiple
objectives with particle swarm optimization", IEEE Trans. Evol. Comput. 8(3),
256–279, 2004, as paper 000 uses it to minimise (FAR, MDR) over the chart parameters
(eq. 36): an external archive of non-dominated solutions on an adaptive hypercube
grid, truncated by eq. 37 when over capacity, leaders drawn from sparsely populated
cells, and the constriction-factor velocity update of eqs. 38–39 (Table 2:
w = 0.7298, c1 = c2 = 1.4962).

Where the paper and Coello 2004 leave a detail open, the choice is documented at the
place that implements it:

* order of eqs. 38/39 — :meth:`MOPSO._infill`;
* how eq. 37 walks over the grid cells — :func:`eq37_removal_counts`;
* duplicates and constraints in the archive — :meth:`GridArchive.update`;
* the mutation schedule and its horizon — :meth:`MOPSO._mutate` and
  :meth:`MOPSO._planned_generations`.

Paper 000's step 4 also says to stop ("jump to step 7") once the archive is full; this
implementation does not: the run length is pymoo's termination criterion (the paper's
Table 2 uses M = 100 iterations), because an archive of 100 fills within a few
generations and stopping there would make M meaningless.
"""
from __future__ import annotations

import math
import warnings

import numpy as np
from pymoo.core.algorithm import Algorithm
from pymoo.core.population import Population
from pymoo.core.sampling import Sampling
from pymoo.operators.sampling.rnd import FloatRandomSampling
from pymoo.termination.max_eval import MaximumFunctionCallTermination
from pymoo.termination.max_gen import MaximumGenerationTermination
from pymoo.util.display.multi import MultiObjectiveOutput

from ..validation import ConfigError, Interval, check_choice, check_in, check_int

#: φ = φ1 + φ2 of Clerc & Kennedy's constriction factor; paper 000 (below eq. 39) uses 4.1.
CONSTRICTION_PHI = 4.1
#: Coello 2004's inertia variant: W = 0.4 and unit acceleration coefficients.
COELLO_INERTIA = (0.4, 1.0, 1.0)
#: Coello 2004's numerator x of the cell fitness x / occupancy used for leader selection.
LEADER_FITNESS_NUMERATOR = 10.0
#: Iterations M of paper 000's Table 2, used as mutation horizon when the termination has none.
PAPER_MAX_ITERATIONS = 100
#: Ways to treat a particle that leaves the box, see :func:`apply_bounds`.
BOUNDARY_RULES = ("reflect", "absorb", "clip")
#: Exponent of the mutation decay law (1 - t / (T p_m))^1.5 (see :meth:`MOPSO._mutate`).
MUTATION_DECAY_EXPONENT = 1.5


def constriction_coefficients(phi: float = CONSTRICTION_PHI) -> tuple[float, float, float]:
    """Constriction factor and acceleration coefficients (paper 000, text below eq. 39).

    w = 2 / (φ − 2 + √(φ² − 4φ)), c1 = w φ1, c2 = w φ2 with φ1 = φ2 = φ / 2.
    φ = 4.1 gives w = 0.7298 and c1 = c2 = 1.4962 (Table 2).

    Parameters
    ----------
    phi : float
        φ > 4.

    Returns
    -------
    w, c1, c2 : float
    """
    phi = check_in("mopso.phi", phi, Interval(4.0, math.inf, open_low=True))
    w = 2.0 / (phi - 2.0 + math.sqrt(phi * phi - 4.0 * phi))
    return w, w * phi / 2.0, w * phi / 2.0


def dominance_matrix(F: np.ndarray, CV: np.ndarray) -> np.ndarray:
    """Constrained Pareto dominance between all pairs of points.

    Feasibility first: a feasible point (CV <= 0) dominates an infeasible one; among
    infeasible points the smaller constraint violation dominates; among feasible points
    ordinary Pareto dominance (minimisation) applies.

    Parameters
    ----------
    F : ndarray, shape (n, n_obj)
        Objective values.
    CV : ndarray, shape (n,)
        Constraint violation, 0 for feasible points.

    Returns
    -------
    ndarray of bool, shape (n, n)
        Entry [i, j] is True when point i dominates point j.
    """
    F = np.asarray(F, dtype=float)
    CV = np.asarray(CV, dtype=float).reshape(-1)
    return _dominates(F[:, None, :], CV[:, None], F[None, :, :], CV[None, :])


def pairwise_dominates(Fa, CVa, Fb, CVb) -> np.ndarray:
    """Row-by-row constrained dominance: does a[i] dominate b[i]? (see :func:`dominance_matrix`)."""
    return _dominates(np.asarray(Fa, float), np.asarray(CVa, float).reshape(-1),
                      np.asarray(Fb, float), np.asarray(CVb, float).reshape(-1))


def _dominates(Fa, CVa, Fb, CVb):
    feasible_a, feasible_b = CVa <= 0.0, CVb <= 0.0
    pareto = np.all(Fa <= Fb, axis=-1) & np.any(Fa < Fb, axis=-1)
    return ((feasible_a & ~feasible_b)
            | (feasible_a & feasible_b & pareto)
            | (~feasible_a & ~feasible_b & (CVa < CVb)))


def eq37_removal_counts(occupancy, capacity: int) -> np.ndarray:
    """How many members eq. 37 removes from each grid cell of an over-full archive.

    Paper 000, eq. 37: PN = Int((|A| − Z_ar) / |A| × Grid[q, 2] + 0.5), with |A| the
    archive size before truncation, Z_ar the capacity and Grid[q, 2] the occupancy of
    cell q. The paper does not say in which order the cells are visited nor what happens
    when the rounded PN do not add up to the excess |A| − Z_ar; here:

    1. cells are visited from the most to the least crowded (ties: lower cell index
       first), and cell q loses min(PN_q, excess still to remove) members — so the
       proportional rule hits the crowded cells and never removes more than the excess;
    2. because Int(· + 0.5) rounds small shares down to 0 (e.g. one member too many in
       an archive of 101 removes nothing from any cell holding fewer than 51), any
       excess left is removed one member at a time from the currently most crowded
       cell, which is Coello 2004's rule.

    Parameters
    ----------
    occupancy : array_like of int, shape (n_cells,)
        Members per occupied cell.
    capacity : int
        Z_ar.

    Returns
    -------
    ndarray of int, shape (n_cells,)
        Members to remove from each cell; the total is max(0, |A| − Z_ar).
    """
    occupancy = np.asarray(occupancy, dtype=int)
    size = int(occupancy.sum())
    excess = size - int(capacity)
    removed = np.zeros_like(occupancy)
    if excess <= 0:
        return removed
    order = np.argsort(-occupancy, kind="stable")
    proportional = np.floor(excess / size * occupancy[order] + 0.5).astype(int)
    # cap the running total at the excess, most crowded cells first
    before = np.cumsum(proportional) - proportional
    removed[order] = np.clip(np.minimum(proportional, excess - before), 0, None)
    for _ in range(excess - int(removed.sum())):
        removed[np.argmax(occupancy - removed)] += 1
    return removed


def apply_bounds(X: np.ndarray, V: np.ndarray, xl: np.ndarray, xu: np.ndarray,
                 rule: str = "reflect") -> tuple[np.ndarray, np.ndarray]:
    """Bring positions that left the box back to its bound and adjust their velocity.

    Every rule sets an out-of-range coordinate to the bound it crossed; they differ in
    what happens to that velocity component:

    * ``"reflect"`` — its sign is reversed: paper 000 (text after eq. 39) and Coello
      2004 §IV-B. The default.
    * ``"absorb"`` — it is set to 0 ("absorbing walls", Robinson & Rahmat-Samii,
      IEEE Trans. Antennas Propag. 52(2), 2004).
    * ``"clip"`` — it is kept, so a particle pushed outwards stays on the bound (what
      pymoo's own PSO-type repair does to positions). This favours optima on the
      bounds, such as those of the ZDT problems; use it knowingly.

    Parameters
    ----------
    X, V : ndarray, shape (n, n_var)
        Positions after eq. 38 and the velocities that produced them.
    xl, xu : ndarray, shape (n_var,)
        Bounds.
    rule : {"reflect", "absorb", "clip"}

    Returns
    -------
    X, V : ndarray
        New arrays; X within [xl, xu].
    """
    outside = (X < xl) | (X > xu)
    if rule == "reflect":
        V = np.where(outside, -V, V)
    elif rule == "absorb":
        V = np.where(outside, 0.0, V)
    elif rule != "clip":
        raise ConfigError(f"mopso.boundary={rule!r} is not allowed; allowed: {', '.join(BOUNDARY_RULES)}")
    return np.clip(X, xl, xu), V


class GridArchive:
    """External archive of non-dominated solutions on an adaptive hypercube grid.

    Coello 2004 §III-B, paper 000 steps 3–5: the objective space spanned by the archive is
    divided into ``n_divisions`` intervals per objective; the grid is recomputed from the
    members' extremes whenever a member lies outside it (i.e. when a newly inserted
    solution falls outside the current bounds). Over capacity, eq. 37 removes members
    from crowded cells (:func:`eq37_removal_counts`); leaders are drawn by roulette on
    cells with fitness x / occupancy (:meth:`select_leaders`).

    Parameters
    ----------
    capacity : int
        Z_ar, the maximum number of members.
    n_divisions : int
        Grid intervals per objective (Coello 2004 uses 30).
    """

    def __init__(self, capacity: int = 100, n_divisions: int = 30):
        self.capacity = check_int("mopso.archive_size", capacity, 1)
        self.n_divisions = check_int("mopso.n_divisions", n_divisions, 1)
        self.members = Population.empty()
        self.lower: np.ndarray | None = None
        self.upper: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.members)

    @property
    def X(self) -> np.ndarray:
        return self.members.get("X")

    @property
    def F(self) -> np.ndarray:
        return self.members.get("F")

    @property
    def CV(self) -> np.ndarray:
        """Constraint violation of each member, shape (n,)."""
        return self.members.get("CV").reshape(-1)

    def update(self, candidates: Population, random_state: np.random.Generator) -> None:
        """Insert evaluated candidates (paper 000 steps 3–4).

        A candidate enters when no member and no other candidate dominates it in the
        constrained sense of :func:`dominance_matrix`; members it dominates leave. A
        candidate equal to a member in F and CV is rejected (and of equal candidates only
        the first enters) so that plateaus of a discrete objective such as FAR/MDR do
        not fill the archive with copies of one point. Then the grid is recomputed if a
        member lies outside it, and eq. 37 truncates an over-full archive.

        Parameters
        ----------
        candidates : Population
            Evaluated solutions (F and, if constrained, G/H set).
        random_state : numpy.random.Generator
            Chooses which members of a crowded cell are removed.
        """
        merged = Population.merge(self.members, candidates)
        F = merged.get("F")
        CV = merged.get("CV").reshape(-1)
        dominated = dominance_matrix(F, CV).any(axis=0)
        same = np.all(F[:, None, :] == F[None, :, :], axis=-1) & (CV[:, None] == CV[None, :])
        repeated = np.triu(same, k=1).any(axis=0)
        self.members = merged[~dominated & ~repeated]
        if self.lower is None or self._outside_grid():
            self._regrid()
        if len(self.members) > self.capacity:
            self._truncate(random_state)

    def cell_coordinates(self, F: np.ndarray | None = None) -> np.ndarray:
        """Integer grid coordinates (n, n_obj) of objective vectors (default: the members).

        Interval i of objective j is [lower_j + i h_j, lower_j + (i + 1) h_j) with
        h_j = (upper_j − lower_j) / n_divisions; the upper bound belongs to the last
        interval, and an objective with zero spread puts every point in interval 0.
        """
        F = self.F if F is None else np.asarray(F, dtype=float)
        width = (self.upper - self.lower) / self.n_divisions
        safe = np.where(width > 0, width, 1.0)
        scaled = np.where(width > 0, (F - self.lower) / safe, 0.0)
        return np.clip(np.floor(scaled), 0, self.n_divisions - 1).astype(int)

    def cells(self) -> tuple[np.ndarray, np.ndarray]:
        """Cell label of each member (0 … n_cells − 1) and the occupancy of each cell."""
        _, labels, occupancy = np.unique(self.cell_coordinates(), axis=0,
                                         return_inverse=True, return_counts=True)
        return labels.reshape(-1), occupancy

    def select_leaders(self, n: int, random_state: np.random.Generator) -> np.ndarray:
        """Indices of ``n`` leaders (gbest), one per particle (Coello 2004 §III-C).

        A cell is chosen by roulette wheel with fitness x / occupancy (x = 10), i.e.
        probability proportional to the inverse cell density (x cancels out in the
        normalisation), then a member of that cell uniformly at random.
        """
        labels, occupancy = self.cells()
        fitness = LEADER_FITNESS_NUMERATOR / occupancy
        chosen = random_state.choice(len(occupancy), size=n, p=fitness / fitness.sum())
        by_cell = np.argsort(labels, kind="stable")
        first = np.cumsum(occupancy) - occupancy
        offset = np.floor(random_state.random(n) * occupancy[chosen]).astype(int)
        return by_cell[first[chosen] + offset]

    def _outside_grid(self) -> bool:
        F = self.F
        return bool(np.any(F < self.lower) or np.any(F > self.upper))

    def _regrid(self) -> None:
        F = self.F
        self.lower, self.upper = F.min(axis=0), F.max(axis=0)

    def _truncate(self, random_state: np.random.Generator) -> None:
        labels, occupancy = self.cells()
        remove = eq37_removal_counts(occupancy, self.capacity)
        # a random rank within each cell; the lowest `remove[cell]` ranks go
        order = np.lexsort((random_state.random(len(labels)), labels))
        first = np.cumsum(occupancy) - occupancy
        rank = np.empty(len(labels), dtype=int)
        rank[order] = np.arange(len(labels)) - first[labels[order]]
        self.members = self.members[rank >= remove[labels]]


class MOPSO(Algorithm):
    """Grid-archive multi-objective PSO of Coello et al. 2004 as used by paper 000.

    Parameters
    ----------
    pop_size : int
        Number of particles N (Table 2: 100).
    archive_size : int
        Archive capacity Z_ar (Table 2: 100).
    n_divisions : int
        Grid intervals per objective (Coello 2004: 30).
    velocity : {"constriction", "inertia"}
        "constriction": paper 000 eq. 39 with Clerc's constriction factor, φ = 4.1 →
        w = 0.7298, c1 = c2 = 1.4962 (Table 2). "inertia": Coello 2004's W = 0.4,
        c1 = c2 = 1.
    w, c1, c2 : float or None
        Override the variant's inertia weight / acceleration coefficients.
    mutation_rate : float or None
        Coello's mutation rate p_m (0.5 in Coello 2004); mutation acts during the first
        p_m fraction of the run (:meth:`_mutate`). None disables it — paper 000 does not
        mention a mutation operator.
    boundary : {"reflect", "absorb", "clip"}
        What an out-of-range coordinate does to its velocity (:func:`apply_bounds`);
        "reflect" is paper 000's and Coello's rule.
    max_velocity : float or None
        If set, each velocity component is clamped to ±max_velocity × (xu − xl) before
        the move (as SMPSO does with 0.5; Eberhart & Shi 2000 recommend 1.0 together with
        constriction). Neither paper 000 nor Coello 2004 clamps: None by default.
    sampling : pymoo Sampling, optional
        Initial positions; uniform in the bounds by default (paper 000 step 1).
    **kwargs
        Passed to :class:`pymoo.core.algorithm.Algorithm` (termination, callback,
        save_history, seed, …).

    Notes
    -----
    Measured on 30-variable ZDT problems at 10,000 evaluations
    (:mod:`mosd.optim.benchmarks`): the paper's settings hardly converge (ZDT1 HV ≈ 0.01
    of 0.877). Two things limit them: c1 = c2 = 1.4962 against w = 0.7298 keeps the swarm
    spread when every particle follows a different, changing leader (smaller c or w
    converges), and reflecting particles off the bound throws them away from ZDT's
    optimum, which lies on the bound. ``boundary="clip"`` scores like SMPSO on ZDT only
    because it parks particles on that bound; on a ZDT1 whose optimum lies inside the box
    it does not help, whereas Coello's ``velocity="inertia"`` matches NSGA-II there.

    ``res.X``/``res.F`` are the final archive. The archive lives in ``self.leader_archive``
    because pymoo's base class reserves ``self.archive``. Every random draw uses
    ``self.random_state``, the Generator pymoo seeds in ``setup`` from ``seed``.
    """

    def __init__(self, pop_size: int = 100, archive_size: int = 100, n_divisions: int = 30,
                 velocity: str = "constriction", w: float | None = None,
                 c1: float | None = None, c2: float | None = None,
                 mutation_rate: float | None = 0.5, boundary: str = "reflect",
                 max_velocity: float | None = None, sampling: Sampling | None = None,
                 output=None, **kwargs):
        super().__init__(output=MultiObjectiveOutput() if output is None else output, **kwargs)
        self.pop_size = check_int("mopso.pop_size", pop_size, 1)
        self.archive_size = check_int("mopso.archive_size", archive_size, 1)
        self.n_divisions = check_int("mopso.n_divisions", n_divisions, 1)
        self.velocity = check_choice("mopso.velocity", velocity, ("constriction", "inertia"))
        default_w, default_c1, default_c2 = (constriction_coefficients() if velocity == "constriction"
                                             else COELLO_INERTIA)
        coefficient = Interval(0.0, math.inf, open_high=True)
        self.w = default_w if w is None else check_in("mopso.w", w, coefficient)
        self.c1 = default_c1 if c1 is None else check_in("mopso.c1", c1, coefficient)
        self.c2 = default_c2 if c2 is None else check_in("mopso.c2", c2, coefficient)
        self.mutation_rate = (None if mutation_rate is None else
                              check_in("mopso.mutation_rate", mutation_rate,
                                       Interval(0.0, 1.0, open_low=True)))
        self.boundary = check_choice("mopso.boundary", boundary, BOUNDARY_RULES)
        self.max_velocity = (None if max_velocity is None else
                             check_in("mopso.max_velocity", max_velocity,
                                      Interval(0.0, math.inf, open_low=True, open_high=True)))
        if sampling is not None and not isinstance(sampling, Sampling):
            raise ConfigError(f"mopso.sampling={sampling!r} is not allowed; allowed: a pymoo Sampling")
        self.sampling = FloatRandomSampling() if sampling is None else sampling

        self.leader_archive: GridArchive | None = None
        self.personal_best: Population | None = None
        self.particle_velocity: np.ndarray | None = None
        self.n_moves = 0
        self.mutation_horizon: int | None = None

    # -- pymoo lifecycle ------------------------------------------------------------------

    def _setup(self, problem, **kwargs):
        if not problem.has_bounds() or not (np.all(np.isfinite(problem.xl))
                                            and np.all(np.isfinite(problem.xu))):
            raise ConfigError("mopso: the problem needs finite bounds xl, xu; allowed: finite bounds")
        if self.mutation_rate is not None:
            self.mutation_horizon = self._planned_generations() - 1

    def _initialize_infill(self):
        return self.sampling.do(self.problem, self.pop_size, algorithm=self,
                                random_state=self.random_state)

    def _initialize_advance(self, infills=None, **kwargs):
        # paper 000 step 1: v_0 = 0 and Pbest_0 = Pop_0
        self.particle_velocity = np.zeros((len(infills), self.problem.n_var))
        self.personal_best = infills.copy()
        self.leader_archive = GridArchive(self.archive_size, self.n_divisions)
        self.leader_archive.update(infills, self.random_state)

    def _infill(self):
        """One move of the swarm, eqs. 38–39.

        Paper 000 prints eq. 38 (x_{p+1} = x_p + v_p) before eq. 39 (the new velocity);
        taken literally with v_0 = 0 the first generation would re-evaluate the initial
        swarm. As Coello 2004 and Clerc & Kennedy do, the velocity is updated first and
        the position moves by the new velocity. r1, r2 are drawn per particle and
        dimension; each particle has its own leader.
        """
        rng, archive = self.random_state, self.leader_archive
        X = self.pop.get("X")
        personal = self.personal_best.get("X")
        leaders = archive.X[archive.select_leaders(len(X), rng)]
        r1, r2 = rng.random(X.shape), rng.random(X.shape)
        velocity = (self.w * self.particle_velocity + self.c1 * r1 * (personal - X)
                    + self.c2 * r2 * (leaders - X))
        if self.max_velocity is not None:
            limit = self.max_velocity * (self.problem.xu - self.problem.xl)
            velocity = np.clip(velocity, -limit, limit)
        X_new, velocity = apply_bounds(X + velocity, velocity, self.problem.xl, self.problem.xu,
                                       self.boundary)
        if self.mutation_rate is not None:
            X_new = self._mutate(X_new, self.n_moves)
        self.particle_velocity = velocity
        self.n_moves += 1
        return Population.new("X", X_new)

    def _advance(self, infills=None, **kwargs):
        self.pop = infills
        self.leader_archive.update(infills, self.random_state)
        self._update_personal_best(infills)

    def _set_optimum(self):
        self.opt = self.leader_archive.members.copy()

    # -- components -------------------------------------------------------------------------

    def _update_personal_best(self, infills: Population) -> None:
        """pbest ← new position if it dominates pbest; keep pbest if pbest dominates it;
        otherwise a fair coin decides (Coello 2004). Dominance is feasibility-first."""
        new_F, new_CV = infills.get("F"), infills.get("CV")
        old_F, old_CV = self.personal_best.get("F"), self.personal_best.get("CV")
        new_wins = pairwise_dominates(new_F, new_CV, old_F, old_CV)
        old_wins = pairwise_dominates(old_F, old_CV, new_F, new_CV)
        coin = self.random_state.random(len(infills)) < 0.5
        replace = new_wins | (~old_wins & coin)
        self.personal_best[replace] = infills[replace]

    def _mutate(self, X: np.ndarray, move: int) -> np.ndarray:
        """Coello 2004's mutation operator (§IV-C).

        With T the number of moves in the run and t the index of this move (0-based),
        the operator is active while t < T p_m, with strength
        s = (1 − t / (T p_m))^1.5: each particle is mutated with probability s, in one
        dimension chosen at random, to a uniform value in [x − s Δ, x + s Δ] ∩ [xl, xu]
        (Δ = xu − xl). So at the start every particle is mutated over the full range, and
        both the share of mutated particles and the range shrink to 0 at t = T p_m. The
        paper gives the operator in words; the 1.5 decay exponent is that of the
        authors' C implementation. The velocity is left unchanged.
        """
        horizon = self.mutation_horizon * self.mutation_rate
        if horizon <= 0 or move >= horizon:
            return X
        strength = (1.0 - move / horizon) ** MUTATION_DECAY_EXPONENT
        rng, (xl, xu) = self.random_state, (self.problem.xl, self.problem.xu)
        n, n_var = X.shape
        hit = rng.random(n) < strength
        dim = rng.integers(n_var, size=n)
        span = strength * (xu[dim] - xl[dim])
        current = X[np.arange(n), dim]
        low, high = np.maximum(xl[dim], current - span), np.minimum(xu[dim], current + span)
        drawn = low + rng.random(n) * (high - low)
        X = X.copy()
        X[np.flatnonzero(hit), dim[hit]] = drawn[hit]
        return X

    def _planned_generations(self) -> int:
        """Generations the termination allows, for the mutation schedule.

        Looks through the termination (and nested criteria, e.g. pymoo's default) for
        ``n_gen`` and ``n_eval`` limits; an ``n_eval`` limit E counts as ⌈E / pop_size⌉
        generations; the smallest finite limit wins. A termination without such a limit
        (time, tolerance) falls back to paper 000's M = 100 iterations, with a warning.
        """
        limits, stack = [], [self.termination]
        while stack:
            criterion = stack.pop()
            if isinstance(criterion, MaximumGenerationTermination):
                limits.append(criterion.n_max_gen)
            elif isinstance(criterion, MaximumFunctionCallTermination) and criterion.n_max_evals is not None:
                limits.append(math.ceil(criterion.n_max_evals / self.pop_size))
            stack.extend(getattr(criterion, "criteria", ()))
            if getattr(criterion, "termination", None) is not None:
                stack.append(criterion.termination)
        limits = [limit for limit in limits if limit is not None and math.isfinite(limit)]
        if limits:
            return max(1, int(min(limits)))
        warnings.warn("MOPSO: the termination has no n_gen/n_eval limit; the mutation schedule "
                      f"assumes {PAPER_MAX_ITERATIONS} generations (paper 000, Table 2)", stacklevel=2)
        return PAPER_MAX_ITERATIONS
