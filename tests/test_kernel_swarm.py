"""The compiled MOPSO move (mosd.kernels.swarm) against the NumPy move it replaces (issue 32: the optimiser's
serial step).

Same draws from the same generator (its state after the move included, compared exactly: the number and kind of
draws is integer bookkeeping, the same on every CPU) and positions within a stated tolerance, never bit for bit
(issue 50): the two moves are two code paths, and NumPy may take a SIMD ``power`` (AVX-512) where the kernel
calls the C library's ``pow``.

Tolerances, derived: a move is a few tens of flops per variable plus at most two ``pow`` calls (SBX's spread and
the polynomial mutation's, each within a few ulps on any libm or SIMD library); a position is
``x + delta * (xu - xl)`` with ``|delta| <= 1``, so its error is a few tens of ulps of the variable's range. One
move: ``ONE_MOVE`` = 64 ulps relative, and absolute 64 ulps of the range. A whole tuning chains 25 such moves
through the velocities (factors below 3 a generation in the worst case, about 1 in practice: 1.2e-14 relative was
measured on an AVX-512 EPYC after 25 generations), so ``WHOLE_RUN`` = 1e-9 of the range: five orders of magnitude
above what was measured, and far below any real change of the move (those move a position by 1e-3 of its range
or more).
"""
import numpy as np
import pytest
from pymoo.optimize import minimize
from pymoo.problems import get_problem

from mosd import kernels
from mosd.kernels import swarm
from mosd.optim import mopso
from mosd.optim.mopso import MOPSO


ULP = np.finfo(float).eps
ONE_MOVE = 64 * ULP
WHOLE_RUN = 1e-9


def _assert_same(compiled, reference, span=1.0, tolerance=ONE_MOVE):
    """Equal within ``tolerance`` relative to each value and to the variables' range ``span``."""
    assert compiled.shape == reference.shape
    np.testing.assert_allclose(compiled, reference, rtol=tolerance, atol=tolerance * float(np.max(span)))


def _swarm(rng):
    n, n_var = int(rng.integers(1, 40)), int(rng.integers(1, 6))
    xl = rng.uniform(-2.0, 0.0, n_var)
    xu = xl + rng.uniform(0.5, 3.0, n_var)
    return n, n_var, xl, xu, (lambda: xl + rng.random((n, n_var)) * (xu - xl))


@pytest.mark.parametrize("seed", range(60))
def test_the_compiled_particle_move_is_the_numpy_move(seed):
    """Velocity (eq. 39, clamped or not), SMPSO's move for the first particles, every boundary rule, the
    polynomial mutation: the NumPy code of MOPSO._particles and the kernel, from one generator state each."""
    rng = np.random.default_rng(1000 + seed)
    n, n_var, xl, xu, point = _swarm(rng)
    if seed % 7 == 0:
        xu[0] = xl[0]  # a fixed variable: never mutated
    X, personal, leaders = point(), point(), point()
    if seed % 5 == 0:
        personal[0] = X[0]
    velocity = rng.normal(0.0, 1.0, (n, n_var)) * (xu - xl)
    w, c1, c2 = rng.random(3) * 2.0
    limit = np.empty(0) if seed % 3 == 0 else 0.7 * (xu - xl)
    n_exploring = int(rng.integers(0, n + 1))
    boundary = mopso.BOUNDARY_RULES[seed % 3]
    etas, rate, mutate = rng.uniform(1.0, 30.0, n), float(rng.random()), seed % 4 != 0
    state = int(rng.integers(1 << 62))
    mine, theirs = np.random.default_rng(state), np.random.default_rng(state)

    moved, new_velocity = swarm.particle_move(X, velocity, personal, leaders, w, c1, c2, limit, n_exploring,
                                              *mopso.SMPSO_C_RANGE, mopso.SMPSO_INERTIA, mopso.SMPSO_MAX_VELOCITY,
                                              xl, xu, swarm.BOUNDARY_CODES[boundary], mutate, etas, rate,
                                              swarm.bit_source(mine))

    r1, r2 = theirs.random(X.shape), theirs.random(X.shape)
    expected = w * velocity + c1 * r1 * (personal - X) + c2 * r2 * (leaders - X)
    if limit.size:
        expected = np.clip(expected, -limit, limit)
    exploring = np.arange(n) < n_exploring
    if n_exploring:
        expected[exploring] = mopso.smpso_velocity(X[exploring], velocity[exploring], personal[exploring],
                                                   leaders[exploring], xl, xu, theirs)
    expected_X, expected_velocity = mopso.apply_bounds(X + expected, expected, xl, xu, boundary)
    if mutate:
        expected_X = mopso.polynomial_mutation(expected_X, xl, xu, etas, rate, theirs)
    _assert_same(moved, expected_X, xu - xl)
    _assert_same(new_velocity, expected_velocity, xu - xl)
    assert mine.bit_generator.state == theirs.bit_generator.state


