"""mosd.metrics.summary: the one accuracy, hypervolume and confidence interval."""
from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from mosd.metrics import Estimate, accuracy, confidence_interval, hypervolume, reference_point
from mosd.metrics.detection import detection_accuracy
from mosd.optim.selection import max_accuracy


def test_hypervolume_is_the_union_of_the_dominated_boxes_up_to_1_1():
    # two staircase points: 1.1 × 1.1 box minus what neither dominates, by hand
    F = np.array([[0.1, 0.5], [0.4, 0.2], [0.5, 0.6]])  # the third is dominated by the first two
    expected = (1.1 - 0.1) * (1.1 - 0.5) + (1.1 - 0.4) * (0.5 - 0.2)
    assert hypervolume(F) == pytest.approx(expected, rel=1e-14)
    np.testing.assert_array_equal(reference_point(3), [1.1, 1.1, 1.1])
    assert hypervolume(np.array([[0.0, 0.0, 0.0]])) == pytest.approx(1.1**3, rel=1e-14)


def test_points_beyond_the_reference_add_nothing_and_an_empty_set_has_none():
    assert hypervolume(np.array([[1.2, 0.0]])) == 0.0
    assert hypervolume(np.empty((0, 2))) == 0.0
    assert hypervolume(np.array([[0.5, 0.5], [1.2, 0.0]])) == pytest.approx(0.36, rel=1e-14)
    assert hypervolume(np.array([[0.5, 0.5]]), reference=[1.0, 1.0]) == pytest.approx(0.25, rel=1e-14)


def test_accuracy_is_one_minus_far_minus_mdr_everywhere_it_is_used():
    alarms = np.array([[0, 1, 0, 1, 1, 0], [1, 0, 0, 0, 1, 1]], bool)
    mask = np.array([False, False, False, True, True, True])
    # run 0: FAR 1/3, MDR 1/3; run 1: FAR 1/3, MDR 1/3 as well, by other points
    np.testing.assert_allclose(detection_accuracy(alarms, mask), [1 / 3, 1 / 3])
    F = np.array([[0.1, 0.3], [0.05, 0.2], [0.0, 0.4]])
    np.testing.assert_allclose(accuracy(F[:, 0], F[:, 1]), [0.6, 0.75, 0.6])
    assert max_accuracy(F) == 1 and accuracy(0.25, 0.5) == 0.25


def test_confidence_interval_is_students_t_on_the_finite_values():
    values = np.array([0.1, 0.4, 0.35, np.nan, 0.2, 0.3])
    finite = values[np.isfinite(values)]
    low, high = stats.t.interval(0.9, finite.size - 1, loc=finite.mean(), scale=stats.sem(finite))
    estimate = confidence_interval(values, level=0.9)
    assert estimate.n == 5 and estimate.mean == pytest.approx(finite.mean())
    assert estimate.half_width == pytest.approx((high - low) / 2, rel=1e-12)
    assert Estimate.of(values, 0.9) == estimate
    assert np.isnan(confidence_interval([0.3]).half_width) and confidence_interval([]).n == 0
