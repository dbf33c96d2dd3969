"""Issue 33: MO-PSO from an infeasible start, and the array form of pymoo's operators the swarm uses."""
import numpy as np
import pytest
from pymoo.core.population import Population
from pymoo.operators.crossover.sbx import SBX
from pymoo.operators.mutation.pm import PolynomialMutation
from pymoo.optimize import minimize
from pymoo.problems import get_problem

from mosd.optim import MOPSO, GridArchive
from mosd.optim.archive import INFEASIBLE_SHARE
from mosd.optim.mopso import PAPER_PRESET, polynomial_mutation, sbx_children
from mosd.validation import ConfigError


def infeasible_population(F, CV):
    F = np.asarray(F, dtype=float)
    pop = Population.new(X=np.arange(len(F) * 2, dtype=float).reshape(-1, 2), F=F)
    pop.set("CV", np.asarray(CV, dtype=float).reshape(-1, 1))
    return pop


def test_while_nothing_is_feasible_the_archive_keeps_a_bounded_set_of_the_least_infeasible_points():
    rng = np.random.default_rng(0)
    F, CV = rng.random((30, 2)), 1.0 + rng.random(30)
    diverse = GridArchive(capacity=20, n_divisions=10, infeasible="diverse")
    diverse.update(infeasible_population(F, CV), rng)
    bound = int(np.ceil(INFEASIBLE_SHARE * 20))
    assert len(diverse) == bound and not diverse.feasible
    assert set(diverse.CV) == set(np.sort(CV)[:bound])  # violation first
    # leaders and parents: binary tournament on the violation, so the worst member never leads
    leaders = diverse.select_leaders(2000, rng)
    assert np.argmax(diverse.CV) not in leaders and len(np.unique(leaders)) > bound // 2
    assert np.mean(diverse.CV[leaders]) < np.mean(diverse.CV)
    # Coello's rule (the paper preset and the default before issue 33): one member, every leader
    least = GridArchive(capacity=20, n_divisions=10, infeasible="least")
    least.update(infeasible_population(F, CV), rng)
    assert len(least) == 1 and least.CV[0] == CV.min()
    # the first feasible point dominates every infeasible one: the archive switches to it
    diverse.update(infeasible_population([[0.9, 0.9], [0.5, 0.5]], [0.0, 3.0]), rng)
    assert len(diverse) == 1 and diverse.feasible and tuple(diverse.F[0]) == (0.9, 0.9)


def test_equal_violations_are_ordered_by_crowding():
    # a plateau of the violation: of the 12 points with CV 1 the archive keeps 6, the least crowded
    F = np.vstack([np.column_stack([np.linspace(0, 1, 6), np.linspace(1, 0, 6)]),  # spread out
                   0.5 + 1e-3 * np.arange(6)[:, None] * np.ones((1, 2))])          # a clump at (0.5, 0.5)
    archive = GridArchive(capacity=12, n_divisions=10, infeasible="diverse")
    archive.update(infeasible_population(F, np.ones(12)), np.random.default_rng(1))
    assert len(archive) == 6 and sum(archive.F[:, 0] >= 0.5 - 1e-9) <= 4  # at most one of the clump
    assert {0.0, 1.0} <= set(archive.F[:, 0])


def test_the_rule_is_a_validated_parameter_and_the_paper_keeps_coellos():
    assert MOPSO().infeasible == "diverse" and MOPSO.paper().infeasible == PAPER_PRESET["infeasible"] == "least"
    with pytest.raises(ConfigError, match=r"^optimizer.infeasible='some'.*allowed: diverse, least"):
        MOPSO(infeasible="some")


def test_mw1_from_an_infeasible_start_reaches_a_feasible_archive():
    """MW1 starts fully infeasible. Before issue 33 the archive held the single least infeasible point
    for 60-100 generations (every leader and both parents of every offspring); with 5,000 evaluations it
    never held a feasible point on seeds 1-3. Now the feasible archive reaches >= 10 points on each."""
    for seed in (1, 2, 3):
        sizes = []
        minimize(get_problem("mw1"), MOPSO(), ("n_eval", 5000), seed=seed,
                 callback=lambda algorithm: sizes.append(len(algorithm.leader_archive)
                                                         if algorithm.leader_archive.feasible else 0))
        assert max(sizes) >= 10, (seed, sizes)
    # the same run under Coello's rule: no feasible point in the whole run
    sizes = []
    minimize(get_problem("mw1"), MOPSO(infeasible="least"), ("n_eval", 5000), seed=1,
             callback=lambda algorithm: sizes.append(algorithm.leader_archive.feasible))
    assert not any(sizes)


def test_array_operators_are_pymoos_bit_for_bit():
    problem = get_problem("zdt1", n_var=7)
    rng = np.random.default_rng(5)
    X = rng.random((40, 7))
    parents = rng.integers(40, size=(25, 2))
    parents[:3, 1] = parents[:3, 0]  # identical parents: SBX returns the parent
    expected = SBX(prob=0.9, eta=15.0, n_offsprings=1).do(problem, Population.new("X", X), parents=parents,
                                                           random_state=np.random.default_rng(11)).get("X")
    got = sbx_children(X[parents[:, 0]], X[parents[:, 1]], problem.xl, problem.xu, np.random.default_rng(11))
    assert np.array_equal(got, expected) and np.array_equal(got[:3], X[parents[:3, 0]])
    for share, eta in ((1.0, 3.0), (0.15, 20.0)):
        expected = PolynomialMutation(prob=share, prob_var=1 / 7, eta=eta).do(
            problem, Population.new("X", X.copy()), random_state=np.random.default_rng(12)).get("X")
        got = polynomial_mutation(X, problem.xl, problem.xu, eta, share, np.random.default_rng(12))
        assert np.array_equal(got, expected)