@pytest.mark.parametrize("seed", range(60))
def test_the_compiled_offspring_are_sbx_then_polynomial_mutation(seed):
    """Crossing and copied pairs, parents within 1e-14, a fixed variable, crossover probability 0, 0.9 and 1:
    the children of mopso.sbx_children and mopso.polynomial_mutation, and the same draws (one 32-bit word per
    copied pair: the generator's spare half-word is part of its state)."""
    rng = np.random.default_rng(2000 + seed)
    n, n_var, xl, xu, point = _swarm(rng)
    if seed % 7 == 0:
        xu[-1] = xl[-1]
    first, second = point(), point()
    if seed % 6 == 0:
        second[: n // 2] = first[: n // 2]
    probability = (0.9, 0.0, 1.0)[seed % 3]
    etas = rng.uniform(1.0, 30.0, n)
    state = int(rng.integers(1 << 62))
    mine, theirs = np.random.default_rng(state), np.random.default_rng(state)
    if seed % 2:  # a spare half-word left in the bit generator by an earlier 32-bit draw
        mine.integers(2, size=1)
        theirs.integers(2, size=1)
    children = swarm.offspring(first, second, xl, xu, probability, 15.0, etas, swarm.bit_source(mine))
    expected = mopso.polynomial_mutation(mopso.sbx_children(first, second, xl, xu, theirs, probability, 15.0),
                                         xl, xu, etas, 1.0, theirs)
    _assert_same(children, expected, xu - xl)
    assert mine.bit_generator.state == theirs.bit_generator.state


@pytest.mark.parametrize("problem, settings", [
    ("zdt1", {}),
    ("zdt4", {"boundary": "reflect", "max_velocity": None}),
    ("dtlz2", {"boundary": "absorb", "mutation": None, "exploration": None}),
    ("zdt1", {"mutation": "coello", "mutation_rate": 0.5}),  # Coello's mutation: the NumPy move
    ("mw1", {}),  # constrained: the reset and refinement children stay NumPy code around the compiled part
])
def test_a_tuning_with_the_compiled_move_is_the_numpy_tuning(problem, settings):
    """Whole runs: the archive, the swarm and every generation's population are those of the NumPy move."""
    kwargs = {"n_var": 6} if problem.startswith("zdt") else {}
    if problem == "dtlz2":
        kwargs = {"n_var": 7, "n_obj": 3}
    runs = []
    for compiled in (True, False):
        algorithm = MOPSO(pop_size=30, archive_size=30, **settings)
        if compiled:
            result = minimize(get_problem(problem, **kwargs), algorithm, ("n_gen", 25), seed=3, save_history=True)
        else:
            with kernels.disabled():
                result = minimize(get_problem(problem, **kwargs), algorithm, ("n_gen", 25), seed=3,
                                  save_history=True)
        runs.append(result)
    compiled_run, numpy_run = runs
    problem = get_problem(problem, **kwargs)
    span = problem.xu - problem.xl
    for read in (lambda run: run.algorithm.leader_archive.X, lambda run: run.algorithm.pbest_X):
        _assert_same(read(compiled_run), read(numpy_run), span, WHOLE_RUN)
    F = numpy_run.algorithm.leader_archive.F
    _assert_same(compiled_run.algorithm.leader_archive.F, F, np.ptp(F, axis=0).max(initial=1.0), WHOLE_RUN)
    for a, b in zip(compiled_run.history, numpy_run.history):
        _assert_same(a.pop.get("X"), b.pop.get("X"), span, WHOLE_RUN)


def test_the_move_is_compiled_only_where_it_reproduces_the_numpy_move():
    algorithm = MOPSO(pop_size=10)
    algorithm.setup(get_problem("zdt1", n_var=3), termination=("n_gen", 10), seed=1)
    assert algorithm._compiled_move() is swarm
    with kernels.disabled():
        assert algorithm._compiled_move() is None
    assert MOPSO(pop_size=10, mutation="coello")._compiled_move() is None
    legacy = MOPSO(pop_size=10)
    legacy.random_state = np.random.RandomState(0)  # not a Generator: its draws are another algorithm's
    assert legacy._compiled_move() is None


def test_a_copy_of_a_running_swarm_draws_from_its_own_generator():
    """The kept addresses of the generator (MOPSO._bit_source) are not the copy's: a deep copy of a running
    algorithm (res.history holds such copies) moves as the original would and leaves the original's state alone."""
    import copy

    algorithm = MOPSO(pop_size=12)
    algorithm.setup(get_problem("zdt1", n_var=4), termination=("n_gen", 10), seed=5)
    for _ in range(3):
        algorithm.next()
    state = algorithm.random_state.bit_generator.state
    twin = copy.deepcopy(algorithm)
    twin.next()
    assert algorithm.random_state.bit_generator.state == state
    algorithm.next()
    np.testing.assert_array_equal(twin.pop.get("X"), algorithm.pop.get("X"))
    assert twin.random_state.bit_generator.state == algorithm.random_state.bit_generator.state
