"""Mixed-integer problems: ``problem.is_integer`` marks variables the MOPSO keeps integral."""
import numpy as np
import pytest
from pymoo.core.problem import Problem
from pymoo.optimize import minimize

from mosd.optim import MOPSO
from mosd.optim.mopso import round_integers
from mosd.validation import ConfigError


class StepsAndSlope(Problem):
    """Two integers and a real: x0 in {0..10}, x1 in {-3..3} (bounds ±3.5), x2 in [0, 1].

    f1 = |x0 − 2| + x1² + x2,  f2 = |x0 − 5| + x1² + (1 − x2).
    On the Pareto set x1 = 0 and x0 ∈ {2, 3, 4, 5} (f1 + f2 = 4, the least possible), and
    every evaluated X is recorded to check integrality.
    """

    def __init__(self):
        super().__init__(n_var=3, n_obj=2, xl=np.array([0.0, -3.5, 0.0]), xu=np.array([10.0, 3.5, 1.0]))
        self.is_integer = np.array([True, True, False])
        self.seen = []

    def _evaluate(self, X, out, *args, **kwargs):
        self.seen.append(X.copy())
        steps = X[:, 1] ** 2
        out["F"] = np.column_stack([np.abs(X[:, 0] - 2) + steps + X[:, 2],
                                    np.abs(X[:, 0] - 5) + steps + 1 - X[:, 2]])


@pytest.mark.parametrize("make", [MOPSO, MOPSO.paper], ids=["default", "paper"])
def test_integer_positions_are_integral_in_every_evaluation_and_in_the_result(make):
    problem = StepsAndSlope()
    res = minimize(problem, make(pop_size=30, archive_size=40), ("n_gen", 40), seed=3)
    seen = np.vstack(problem.seen)
    assert len(seen) == 1200
    assert np.array_equal(seen[:, :2], np.round(seen[:, :2]))
    assert seen[:, 1].min() >= -3 and seen[:, 1].max() <= 3             # inside [ceil(xl), floor(xu)]
    assert np.array_equal(res.X[:, :2], np.round(res.X[:, :2]))
    # the real variable is not rounded: the archive spreads it over [0, 1]
    assert len(np.unique(res.X[:, 2])) > 10
    # velocities stay real
    assert not np.array_equal(res.algorithm.particle_velocity, np.round(res.algorithm.particle_velocity))


def test_the_mixed_integer_front_is_found():
    problem = StepsAndSlope()
    res = minimize(problem, MOPSO(pop_size=30, archive_size=40), ("n_gen", 40), seed=3)
    assert np.all(res.X[:, 1] == 0)
    assert set(res.X[:, 0]) <= {2.0, 3.0, 4.0, 5.0} and len(set(res.X[:, 0])) >= 3
    assert np.allclose(res.F.sum(axis=1), 4.0)
    assert res.F[:, 0].min() < 0.05 and res.F[:, 1].min() < 0.05         # both ends reached


def test_all_real_or_absent_mask_changes_nothing():
    problem = StepsAndSlope()
    problem.is_integer = np.zeros(3, dtype=bool)
    res = minimize(problem, MOPSO(pop_size=20), ("n_gen", 10), seed=1)
    assert not np.array_equal(res.X[:, 0], np.round(res.X[:, 0]))
    X = np.array([[0.4, -2.6, 0.5]])
    assert round_integers(X, None, problem.xl, problem.xu) is X
    assert round_integers(X, np.array([True, True, False]), problem.xl, problem.xu).tolist() == [[0.0, -3.0, 0.5]]


@pytest.mark.parametrize("mask, message", [
    (np.array([True, False]), "length n_var=3"),
    (np.array([1, 0, 0]), "boolean array"),
])
def test_a_malformed_mask_fails_at_setup(mask, message):
    problem = StepsAndSlope()
    problem.is_integer = mask
    with pytest.raises(ConfigError, match=message):
        MOPSO().setup(problem, termination=("n_gen", 2), seed=0)


def test_an_integer_variable_without_an_integer_in_its_bounds_fails():
    problem = StepsAndSlope()
    problem.xl, problem.xu = np.array([0.2, -3.5, 0.0]), np.array([0.8, 3.5, 1.0])
    with pytest.raises(ConfigError, match="no integer"):
        MOPSO().setup(problem, termination=("n_gen", 2), seed=0)
