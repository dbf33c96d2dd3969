"""The parameter contracts of mosd.validation: intervals, their integer rounding, one-line errors."""
from __future__ import annotations

import numpy as np
import pytest

from mosd.validation import ConfigError, Interval, check_in


def test_integer_rounding_goes_to_the_nearest_integer_ties_to_even():
    L = Interval(1, 20, integer=True)
    np.testing.assert_array_equal(L.round(np.array([0.4, 1.5, 2.5, 2.6, 19.7, 25.0])), [0, 2, 2, 3, 20, 25])
    assert L.round(2.5) == 2 and L.round(3.5) == 4  # as Python's round and np.round


def test_clipped_rounding_stays_inside_the_interval_and_its_open_bounds():
    np.testing.assert_array_equal(Interval(1, 20, integer=True).round(np.array([-3.0, 0.4, 7.2, 30.0]), clip=True),
                                  [1, 1, 7, 20])
    np.testing.assert_array_equal(Interval(1, 5, open_low=True, open_high=True, integer=True)
                                  .round(np.array([0.0, 9.0]), clip=True), [2, 4])
    # one box per column: bounds broadcast against the values
    box = Interval(np.array([0.5, 2.0]), np.array([3.7, 9.0]), integer=True)
    np.testing.assert_array_equal(box.round(np.array([[0.2, 12.4], [3.9, 2.6]]), clip=True), [[1, 9], [3, 3]])


def test_a_real_interval_leaves_values_unchanged():
    x = np.array([0.25, 1.5])
    assert Interval(0.0, 1.0).round(x) is x


def test_a_rounded_value_outside_the_interval_is_refused_with_the_key_and_the_range():
    interval = Interval(1, 20, integer=True)
    with pytest.raises(ConfigError, match=r"detector.persistence=0 is out of range; allowed: integers in \[1, 20\]"):
        check_in("detector.persistence", interval.round(0.4), interval)
    with pytest.raises(ConfigError, match="out of range"):
        check_in("detector.persistence", interval.round(float("nan")), interval)
