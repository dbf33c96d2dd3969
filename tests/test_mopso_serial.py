"""Issue 32, the optimiser's own time per generation: the array forms that replaced pymoo's operator functions,
``Generator.choice``, ``np.unique`` and the dominance matrices, and MOPSO's array path through a generation, give
what they replaced, value for value and draw for draw."""
from __future__ import annotations

import numpy as np
import pytest
from pymoo.core.individual import Individual
from pymoo.operators.crossover.sbx import cross_sbx
from pymoo.operators.mutation.pm import mut_pm
from pymoo.operators.repair.to_bound import set_to_bounds_if_outside
from pymoo.optimize import minimize
from pymoo.problems import get_problem

from mosd.optim.archive import GridArchive, _all_objectives, _front_of_two, dominance_matrix, eq37_removal_counts
from mosd.optim.mopso import MOPSO, polynomial_steps, sbx_pairs, to_bounds


def random_box(rng, n_var):
    xl = rng.uniform(-3.0, 1.0, n_var)
    xu = xl + rng.uniform(0.0, 4.0, n_var)
    return xl, xu


@pytest.mark.parametrize("seed", range(0, 400, 7))
def test_polynomial_steps_are_pymoos_mut_pm(seed):
    rng = np.random.default_rng(seed)
    n, n_var = int(rng.integers(0, 40)), int(rng.integers(1, 6))
    xl, xu = random_box(rng, n_var)
    if seed % 2:
        xu[0] = xl[0]  # a fixed variable is never mutated
    X = rng.uniform(xl, xu, (n, n_var))
    if n:
        X[0], X[-1] = xl, xu  # on the bounds
    etas = rng.choice([3.0, 20.0, 50.0, 100.0], n)
    prob = (1.0 / n_var, 1.0)[seed % 3 == 0]
    theirs, ours = np.random.default_rng(seed + 1), np.random.default_rng(seed + 1)
    expected = mut_pm(X.copy(), xl, xu, etas, np.full(n, prob), at_least_once=False, random_state=theirs)
    assert np.array_equal(polynomial_steps(X, xl, xu, etas, prob, ours), expected)
    assert ours.random() == theirs.random()  # the same draws were made


@pytest.mark.parametrize("seed", range(0, 400, 7))
def test_sbx_pairs_are_pymoos_cross_sbx(seed):
    rng = np.random.default_rng(seed)
    n, n_var = int(rng.integers(0, 40)), int(rng.integers(1, 6))
    xl, xu = random_box(rng, n_var)
    if seed % 2:
        xu[-1] = xl[-1]
    X = rng.uniform(xl, xu, (2, n, n_var))
    if n:
        X[1, 0] = X[0, 0]  # identical parents do not cross
        X[1, :, 0] = X[0, :, 0] + 1e-15  # nor parents within 1e-14
    column = np.ones((n, 1))
    theirs, ours = np.random.default_rng(seed + 2), np.random.default_rng(seed + 2)
    expected = cross_sbx(X.copy(), xl, xu, 15.0 * column, 0.5 * column, 0.5 * column, random_state=theirs)
    assert np.array_equal(sbx_pairs(X, xl, xu, 15.0, ours), expected)
    assert ours.random() == theirs.random()


def test_to_bounds_is_pymoos_set_to_bounds_if_outside():
    rng = np.random.default_rng(4)
    xl, xu = random_box(rng, 3)
    X = rng.uniform(xl - 1.0, xu + 1.0, (50, 3))
    X[0, 0] = np.nan
    assert np.array_equal(to_bounds(X.copy(), xl, xu), set_to_bounds_if_outside(X.copy(), xl, xu), equal_nan=True)


def archive_of(F, capacity=200, n_divisions=7):
    from pymoo.core.population import Population

    F = np.asarray(F, dtype=float)
    population = Population.new(X=np.zeros((len(F), 2)), F=F)
    population.set("CV", np.zeros((len(F), 1)))
    archive = GridArchive(capacity=capacity, n_divisions=n_divisions)
    archive.update(population, np.random.default_rng(0))
    return archive


@pytest.mark.parametrize("seed", range(12))
def test_cells_and_roulette_leaders_are_np_unique_and_generator_choice(seed):
    """The cells by one stable sort are np.unique's; the roulette's draws are Generator.choice's with p."""
    rng = np.random.default_rng(seed)
    n_obj = 2 + seed % 2
    # a non-dominated set with clumps: points on a simplex-like front, some repeated cells
    F = rng.dirichlet(np.ones(n_obj), size=int(rng.integers(5, 60)))
    archive = archive_of(F, n_divisions=int(rng.integers(2, 12)))
    labels, occupancy = archive.cells()
    codes = archive.cell_coordinates()
    _, expected_labels, expected_occupancy = np.unique(codes, axis=0, return_inverse=True, return_counts=True)
    assert np.array_equal(labels, expected_labels.reshape(-1)) and np.array_equal(occupancy, expected_occupancy)
    # the code before issue 32's cut, draw for draw
    ours, theirs = np.random.default_rng(seed + 10), np.random.default_rng(seed + 10)
    leaders = archive.select_leaders(500, ours)
    fitness = 10.0 / occupancy
    chosen = theirs.choice(len(occupancy), size=500, p=fitness / fitness.sum())
    by_cell = np.argsort(labels, kind="stable")
    first = np.cumsum(occupancy) - occupancy
    offset = np.floor(theirs.random(500) * occupancy[chosen]).astype(int)
    assert np.array_equal(leaders, by_cell[first[chosen] + offset])
    assert ours.random() == theirs.random()


