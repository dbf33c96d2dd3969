"""Choosing one design from an archive: hand-made fronts with known answers."""
import warnings

import numpy as np
import pytest

from mosd.optim import selection
from mosd.optim.selection import (Selection, SelectionWarning, choose, knee, max_accuracy,
                                  min_mdr_far_le, select)
from mosd.validation import ConfigError

# columns: FAR, MDR
FRONT = np.array([
    [0.00, 0.60],
    [0.02, 0.20],   # accuracy 0.78
    [0.05, 0.10],   # accuracy 0.85  <- best accuracy
    [0.10, 0.07],   # accuracy 0.83
    [0.30, 0.00],
])
X = np.arange(10).reshape(5, 2).astype(float)


def test_max_accuracy_picks_the_largest_one_minus_far_minus_mdr():
    assert max_accuracy(FRONT) == 2
    assert choose(X, FRONT) == 2


def test_max_accuracy_tie_goes_to_lower_far():
    # both have accuracy 0.9 (up to rounding of 0.1 + 0.0 vs 0.05 + 0.05)
    F = np.array([[0.10, 0.00], [0.05, 0.05], [0.0, 0.5]])
    assert max_accuracy(F) == 1
    # and the order of the rows does not matter
    assert max_accuracy(F[::-1]) == 1


def test_max_accuracy_does_not_treat_a_real_difference_as_a_tie():
    F = np.array([[0.05, 0.05], [0.10, 0.0 - 1e-9 + 1e-9 - 1e-6]])  # second: accuracy 0.900001
    assert max_accuracy(F) == 1


def test_knee_of_a_convex_front_is_the_bulge():
    # on the scaled front the extremes are (0, 1) and (1, 0); (0.2, 0.2) is farthest
    # from x + y = 1 towards the origin; (0.5, 0.45) is barely below it
    F = np.array([[0.0, 1.0], [0.5, 0.45], [0.2, 0.2], [1.0, 0.0]])
    assert knee(F) == 2


def test_knee_does_not_depend_on_the_units_of_the_objectives():
    F = np.array([[0.0, 1.0], [0.5, 0.45], [0.2, 0.2], [1.0, 0.0]])
    assert knee(F * [1.0, 100.0]) == knee(F) == knee(F * [0.01, 1.0] + [0.3, 2.0])
    # a front whose FAR span is ten times smaller: the bulge is still found
    G = np.array([[0.0, 1.0], [0.01, 0.3], [0.05, 0.05], [0.1, 0.0]])
    # scaled: (0.1, 0.3) lies 0.6 below x + y = 1, (0.5, 0.05) only 0.45
    assert knee(G) == 1


def test_knee_degenerate_cases():
    assert knee(np.array([[0.3, 0.4]])) == 0
    # one design best in both objectives
    assert knee(np.array([[0.5, 0.5], [0.1, 0.1], [0.2, 0.3]])) == 1


def test_min_mdr_subject_to_far_budget():
    chosen = min_mdr_far_le(FRONT, alpha=0.05)
    assert chosen == Selection(2, "min_mdr_far_le", True)
    assert min_mdr_far_le(FRONT, alpha=0.1).index == 3
    assert min_mdr_far_le(FRONT, alpha=0.01).index == 0
    assert choose(X, FRONT, rule="min_mdr_far_le", alpha=0.3) == 4


def test_min_mdr_ties_go_to_lower_far():
    F = np.array([[0.04, 0.1], [0.01, 0.1], [0.2, 0.0]])
    assert min_mdr_far_le(F, alpha=0.05).index == 1


def test_min_mdr_far_at_exactly_alpha_counts_as_feasible():
    F = np.array([[0.1 * 3 / 6, 0.2], [0.0, 0.9]])   # 0.05000000000000001 in floating point
    assert min_mdr_far_le(F, alpha=0.05).index == 0


def test_min_mdr_without_feasible_design_falls_back_to_lowest_far_with_a_warning():
    F = np.array([[0.3, 0.1], [0.2, 0.3], [0.2, 0.2], [0.5, 0.0]])
    with pytest.warns(SelectionWarning, match="no design has FAR"):
        chosen = select(F, "min_mdr_far_le", alpha=0.05)
    assert chosen.index == 2 and not chosen.constraint_met
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert select(F, "min_mdr_far_le", alpha=0.25).constraint_met


def test_unknown_rule_lists_the_allowed_ones():
    with pytest.raises(ConfigError) as err:
        choose(X, FRONT, rule="best")
    for rule in selection.RULES:
        assert rule in str(err.value)


def test_bad_inputs_are_rejected():
    with pytest.raises(ConfigError):
        min_mdr_far_le(FRONT, alpha=1.5)
    with pytest.raises(ValueError):
        choose(X[:3], FRONT)
    with pytest.raises(ValueError):
        max_accuracy(np.array([[0.1, np.nan]]))
    with pytest.raises(ValueError):
        knee(np.zeros((3, 3)))
