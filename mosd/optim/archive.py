"""The external archive of the grid MOPSO (paper 000 steps 3–5, eq. 37) and constrained dominance.

:class:`GridArchive` keeps the non-dominated solutions found so far on Coello 2004's
adaptive hypercube grid, truncates an over-full archive by paper 000's eq. 37
(:func:`eq37_removal_counts`) and draws leaders from sparsely populated cells.
:func:`dominance_matrix` and :func:`pairwise_dominates` are the feasibility-first
Pareto dominance the archive and the swarm's personal bests use.
:class:`mosd.optim.mopso.MOPSO` is the algorithm that feeds it.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit
from pymoo.core.population import Population

from ..validation import check_choice, check_int

#: Coello 2004's numerator x of the cell fitness x / occupancy used for leader selection.
LEADER_FITNESS_NUMERATOR = 10.0
#: Leader choice, see :meth:`GridArchive.select_leaders`.
LEADER_RULES = ("roulette", "tournament")
#: Which members of a crowded cell eq. 37 removes, see :meth:`GridArchive._truncate`.
REMOVAL_RULES = ("crowding", "random")
#: What the archive holds while nothing feasible has been found, see :meth:`GridArchive.update`.
INFEASIBLE_RULES = ("diverse", "least")
#: How the archive of a constrained problem keeps its feasible front spread, see :meth:`GridArchive.select_leaders`
#: and :meth:`GridArchive._truncate`.
CONSTRAINED_RULES = ("crowding", "grid")
#: ``constrained="crowding"``: the crowding-distance leaders and the fine mutation start once the feasible archive
#: holds this share of its capacity (docs/MOPSO.md: from the first feasible point on, OSY lost one of its
#: disconnected regions on 2 of 10 seeds; from half full, MW3 and MW7 gained nothing).
SPREAD_FILL = 1.0
#: ``infeasible="diverse"``: the least-infeasible set holds this share of the capacity. Measured on MW1
#: (docs/MOPSO.md): the whole capacity kept too little selection pressure on the violation (seeds 1–3 at
#: 3,000 evaluations: a first feasible point at generation 30, 30 and never), half reached one on all ten
#: seeds at 6,000 (generations 22–27).
INFEASIBLE_SHARE = 0.5


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


def _all_objectives(compare, Fa, Fb, combine):
    """compare(Fa[..., j], Fb[..., j]) combined over the objectives j by ``combine`` (np.logical_and / _or).

    One elementwise pass per objective: NumPy's reductions over a last axis of
    2 or 3 cost more than the comparisons themselves (this runs every generation).
    """
    result = compare(Fa[..., 0], Fb[..., 0])
    for j in range(1, Fa.shape[-1]):
        combine(result, compare(Fa[..., j], Fb[..., j]), out=result)
    return result


def _dominates(Fa, CVa, Fb, CVb):
    feasible_a, feasible_b = CVa <= 0.0, CVb <= 0.0
    pareto = (_all_objectives(np.less_equal, Fa, Fb, np.logical_and)
              & _all_objectives(np.less, Fa, Fb, np.logical_or))
    if feasible_a.all() and feasible_b.all():
        return pareto
    return ((feasible_a & ~feasible_b)
            | (feasible_a & feasible_b & pareto)
            | (~feasible_a & ~feasible_b & (CVa < CVb)))


def _first_of_equals(F: np.ndarray, CV: np.ndarray) -> np.ndarray:
    """Points that no earlier point equals in F and CV (the first of each group of equal points)."""
    same = _all_objectives(np.equal, F[:, None, :], F[None, :, :], np.logical_and) & (CV[:, None] == CV[None, :])
    return ~np.triu(same, k=1).any(axis=0)


def _front_of_two(F: np.ndarray, CV: np.ndarray) -> np.ndarray | None:
    """The members :meth:`GridArchive.update` keeps from feasible points in two objectives, by one sort.

    The same mask as ``distinct & ~dominance_matrix(F, CV).any(axis=0)`` there (a point enters unless an earlier
    point equals it in F and CV or a point dominates it), where every point is feasible, so dominance is Pareto
    dominance: after a stable sort by f1, then f2, then CV, a point is dominated exactly when a point of smaller
    f1 has an f2 no larger (the running minimum of f2 before its run of equal f1) or a point of its run has a
    smaller f2 (the run's first), and equals an earlier point exactly when it equals its predecessor in the sort.
    O(n log n) instead of the (n, n) comparisons, which on a swarm of 100 were the archive's main cost (issue 32);
    ``tests/test_mopso_serial.py`` compares the two on ties, signed zeros and infinities. None (use the matrices)
    when F holds a NaN, whose comparisons are all false.
    """
    n = len(CV)
    if n == 0 or np.isnan(F).any():
        return None
    order = np.lexsort((CV, F[:, 1], F[:, 0]))
    f1, f2, cv = F[order, 0], F[order, 1], CV[order]
    same_f1 = f1[1:] == f1[:-1]
    index = np.arange(n)
    run_start = np.maximum.accumulate(np.where(np.concatenate(([True], ~same_f1)), index, 0))
    running_min = np.minimum.accumulate(f2)
    before = running_min[np.maximum(run_start - 1, 0)]
    dominated = ((run_start > 0) & (before <= f2)) | (f2[run_start] < f2)
    repeated = np.zeros(n, dtype=bool)
    repeated[1:] = same_f1 & (f2[1:] == f2[:-1]) & (cv[1:] == cv[:-1])
    keep = np.empty(n, dtype=bool)
    keep[order] = ~(dominated | repeated)
    return keep


def eq37_removal_counts(occupancy, capacity: int, tie_break=None, removable=None,
                        leftover: bool = True) -> np.ndarray:
    """How many members eq. 37 removes from each grid cell of an over-full archive.

    Paper 000, eq. 37: PN = Int((|A| − Z_ar) / |A| × Grid[q, 2] + 0.5), with |A| the
    archive size before truncation, Z_ar the capacity and Grid[q, 2] the occupancy of
    cell q. The paper does not say in which order the cells are visited nor what happens
    when the rounded PN do not add up to the excess |A| − Z_ar; here:

    1. cells are visited from the most to the least crowded (ties: larger ``tie_break``
       first, then lower cell index), and cell q loses min(PN_q, excess still to
       remove) members — so the proportional rule hits the crowded cells and never
       removes more than the excess;
    2. because Int(· + 0.5) rounds small shares down to 0 (e.g. one member too many in
       an archive of 101 removes nothing from any cell holding fewer than 51), any
       excess left is removed one member at a time from the currently most crowded
       cell, which is Coello 2004's rule (same tie order). ``leftover=False`` skips
       this step, for a caller that breaks those ties with information that changes as
       members go (:meth:`GridArchive._truncate`).

    Parameters
    ----------
    occupancy : array_like of int, shape (n_cells,)
        Members per occupied cell.
    capacity : int
        Z_ar.
    tie_break : array_like of float, shape (n_cells,), optional
        Order among equally crowded cells, larger first; None: cell index order.
    removable : array_like of int, shape (n_cells,), optional
        At most this many members may leave each cell (protected members stay); None:
        all. Ignored if the cells cannot give up the excess together.
    leftover : bool
        Whether to apply step 2.

    Returns
    -------
    ndarray of int, shape (n_cells,)
        Members to remove from each cell; with ``leftover`` the total is
        max(0, |A| − Z_ar).
    """
    occupancy = np.asarray(occupancy, dtype=int)
    size = int(occupancy.sum())
    excess = size - int(capacity)
    removed = np.zeros_like(occupancy)
    if excess <= 0:
        return removed
    tie = np.zeros(len(occupancy)) if tie_break is None else np.asarray(tie_break, dtype=float)
    cap = occupancy if removable is None else np.minimum(np.asarray(removable, dtype=int), occupancy)
    if cap.sum() < excess:
        cap = occupancy
    order = np.lexsort((np.arange(len(occupancy)), -tie, -occupancy))
    proportional = np.minimum(np.floor(excess / size * occupancy[order] + 0.5).astype(int), cap[order])
    # cap the running total at the excess, most crowded cells first
    before = np.cumsum(proportional) - proportional
    removed[order] = np.clip(np.minimum(proportional, excess - before), 0, None)
    left = excess - int(removed.sum())
    if leftover and left > 0:
        removed += _most_crowded_first(occupancy - removed, cap - removed, tie, left)
    return removed


def _most_crowded_first(crowd, available, tie, count: int) -> np.ndarray:
    """Eq. 37's step 2 (:func:`eq37_removal_counts`): ``count`` members taken one at a time from the most crowded cell.

    Taking one member at a time from the cell with the largest ``crowd`` among those with ``available`` members
    left (ties: larger ``tie``, then lower index) takes from cell q the members at crowds crowd_q, crowd_q − 1, …:
    each cell's removals come in decreasing crowd, so the one-at-a-time walk is the first ``count`` of all
    possible removals sorted by crowd (descending), then by the tie order. Sorted once here, instead of one
    Python-level pass per removal, which cost 15 µs each and most of a truncation (issue 32);
    ``tests/test_mopso_serial.py`` compares the two.
    """
    n_cells = len(crowd)
    available = np.maximum(available, 0)
    cell = np.repeat(np.arange(n_cells), available)
    step = np.arange(len(cell)) - np.repeat(np.cumsum(available) - available, available)
    rank = np.empty(n_cells, dtype=int)
    rank[np.lexsort((np.arange(n_cells), -tie))] = np.arange(n_cells)
    taken = cell[np.lexsort((rank[cell], step - crowd[cell]))[:count]]
    return np.bincount(taken, minlength=n_cells)


def evaluated_arrays(population: Population, constrained: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """X (n, n_var), F (n, n_obj) and CV (n, 1) of an evaluated population.

    The same arrays as ``population.get("X", "F", "CV")``, read through the
    individuals' attributes: ``Population.get`` resolves every key of every
    individual through ``Individual.get``'s generic lookup, which cost more per
    generation than the whole archive update. ``constrained=False`` (a problem
    without constraints, whose CV is 0 by definition) skips reading CV.
    """
    if len(population) == 0:
        return population.get("X", "F", "CV")
    X = np.array([ind.X for ind in population])
    F = np.array([ind.F for ind in population])
    CV = np.array([ind.CV for ind in population]) if constrained else np.zeros((len(population), 1))
    return X, F, CV


class _Merged:
    """The members followed by the candidates of :meth:`GridArchive.update`, from which it keeps some.

    ``candidates`` is a Population or a generation's arrays whose individuals are built on request
    (:class:`mosd.optim.mopso.EvaluatedArrays`, anything with ``select(index) -> Population``): only the
    candidates that enter the archive are then built (issue 32).
    """

    def __init__(self, members: Population, candidates):
        self.members, self.candidates = members, candidates

    def select(self, index: np.ndarray) -> Population:
        """The members and candidates at ``index`` (ascending positions in members + candidates)."""
        n_members = len(self.members)
        split = int(np.searchsorted(index, n_members))
        if isinstance(self.candidates, Population):
            chosen = self.candidates[index[split:] - n_members]
        elif hasattr(self.candidates, "select"):
            chosen = self.candidates.select(index[split:] - n_members)
        else:  # an individual, a list of them: pymoo's merge makes a Population of them
            return Population.merge(self.members, self.candidates)[index]
        return np.concatenate((self.members[index[:split]], chosen)).view(Population)


class GridArchive:
    """External archive of non-dominated solutions on an adaptive hypercube grid.

    Coello 2004 §III-B, paper 000 steps 3–5: the objective space spanned by the archive
    is divided into ``n_divisions`` intervals per objective, so d objectives give
    hypercubes of d dimensions; the grid is recomputed from the members' extremes
    whenever a member lies outside it (i.e. when a newly inserted solution falls outside
    the current bounds). Over capacity, eq. 37 removes members from crowded cells
    (:meth:`_truncate`); leaders come from sparsely populated cells
    (:meth:`select_leaders`). Nothing here depends on d: cells are the distinct rows of
    the members' integer grid coordinates, and crowding inside and between cells is
    measured by Euclidean distances in grid-normalised objective space.

    Parameters
    ----------
    capacity : int
        Z_ar, the maximum number of members.
    n_divisions : int
        Grid intervals per objective (Coello 2004 uses 30).
    removal : {"crowding", "random"}
        Which members of a cell eq. 37 removes: see :meth:`_truncate`.
    keep_extremes : bool
        Never remove the member with the smallest value of an objective (one per
        objective) in truncation — they span the grid and the ends of the front.
    infeasible : {"diverse", "least"}
        What the archive holds while no feasible point has been found (:meth:`update`):
        "diverse", up to ⌈:data:`INFEASIBLE_SHARE` × ``capacity``⌉ of the least infeasible points,
        constraint violation first, then crowding, as NSGA-II's constrained domination ranks its population; "least"
        (Coello 2004), the constrained dominance alone, which keeps only the least infeasible
        point.
    constrained : {"grid", "crowding"}
        How a feasible archive is kept spread. "grid" (Coello 2004): leaders from sparse
        cells, eq. 37 per cell. "crowding" (what :class:`~mosd.optim.mopso.MOPSO` passes for a
        constrained problem, issue 33): once the archive is full (:data:`SPREAD_FILL`), leaders
        and parents by NSGA-II's crowding-distance binary tournament; truncation of the most
        crowded members over the whole archive.
    """

    def __init__(self, capacity: int = 100, n_divisions: int = 50, removal: str = "crowding",
                 keep_extremes: bool = True, infeasible: str = "least", constrained: str = "grid"):
        self.capacity = check_int("optimizer.archive_size", capacity, 1)
        self.n_divisions = check_int("optimizer.n_divisions", n_divisions, 1)
        self.removal = check_choice("optimizer.removal", removal, REMOVAL_RULES)
        self.keep_extremes = check_choice("optimizer.keep_extremes", keep_extremes, (True, False))
        self.infeasible = check_choice("optimizer.infeasible", infeasible, INFEASIBLE_RULES)
        self.constrained = check_choice("optimizer.constrained", constrained, CONSTRAINED_RULES)
        self.members = Population.empty()
        self._X, self._F, self._CV = np.empty((0, 0)), np.empty((0, 0)), np.empty(0)
        self.lower: np.ndarray | None = None
        self.upper: np.ndarray | None = None
        self._cells: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None
        self._roulette: np.ndarray | None = None
        self._crowding: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.members)

    @property
    def X(self) -> np.ndarray:
        return self._X

    @property
    def F(self) -> np.ndarray:
        return self._F

    @property
    def CV(self) -> np.ndarray:
        """Constraint violation of each member, shape (n,)."""
        return self._CV

    @property
    def filled(self) -> bool:
        """Whether the archive holds at least :data:`SPREAD_FILL` × ``capacity`` members."""
        return len(self._CV) >= SPREAD_FILL * self.capacity

    @property
    def feasible(self) -> bool:
        """Whether the members are feasible (all or none are: a feasible point dominates every infeasible one)."""
        return bool(len(self._CV)) and bool(self._CV[0] <= 0.0)

    def update(self, candidates: Population, random_state: np.random.Generator,
               evaluated: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None) -> None:
        """Insert evaluated candidates (paper 000 steps 3–4).

        A candidate enters when no member and no other candidate dominates it in the
        constrained sense of :func:`dominance_matrix`; members it dominates leave. A
        candidate equal to a member in F and CV is rejected (and of equal candidates only
        the first enters) so that plateaus of a discrete objective such as FAR/MDR do
        not fill the archive with copies of one point. Then the grid is recomputed if a
        member lies outside it, and eq. 37 truncates an over-full archive.

        While neither the members nor the candidates include a feasible point,
        ``infeasible="diverse"`` keeps instead a bounded set of the least infeasible distinct points
        (:meth:`_keep_least_infeasible`): under the constrained dominance alone the least
        infeasible point dominates all others, and an archive of that one point makes it
        every particle's leader and both parents of every offspring (on MW1 for 60–100
        generations, docs/MOPSO.md). The first feasible point dominates every infeasible
        one, so the archive is the feasible non-dominated set from then on.

        Parameters
        ----------
        candidates : Population
            Evaluated solutions (F and, if constrained, G/H set).
        random_state : numpy.random.Generator
            Breaks ties in truncation.
        evaluated : (X, F, CV), optional
            The candidates' arrays when the caller has them (:func:`evaluated_arrays`).
        """
        merged = _Merged(self.members, candidates)
        X, F, CV = evaluated_arrays(candidates) if evaluated is None else evaluated
        if len(self.members):
            X, F = np.concatenate([self._X, X]), np.concatenate([self._F, F])
        CV = np.concatenate([self._CV, CV.reshape(-1)])
        feasible = CV <= 0.0
        if self.infeasible == "diverse" and not feasible.any():
            self._keep_least_infeasible(merged, X, F, CV, _first_of_equals(F, CV))
            return
        keep = _front_of_two(F, CV) if F.shape[1] == 2 and feasible.all() else None
        if keep is None:
            keep = _first_of_equals(F, CV) & ~dominance_matrix(F, CV).any(axis=0)
        n_members = len(self._CV)
        if n_members and self.lower is not None and keep[:n_members].all() and not keep[n_members:].any():
            # nothing entered and nothing left: members, grid and cells stay as they are
            return
        self._set_members(merged.select(np.flatnonzero(keep)), X[keep], F[keep], CV[keep])
        if self.lower is None or self._outside_grid():
            self._regrid()
        if len(self.members) > self.capacity:
            self._truncate(random_state)

    def _keep_least_infeasible(self, merged: _Merged, X: np.ndarray, F: np.ndarray, CV: np.ndarray,
                               distinct: np.ndarray) -> None:
        """Members while nothing is feasible: the ⌈:data:`INFEASIBLE_SHARE` × capacity⌉ least infeasible points.

        Constraint violation first, as NSGA-II's constrained domination ranks an infeasible
        population; equal violations (a plateau of a discrete constraint) are ordered by
        crowding, the less crowded first: the sum of the distances to the two nearest other
        points in objective space normalised by their range. The grid follows these members,
        and leaders and parents are drawn from them by binary tournament on CV
        (:meth:`select_leaders`), so the swarm keeps a diverse, improving set of attractors
        instead of one point.
        """
        index = np.flatnonzero(distinct)
        bound = int(np.ceil(INFEASIBLE_SHARE * self.capacity))
        if len(index) > bound:
            crowding = np.zeros(len(index))
            if len(index) > 2 and len(np.unique(CV[index])) < len(index):
                span = np.ptp(F[index], axis=0)
                Z = (F[index] - F[index].min(axis=0)) / np.where(span > 0, span, 1.0)
                D = np.sqrt(((Z[:, None, :] - Z[None, :, :]) ** 2).sum(axis=-1))
                np.fill_diagonal(D, np.inf)
                crowding = np.partition(D, 1, axis=1)[:, :2].sum(axis=1)
            index = index[np.lexsort((-crowding, CV[index]))[:bound]]
            index.sort()
        self._set_members(merged.select(index), X[index], F[index], CV[index])
        self._regrid()

    def cell_coordinates(self, F: np.ndarray | None = None) -> np.ndarray:
        """Integer grid coordinates (n, n_obj) of objective vectors (default: the members).

        Interval i of objective j is [lower_j + i h_j, lower_j + (i + 1) h_j) with
        h_j = (upper_j − lower_j) / n_divisions; the upper bound belongs to the last
        interval, and an objective with zero spread puts every point in interval 0.
        """
        F = self.F if F is None else np.asarray(F, dtype=float)
        lower, upper, spread, safe = self._scale()
        scaled = np.where(spread, (F - lower) / safe, 0.0)
        # np.clip(floor, 0, n_divisions - 1) as two ufuncs (np.clip's Python wrapper costs more than the work here)
        return np.minimum(np.maximum(np.floor(scaled), 0), self.n_divisions - 1).astype(int)

    def _scale(self):
        """The grid's bounds, which objectives have a spread (h_j > 0) and h_j where it is (1 elsewhere); kept
        while ``lower`` and ``upper`` are the same arrays (they are replaced, never changed in place, by a regrid)."""
        cached = self.__dict__.get("_scale_cache")
        if cached is None or cached[0] is not self.lower or cached[1] is not self.upper:
            width = (self.upper - self.lower) / self.n_divisions
            cached = (self.lower, self.upper, width > 0, np.where(width > 0, width, 1.0))
            self.__dict__["_scale_cache"] = cached
        return cached

    def cells(self) -> tuple[np.ndarray, np.ndarray]:
        """Cell label of each member (0 … n_cells − 1) and the occupancy of each cell.

        Labels number the occupied cells in lexicographic order of their coordinates. The
        coordinates are read as the digits of one integer (base ``n_divisions``, first
        objective most significant), which orders the cells the same way: ``np.unique`` on
        integers is several times faster than on rows (``axis=0``), which remains for grids
        too large for 63 bits.
        """
        if self._cells is None:
            self._cells = self._grid_cells()
        return self._cells[:2]

    def _grid_cells(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`cells`, the members in cell order (a stable sort by label) and each cell's first position in it.

        ``np.unique(codes, return_inverse=True, return_counts=True)`` sorts the codes and marks where they
        change; so does this, once, with a stable sort that also gives the members' order by cell for
        :meth:`select_leaders` (a stable sort by label is one by code: labels number the codes in order).
        """
        coordinates = self.cell_coordinates()
        n, n_obj = coordinates.shape
        if n_obj * math.log2(max(self.n_divisions, 2)) < 62:
            codes = coordinates[:, 0].astype(np.int64)
            for j in range(1, n_obj):
                # Horner's scheme: the integer with these digits in base n_divisions, first objective most significant
                codes = codes * self.n_divisions + coordinates[:, j]
            by_cell = np.argsort(codes, kind="stable")
            ordered = codes[by_cell]
            starts = np.empty(n, dtype=bool)
            starts[:1] = True
            np.not_equal(ordered[1:], ordered[:-1], out=starts[1:])
            labels = np.empty(n, dtype=np.intp)
            labels[by_cell] = np.cumsum(starts) - 1
            first = np.flatnonzero(starts)
            ends = np.empty(len(first) + 1, dtype=np.intp)
            ends[:-1], ends[-1] = first, n
            occupancy = ends[1:] - first
        else:
            _, labels, occupancy = np.unique(coordinates, axis=0, return_inverse=True, return_counts=True)
            labels = labels.reshape(-1)
            by_cell = np.argsort(labels, kind="stable")
            first = np.cumsum(occupancy) - occupancy
        # kept until the members or the grid change (leaders are drawn twice per generation)
        return labels, occupancy, by_cell, first

    def select_leaders(self, n: int, random_state: np.random.Generator,
                       rule: str = "roulette") -> np.ndarray:
        """Indices of ``n`` leaders (gbest), one per particle (Coello 2004 §III-C).

        Both rules prefer members of sparsely populated cells, through Coello's cell
        fitness x / occupancy (x = 10):

        * ``"roulette"`` — Coello's rule: a cell by roulette wheel on that fitness, i.e.
          probability proportional to the inverse cell density (x cancels out in the
          normalisation), then a member of that cell uniformly at random;
        * ``"tournament"`` — a binary tournament, as SMPSO chooses leaders by crowding
          distance: two members uniformly at random, the one in the less crowded cell
          wins (a fair coin on equal occupancy).

        While the members are the least infeasible points (``infeasible="diverse"``, nothing
        feasible found yet) either rule becomes NSGA-II's constrained binary tournament: two
        members uniformly at random, the smaller constraint violation wins. With
        ``constrained="crowding"`` and a feasible, full archive it is NSGA-II's crowding
        tournament: two members uniformly at random, the larger crowding distance wins.
        """
        if self.infeasible == "diverse" and len(self._CV) > 1 and not self.feasible:
            # two distinct members, so the most infeasible one never wins
            size = len(self._CV)
            a = random_state.integers(size, size=n)
            b = (a + 1 + random_state.integers(size - 1, size=n)) % size
            return np.where(self._CV[a] <= self._CV[b], a, b)
        if self.constrained == "crowding" and self.filled and self.feasible:
            crowding = self.crowding_distances()
            a, b = random_state.integers(len(crowding), size=(2, n))
            return np.where(crowding[a] >= crowding[b], a, b)
        labels, occupancy = self.cells()
        if rule == "tournament":
            a, b = random_state.integers(len(labels), size=(2, n))
            first, second = occupancy[labels[a]], occupancy[labels[b]]
            coin = random_state.random(n) < 0.5
            return np.where((first < second) | ((first == second) & coin), a, b)
        _, _, by_cell, first = self._cells
        if self._roulette is None:
            fitness = LEADER_FITNESS_NUMERATOR / occupancy
            # Generator.choice(len(occupancy), size=n, p=fitness / fitness.sum())'s sampling: the normalised
            # cumulative sum searched with n uniforms (tests/test_mopso_serial.py checks the draws are choice's)
            cdf = np.cumsum(fitness / fitness.sum())
            cdf /= cdf[-1]
            self._roulette = cdf
        chosen = self._roulette.searchsorted(random_state.random(n), side="right")
        offset = np.floor(random_state.random(n) * occupancy[chosen]).astype(int)
        return by_cell[first[chosen] + offset]

    def crowding_distances(self) -> np.ndarray:
        """NSGA-II's crowding distance of each member (pymoo's ``calc_crowding_distance``; the extremes: inf)."""
        if self._crowding is None:
            # imported here: pymoo's rank_and_crowding package loads scipy.spatial and scipy.linalg (0.2-0.8 s of a
            # run's startup), and only a constrained problem's full archive needs it (issue 32)
            from pymoo.operators.survival.rank_and_crowding.metrics import calc_crowding_distance

            self._crowding = calc_crowding_distance(self._F)
        return self._crowding

    def _set_members(self, members: Population, X: np.ndarray, F: np.ndarray, CV: np.ndarray) -> None:
        # X, F and CV are kept as arrays too: Population.get walks every individual
        self.members, self._X, self._F, self._CV = members, X, F, CV
        self._cells = self._roulette = self._crowding = None

    def _outside_grid(self) -> bool:
        return bool(np.any(self._F < self.lower) or np.any(self._F > self.upper))

    def _regrid(self) -> None:
        self.lower, self.upper = self._F.min(axis=0), self._F.max(axis=0)
        self._cells = self._roulette = None

    def _truncate(self, random_state: np.random.Generator) -> None:
        """Eq. 37 down to ``capacity`` members.

        Eq. 37 (:func:`eq37_removal_counts`) says how many members each cell loses; the
        paper does not say which. ``removal="random"`` takes them at random, with
        equally crowded cells taken in cell order (the previous behaviour, kept for the
        paper preset). ``removal="crowding"``
        removes, one at a time, the member of the cell whose two nearest other members
        (grid-normalised objectives, d dimensions) are closest, and when eq. 37's
        rounding leaves an excess, takes it from the most crowded cells, the most
        crowded member first — so equally crowded cells (in three or more objectives,
        typically all cells hold one member) are told apart by distances rather than by
        their index. ``keep_extremes`` protects the per-objective minima either way.
        """
        if self.constrained == "crowding" and self.removal == "crowding":
            # one cell: the most crowded members go wherever they are on the front
            labels, occupancy = np.zeros(len(self._F), dtype=int), np.array([len(self._F)])
        else:
            labels, occupancy = self.cells()
        protected = np.zeros(len(labels), dtype=bool)
        if self.keep_extremes:
            protected[np.argmin(self._F, axis=0)] = True
        removable = np.bincount(labels[~protected], minlength=len(occupancy))
        excess = len(labels) - self.capacity
        if removable.sum() < excess:
            protected[:] = False
            removable = occupancy.copy()
        if self.removal == "random":
            remove = eq37_removal_counts(occupancy, self.capacity, removable=removable)
            # a random rank within each cell (protected members last); the lowest `remove[cell]` go
            order = np.lexsort((random_state.random(len(labels)) + 2.0 * protected, labels))
            first = np.cumsum(occupancy) - occupancy
            rank = np.empty(len(labels), dtype=int)
            rank[order] = np.arange(len(labels)) - first[labels[order]]
            keep = rank >= remove[labels]
        else:
            keep = self._remove_crowded(labels, occupancy, protected, removable, excess, random_state)
        self._set_members(self.members[keep], self._X[keep], self._F[keep], self._CV[keep])

    def _remove_crowded(self, labels, occupancy, protected, removable, excess, random_state):
        span = self.upper - self.lower
        Z = (self._F - self.lower) / np.where(span > 0, span, 1.0)
        # objective by objective, in the order a reduction over the last axis adds (same values, no (n, n, d) array)
        D = (Z[:, None, 0] - Z[None, :, 0]) ** 2
        for j in range(1, Z.shape[1]):
            D += (Z[:, None, j] - Z[None, :, j]) ** 2
        np.sqrt(D, out=D)
        # a tiny random jitter turns exact distance ties into a random order
        D += 1e-12 * random_state.random(D.shape)
        np.fill_diagonal(D, np.inf)
        alive = np.ones(len(D), dtype=bool)
        # each member's two nearest (as np.argpartition(D, 1, axis=1)[:, :2], which took most of this method's time:
        # with the jitter, distances within a row tie with probability 0, and a tie would change which index is kept,
        # never a crowding value) and their distances, summed nearest first as before
        rows = np.arange(len(D))
        nearest = D.argmin(axis=1)
        nearest_distance = D[rows, nearest]
        D[rows, nearest] = np.inf
        second = D.argmin(axis=1)
        crowding = nearest_distance + D[rows, second]
        D[rows, nearest] = nearest_distance
        # laid out as argpartition's slice was (a non-contiguous view), the layout _drop_crowded is compiled for
        neighbours = np.empty((len(D), 3), dtype=np.intp)[:, :2]
        neighbours[:, 0], neighbours[:, 1] = nearest, second
        nearest_cells = np.full(len(occupancy), np.inf)
        np.minimum.at(nearest_cells, labels[~protected], crowding[~protected])
        remove = eq37_removal_counts(occupancy, self.capacity, tie_break=-nearest_cells,
                                     removable=removable, leftover=False)
        _drop_crowded(D, crowding, neighbours, labels.astype(np.int64), protected, alive,
                      occupancy.astype(np.int64), removable.astype(np.int64), remove.astype(np.int64), int(excess))
        return alive