@pytest.mark.parametrize("seed", range(0, 3000, 11))
def test_two_objective_front_by_sorting_is_the_dominance_matrix_one(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 40))
    F = rng.integers(0, (2, 3, 5, 50)[seed % 4], (n, 2)).astype(float)  # many ties
    if seed % 3 == 0:
        F[rng.random((n, 2)) < 0.2] *= -1.0  # signed zeros
    if seed % 5 == 0:
        F[rng.random((n, 2)) < 0.1] = np.inf
    if seed % 7 == 0:
        F[rng.random((n, 2)) < 0.1] = -np.inf
    CV = np.where(rng.random(n) < 0.3, -0.0, 0.0) if seed % 2 else -rng.integers(0, 2, n).astype(float)
    same = _all_objectives(np.equal, F[:, None, :], F[None, :, :], np.logical_and) & (CV[:, None] == CV[None, :])
    expected = ~np.triu(same, k=1).any(axis=0) & ~dominance_matrix(F, CV).any(axis=0)
    assert np.array_equal(_front_of_two(F, CV), expected)


class PopulationPath(MOPSO):
    """Overrides a hook of pymoo's Population path, so MOPSO.next hands every generation to pymoo's own."""

    def infill(self):
        return super().infill()


def individuals(population):
    return [(ind.X.tolist(), ind.F.tolist(), ind.CV.tolist(), ind.G.tolist(), sorted(ind.evaluated),
             ind.get("n_gen"), ind.get("n_iter")) for ind in population]


@pytest.mark.parametrize("name, preset, n_gen, seed", [("osy", "default", 12, 1), ("zdt1", "paper", 10, 2),
                                                       ("mw1", "default", 8, 3)])
def test_the_array_path_through_a_generation_is_the_population_path(name, preset, n_gen, seed):
    """Every generation's pop, archive and history, the counts and the individuals' contents are the same whether
    MOPSO.next runs on arrays (individuals built when read) or through pymoo's Population path."""
    runs = {}
    for cls in (MOPSO, PopulationPath):
        algorithm = cls.paper(pop_size=30) if preset == "paper" else cls(pop_size=30, archive_size=40)
        seen = []
        runs[cls] = (minimize(get_problem(name), algorithm, ("n_gen", n_gen), seed=seed, save_history=True,
                              callback=lambda a: seen.append((a.n_gen, a.evaluator.n_eval, individuals(a.pop)))),
                     seen)
    (fast, fast_seen), (slow, slow_seen) = runs[MOPSO], runs[PopulationPath]
    assert fast_seen == slow_seen and len(fast_seen) == n_gen
    for ours, theirs in zip(fast.history, slow.history):
        assert individuals(ours.pop) == individuals(theirs.pop)
        assert individuals(ours.opt) == individuals(theirs.opt)
        assert np.array_equal(ours.leader_archive.F, theirs.leader_archive.F)
    assert np.array_equal(fast.algorithm.particle_velocity, slow.algorithm.particle_velocity)
    assert fast.algorithm.off is fast.algorithm.pop and all(type(ind) is Individual for ind in fast.pop)
    # the archive's members are the pop's own individuals, as on pymoo's path
    last = fast.algorithm.pop
    assert {id(ind) for ind in fast.algorithm.leader_archive.members} & {id(ind) for ind in last} == \
        {id(ind) for ind in fast.algorithm.leader_archive.members if ind.get("n_gen") == n_gen}


def one_removal_at_a_time(occupancy, capacity, tie_break=None, removable=None):
    """Eq. 37's step 2 as the loop it replaced: one Python-level pass per leftover removal."""
    occupancy = np.asarray(occupancy, dtype=int)
    removed = eq37_removal_counts(occupancy, capacity, tie_break, removable, leftover=False)
    excess = int(occupancy.sum()) - capacity
    tie = np.zeros(len(occupancy)) if tie_break is None else np.asarray(tie_break, dtype=float)
    cap = occupancy if removable is None else np.minimum(np.asarray(removable, dtype=int), occupancy)
    if cap.sum() < excess:
        cap = occupancy
    rank = np.empty(len(occupancy), dtype=int)
    rank[np.lexsort((np.arange(len(occupancy)), -tie))] = np.arange(len(occupancy))
    for _ in range(max(0, excess - int(removed.sum()))):
        crowd = np.where(removed < cap, occupancy - removed, -1)
        tied = np.flatnonzero(crowd == crowd.max())
        removed[tied[np.argmin(rank[tied])]] += 1
    return removed


@pytest.mark.parametrize("seed", range(300))
def test_eq37_leftover_is_the_one_at_a_time_walk(seed):
    rng = np.random.default_rng(seed)
    n_cells = int(rng.integers(1, 60))
    # few distinct occupancies and tie values, so that crowds and ties repeat
    occupancy = rng.integers(1, int(rng.integers(2, 12)), n_cells)
    size = int(occupancy.sum())
    capacity = int(rng.integers(0, size + 2))
    tie = None if seed % 3 == 0 else rng.integers(0, 3, n_cells).astype(float)
    removable = None if seed % 2 else rng.integers(0, 12, n_cells)
    expected = one_removal_at_a_time(occupancy, capacity, tie, removable)
    counts = eq37_removal_counts(occupancy, capacity, tie, removable)
    assert np.array_equal(counts, expected)
    assert counts.sum() == max(0, size - capacity)
