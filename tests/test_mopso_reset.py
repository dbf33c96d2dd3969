"""Issue 33: on a constrained problem a share of the archive offspring gets one variable redrawn uniformly.

MW2's distance function has a second basin far from each variable's optimum; without the redraw the
default settled there on 2 of seeds 1-5 (a local front 0.04-0.1 above the true one, docs/MOPSO.md). The
share is larger (0.3) until the archive is feasible and full: the redraw then also makes the long jumps
that the fine mutation (eta 20 from the first generation) no longer makes (OSY's disconnected regions).
"""
import numpy as np
import pytest
from pymoo.indicators.igd import IGD
from pymoo.optimize import minimize
from pymoo.problems import get_problem

from mosd.optim import MOPSO
from mosd.optim.benchmarks import make_problem, normalisation
from mosd.optim.mopso import CONSTRAINED_RESET, PAPER_PRESET, uniform_reset
from mosd.validation import ConfigError


def test_uniform_reset_redraws_one_variable_of_the_requested_share_of_rows():
    rng = np.random.default_rng(3)
    X = rng.random((70, 15))
    xl, xu = np.zeros(15), np.full(15, 2.0)
    out = uniform_reset(X, xl, xu, 0.1, np.random.default_rng(8))
    changed = out != X
    assert changed.sum(axis=1).max() == 1 and changed.any(axis=1).sum() == 7  # 7 rows, one variable each
    assert np.all((out >= xl) & (out <= xu)) and not np.shares_memory(out, X)
    # values drawn over the whole range, not near the old value: some land in the upper half [1, 2]
    assert np.any(out[changed] > 1.0)
    assert np.array_equal(out, uniform_reset(X, xl, xu, 0.1, np.random.default_rng(8)))
    assert np.array_equal(uniform_reset(X, xl, xu, 0.0, np.random.default_rng(8)), X)


def test_the_share_is_a_validated_parameter_and_the_paper_has_none():
    assert MOPSO().constrained_reset == CONSTRAINED_RESET == (0.3, 0.1)
    # one share for both phases, or a pair [until the archive is feasible and full, afterwards]
    assert MOPSO(constrained_reset=0.2).constrained_reset == (0.2, 0.2)
    assert MOPSO(constrained_reset=[0.5, 0]).constrained_reset == (0.5, 0.0)
    assert MOPSO.paper().constrained_reset is None and PAPER_PRESET["constrained_reset"] is None
    for bad in (1.5, [0.3, 1.5]):
        with pytest.raises(ConfigError, match=r"^optimizer.constrained_reset=1.5.*allowed"):
            MOPSO(constrained_reset=bad)
    for bad in ([0.1], [0.1, 0.2, 0.3], [0.1, None], True):
        with pytest.raises(ConfigError, match=r"^optimizer.constrained_reset=.*allowed: a share in \[0, 1\]"):
            MOPSO(constrained_reset=bad)


def test_the_redraw_share_drops_once_the_archive_is_feasible_and_full():
    """BNH (two constraints, a continuous front): its archive fills within 2,000 evaluations."""
    algorithm, shares = MOPSO(constrained_reset=[0.3, 0.1]), []
    minimize(get_problem("bnh"), algorithm, ("n_eval", 2000), seed=4,
             callback=lambda a: shares.append((a.leader_archive.feasible and a.leader_archive.filled,
                                               a._reset_share())))
    assert {share for full, share in shares if not full} == {0.3}
    assert {share for full, share in shares if full} == {0.1}
    unconstrained = MOPSO()
    minimize(get_problem("zdt1", n_var=5), unconstrained, ("n_eval", 300), seed=1)
    assert unconstrained._reset_share() == 0.0


def test_mw2_leaves_the_local_front_it_settles_on_without_the_redraw():
    """MW2, seed 1, 10,000 evaluations: without the redraw the archive ends on a local front (IGD 0.073);
    with it the IGD is 0.009 (NSGA-II: 0.015). (Before the fine mutation acted from the first generation,
    seed 4 was the trapped one: 0.102 without the redraw, 0.023 with it.)"""
    problem, (_, _, true_front) = make_problem("mw2"), normalisation("mw2")
    igd = {}
    for share in (CONSTRAINED_RESET, None):
        result = minimize(problem, MOPSO(constrained_reset=share), ("n_eval", 10_000), seed=1)
        igd[share] = IGD(true_front)(result.F[result.CV.reshape(-1) <= 0.0])
    assert igd[CONSTRAINED_RESET] < 0.02 < 0.05 < igd[None], igd