@njit(cache=True, nogil=True)
def _drop_crowded(D, crowding, neighbours, labels, protected, alive, left, can_go, remove, excess):  # pragma: no cover
    """The removals of :meth:`GridArchive._remove_crowded`, one member at a time, in place on ``alive``.

    First eq. 37's counts, cell by cell in index order; then the excess eq. 37's rounding
    left, from the cells with the most members left that may still lose one. Each time the
    member of the allowed cells with the smallest crowding (the first on ties, as
    ``np.argmin``) goes, its distances become infinite, and only the members that had it
    among their two nearest get a new crowding: the sum of their two smallest distances,
    smallest first (the order of the NumPy computation, so the values are the same bit for
    bit). Compiled: one Python-level iteration per removal cost half of the optimiser's own
    time per evaluation (docs/MOPSO.md, "Cost per evaluation").
    """
    n, n_cells = D.shape[0], left.shape[0]
    allowed = np.zeros(n_cells, dtype=np.bool_)
    removed = 0
    for cell in range(n_cells):
        for _ in range(remove[cell]):
            allowed[:] = False
            allowed[cell] = True
            _drop_one(D, crowding, neighbours, labels, protected, alive, left, can_go, allowed)
            removed += 1
    for _ in range(excess - removed):
        most = -1
        for cell in range(n_cells):
            crowd = left[cell] if can_go[cell] > 0 else -1
            most = max(most, crowd)
        for cell in range(n_cells):
            allowed[cell] = (left[cell] if can_go[cell] > 0 else -1) == most
        _drop_one(D, crowding, neighbours, labels, protected, alive, left, can_go, allowed)


@njit(cache=True, nogil=True)
def _drop_one(D, crowding, neighbours, labels, protected, alive, left, can_go, allowed):  # pragma: no cover
    n = D.shape[0]
    gone = -1
    for i in range(n):
        if alive[i] and not protected[i] and allowed[labels[i]]:
            if gone < 0 or crowding[i] < crowding[gone]:
                gone = i
    alive[gone] = False
    left[labels[gone]] -= 1
    can_go[labels[gone]] -= 1
    D[gone, :] = np.inf
    D[:, gone] = np.inf
    for i in range(n):
        if alive[i] and (neighbours[i, 0] == gone or neighbours[i, 1] == gone):
            first, second = -1, -1
            for j in range(n):
                if first < 0 or D[i, j] < D[i, first]:
                    second, first = first, j
                elif second < 0 or D[i, j] < D[i, second]:
                    second = j
            neighbours[i, 0], neighbours[i, 1] = first, second
            crowding[i] = D[i, first] + D[i, second]
